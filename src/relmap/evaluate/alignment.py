"""Aligning an estimate to its reference before the absolute error is taken.

Umeyama's least-squares similarity (S. Umeyama, IEEE PAMI 13(4), 1991, Eqs. 34-43) between the
associated positions, the same as evo's ``geometry.umeyama_alignment`` and
``PosePath3D.align``/``align_origin``: ``se3`` (rotation and translation), ``sim3`` (and a
scale: monocular estimates), ``scale`` (the scale only), ``origin`` (the first estimated pose
moved onto the first reference pose), ``none``. ``n`` limits Umeyama to the first ``n`` pairs.

The estimate's poses become ``T' = A·T`` with ``A = (R, t)`` applied after scaling the positions
by ``s``; its covariance follows exactly, in relmap's chart: ``δt' = s R δt``, ``δφ' = R δφ``.
What alignment does to the *meaning* of a covariance: an estimator's covariance describes its
error in its own frame, about its own start; aligning by Umeyama fits the transform to the very
errors being judged, which removes part of them (6 or 7 degrees of freedom spread over the
run), so NEES after ``se3``/``sim3`` alignment is biased low — an optimistic check, best for long
runs. ``origin`` alignment keeps the errors' growth from the start, which is what a covariance
propagated from a known start describes.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from relmap.errors import ParameterError
from relmap.typing import FloatArray, Option
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3
from relmap.uncertain.gaussian import congruence
from relmap.uncertain.trajectory import Trajectory, planar_from_matrices

__all__ = ["AlignMode", "Alignment", "align", "umeyama"]


class AlignMode(Option):
    """How :func:`align` moves the estimate onto the reference (evo's ``-a``, ``-s``,
    ``--align_origin``): Umeyama's rotation and translation (``"se3"``), with scale
    (``"sim3"``), scale alone (``"scale"``), the first poses made equal (``"origin"``), or not at
    all (``"none"``)."""

    SE3 = "se3"
    SIM3 = "sim3"
    SCALE = "scale"
    ORIGIN = "origin"
    NONE = "none"


class Alignment(NamedTuple):
    """The transform applied to the estimate: ``p' = R (s p) + t``, rotations ``R·R_est``."""

    mode: AlignMode
    rotation: FloatArray  #: (3, 3)
    translation: FloatArray  #: (3,)
    scale: float

    @property
    def matrix(self) -> FloatArray:
        """The Sim(3) matrix ``[[s R, t], [0, 1]]`` (4, 4)."""
        M = np.eye(4)
        M[:3, :3] = self.scale * self.rotation
        M[:3, 3] = self.translation
        return M


def umeyama(
    x: FloatArray, y: FloatArray, *, with_scale: bool
) -> tuple[FloatArray, FloatArray, float]:
    """``(R, t, c)`` minimizing ``Σ |y_i - (c R x_i + t)|²`` for points ``x, y`` (n, m)."""
    n, m = x.shape
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    sigma_x = 1.0 / n * np.linalg.norm(xc) ** 2  # Eq. 36
    # Eq. 38; the outer products summed in order over the points (a reduction over the outer
    # axis is sequential in numpy), so that the result is evo's to the last bit
    cov = np.multiply(1.0 / n, (yc[:, :, None] * xc[:, None, :]).sum(axis=0))
    u, d, vt = np.linalg.svd(cov)
    if np.count_nonzero(d > np.finfo(d.dtype).eps) < m - 1:
        raise ParameterError(
            "the positions are degenerate (all on a point or a line): no alignment is defined"
        )
    s = np.eye(m)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:  # Eq. 43: a proper rotation
        s[m - 1, m - 1] = -1.0
    R = u @ s @ vt  # Eq. 40
    c = float(1.0 / sigma_x * np.trace(np.diag(d) @ s)) if with_scale else 1.0  # Eq. 42
    t = my - c * (R @ mx)  # Eq. 41
    return R, t, c


def align(
    est: Trajectory,
    ref: Trajectory,
    mode: AlignMode | str = AlignMode.SE3,
    *,
    n: int | None = None,
) -> tuple[Trajectory, Alignment]:
    """``est`` aligned to ``ref`` (associated pose by pose) by ``mode`` (an
    :class:`AlignMode`), and the transform used."""
    mode = AlignMode.parse(mode, "alignment")
    if len(est) != len(ref):
        raise ParameterError(
            f"align needs associated trajectories; got {len(est)} and {len(ref)} poses"
        )
    if n is not None and not 1 <= n:
        raise ParameterError(f"the number of poses to align must be >= 1; got {n}")
    Me, Mr = est.matrices, ref.matrices
    R, t, s = np.eye(3), np.zeros(3), 1.0
    if mode in (AlignMode.SE3, AlignMode.SIM3, AlignMode.SCALE):
        k = len(est) if n is None else min(n, len(est))
        R, t, s = umeyama(Me[:k, :3, 3], Mr[:k, :3, 3], with_scale=mode is not AlignMode.SE3)
        if mode is AlignMode.SCALE:
            R, t = np.eye(3), np.zeros(3)
    elif mode is AlignMode.ORIGIN:
        E0 = Me[0]
        inv = np.eye(4)
        inv[:3, :3] = E0[:3, :3].T
        inv[:3, 3] = -E0[:3, :3].T @ E0[:3, 3]
        A = Mr[0] @ inv
        R, t = A[:3, :3], A[:3, 3]
    result = Alignment(mode, R, t, s)
    if mode is AlignMode.NONE:
        return est, result
    return est.with_poses(_transformed(est, R, t, s)), result


def _transformed(est: Trajectory, R: FloatArray, t: FloatArray, s: float) -> AT | AT3:
    M = np.array(est.matrices)
    M[:, :3, 3] *= s
    A = np.eye(4)
    A[:3, :3], A[:3, 3] = R, t
    M = A @ M
    if est.is_planar:
        B = np.zeros((3, 3))
        B[:2, :2], B[2, 2] = s * R[:2, :2], 1.0
        return AT._trusted(planar_from_matrices(M), congruence(B, est.poses.cov))
    B = np.zeros((6, 6))
    B[:3, :3], B[3:, 3:] = s * R, R
    cov = congruence(B, est.poses.cov)
    return Trajectory.from_matrices(M, None, cov if est.has_cov else None).poses
