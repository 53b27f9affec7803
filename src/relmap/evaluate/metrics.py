"""Absolute and relative pose errors, and their statistics, with evo's definitions.

With ``P`` the estimated and ``Q`` the reference poses (4×4, after association and alignment),
inverses taken as ``[Rᵀ, -Rᵀt]`` (as evo does, also for a KITTI file's rounded rotations):

- APE: ``E = P⁻¹ Q``; translation error ``|p - q|``;
- RPE for a pair ``(i, j)``: ``E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)``; translation error ``|t(E)|``;
- rotation angle ``|Log R(E)|`` (rad or deg, via scipy's ``Rotation.from_matrix``, which
  is what evo uses too), rotation part ``‖R(E) - I‖_F``, full pose ``‖E - I‖_F``.

RPE pairs (evo's ``filters``): ``frames`` — consecutive ``(0, d), (d, 2d), …`` or all ``(i, i +
d)``; ``m`` — consecutive: the first pose is taken, then every pose where the path walked since the
last one taken (summed step by step) reaches ``d``, and consecutive taken poses pair; all pairs: for
each ``i`` the ``j > i`` whose path from ``i`` is nearest ``d``, kept if within ``rel_tol·d``; ``s``
(relmap's addition) — the same as ``m`` with time in place of path. Pairs are chosen on the
estimate's poses unless ``pairs_from_reference``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from relmap.errors import ParameterError
from relmap.typing import FloatArray, IntArray, Option

__all__ = [
    "STATISTICS",
    "DeltaUnit",
    "Relation",
    "ape",
    "pairs",
    "pose_errors",
    "rpe",
    "statistics",
]


class Relation(Option):
    """The error of an error pose ``E`` (evo's pose relations): the translation's length
    ``|t(E)|`` (m), the rotation angle ``|Log R(E)|`` in radians or degrees, the rotation part
    ``‖R(E) - I‖_F`` or the full pose ``‖E - I‖_F`` (no unit)."""

    TRANS = "trans"
    ANGLE_RAD = "angle_rad"
    ANGLE_DEG = "angle_deg"
    ROT = "rot"
    FULL = "full"

    @property
    def unit(self) -> str:
        """The errors' unit as printed: ``"m"``, ``"rad"``, ``"°"``, or ``""`` for a norm."""
        units = {Relation.TRANS: "m", Relation.ANGLE_RAD: "rad", Relation.ANGLE_DEG: "°"}
        return units.get(self, "")


class DeltaUnit(Option):
    """What an RPE pair distance counts (module docstring): poses (``"frames"``), metres of
    path walked (``"m"``) or seconds (``"s"``)."""

    FRAMES = "frames"
    METRES = "m"
    SECONDS = "s"


#: evo's statistics of errors, in the order :func:`statistics` gives them.
STATISTICS: tuple[str, ...] = ("rmse", "mean", "median", "std", "min", "max", "sse")


class Errors(NamedTuple):
    """Per-pose (APE) or per-pair (RPE) errors of one relation, and which poses they belong to."""

    relation: Relation
    values: FloatArray  #: (k,)
    first: IntArray  #: (k,) index of the pose (APE) or of the pair's first pose (RPE)
    second: IntArray  #: (k,) the same as ``first`` (APE) or the pair's second pose (RPE)

    def stats(self) -> dict[str, float]:
        return statistics(self.values)


def statistics(e: FloatArray) -> dict[str, float]:
    """evo's statistics of errors ``e``: rmse, mean, median, std (population), min, max, sse."""
    e = np.asarray(e, dtype=np.float64)
    if e.size == 0:
        raise ParameterError("no errors to summarize")
    sq = e * e
    return {
        "rmse": float(np.sqrt(np.mean(sq))),
        "mean": float(np.mean(e)),
        "median": float(np.median(e)),
        "std": float(np.std(e)),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "sse": float(np.sum(sq)),
    }


def _inv(M: FloatArray) -> FloatArray:
    """``[Rᵀ, -Rᵀ t]`` of (..., 4, 4) poses (the transpose, as for exact rotations)."""
    out = np.zeros_like(M)
    Rt = np.swapaxes(M[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, M[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def _relative(A: FloatArray, B: FloatArray) -> FloatArray:
    """``A⁻¹ B`` with :func:`_inv`."""
    return _inv(A) @ B


def pose_errors(E: FloatArray, relation: Relation | str) -> FloatArray:
    """The error of each error pose ``E`` (k, 4, 4) for ``relation`` (a :class:`Relation`,
    ``trans`` being the norm of E's translation)."""
    relation = Relation.parse(relation, "pose relation")
    if relation is Relation.TRANS:
        return np.linalg.norm(E[:, :3, 3], axis=1)
    if relation in (Relation.ANGLE_RAD, Relation.ANGLE_DEG):
        from scipy.spatial.transform import Rotation

        angle = Rotation.from_matrix(E[:, :3, :3]).magnitude() if len(E) else np.zeros(0)
        return np.degrees(angle) if relation is Relation.ANGLE_DEG else np.asarray(angle)
    if relation is Relation.ROT:
        return np.linalg.norm(E[:, :3, :3] - np.eye(3), axis=(1, 2))
    return np.linalg.norm(E - np.eye(4), axis=(1, 2))  # Relation.FULL


def ape(P: FloatArray, Q: FloatArray, relation: Relation | str = Relation.TRANS) -> Errors:
    """Absolute pose errors of estimated poses ``P`` against reference poses ``Q`` (n, 4, 4)."""
    relation = Relation.parse(relation, "pose relation")
    idx = np.arange(len(P))
    if relation is Relation.TRANS:
        values = np.linalg.norm(P[:, :3, 3] - Q[:, :3, 3], axis=1)
    else:
        values = pose_errors(_relative(P, Q), relation)
    return Errors(relation, values, idx, idx)


def pairs(
    M: FloatArray,
    delta: float,
    unit: DeltaUnit | str = DeltaUnit.FRAMES,
    *,
    all_pairs: bool = False,
    rel_tol: float = 0.1,
    stamps: FloatArray | None = None,
) -> tuple[IntArray, IntArray]:
    """RPE index pairs ``(i, j)`` chosen on poses ``M`` (n, 4, 4), ``delta`` apart in
    ``unit`` (a :class:`DeltaUnit`; module docstring)."""
    n = len(M)
    unit = DeltaUnit.parse(unit, "delta unit")
    if not delta > 0:
        raise ParameterError(f"delta must be > 0; got {delta}")
    if unit is DeltaUnit.FRAMES:
        if int(delta) != delta:
            raise ParameterError(f"a delta in frames must be a whole number; got {delta}")
        d = int(delta)
        if all_pairs:
            i = np.arange(max(n - d, 0))
            return i, i + d
        every = np.arange(0, n, d)
        return every[:-1], every[1:]
    if unit is DeltaUnit.METRES:
        steps = np.linalg.norm(M[1:, :3, 3] - M[:-1, :3, 3], axis=1)
    else:
        if stamps is None:
            raise ParameterError("a delta in seconds needs time stamps")
        steps = np.diff(stamps)
    if all_pairs:
        return _all_pairs(np.concatenate(([0.0], np.cumsum(steps))), delta, delta * rel_tol)
    # consecutive: the first pose, then each pose where the walked distance, summed step by
    # step since the last pose taken, reaches delta
    ids: list[int] = [0]
    walked = 0.0
    for k, step in enumerate(steps.tolist(), start=1):
        walked += step
        if walked >= delta:
            ids.append(k)
            walked = 0.0
    a = np.asarray(ids, dtype=np.intp)
    return a[:-1], a[1:]


def _all_pairs(D: FloatArray, delta: float, tol: float) -> tuple[IntArray, IntArray]:
    """For each i < n - 1 the first j > i minimizing ``|(D_j - D_i) - delta|``; kept within tol.

    D is non-decreasing, so ``(D_j - D_i) - delta`` is too (rounding is monotonic): the
    minimum is next to where it changes sign, searched in a window there, and a run of equal
    D values is represented by its first member (``np.argmin``'s choice on ties)."""
    n = len(D)
    i = np.arange(n - 1)
    k = np.searchsorted(D, D[i] + delta, side="left")
    window = np.arange(-3, 4)
    cand = np.clip(k[:, None] + window[None, :], (i + 1)[:, None], n - 1)
    cand = np.maximum(np.searchsorted(D, D[cand], side="left"), (i + 1)[:, None])
    err = np.abs((D[cand] - D[i][:, None]) - delta)
    best = np.min(err, axis=1)
    # the smallest index among the window's minima
    j = np.where(err == best[:, None], cand, n).min(axis=1)
    keep = best <= tol
    return i[keep], j[keep]


def rpe(
    P: FloatArray,
    Q: FloatArray,
    relation: Relation | str = Relation.TRANS,
    *,
    delta: float = 1,
    unit: DeltaUnit | str = DeltaUnit.FRAMES,
    all_pairs: bool = False,
    rel_tol: float = 0.1,
    pairs_from_reference: bool = False,
    stamps: FloatArray | None = None,
) -> Errors:
    """Relative pose errors of ``P`` against ``Q`` (n, 4, 4) (module docstring)."""
    relation = Relation.parse(relation, "pose relation")
    i, j = pairs(
        Q if pairs_from_reference else P,
        delta,
        unit,
        all_pairs=all_pairs,
        rel_tol=rel_tol,
        stamps=stamps,
    )
    if not len(i):
        raise ParameterError(
            f"delta = {delta} {unit} gives no pose pairs in {len(P)} poses; try a smaller delta"
        )
    E = _relative(_relative(Q[i], Q[j]), _relative(P[i], P[j]))
    return Errors(relation, pose_errors(E, relation), i, j)
