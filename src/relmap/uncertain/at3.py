"""AT3: uncertain SE(3) relative poses — the paper's ATs in six degrees of freedom, without poles.

The mean is a translation and a rotation (a homogeneous matrix ``(..., 4, 4)`` inside; quaternions
``(qx, qy, qz, qw)`` at the edges), never Euler angles. The 6×6 covariance is on
``(δx, δy, δz, δφx, δφy, δφz)``: the translation perturbation in the parent frame and a rotation
perturbation applied on the left in the parent frame, ``T' = (t + δt, Exp(δφ) R)``
(:mod:`relmap.lie.se3`). In the plane (rotation about z only) this is exactly the paper's
``(x, y, θ)`` chart, so an AT3 reduces to an AT. Its Jacobians have no singularity anywhere —
the §7 "poles" belong to Euler angles, which exist here only as a conversion
(:meth:`AT3.to_euler`, :meth:`AT3.from_euler`) that detects them.

This module holds the whole SE(3) algebra: compounding (``a @ b``), reversal (``a.reverse()``),
merging at a common pose and chains follow Eqs. (1)-(10) with the 3-D Jacobians; batch axes
broadcast like numpy; the free functions that take either kind (:func:`relmap.compound`,
:func:`relmap.reverse`, :func:`relmap.merge`, :func:`relmap.compound_chain`) are
:mod:`relmap.uncertain.algebra`'s. Batches are stored entry-major (:mod:`relmap._layout`).
Compounding and reversal run in relmap's compiled core (``relmap._core.compound3`` and
``reverse3``, ``src/core/se3.cpp``), one implementation for a single pair and for any batch: one
pass over the batch, each element's propagation on 3×3 blocks (the Jacobians' structure, a shear
and a rotation, rather than 6×6 matrix products).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from relmap import _core
from relmap._layout import compact, components_outermost
from relmap.errors import ArgumentTypeError, ParameterError, ShapeError
from relmap.lie import se3, so3
from relmap.lie.group import SE2, SE3
from relmap.lie.so3 import ROTATION_ATOL
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain import gaussian
from relmap.uncertain.gaussian import DEFAULT_RTOL
from relmap.uncertain.pose import UncertainPose, broadcast_error, check_result, overflow_error

__all__ = ["AT3", "PoleWarning", "ellipsoid"]


def _rotation(rotation: ArrayLike, *, atol: float) -> FloatArray:
    """Rotation matrices from quaternions (..., 4) or matrices (..., 3, 3), checked."""
    r = gaussian.real_array(rotation, "rotation")
    gaussian.check_finite(r, "rotation")
    if r.shape[-1:] == (4,):
        return so3.from_quaternion(r, atol=atol)
    if r.shape[-2:] != (3, 3):
        raise ShapeError(
            f"rotation must be quaternions (..., 4) or matrices (..., 3, 3); got {r.shape}"
        )
    err = np.abs(np.swapaxes(r, -1, -2) @ r - np.eye(3)).max(axis=(-2, -1))
    det = np.linalg.det(r)
    bad = (err > atol) | (det < 0)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ParameterError(
            f"rotation{list(idx) if idx else ''} is not a rotation matrix: "
            f"|RᵀR - I| = {err[idx]:.3g}, det = {det[idx]:.6g} (tolerance {atol:g})"
        )
    # project onto SO(3) (polar decomposition) so that rounding does not accumulate
    U, _, Vt = np.linalg.svd(r)
    return U @ Vt


class AT3(UncertainPose):
    """An uncertain 3-D pose of a child frame in its parent frame.

    ``AT3(translation (..., 3), rotation (..., 4) quaternion (qx, qy, qz, qw) or (..., 3, 3),
    cov (..., 6, 6) on (δt, δφ) or None for exact)``. Quaternions and rotation matrices are
    checked (unit norm, orthonormal, det 1) to ``atol`` (default
    :data:`relmap.lie.so3.ROTATION_ATOL`), then normalized; covariances like
    :class:`relmap.AT`'s.
    """

    __slots__ = ()
    group = SE3  #: the pose group (generic code reads it)
    _translation = (Ellipsis, slice(0, 3), 3)

    def __init__(
        self,
        translation: ArrayLike,
        rotation: ArrayLike,
        cov: ArrayLike | None = None,
        *,
        atol: float = ROTATION_ATOL,
        rtol: float = DEFAULT_RTOL,
    ) -> None:
        atol = gaussian.check_tolerance(atol, "atol")
        t = gaussian.real_array(translation, "translation")
        if t.ndim == 0 or t.shape[-1] != 3:
            raise ShapeError(f"translation must have shape (..., 3); got {t.shape}")
        gaussian.check_finite(t, "translation")
        R = _rotation(rotation, atol=atol)
        gaussian.broadcast("AT3 translation and rotation batch", t.shape[:-1], R.shape[:-2])
        T = se3.from_parts(t, R)
        C = (
            np.zeros((*T.shape[:-2], 6, 6))
            if cov is None
            else gaussian.validate_covariance(cov, dim=6, name="AT3 cov", rtol=rtol)
        )
        # each matrix entry stored as one contiguous block over the batch (relmap._layout):
        # the batched compound and reverse read and write them entry by entry
        T, C = components_outermost(T, 2), components_outermost(C, 2)
        try:
            batch = np.broadcast_shapes(T.shape[:-2], C.shape[:-2])
        except ValueError:
            raise ShapeError(
                f"pose batch {T.shape[:-2]} and cov batch {C.shape[:-2]} do not broadcast"
            ) from None
        self._set(T, C, batch)

    @classmethod
    def _own(cls, T: FloatArray, C: FloatArray) -> AT3:
        """Take arrays relmap just made, (..., 4, 4) and (..., 6, 6) with the same batch
        shape and referenced nowhere else: no checks, no views; they are made read-only."""
        T.flags.writeable = False
        C.flags.writeable = False
        out = object.__new__(cls)
        object.__setattr__(out, "_mean", T)
        object.__setattr__(out, "_cov", C)
        return out

    # ------------------------------------------------------------- constructors
    @classmethod
    def from_matrix(
        cls, T: ArrayLike, cov: ArrayLike | None = None, *, atol: float = ROTATION_ATOL
    ) -> AT3:
        """From homogeneous matrices (..., 4, 4)."""
        T = gaussian.real_array(T, "T")
        if T.shape[-2:] != (4, 4):
            raise ShapeError(f"T must have shape (..., 4, 4); got {T.shape}")
        return cls(T[..., :3, 3], T[..., :3, :3], cov, atol=atol)

    @classmethod
    def from_vector(
        cls, v: ArrayLike, cov: ArrayLike | None = None, *, atol: float = ROTATION_ATOL
    ) -> AT3:
        """From ``[x, y, z, qx, qy, qz, qw]`` (..., 7) (g2o, ROS, SciPy order)."""
        v = gaussian.real_array(v, "pose vectors")
        if v.shape[-1:] != (7,):
            raise ShapeError(f"pose vectors must have shape (..., 7); got {v.shape}")
        return cls(v[..., :3], v[..., 3:], cov, atol=atol)

    @classmethod
    def from_sigmas(cls, translation: ArrayLike, rotation: ArrayLike, sigmas: ArrayLike) -> AT3:
        """Independent errors ``(σx, σy, σz, σφx, σφy, σφz)`` (..., 6)."""
        return cls(translation, rotation, cls._diagonal_cov(sigmas, 6))

    @classmethod
    def from_planar(cls, at: object) -> AT3:
        """The AT3 of a planar :class:`relmap.AT` (rotation about z; z, roll, pitch exact)."""
        if not isinstance(at, UncertainPose) or at.group is not SE2:
            raise ArgumentTypeError(f"expected an AT, got {type(at).__name__}")
        x, y, th = at.mean[..., 0], at.mean[..., 1], at.mean[..., 2]
        t = np.stack([x, y, np.zeros_like(x)], axis=-1)
        R = so3.exp(np.stack([np.zeros_like(th), np.zeros_like(th), th], axis=-1))
        cov = np.zeros((*at.batch_shape, 6, 6))
        keep = np.array([0, 1, 5])
        cov[..., keep[:, None], keep[None, :]] = at.cov
        return cls._trusted(se3.from_parts(t, R), cov)

    @classmethod
    def from_euler(cls, xyz_rpy: ArrayLike, cov: ArrayLike | None = None) -> AT3:
        """From ``(x, y, z, roll, pitch, yaw)`` (..., 6), ``R = Rz(yaw) Ry(pitch) Rx(roll)``, and
        a covariance on those six numbers, mapped to relmap's chart by the first-order
        Jacobian. At pitch = ±90° the Euler covariance cannot describe every rotation error: the
        mapping is then singular, and this says so."""
        v = gaussian.real_array(xyz_rpy, "(x, y, z, roll, pitch, yaw)")
        if v.shape[-1:] != (6,):
            raise ShapeError(f"(x, y, z, roll, pitch, yaw) must have shape (..., 6); got {v.shape}")
        gaussian.check_finite(v, "(x, y, z, roll, pitch, yaw)")
        R = so3.from_euler(v[..., 3:])
        if cov is None:
            return cls._trusted(se3.from_parts(v[..., :3], R), np.zeros((*v.shape[:-1], 6, 6)))
        C = gaussian.validate_covariance(cov, dim=6, name="Euler cov")
        J = np.zeros((*v.shape[:-1], 6, 6))
        J[..., :3, :3] = np.eye(3)
        J[..., 3:, 3:] = _euler_rates(v[..., 3:])  # δφ = E(rpy) δrpy
        return cls._trusted(se3.from_parts(v[..., :3], R), gaussian.congruence(J, C))

    # ----------------------------------------------------------------- accessors
    @property
    def matrix(self) -> FloatArray:
        """(..., 4, 4) homogeneous matrices (read-only); the same as :attr:`mean`."""
        return self._mean

    @property
    def translation(self) -> FloatArray:
        """(..., 3) the child origin in the parent frame (read-only)."""
        return self._position()

    @property
    def rotation(self) -> FloatArray:
        return self._mean[..., :3, :3]

    @property
    def quaternion(self) -> FloatArray:
        """``(qx, qy, qz, qw)`` with ``qw ≥ 0``."""
        return so3.to_quaternion(self.rotation)

    @property
    def vector(self) -> FloatArray:
        """``[x, y, z, qx, qy, qz, qw]`` (..., 7): the output format of JSON and text."""
        return np.concatenate([self.translation, self.quaternion], axis=-1)

    def __repr__(self) -> str:
        if self.ndim:
            return f"AT3(batch_shape={self.batch_shape})"
        t = ", ".join(f"{v:.6g}" for v in self.translation)
        q = ", ".join(f"{v:.6g}" for v in self.quaternion)
        s = ", ".join(f"{v:.3g}" for v in self.sigmas)
        return f"AT3(t=[{t}], q=[{q}], sigmas=[{s}])"

    # ---------------------------------------------------------------- operations
    def ellipsoid(self, probability: float = 0.9) -> tuple[FloatArray, FloatArray]:
        """The position's ``probability`` confidence ellipsoid (Appendix A, N = 3): half-axes
        (..., 3) ascending and their directions (..., 3, 3) (columns), in the parent frame."""
        return ellipsoid(self._cov[..., :3, :3], probability)

    def to_euler(self) -> tuple[FloatArray, FloatArray]:
        """``(x, y, z, roll, pitch, yaw)`` (..., 6) and the covariance on them (..., 6, 6).

        The Euler covariance is ``E⁻¹ C_φ E⁻ᵀ`` with E the Euler-rate matrix: its entries grow
        like ``1/cos(pitch)`` near the pole — the singularity of §7 — and at the pole
        (gimbal lock) :class:`ParameterError` is raised rather than an infinite covariance.
        Near the pole the first order is wrong long before it is infinite: when the pitch is
        within :data:`POLE_SIGMAS` rotation σ (√ of the largest eigenvalue of the rotation
        covariance) of ±90°, roll and yaw are not separately determined by the distribution,
        and a :class:`PoleWarning` says so (the numbers are still returned).
        """
        rpy = so3.to_euler(self.rotation)
        distance = np.pi / 2 - np.abs(rpy[..., 1])
        sigma = np.sqrt(np.maximum(np.linalg.eigvalsh(self._cov[..., 3:, 3:])[..., -1], 0.0))
        near = distance < POLE_SIGMAS * sigma
        if np.any(near):
            import warnings

            k = tuple(int(i) for i in np.argwhere(near)[0]) if near.ndim else ()
            warnings.warn(
                f"Euler angles near the pole{' at batch element ' + str(k) if k else ''}: "
                f"pitch is {np.degrees(distance[k]):.3g}° from ±90° with a rotation σ of "
                f"{np.degrees(sigma[k]):.3g}° (within {POLE_SIGMAS:g}σ); the first-order roll "
                "and yaw covariance does not describe the distribution there",
                PoleWarning,
                stacklevel=2,
            )
        J = np.zeros((*self.batch_shape, 6, 6))
        J[..., :3, :3] = np.eye(3)
        J[..., 3:, 3:] = np.linalg.inv(_euler_rates(rpy))
        return np.concatenate([self.translation, rpy], -1), gaussian.congruence(J, self._cov)

    def to_body(self) -> FloatArray:
        """The covariance in GTSAM's Pose3 convention: body (right) perturbation
        ``T Exp(ξ)``, ``ξ = (ω, v)`` rotation first — ``M⁻¹ Σ M⁻ᵀ``
        (:func:`relmap.lie.se3.body_to_chart`), (..., 6, 6)."""
        Mi = np.swapaxes(se3.body_to_chart(self._mean), -1, -2)  # M is orthogonal
        return gaussian.congruence(Mi, self._cov)

    @classmethod
    def from_body(cls, T: ArrayLike, cov_body: ArrayLike, *, rtol: float = DEFAULT_RTOL) -> AT3:
        """From homogeneous poses (..., 4, 4) and covariances in GTSAM's Pose3 convention
        (body frame, rotation first; see :meth:`to_body`)."""
        T = gaussian.real_array(T, "T")
        if T.shape[-2:] != (4, 4):
            raise ShapeError(f"T must have shape (..., 4, 4); got {T.shape}")
        C = gaussian.validate_covariance(cov_body, dim=6, name="body cov", rtol=rtol)
        M = se3.body_to_chart(T)
        return cls.from_matrix(T, gaussian.congruence(M, C))

    def to_ros(self) -> FloatArray:
        """ROS ``PoseWithCovariance``'s 6×6 on ``(x, y, z, rot_x, rot_y, rot_z)``: translation in
        the parent (header) frame and rotation about the fixed parent axes — relmap's chart,
        so the covariance is returned as it is (``.reshape(..., 36)`` for the message)."""
        return np.array(self._cov)

    @classmethod
    def from_ros(cls, translation: ArrayLike, quaternion: ArrayLike, cov: ArrayLike) -> AT3:
        """From a ROS pose (position, orientation ``(x, y, z, w)``) and its covariance
        (..., 6, 6) or the message's row-major (..., 36)."""
        c = np.asarray(cov, dtype=np.float64)
        if c.shape[-1:] == (36,):
            c = c.reshape(*c.shape[:-1], 6, 6)
        return cls(translation, quaternion, c)

    # ------------------------------------------- the algebra (relmap.uncertain.algebra calls it)
    def __matmul__(self, other: AT3) -> AT3:
        """``a @ b`` is :func:`relmap.compound` ``(a, b)``: frame b's pose given in frame a,
        chained."""
        if not isinstance(other, AT3):
            return NotImplemented
        return self._compound(other, None)

    def reverse(self) -> AT3:
        """The reversed pose ``Aᴿ`` (:func:`relmap.reverse`): where A's parent frame is, seen
        from A's child frame."""
        return self._reverse(False)  # type: ignore[return-value]

    def _compound(self, other: AT3, cross_cov: FloatArray | None) -> AT3:
        """``C = J_a C_a J_aᵀ + J_b C_b J_bᵀ`` (+ the cross terms of a dependent pair), with
        ``J_a = [[I, -[R_a t_b]×], [0, I]]``, ``J_b = blkdiag(R_a, R_a)``
        (:func:`relmap.lie.se3.compose`), in the compiled core."""
        batch = self._mean.shape[:-2]
        try:
            if other._mean.shape[:-2] != batch:
                batch = np.broadcast_shapes(batch, other._mean.shape[:-2])
            if cross_cov is not None:
                batch = np.broadcast_shapes(batch, cross_cov.shape[:-2])
        except ValueError:
            shapes = [self.batch_shape, other.batch_shape]
            raise broadcast_error(
                "compound", *shapes, *([] if cross_cov is None else [cross_cov.shape[:-2]])
            ) from None
        return _compound_batched(self, other, cross_cov, batch)

    def _reverse(self, jacobians: bool) -> AT3 | tuple[AT3, FloatArray]:
        """``C' = J C Jᵀ`` with J the inverse's Jacobian (:func:`relmap.lie.se3.inverse`),
        in the compiled core; with ``jacobians`` J too."""
        out = _reverse_batched(self)
        if jacobians:
            return out, se3.inverse(self._mean, jacobians=True)[1]
        return out

    @classmethod
    def _merge(cls, ats: Sequence[AT3], atol: float) -> AT3:
        """Eqs. (8)-(10) at a common pose (:func:`_merge_at_common_pose`)."""
        return _merge_at_common_pose(ats, atol, 50)

    def _chain(self, axis: int) -> AT3:
        """Every prefix along ``axis``: compounding one step at a time, ``acc = acc @ step``,
        one batched compound per step (vectorized across the chains)."""
        batch = self.batch_shape
        if 0 in batch:  # no chains: no prefixes either
            return self
        index = (slice(None),) * axis
        out = [self[(*index, 0)]]
        for k in range(1, batch[axis]):
            out.append(out[-1]._compound(self[(*index, k)], None))
        return AT3.stack(out, axis=axis)


#: :meth:`AT3.to_euler` warns when the pitch is within this many rotation σ of ±90°
POLE_SIGMAS = 3.0


class PoleWarning(UserWarning):
    """Euler angles near their pole (pitch ±90°): roll and yaw are poorly determined and their
    first-order covariance is not to be trusted (:meth:`AT3.to_euler`)."""


def _euler_rates(rpy: FloatArray) -> FloatArray:
    """E with ``δφ = E δ(roll, pitch, yaw)`` for ``R = Rz(y) Ry(p) Rx(r)`` (left perturbation):
    the columns are the three rotation axes in the parent frame."""
    r, p, y = rpy[..., 0], rpy[..., 1], rpy[..., 2]
    cy, sy, cp, sp = np.cos(y), np.sin(y), np.cos(p), np.sin(p)
    E = np.zeros((*rpy.shape[:-1], 3, 3))
    # roll axis: Rz Ry x̂ ; pitch axis: Rz ŷ ; yaw axis: ẑ
    E[..., 0, 0], E[..., 1, 0], E[..., 2, 0] = cy * cp, sy * cp, -sp
    E[..., 0, 1], E[..., 1, 1] = -sy, cy
    E[..., 2, 2] = 1.0
    del r
    return E


def ellipsoid(cov3: ArrayLike, probability: float = 0.9) -> tuple[FloatArray, FloatArray]:
    """Half-axes (..., 3), ascending, and axis directions (..., 3, 3) of the ``probability``
    confidence ellipsoid of a 3-D Gaussian (Appendix A with N = 3)."""
    k = np.sqrt(gaussian.confidence_k2(probability, 3))
    lam, U = np.linalg.eigh(np.asarray(cov3, dtype=np.float64))
    return k * np.sqrt(np.clip(lam, 0, None)), U


# ------------------------------------------------------- compounding and reversal (the core)
# One implementation for one pair and for any batch: relmap._core's compound3 and reverse3
# (src/core/se3.cpp) take the batch entry-major, as relmap stores it (relmap._layout): every
# entry of every matrix one block over the batch, (r, c, N), any strides (a broadcast input has
# stride 0 along the batch), and return new (4, 4, N) and (6, 6, N) arrays.


def _planes(x: FloatArray, batch: tuple[int, ...], size: int) -> FloatArray:
    """``(..., r, c)`` as ``(r, c, N)``, entry-major (a view for relmap's own layout)."""
    r, c = x.shape[-2:]
    if x.shape[:-2] != batch:
        x = np.broadcast_to(x, (*batch, r, c))
    nd = x.ndim
    return x.transpose(nd - 2, nd - 1, *range(nd - 2)).reshape(r, c, size)


def _logical(p: FloatArray, batch: tuple[int, ...]) -> FloatArray:
    nb = len(batch)
    return p.reshape(*p.shape[:2], *batch).transpose(*range(2, nb + 2), 0, 1)


def _compound_batched(a: AT3, b: AT3, X: FloatArray | None, batch: tuple[int, ...]) -> AT3:
    N = math.prod(batch)
    To, Co, finite = _core.compound3(
        _planes(a._mean, batch, N),
        _planes(a._cov, batch, N),
        _planes(b._mean, batch, N),
        _planes(b._cov, batch, N),
        None if X is None else _planes(X, batch, N),
    )
    if not finite:  # the core watched its results for inf and NaN
        raise overflow_error("compound")
    return AT3._own(_logical(To, batch), _logical(Co, batch))


def _reverse_batched(a: AT3) -> AT3:
    batch = a.batch_shape
    N = math.prod(batch)
    To, Co, finite = _core.reverse3(_planes(a._mean, batch, N), _planes(a._cov, batch, N))
    if not finite:
        raise overflow_error("reverse")
    return AT3._own(_logical(To, batch), _logical(Co, batch))


def _merge_at_common_pose(ats: Sequence[AT3], atol: float, max_iterations: int) -> AT3:
    """The merge of two or more checked, independent AT3s (Eqs. 8-10), order-independent.

    The rotation chart is curved, so fusing pairwise in each AT's own chart would depend on the
    order at second order in the spread of the means. Instead every mean is expressed in the
    chart at a common pose X (``δᵢ = minus(Tᵢ, X)``), the δᵢ are fused linearly with
    :func:`relmap.uncertain.gaussian.fuse` (Joseph form, exact components allowed; the same as the
    information-weighted mean, which does not depend on the order), X moves by the result, and
    this repeats until the step is at rounding level (a fixed point symmetric in the inputs),
    at most ``max_iterations`` times. Contradictions along exactly known directions raise
    :class:`relmap.errors.InconsistentMergeError`.
    """
    # the gains depend on the covariances only: compute them once
    # (on the covariances' own batch shape: once for a covariance the batch shares)
    gains, C = [], compact(ats[0]._cov, 2)
    for b in ats[1:]:
        gains.append(gaussian.fusion(C, compact(b._cov, 2)))
        C = gains[-1].cov
    X = ats[0]._mean
    for _ in range(max_iterations):
        d = se3.minus(ats[0]._mean, X)
        for k, (b, g) in enumerate(zip(ats[1:], gains, strict=True), start=1):
            v = se3.minus(b._mean, X) - d
            gaussian.check_agreement(
                v,
                g.null,
                atol=atol,
                what=f"AT3 #{k} into the preceding ones",
                components="(δt, δφ)",
            )
            d = d + np.einsum("...ij,...j->...i", g.gain, v)
        X = se3.plus(X, d)
        scale = 1.0 + np.abs(X[..., :3, 3]).max(initial=0.0)  # translations round at ε·|t|
        if (
            np.abs(d[..., :3]).max(initial=0.0) <= 1e-13 * scale
            and np.abs(d[..., 3:]).max(initial=0.0) <= 1e-13
        ):
            break
    check_result("merge", X, C)
    return AT3._trusted(X, C)
