"""Pairing the poses of an estimate with those of a reference: by time stamp, or by index.

:func:`associate` follows evo's ``sync.associate_trajectories`` exactly, so that relmap's APE and
RPE agree with evo's: the trajectory with fewer poses (the reference when both have as many) is
walked in order, and each of its stamps takes the nearest stamp of the other (the earlier on a tie;
of equal stamps, the last) if it lies within ``max_diff`` seconds; the other trajectory's stamps are
shifted by ``offset`` first (the estimate's stamps by ``+offset``). A pose of the longer trajectory
may be taken twice. Without stamps on either side the poses pair by index and the counts must be
equal. :func:`interpolate` is relmap's alternative: the reference interpolated at the estimate's
stamps (:meth:`relmap.lie.Group.at_times`: positions linearly, rotations along the shorter
arc), for references sampled finely.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from relmap.errors import ParameterError
from relmap.lie.group import SE2, SE3
from relmap.typing import FloatArray, IntArray
from relmap.uncertain.trajectory import Trajectory

__all__ = ["Association", "associate", "interpolate"]


class Association(NamedTuple):
    """Index pairs: ``ref[i]`` goes with ``est[j]`` for ``(i, j)`` in ``zip(ref_index,
    est_index)``, in time order."""

    ref_index: IntArray
    est_index: IntArray
    ref: Trajectory  #: the reference at the pairs
    est: Trajectory  #: the estimate at the pairs


def _nearest(short: FloatArray, long: FloatArray, max_diff: float) -> tuple[IntArray, np.ndarray]:
    """For each ``short`` stamp, the nearest ``long`` stamp (``long`` non-decreasing) and whether
    it is within ``max_diff``: the stamps either side of where it would be inserted after its
    equals, the earlier one on a tie; stamps outside ``long``'s span by more than ``max_diff``
    match nothing."""
    n = len(long)
    up = np.minimum(np.searchsorted(long, short, side="right"), n - 1)
    d_up = long[up] - short
    d_lo = np.where(up > 0, short - long[np.maximum(up - 1, 0)], np.inf)
    take_up = (d_up <= max_diff) & (d_up < d_lo)
    take_lo = ~take_up & (d_lo <= max_diff) & (d_lo <= d_up)
    inside = (short >= long[0] - max_diff) & (short <= long[-1] + max_diff)
    return np.where(take_up, up, up - 1), inside & (take_up | take_lo)


def associate(
    ref: Trajectory, est: Trajectory, *, max_diff: float = 0.01, offset: float = 0.0
) -> Association:
    """Pair ``est`` with ``ref`` by stamps within ``max_diff`` s after shifting ``est`` by
    ``offset`` s (module docstring); by index when either has no stamps."""
    if not max_diff >= 0:
        raise ParameterError(f"max_diff must be >= 0 s; got {max_diff}")
    if ref.stamps is None or est.stamps is None:
        if len(ref) != len(est):
            raise ParameterError(
                f"{_name(ref, 'reference')} has {len(ref)} poses and {_name(est, 'estimate')} "
                f"{len(est)}; without time stamps on both they pair by index and must be as many"
            )
        i = np.arange(len(ref))
        return Association(i, i, ref, est)
    est_longer = len(est) > len(ref)
    if est_longer:
        short, long = ref.stamps, est.stamps + offset
    else:
        short, long = est.stamps, ref.stamps + (-offset)
    k, matched = _nearest(short, long, max_diff)
    ok = np.flatnonzero(matched)
    if not ok.size:
        raise ParameterError(
            f"no time stamps of {_name(est, 'the estimate')} "
            f"[{est.stamps[0]:.9g}, {est.stamps[-1]:.9g}] s match {_name(ref, 'the reference')} "
            f"[{ref.stamps[0]:.9g}, {ref.stamps[-1]:.9g}] s within {max_diff:g} s "
            f"(offset {offset:g} s)"
        )
    i_short, i_long = ok, k[ok]
    ri, ei = (i_short, i_long) if est_longer else (i_long, i_short)
    return Association(ri, ei, ref.select(ri), est.select(ei))


def interpolate(ref: Trajectory, est: Trajectory, *, offset: float = 0.0) -> Association:
    """The reference interpolated at the estimate's stamps (shifted by ``offset``) that lie in
    its span; ``ref_index`` holds the index of the record before each stamp."""
    if ref.stamps is None or est.stamps is None:
        raise ParameterError("interpolation needs time stamps on both trajectories")
    t = est.stamps + offset
    inside = np.flatnonzero((t >= ref.stamps[0]) & (t <= ref.stamps[-1]))
    if not inside.size:
        raise ParameterError(
            f"no time stamp of {_name(est, 'the estimate')} lies in the span of "
            f"{_name(ref, 'the reference')} [{ref.stamps[0]:.9g}, {ref.stamps[-1]:.9g}] s"
        )
    q = t[inside]
    if ref.is_planar:
        x = SE2.at_times(ref.stamps, ref.poses.mean, q)
        at = Trajectory.planar(x, est.stamps[inside], frame=ref.frame, child=ref.child)
        before = np.clip(np.searchsorted(ref.stamps, q, side="right") - 1, 0, len(ref) - 1)
        return Association(before, inside, at, est.select(inside))
    i = np.clip(np.searchsorted(ref.stamps, q, side="right") - 1, 0, max(len(ref) - 2, 0))
    at = Trajectory.from_matrices(SE3.at_times(ref.stamps, ref.matrices, q), est.stamps[inside])
    return Association(i, inside, at, est.select(inside))


def _name(traj: Trajectory, default: str) -> str:
    return traj.source or default
