"""AT3: uncertain SE(3) relative poses — the paper's ATs in six degrees of freedom, without poles.

The mean is a translation and a rotation (a homogeneous matrix ``(..., 4, 4)`` inside; quaternions
``(qx, qy, qz, qw)`` at the edges), never Euler angles. The 6×6 covariance is on
``(δx, δy, δz, δφx, δφy, δφz)``: the translation perturbation in the parent frame and a rotation
perturbation applied on the left in the parent frame, ``T' = (t + δt, Exp(δφ) R)``
(:mod:`relmap.lie.se3`). In the plane (rotation about z only) this is exactly the paper's
``(x, y, θ)`` chart, so an AT3 reduces to an AT. Its Jacobians have no singularity anywhere —
the §7 "poles" belong to Euler angles, which exist here only as a conversion
(:meth:`AT3.to_euler`, :meth:`AT3.from_euler`) that detects them.

Compounding, reversal and merging follow Eqs. (1)-(10) with the 3-D Jacobians; batch axes
broadcast like numpy. Batches are stored entry-major (:mod:`relmap._layout`). What runs:

- for batches of :data:`relmap._numba.LARGE` elements or more, with numba
  (:func:`relmap._numba.enabled`), compound (with or without ``cross_cov``), reverse and
  :func:`compound_chain3` run fused kernels (:mod:`relmap._at3_kernels`): one pass over the
  batch, the propagation in registers, vectorized across the batch. Kernels compile on first
  use (seconds, once per machine; numba's disk cache after) and the first call in a process
  pays numba's import and the cache load (about 1 s);
- otherwise (smaller batches, a single pair, ``RELMAP_NUMBA=0``, no numba) the numpy kernels
  below: batched compounding and
  reversal on 3×3 blocks of a chunk of the batch at a time, the Jacobians' structure (a shear
  and a rotation) written out rather than 6×6 matrix products; a single pair a path of a few
  numpy calls.

Both give the same values to rounding (the batched kernels bitwise, in the cases tested).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import Literal, overload

import numpy as np

from relmap import _numba, gaussian
from relmap._layout import components_outermost, read_only
from relmap.errors import ArgumentTypeError, NumericalError, ParameterError, ShapeError
from relmap.gaussian import DEFAULT_RTOL
from relmap.lie import SE3, se3, so3
from relmap.lie.so3 import ROTATION_ATOL
from relmap.typing import ArrayLike, FloatArray, SeedLike

__all__ = ["AT3", "compound3", "compound_chain3", "ellipsoid", "merge3", "reverse3"]


def _finite(what: str, *arrays: FloatArray) -> None:
    """Raise :class:`NumericalError` if relmap's own arithmetic overflowed (inf or NaN): only
    possible for inputs near the floating-point range (e.g. translations of 1e300 m, whose
    squares in the covariance overflow). The one check on the paths of relmap's results."""
    for arr in arrays:
        # a sum is the cheapest test (NaN and inf propagate through it); only when it is not
        # finite are the entries tested, since a sum of huge finite entries can overflow too
        total = sum(arr.ravel().tolist()) if arr.size <= 64 else np.add.reduce(arr, axis=None)
        if not math.isfinite(total) and not np.isfinite(arr).all():
            raise NumericalError(
                f"{what} overflowed the floating-point range (inputs too large): the result "
                "would hold inf or NaN"
            )


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


class AT3:
    """An uncertain 3-D pose of a child frame in its parent frame.

    ``AT3(translation (..., 3), rotation (..., 4) quaternion (qx, qy, qz, qw) or (..., 3, 3),
    cov (..., 6, 6) on (δt, δφ) or None for exact)``. Quaternions and rotation matrices are
    checked (unit norm, orthonormal, det 1) to ``atol`` (default
    :data:`relmap.lie.so3.ROTATION_ATOL`), then normalized; covariances like
    :class:`relmap.AT`'s.
    """

    __slots__ = ("_cov", "_mean")
    group = SE3  #: the pose group (generic code reads it)
    _mean: FloatArray
    _cov: FloatArray
    __array_ufunc__ = None

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
        T = se3.from_parts(t, _rotation(rotation, atol=atol))
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

    def _set(self, T: FloatArray, C: FloatArray, batch: tuple[int, ...]) -> None:
        # read-only views: the arrays cannot be modified through the AT3
        object.__setattr__(self, "_mean", read_only(T, (*batch, 4, 4)))
        object.__setattr__(self, "_cov", read_only(C, (*batch, 6, 6)))

    @classmethod
    def _trusted(cls, T: FloatArray, C: FloatArray) -> AT3:
        """Build from arrays relmap computed itself (already valid): no checks."""
        out = object.__new__(cls)
        batch = T.shape[:-2]
        if C.shape[:-2] != batch:
            batch = np.broadcast_shapes(batch, C.shape[:-2])
        out._set(T, C, batch)
        return out

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

    def __reduce__(self) -> tuple[object, ...]:
        """Pickle as the two arrays (values travel to Dask workers, ``relmap.distributed``)."""
        return (type(self)._trusted, (np.array(self._mean), np.array(self._cov)))

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError("AT3 is immutable; operations return new ATs")

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
        s = gaussian.real_array(sigmas, "sigmas")
        if s.shape[-1:] != (6,):
            raise ShapeError(f"sigmas must have shape (..., 6); got {s.shape}")
        gaussian.check_finite(s, "sigmas")
        if (s < 0).any():
            raise ParameterError(f"standard deviations must be non-negative; got {s.min()}")
        cov = np.zeros((*s.shape, 6))
        idx = np.arange(6)
        cov[..., idx, idx] = s * s
        return cls(translation, rotation, cov)

    @classmethod
    def from_planar(cls, at: object) -> AT3:
        """The AT3 of a planar :class:`relmap.AT` (rotation about z; z, roll, pitch exact)."""
        from relmap.at import AT

        if not isinstance(at, AT):
            raise ArgumentTypeError(f"expected an AT, got {type(at).__name__}")
        x, y, th = at.mean[..., 0], at.mean[..., 1], at.mean[..., 2]
        t = np.stack([x, y, np.zeros_like(x)], axis=-1)
        R = so3.exp(np.stack([np.zeros_like(th), np.zeros_like(th), th], axis=-1))
        cov = np.zeros((*at.batch_shape, 6, 6))
        keep = np.array([0, 1, 5])
        cov[..., keep[:, None], keep[None, :]] = at.cov
        return cls._trusted(se3.from_parts(t, R), cov)

    @classmethod
    def identity(cls, batch_shape: tuple[int, ...] = ()) -> AT3:
        from relmap.at import _batch_shape

        batch_shape = _batch_shape(batch_shape)
        return cls._trusted(se3.identity(batch_shape), np.zeros((*batch_shape, 6, 6)))

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
        return cls._trusted(se3.from_parts(v[..., :3], R), _sym(J @ C @ np.swapaxes(J, -1, -2)))

    @classmethod
    def stack(cls, ats: Sequence[AT3], axis: int = 0) -> AT3:
        from relmap.at import _sequence_of, _stack_axis

        ats = _sequence_of(ats, "AT3.stack")
        for i, x in enumerate(ats):
            if not isinstance(x, AT3):
                raise ArgumentTypeError(f"AT3.stack: item {i} is a {type(x).__name__}, not an AT3")
        ax = _stack_axis(ats, axis, "AT3.stack")
        return cls._trusted(
            np.stack([a._mean for a in ats], ax), np.stack([a._cov for a in ats], ax)
        )

    # ----------------------------------------------------------------- accessors
    @property
    def mean(self) -> FloatArray:
        """The mean pose: homogeneous matrices (..., 4, 4) (read-only)."""
        return self._mean

    @property
    def matrix(self) -> FloatArray:
        """(..., 4, 4) homogeneous matrices (read-only); the same as :attr:`mean`."""
        return self._mean

    @property
    def translation(self) -> FloatArray:
        return self._mean[..., :3, 3]

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

    @property
    def cov(self) -> FloatArray:
        """(..., 6, 6) on ``(δt, δφ)``: parent-frame translation, left rotation perturbation."""
        return self._cov

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self._mean.shape[:-2]

    @property
    def ndim(self) -> int:
        return self._mean.ndim - 2

    @property
    def sigmas(self) -> FloatArray:
        return np.sqrt(np.diagonal(self._cov, axis1=-2, axis2=-1))

    def __getitem__(self, index: object) -> AT3:
        if self.ndim == 0:
            raise IndexError("a single AT3 has no batch axes to index")
        return AT3._trusted(self._mean[index], self._cov[index])

    def __len__(self) -> int:
        if self.ndim == 0:
            raise TypeError("a single AT3 has no length")
        return self.batch_shape[0]

    def __repr__(self) -> str:
        if self.ndim:
            return f"AT3(batch_shape={self.batch_shape})"
        t = ", ".join(f"{v:.6g}" for v in self.translation)
        q = ", ".join(f"{v:.6g}" for v in self.quaternion)
        s = ", ".join(f"{v:.3g}" for v in self.sigmas)
        return f"AT3(t=[{t}], q=[{q}], sigmas=[{s}])"

    # ---------------------------------------------------------------- operations
    def __matmul__(self, other: AT3) -> AT3:
        if not isinstance(other, AT3):
            return NotImplemented
        return compound3(self, other)

    def reverse(self) -> AT3:
        return reverse3(self)

    def sample(self, n: int, seed: SeedLike = None) -> FloatArray:
        """``n`` pose draws (n, ..., 4, 4) from ``N(mean, cov)`` in the chart."""
        delta = gaussian._sample(np.zeros(6), self._cov, n, seed)
        return se3.plus(self._mean, delta)

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
        return np.concatenate([self.translation, rpy], -1), _sym(
            J @ self._cov @ np.swapaxes(J, -1, -2)
        )

    def to_body(self) -> FloatArray:
        """The covariance in GTSAM's Pose3 convention: body (right) perturbation
        ``T Exp(ξ)``, ``ξ = (ω, v)`` rotation first — ``M⁻¹ Σ M⁻ᵀ``
        (:func:`relmap.lie.se3.body_to_chart`), (..., 6, 6)."""
        Mi = np.swapaxes(se3.body_to_chart(self._mean), -1, -2)  # M is orthogonal
        return _sym(Mi @ self._cov @ np.swapaxes(Mi, -1, -2))

    @classmethod
    def from_body(cls, T: ArrayLike, cov_body: ArrayLike, *, rtol: float = DEFAULT_RTOL) -> AT3:
        """From homogeneous poses (..., 4, 4) and covariances in GTSAM's Pose3 convention
        (body frame, rotation first; see :meth:`to_body`)."""
        T = gaussian.real_array(T, "T")
        if T.shape[-2:] != (4, 4):
            raise ShapeError(f"T must have shape (..., 4, 4); got {T.shape}")
        C = gaussian.validate_covariance(cov_body, dim=6, name="body cov", rtol=rtol)
        M = se3.body_to_chart(T)
        return cls.from_matrix(T, _sym(M @ C @ np.swapaxes(M, -1, -2)))

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


#: :meth:`AT3.to_euler` warns when the pitch is within this many rotation σ of ±90°
POLE_SIGMAS = 3.0


class PoleWarning(UserWarning):
    """Euler angles near their pole (pitch ±90°): roll and yaw are poorly determined and their
    first-order covariance is not to be trusted (:meth:`AT3.to_euler`)."""


def _sym(C: FloatArray) -> FloatArray:
    return 0.5 * (C + np.swapaxes(C, -1, -2))


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


# ---------------------------------------------------------------- batched SE(3) kernels
# A batch of ATs is worked on in relmap's layout (relmap._layout): every entry of every matrix is
# one contiguous block over the batch, so a 3×3 block of a chunk of the batch is a (3, 3, w)
# array and the Jacobian sandwiches are a handful of einsum contractions over 3×3 blocks
# (``Ja = [[I, -[u]×], [0, I]]`` is a shear, ``Jb = blkdiag(R, R)`` a rotation). numpy's
# batched matmul on 6×6 matrices costs about as much per matrix as the whole sandwich done this
# way, and working in chunks keeps the scratch in cache.

_CHUNK = 4096  # batch elements per pass: the scratch (~90 planes) stays in the L2 cache
_es = np.einsum  # optimize=False: one C-level pass, no path search


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


def _new_pose_and_cov(size: int) -> tuple[FloatArray, FloatArray]:
    T, C = np.empty((4, 4, size)), np.empty((6, 6, size))
    T[3, :3] = 0.0
    T[3, 3] = 1.0
    return T, C


def _write_cov(
    out: FloatArray, A: FloatArray, E: FloatArray, D: FloatArray, tmp: FloatArray
) -> None:
    """Write the (6, 6, w) ``out``, once and exactly symmetric, from its blocks (0, 0) ``A``,
    (0, 1) ``E`` and (1, 1) ``D`` (each (3, 3, w) scratch; A and D symmetric up to rounding,
    made exact by averaging with their transposes)."""
    np.copyto(out[:3, 3:], E)
    np.copyto(out[3:, :3], E.transpose(1, 0, 2))
    for blk, dst in ((A, out[:3, :3]), (D, out[3:, 3:])):
        _add(blk, blk.transpose(1, 0, 2), out=tmp)
        np.multiply(tmp, 0.5, out=dst)


_add, _sub = np.add, np.subtract


def _shear(C: FloatArray, u: FloatArray, out: FloatArray, S: FloatArray, tmp: FloatArray) -> None:
    """Blocks (0, 0) and (0, 1) of ``Ja C Jaᵀ`` into ``out`` (3, 6, w): ``E = B - [u]× D`` and
    ``A - [u]× Bᵀ - E [u]×ᵀ``; block (1, 1) is C's own D. ``S`` (3, 3, w) receives ``[u]×``
    (its diagonal must be zero), ``tmp`` (3, 3, w) is scratch."""
    A, B, D = C[:3, :3], C[:3, 3:], C[3:, 3:]
    E = out[:, 3:]
    np.negative(u[2], out=S[0, 1])  # [u]× (its diagonal stays zero)
    np.copyto(S[0, 2], u[1])
    np.copyto(S[1, 0], u[2])
    np.negative(u[0], out=S[1, 2])
    np.negative(u[1], out=S[2, 0])
    np.copyto(S[2, 1], u[0])
    _es("ijw,jkw->ikw", S, D, out=tmp)
    _sub(B, tmp, out=E)
    _es("ijw,kjw->ikw", S, B, out=tmp)  # [u]× Bᵀ
    _sub(A, tmp, out=out[:, :3])
    _es("ijw,kjw->ikw", E, S, out=tmp)  # E [u]×ᵀ
    _sub(out[:, :3], tmp, out=out[:, :3])


def _rotate(top: FloatArray, D: FloatArray, R: FloatArray, Z: FloatArray, W: FloatArray) -> None:
    """``Jb C Jbᵀ`` for C with top rows ``top`` (3, 6, w) and block (1, 1) ``D``: W[0] and W[1]
    get its blocks (0, 0) and (0, 1), W[2] its block (1, 1). Z: (3, 9, w) scratch."""
    _es("ijw,jcw->icw", R, top, out=Z[:, :6])
    _es("ijw,jcw->icw", R, D, out=Z[:, 6:])
    for k, zs in enumerate((Z[:, 0:3], Z[:, 3:6], Z[:, 6:9])):
        _es("ilw,klw->ikw", zs, R, out=W[k])


_KERNELS: list[ModuleType] = []  # relmap._at3_kernels once imported (numba's import is ~0.3 s)


def _kernels(size: int) -> ModuleType | None:
    """The fused numba kernels (:mod:`relmap._at3_kernels`) when they run for a batch of
    ``size`` elements (:func:`relmap._numba.enabled`), else None (the numpy kernels here run)."""
    if not _numba.enabled(size):
        return None
    if not _KERNELS:
        from relmap import _at3_kernels

        _KERNELS.append(_at3_kernels)
    return _KERNELS[0]


_KERNEL_CHUNK = 8192  # elements per kernel call when inputs must be copied to C order


def _run(
    kernel: Callable[..., tuple[FloatArray, FloatArray]],
    planes: tuple[FloatArray, ...],
    N: int,
) -> tuple[FloatArray, FloatArray]:
    """A batched numba kernel on entry-major planes (r, c, N) → new (4, 4, N), (6, 6, N).

    The kernels read C-contiguous planes (relmap's own layout). Other views (slices of a larger
    batch, one AT3 broadcast against a batch) are copied to C order, in slices of
    _KERNEL_CHUNK elements for a large batch so that the copies stay small."""
    planes = tuple(np.asarray(p, dtype=np.float64) for p in planes)
    if N <= _KERNEL_CHUNK or all(p.flags.c_contiguous for p in planes):
        return kernel(*(np.ascontiguousarray(p) for p in planes))  # type: ignore[no-any-return]
    To, Co = np.empty((4, 4, N)), np.empty((6, 6, N))
    for s in range(0, N, _KERNEL_CHUNK):
        e = min(N, s + _KERNEL_CHUNK)
        To[..., s:e], Co[..., s:e] = kernel(*(np.ascontiguousarray(p[..., s:e]) for p in planes))
    return To, Co


def _compound_batched(a: AT3, b: AT3, X: FloatArray | None, batch: tuple[int, ...]) -> AT3:
    N = math.prod(batch)
    Ta, Ca = _planes(a._mean, batch, N), _planes(a._cov, batch, N)
    Tb, Cb = _planes(b._mean, batch, N), _planes(b._cov, batch, N)
    Xp = None if X is None else _planes(X, batch, N)
    kernels = _kernels(N)
    if kernels is not None:
        if Xp is None:
            To, Co = _run(kernels.compound_batched, (Ta, Ca, Tb, Cb), N)
        else:
            To, Co = _run(kernels.compound_cross_batched, (Ta, Ca, Tb, Cb, Xp), N)
        return AT3._own(_logical(To, batch), _logical(Co, batch))
    To, Co = _new_pose_and_cov(N)
    m = min(N, _CHUNK)
    scratch = np.empty((3 + 27 + 27 + 9 + 9 + 18 + (0 if X is None else 72), m))
    scratch[57:66:4] = 0.0  # the diagonal of [u]× (S below)
    for s in range(0, N, _CHUNK):
        e = min(N, s + _CHUNK)
        w = e - s
        sc = scratch[:, :w]
        u, Z, W = sc[0:3], sc[3:30].reshape(3, 9, w), sc[30:57].reshape(3, 3, 3, w)
        S, tmp, top = (
            sc[57:66].reshape(3, 3, w),
            sc[66:75].reshape(3, 3, w),
            sc[75:93].reshape(3, 6, w),
        )
        ta, tb, to = Ta[..., s:e], Tb[..., s:e], To[..., s:e]
        ca, cb, co = Ca[..., s:e], Cb[..., s:e], Co[..., s:e]
        R = ta[:3, :3]
        # the mean: Ra [Rb tb], then t = ta + u with u = Ra tb (summed in scratch, stored once)
        _es("ijw,jkw->ikw", R, tb[:3], out=Z[:, :4])
        np.copyto(to[:3, :3], Z[:, :3])
        np.copyto(u, Z[:, 3])
        _add(u, ta[:3, 3], out=to[:3, 3])
        _shear(ca, u, top, S, tmp)  # Ja Ca Jaᵀ: blocks (0, 0), (0, 1); (1, 1) is Ca's
        _rotate(cb[:3], cb[3:, 3:], R, Z, W)  # Jb Cb Jbᵀ
        _add(top[:, :3], W[0], out=W[0])
        _add(top[:, 3:], W[1], out=W[1])
        _add(ca[3:, 3:], W[2], out=W[2])
        if Xp is not None:  # + K + Kᵀ with K = Ja X Jbᵀ
            K, Y = sc[93:129].reshape(6, 6, w), sc[129:165].reshape(6, 6, w)
            _es("rlw,klw->rkw", Xp[:, :3, s:e], R, out=Y[:, :3])  # Y = X Jbᵀ
            _es("rlw,klw->rkw", Xp[:, 3:, s:e], R, out=Y[:, 3:])
            _es("ijw,jcw->icw", S, Y[3:], out=K[:3])  # S still holds [u]×
            _sub(Y[:3], K[:3], out=K[:3])
            np.copyto(K[3:], Y[3:])
            _add(K, K.transpose(1, 0, 2), out=Y)  # exactly symmetric
            _add(W[0], Y[:3, :3], out=W[0])
            _add(W[1], Y[:3, 3:], out=W[1])
            _add(W[2], Y[3:, 3:], out=W[2])
        _write_cov(co, W[0], W[1], W[2], tmp)
    return AT3._own(_logical(To, batch), _logical(Co, batch))


def _reverse_batched(a: AT3) -> AT3:
    batch = a.batch_shape
    N = math.prod(batch)
    T, C = _planes(a._mean, batch, N), _planes(a._cov, batch, N)
    kernels = _kernels(N)
    if kernels is not None:
        To, Co = _run(kernels.reverse_batched, (T, C), N)
        return AT3._own(_logical(To, batch), _logical(Co, batch))
    To, Co = _new_pose_and_cov(N)
    m = min(N, _CHUNK)
    scratch = np.empty((3 + 27 + 27 + 18 + 9 + 9, m))
    scratch[75:84:4] = 0.0  # the diagonal of [u]× (S below)
    for s in range(0, N, _CHUNK):
        e = min(N, s + _CHUNK)
        w = e - s
        sc = scratch[:, :w]
        u, Z, W = sc[0:3], sc[3:30].reshape(3, 9, w), sc[30:57].reshape(3, 3, 3, w)
        top, S, tmp = (
            sc[57:75].reshape(3, 6, w),
            sc[75:84].reshape(3, 3, w),
            sc[84:93].reshape(3, 3, w),
        )
        t, to, c, co = T[..., s:e], To[..., s:e], C[..., s:e], Co[..., s:e]
        Rt = t[:3, :3].transpose(1, 0, 2)
        # the inverse (Rᵀ, -Rᵀ t)
        np.copyto(to[:3, :3], Rt)
        _es("ijw,jw->iw", Rt, t[:3, 3], out=Z[:, 0])
        np.negative(Z[:, 0], out=to[:3, 3])
        # J = -blkdiag(Rᵀ, Rᵀ) [[I, [t]×], [0, I]]: a shear with u = -t, then a rotation by Rᵀ
        np.negative(t[:3, 3], out=u)
        _shear(c, u, top, S, tmp)
        _rotate(top, c[3:, 3:], Rt, Z, W)
        _write_cov(co, W[0], W[1], W[2], tmp)
    return AT3._own(_logical(To, batch), _logical(Co, batch))


def _compound_one(
    T1: FloatArray, C1: FloatArray, T2: FloatArray, C2: FloatArray, X: FloatArray | None
) -> AT3:
    """One pair (no batch axes): the Jacobian ``J = [Ja Jb]`` (6×12) from Python floats, then
    ``J [[C1, X], [Xᵀ, C2]] Jᵀ`` in two matrix products; a few numpy calls in all."""
    (r00, r01, r02, _), (r10, r11, r12, _), (r20, r21, r22, _), _ = T1.tolist()
    (_, _, _, b0), (_, _, _, b1), (_, _, _, b2), _ = T2.tolist()
    u0 = r00 * b0 + r01 * b1 + r02 * b2  # R_a t_b
    u1 = r10 * b0 + r11 * b1 + r12 * b2
    u2 = r20 * b0 + r21 * b1 + r22 * b2
    J = np.array(
        [
            *(1.0, 0.0, 0.0, 0.0, u2, -u1, r00, r01, r02, 0.0, 0.0, 0.0),
            *(0.0, 1.0, 0.0, -u2, 0.0, u0, r10, r11, r12, 0.0, 0.0, 0.0),
            *(0.0, 0.0, 1.0, u1, -u0, 0.0, r20, r21, r22, 0.0, 0.0, 0.0),
            *(0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, r00, r01, r02),
            *(0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, r10, r11, r12),
            *(0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, r20, r21, r22),
        ]
    ).reshape(6, 12)
    big = np.zeros((12, 12))
    big[:6, :6] = C1
    big[6:, 6:] = C2
    if X is not None:
        big[:6, 6:] = X
        big[6:, :6] = X.T
    C = J @ big @ J.T
    C += C.T
    C *= 0.5
    return AT3._own(T1 @ T2, C)


def _reverse_one(T: FloatArray, C: FloatArray) -> AT3:
    """One AT3: ``J = -[[Rᵀ, Rᵀ [t]×], [0, Rᵀ]]`` from Python floats (its sign cancels)."""
    (r00, r01, r02, x0), (r10, r11, r12, x1), (r20, r21, r22, x2), _ = T.tolist()
    v0 = r00 * x0 + r10 * x1 + r20 * x2  # Rᵀ t
    v1 = r01 * x0 + r11 * x1 + r21 * x2
    v2 = r02 * x0 + r12 * x1 + r22 * x2
    # M = [[Rᵀ, Rᵀ [t]×], [0, Rᵀ]] (row i of Rᵀ [t]× is (Rᵀ)ᵢ × t), then T⁻¹
    flat = np.array(
        [
            *(r00, r10, r20, r10 * x2 - r20 * x1, r20 * x0 - r00 * x2, r00 * x1 - r10 * x0),
            *(r01, r11, r21, r11 * x2 - r21 * x1, r21 * x0 - r01 * x2, r01 * x1 - r11 * x0),
            *(r02, r12, r22, r12 * x2 - r22 * x1, r22 * x0 - r02 * x2, r02 * x1 - r12 * x0),
            *(0.0, 0.0, 0.0, r00, r10, r20),
            *(0.0, 0.0, 0.0, r01, r11, r21),
            *(0.0, 0.0, 0.0, r02, r12, r22),
            *(r00, r10, r20, -v0, r01, r11, r21, -v1, r02, r12, r22, -v2, 0.0, 0.0, 0.0, 1.0),
        ]
    )
    M = flat[:36].reshape(6, 6)
    out = M @ C @ M.T
    out += out.T
    out *= 0.5
    return AT3._own(flat[36:].reshape(4, 4), out)


def compound3(a: AT3, b: AT3, *, cross_cov: ArrayLike | None = None) -> AT3:
    """``a ⊕ b`` in 3-D: ``C = J_a C_a J_aᵀ + J_b C_b J_bᵀ`` (+ the cross terms of a dependent
    pair, ``cross_cov = E[δa δbᵀ]`` (..., 6, 6)), with ``J_a = [[I, -[R_a t_b]×], [0, I]]``,
    ``J_b = blkdiag(R_a, R_a)`` (:func:`relmap.lie.se3.compose`). Runs the numba kernels when
    enabled, else the numpy ones (module docstring)."""
    for i, x in enumerate((a, b)):
        if not isinstance(x, AT3):
            raise ArgumentTypeError(f"argument {i} is a {type(x).__name__}, not an AT3")
    X = None
    if cross_cov is not None:
        from relmap.at import _cross_cov

        X = _cross_cov(a._cov, b._cov, cross_cov, 6)
    Ta, Tb = a._mean, b._mean
    if Ta.ndim == 2 and Tb.ndim == 2 and (X is None or X.ndim == 2):
        out = _compound_one(Ta, a._cov, Tb, b._cov, X)
        _finite("compound", out._mean, out._cov)
        return out
    batch = Ta.shape[:-2]
    try:
        if Tb.shape[:-2] != batch:
            batch = np.broadcast_shapes(batch, Tb.shape[:-2])
        if X is not None:
            batch = np.broadcast_shapes(batch, X.shape[:-2])
    except ValueError:
        shapes = [a.batch_shape, b.batch_shape] + ([] if X is None else [X.shape[:-2]])
        raise ShapeError(f"compound: batch shapes {shapes} do not broadcast") from None
    out = _compound_batched(a, b, X, batch)
    _finite("compound", out._mean, out._cov)
    return out


_SCAN_BELOW = 32  # chains: fewer than this are scanned one at a time (lanes would go unused)


def compound_chain3(steps: AT3, *, axis: int = -1) -> AT3:
    """Every prefix ``A₁ ⊕ A₂ ⊕ … ⊕ A_k`` of the chains laid along batch ``axis`` of ``steps``.

    Returns an AT3 of the same batch shape whose element k along ``axis`` is frame k in the
    chain's first parent frame, for independent steps (Eq. 4's assumption): the same values as
    compounding one step at a time, ``acc = acc @ step`` (to rounding; bitwise in the numba
    kernel), in one call. With numba (:func:`relmap._numba.enabled`) one kernel pass over the
    steps, step-major: vectorized across the chains (32 or more; fewer are scanned one at a
    time, the running prefix in registers). Step-major is relmap's storage when ``axis`` is the
    first batch axis; for another axis the steps are first copied in that order (one more pass
    over memory). Without numba (or for fewer than :data:`relmap._numba.LARGE` elements), one
    batched :func:`compound3` per step along ``axis``.
    """
    if not isinstance(steps, AT3):
        raise ArgumentTypeError(f"expected an AT3, got {type(steps).__name__}")
    if steps.ndim == 0:
        raise ShapeError("compound_chain3 needs an AT3 with at least one batch axis (the chain)")
    if not -steps.ndim <= axis < steps.ndim:
        raise ShapeError(f"axis {axis} is out of range for batch shape {steps.batch_shape}")
    axis %= steps.ndim
    batch = steps.batch_shape
    if batch[axis] == 0:
        raise ShapeError(
            f"compound_chain needs at least one step along axis {axis}; batch shape {batch} "
            "has none"
        )
    if 0 in batch:  # no chains: no prefixes either
        return steps
    kernels = _kernels(math.prod(batch))
    if kernels is None:
        out = [steps[(slice(None),) * axis + (0,)]]
        for k in range(1, batch[axis]):
            out.append(out[-1] @ steps[(slice(None),) * axis + (k,)])
        return AT3.stack(out, axis=axis)
    # step-major planes (4, 4, L, M), the chain axis first among the batch axes: a view for
    # relmap's layout when the chain axis is the first batch axis; a copy otherwise
    moved = (batch[axis], *batch[:axis], *batch[axis + 1 :])
    L, M = moved[0], math.prod(moved[1:])
    planes = []
    for x in (steps._mean, steps._cov):
        x = np.moveaxis(x, axis, 0)
        nd = x.ndim
        p = x.transpose(nd - 2, nd - 1, *range(nd - 2))
        planes.append(np.ascontiguousarray(p).reshape(*p.shape[:2], L, M))
    # vectorized across the chains; fewer than _SCAN_BELOW are scanned one at a time
    chain = kernels.compound_chain if M >= _SCAN_BELOW else kernels.compound_chain_scan
    To, Co = chain(*planes)
    T, C = (np.moveaxis(_logical(p.reshape(*p.shape[:2], -1), moved), 0, axis) for p in (To, Co))
    _finite("compound_chain", T, C)
    return AT3._trusted(T, C)


@overload
def reverse3(a: AT3, *, jacobian: Literal[False] = ...) -> AT3: ...
@overload
def reverse3(a: AT3, *, jacobian: Literal[True]) -> tuple[AT3, FloatArray]: ...
def reverse3(a: AT3, *, jacobian: bool = False) -> AT3 | tuple[AT3, FloatArray]:
    """``Aᴿ`` in 3-D: ``C' = J C Jᵀ`` with J the inverse's Jacobian (returned too with
    ``jacobian=True``; A's cross-covariance with its reversal is then ``C Jᵀ``). Runs the numba
    kernels when enabled, else the numpy ones (module docstring); the Jacobian is numpy's."""
    if not isinstance(a, AT3):
        raise ArgumentTypeError(f"expected an AT3, got {type(a).__name__}")
    out = _reverse_one(a._mean, a._cov) if a._mean.ndim == 2 else _reverse_batched(a)
    _finite("reverse", out._mean, out._cov)
    if jacobian:
        return out, se3.inverse(a._mean, jacobians=True)[1]
    return out


def merge3(*ats: AT3, atol: float = 1e-9, max_iterations: int = 50) -> AT3:
    """Merge parallel AT3s (Eqs. 8-10), order-independent.

    The rotation chart is curved, so fusing pairwise in each AT's own chart would depend on the
    order at second order in the spread of the means. Instead every mean is expressed in the
    chart at a common pose X (``δᵢ = minus(Tᵢ, X)``), the δᵢ are fused linearly with
    :func:`relmap.gaussian.fuse` (Joseph form, exact components allowed; the same as the
    information-weighted mean, which does not depend on the order), X moves by the result, and
    this repeats until the step is at rounding level (a fixed point symmetric in the inputs).
    Inputs are assumed independent; contradictions along exactly known directions raise
    :class:`relmap.errors.InconsistentMergeError`.
    """
    if not ats:
        raise ShapeError("merge3 needs at least one AT3")
    for i, x in enumerate(ats):
        if not isinstance(x, AT3):
            raise ArgumentTypeError(f"argument {i} is a {type(x).__name__}, not an AT3")
    atol = gaussian.check_tolerance(atol, "atol")
    if len(ats) == 1:
        return ats[0]
    try:
        np.broadcast_shapes(*(x.batch_shape for x in ats))
    except ValueError:
        shapes = " and ".join(str(x.batch_shape) for x in ats)
        raise ShapeError(f"merge: batch shapes {shapes} do not broadcast") from None
    # the gains depend on the covariances only: compute them once
    gains, C = [], ats[0]._cov
    for b in ats[1:]:
        gains.append(gaussian.fusion(C, b._cov))
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
    _finite("merge", X, C)
    return AT3._trusted(X, C)
