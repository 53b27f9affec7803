"""Approximate transformations (ATs): uncertain SE(2) relative poses, and their algebra.

An AT on the edge ``A → B`` says where frame B is, expressed in frame A: a mean ``(x, y, θ)``
(metres, radians, θ in [-π, π)) and a 3×3 covariance on ``(x, y, θ)`` in the **parent frame A**,
exactly the convention of Smith & Cheeseman (1986). Every AT may carry leading batch axes
(mean ``(..., 3)``, covariance ``(..., 3, 3)``), and every operation broadcasts them like numpy.

This module holds the whole SE(2) algebra, one step after the other: compounding (``a @ b``,
Eqs. 1-4), reversal (``a.reverse()``, Eqs. 5-7), merging (Eqs. 8-10) and the parallel scan of a
chain, written on the six distinct entries of the symmetric 3×3 covariances (the congruences
``K C Kᵀ``, ``H C Hᵀ`` and an odometry step's ``J S Jᵀ``, at the end of the module: several
times faster than batched 3×3 matmul, and symmetric by construction). The free functions that
take either kind — :func:`relmap.compound`, :func:`relmap.reverse`, :func:`relmap.merge`,
:func:`relmap.compound_chain` — are :mod:`relmap.uncertain.algebra`'s; what AT and AT3 share
(storage, stacking, indexing, sampling, the ellipse, the argument checks) is their base
:class:`relmap.uncertain.pose.UncertainPose`.

ATs are immutable values: operations return new ATs. User input is validated once, in
:class:`AT`'s constructor; results of relmap's own operations skip the check.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from relmap._layout import compact, components_outermost, matrix, stack_last
from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.lie.group import SE2
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain import gaussian
from relmap.uncertain.gaussian import DEFAULT_RTOL
from relmap.uncertain.pose import UncertainPose, broadcast_error, check_result

__all__ = ["AT"]


class AT(UncertainPose):
    """An approximate transformation: uncertain pose of a child frame in its parent frame.

    Parameters
    ----------
    mean:
        ``(..., 3)``: ``(x, y, θ)`` of the child frame's origin and heading in the parent frame
        (metres, radians; θ is wrapped to [-π, π)).
    cov:
        ``(..., 3, 3)`` covariance on ``(x, y, θ)`` in the parent frame (the paper's convention),
        or None for an exactly known transformation (zero covariance). Zero variances are
        allowed. Batch axes of mean and cov broadcast together.
    rtol:
        Tolerance of the symmetry and positive-semi-definiteness checks
        (:func:`relmap.uncertain.gaussian.validate_covariance`).

    Examples
    --------
    >>> import numpy as np, relmap as rm
    >>> a = rm.AT([1.0, 0.0, 0.1], np.diag([0.01, 0.01, 0.001]))
    >>> b = rm.AT.from_sigmas([2.0, 0.5, -0.2], [0.1, 0.1, 0.02])
    >>> c = a @ b                    # compound: b after a
    >>> r = a.reverse()              # where a's parent is, seen from a's child
    >>> m = rm.merge(c, c)           # merge parallel ATs (independent estimates)
    """

    __slots__ = ()
    group = SE2  #: the pose group (generic code reads it)
    _translation = (Ellipsis, slice(0, 2))

    def __init__(
        self, mean: ArrayLike, cov: ArrayLike | None = None, *, rtol: float = DEFAULT_RTOL
    ):
        mean_arr = gaussian.real_array(mean, "AT mean")
        if mean_arr.ndim == 0 or mean_arr.shape[-1] != 3:
            raise ShapeError(
                f"AT mean must have shape (..., 3) holding (x, y, θ); got {mean_arr.shape}"
            )
        gaussian.check_finite(mean_arr, "AT mean")
        if cov is None:
            gaussian.check_tolerance(rtol, "rtol")
            cov_arr = np.zeros((*mean_arr.shape[:-1], 3, 3))
        else:
            cov_arr = gaussian.validate_covariance(cov, dim=3, name="AT cov", rtol=rtol)
        try:
            batch = np.broadcast_shapes(mean_arr.shape[:-1], cov_arr.shape[:-2])
        except ValueError:
            raise ShapeError(
                f"AT mean batch shape {mean_arr.shape[:-1]} and cov batch shape "
                f"{cov_arr.shape[:-2]} do not broadcast"
            ) from None
        mean_arr[..., 2] = se2.wrap_angle(mean_arr[..., 2])
        self._set(components_outermost(mean_arr, 1), components_outermost(cov_arr, 2), batch)

    @classmethod
    def _single(cls, v: Sequence[float]) -> AT:
        """One AT from ``[x, y, θ, c00, c01, c02, c11, c12, c22]`` relmap computed itself (θ
        wrapped): one read-only buffer for mean and covariance — what :meth:`_trusted` builds,
        in fewer numpy calls (they are most of the cost of a single AT)."""
        x, y, t, c00, c01, c02, c11, c12, c22 = v
        buf = np.array([x, y, t, c00, c01, c02, c01, c11, c12, c02, c12, c22])
        buf.flags.writeable = False
        out = object.__new__(cls)
        object.__setattr__(out, "_mean", buf[:3])
        object.__setattr__(out, "_cov", buf[3:].reshape(3, 3))
        return out

    # ----------------------------------------------------------------- constructors
    @classmethod
    def from_sigmas(cls, mean: ArrayLike, sigmas: ArrayLike) -> AT:
        """An AT with independent errors: standard deviations ``(σx, σy, σθ)``, ``(..., 3)``."""
        return cls(mean, cls._diagonal_cov(sigmas, 3))

    @classmethod
    def from_ellipse(
        cls,
        mean: ArrayLike,
        sigma_major: ArrayLike,
        sigma_minor: ArrayLike,
        angle: ArrayLike,
        sigma_theta: ArrayLike = 0.0,
    ) -> AT:
        """An AT whose position error is a rotated ellipse (lecture Eq. 6: ``Σ = R D Rᵀ``).

        ``sigma_major``/``sigma_minor`` are the standard deviations along the ellipse's axes,
        ``angle`` the direction of the major axis from the parent's x axis (radians);
        the heading error ``sigma_theta`` is independent of the position error.
        """
        st = gaussian.real_array(sigma_theta, "sigma_theta")
        gaussian.check_finite(st, "sigma_theta")
        if (st < 0).any():
            raise ParameterError(f"sigma_theta must be non-negative; got {st.min()}")
        xy = gaussian.rotated_covariance(sigma_major, sigma_minor, angle)
        cov = np.zeros((*gaussian.broadcast("from_ellipse", xy.shape[:-2], st.shape), 3, 3))
        cov[..., :2, :2] = xy
        cov[..., 2, 2] = st * st
        return cls(mean, cov)

    @classmethod
    def from_body(cls, mean: ArrayLike, cov_body: ArrayLike, *, rtol: float = DEFAULT_RTOL) -> AT:
        """An AT from a covariance in the body (right, child-frame) convention of GTSAM and manif.

        Body perturbation ``T ∘ Exp(ξ)``, ``ξ = (vx, vy, ω)``. The paper's covariance is
        ``Σ = M Σ_body Mᵀ`` with ``M = blkdiag(R(θ), 1)`` (:func:`relmap.lie.se2.body_to_chart`).
        """
        checked = gaussian.validate_covariance(cov_body, dim=3, name="body cov", rtol=rtol)
        mean_arr = gaussian.real_array(mean, "AT mean")
        if mean_arr.ndim == 0 or mean_arr.shape[-1] != 3:
            raise ShapeError(f"AT mean must have shape (..., 3); got {mean_arr.shape}")
        gaussian.check_finite(mean_arr, "AT mean")
        gaussian.broadcast("AT mean and body cov batch", mean_arr.shape[:-1], checked.shape[:-2])
        M = se2.body_to_chart(mean_arr)
        return cls(mean_arr, gaussian.congruence(M, checked), rtol=rtol)

    @classmethod
    def from_ros(cls, mean: ArrayLike, cov6: ArrayLike, *, rtol: float = DEFAULT_RTOL) -> AT:
        """An AT from a ROS ``PoseWithCovariance``-style 6×6 covariance (see :meth:`to_ros`).

        ``cov6`` is ``(..., 6, 6)`` or ``(..., 36)`` (the message's row-major array) on
        ``(x, y, z, rot_x, rot_y, rot_z)``; the planar rows/columns ``(0, 1, 5)`` are kept.
        """
        c6 = gaussian.real_array(cov6, "ROS covariance")
        if c6.shape[-1:] == (36,):
            c6 = c6.reshape(*c6.shape[:-1], 6, 6)
        if c6.shape[-2:] != (6, 6):
            raise ShapeError(
                f"ROS covariance must have shape (..., 6, 6) or (..., 36); got {c6.shape}"
            )
        planar = c6[..., [0, 1, 5], :][..., :, [0, 1, 5]]
        return cls(mean, planar, rtol=rtol)

    # ------------------------------------------------------------------- accessors
    def __repr__(self) -> str:
        if self.ndim:
            return f"AT(batch_shape={self.batch_shape})"
        x, y, t = self._mean
        sx, sy, st = self.sigmas
        return f"AT(mean=[{x:.6g}, {y:.6g}, {t:.6g}], sigmas=[{sx:.3g}, {sy:.3g}, {st:.3g}])"

    # ------------------------------------------------------------------ operations
    def to_body(self) -> FloatArray:
        """The covariance in the body convention of GTSAM/manif: ``M⁻¹ Σ M⁻ᵀ``, ``(..., 3, 3)``."""
        t = self._mean[..., 2]
        return to_matrix(rotate(entries(self._cov), np.cos(t), -np.sin(t)))

    def to_ros(self, unused_variance: float = 0.0) -> FloatArray:
        """The covariance as ROS's ``PoseWithCovariance`` 6×6 on ``(x, y, z, rot_x, rot_y, rot_z)``.

        ROS expresses the pose covariance in the parent (header) frame with fixed-axis
        rotations, which for a planar pose is exactly relmap's convention: ``(x, y, θ)`` fill
        rows/columns ``(0, 1, 5)``. The z, roll and pitch rows are not estimated by a planar
        AT; their diagonal is ``unused_variance`` (0 says "exactly planar", as amcl publishes;
        a large value such as 1e6 says "unknown", as some planar odometry drivers publish),
        and their cross terms are zero. Returns ``(..., 6, 6)``; ``.reshape(..., 36)`` gives
        the message's row-major array.
        """
        out = np.zeros((*self.batch_shape, 6, 6))
        keep = np.array([0, 1, 5])
        out[..., keep[:, None], keep[None, :]] = self._cov
        for i in (2, 3, 4):
            out[..., i, i] = unused_variance
        return out

    # ------------------------------------------- the algebra (relmap.uncertain.algebra calls it)
    def __matmul__(self, other: AT) -> AT:
        """``a @ b`` is :func:`relmap.compound` ``(a, b)``: frame b's pose given in frame a,
        chained."""
        if not isinstance(other, AT):
            return NotImplemented
        return self._compound(other, None)

    def reverse(self) -> AT:
        """The reversed AT ``Aᴿ`` (:func:`relmap.reverse`): where A's parent frame is, seen
        from A's child frame."""
        return self._reverse(False)  # type: ignore[return-value]

    def _compound(self, other: AT, cross_cov: FloatArray | None) -> AT:
        """Eqs. (1)-(4): ``C = H C_a Hᵀ + K C_b Kᵀ`` on the six entries; with ``cross_cov`` (a
        dependent pair, §3.2) ``+ H C_ab Kᵀ + K C_abᵀ Hᵀ``."""
        try:
            mean, cov = compound_arrays(self._mean, self._cov, other._mean, other._cov)
        except ValueError:
            raise broadcast_error("compound", self.batch_shape, other.batch_shape) from None
        if cross_cov is not None:
            _, H, K = se2.compose(self._mean, other._mean, jacobians=True)
            HXK = H @ cross_cov @ np.swapaxes(K, -1, -2)
            cov = cov + HXK + np.swapaxes(HXK, -1, -2)
        check_result("compound", mean, cov)
        return AT._trusted(mean, cov)

    def _reverse(self, jacobians: bool) -> AT | tuple[AT, FloatArray]:
        """Eqs. (5)-(7): ``C' = R C Rᵀ``; with ``jacobians`` R too."""
        inv = se2.inverse(self._mean)
        # R = H(x', y') · blkdiag(-R(θ)ᵀ, -1): the signs cancel in the sandwich.
        t = self._mean[..., 2]
        e = shear(rotate(entries(self._cov), np.cos(t), -np.sin(t)), inv[..., 0], inv[..., 1])
        cov = to_matrix(e)
        check_result("reverse", inv, cov)
        out = AT._trusted(inv, cov)
        if jacobians:
            return out, se2.inverse(self._mean, jacobians=True)[1]
        return out

    @classmethod
    def _merge(cls, ats: Sequence[AT], atol: float) -> AT:
        """Eqs. (8)-(10), pairwise (:func:`relmap.uncertain.gaussian.fuse`, Joseph form)."""
        result = ats[0]
        for k, b in enumerate(ats[1:], start=1):
            result = _merge_pair(result, b, atol, k)
        check_result("merge", result._mean, result._cov)
        return result

    def _chain(self, axis: int) -> AT:
        """Every prefix along ``axis`` by a parallel scan (:func:`_scan`)."""
        mean, cov = _scan(np.moveaxis(self._mean, axis, 0), np.moveaxis(self._cov, axis, 0))
        check_result("compound_chain", mean, cov)
        return AT._trusted(np.moveaxis(mean, 0, axis), np.moveaxis(cov, 0, axis))


_TWO_PI = 2.0 * np.pi


def compound_arrays(
    mean_a: FloatArray, cov_a: FloatArray, mean_b: FloatArray, cov_b: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Eqs. (1)-(4) on raw arrays — means (..., 3), covariances (..., 3, 3), broadcast — with
    no checks (the caller's are valid): ``(a ∘ b, H C_a Hᵀ + K C_b Kᵀ)``, written out on the
    covariances' six entries."""
    mean, c, s, dx, dy = se2._compose_terms(mean_a, mean_b)
    sheared, rotated = shear(entries(cov_a), dx, dy), rotate(entries(cov_b), c, s)
    total = tuple(p + q for p, q in zip(sheared, rotated, strict=True))
    return mean, to_matrix(total)  # type: ignore[arg-type]


def _merge_pair(a: AT, b: AT, atol: float, position: int) -> AT:
    # the gain from the covariances as stored: once for a covariance the batch shares
    mean, cov = gaussian.fuse(
        a.mean,
        compact(a.cov, 2),
        b.mean,
        compact(b.cov, 2),
        minus=se2.minus,
        plus=se2.plus,
        atol=atol,
        what=f"AT #{position} into the preceding ones",
        components="(x, y, θ)",
    )
    return AT._trusted(mean, cov)


def _scan(mean: FloatArray, cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inclusive prefix compounds along axis 0 (recursive pairing; depth log₂ n), on the nine
    distinct numbers of each AT kept as separate arrays until the end."""
    parts = (mean[..., 0], mean[..., 1], mean[..., 2], *entries(cov))
    x, y, t, *e = _scan_parts(parts)
    return stack_last([x, y, t], mean.shape[:-1]), to_matrix(tuple(e))  # type: ignore[arg-type]


def _scan_parts(p: tuple[FloatArray, ...]) -> tuple[FloatArray, ...]:
    n = p[0].shape[0]
    if n == 1:
        return p
    odd = _scan_parts(_compound_parts([v[0 : n - 1 : 2] for v in p], [v[1::2] for v in p]))
    m = (n - 1) // 2  # the prefixes ending at steps 1, 3, 5, ... are odd; the rest follow
    even = _compound_parts([v[:m] for v in odd], [v[2::2] for v in p])
    out = tuple(np.empty_like(v) for v in p)
    for o, v, od, ev in zip(out, p, odd, even, strict=True):
        o[0], o[1::2], o[2::2] = v[0], od, ev
    return out


def _compound_parts(a: list[FloatArray], b: list[FloatArray]) -> tuple[FloatArray, ...]:
    """:func:`compound_arrays` on parts ``(x, y, θ, c00, c01, c02, c11, c12, c22)`` of wrapped
    poses: their headings sum within [-2π, 2π), so one shift wraps them."""
    xa, ya, ta, *ca = a
    xb, yb, tb, *cb = b
    c, s = np.cos(ta), np.sin(ta)
    dx = c * xb - s * yb
    dy = s * xb + c * yb
    t = ta + tb
    np.subtract(t, _TWO_PI, out=t, where=t >= np.pi)
    np.add(t, _TWO_PI, out=t, where=t < -np.pi)
    sheared = shear(tuple(ca), dx, dy)  # type: ignore[arg-type]
    rotated = rotate(tuple(cb), c, s)  # type: ignore[arg-type]
    return (xa + dx, ya + dy, t, *(u + w for u, w in zip(sheared, rotated, strict=True)))


# --------------------------------------------- symmetric 3×3 matrices on their six entries
# Covariances on SE(2)'s (x, y, θ) as their distinct entries (c00, c01, c02, c11, c12, c22), each
# an array over the batch (or a Python float for one matrix): the congruences that first-order
# propagation on SE(2) needs, written out once on these entries. The general N-d congruence
# ``J C Jᵀ`` is :func:`relmap.uncertain.gaussian.congruence`.

Value = FloatArray | float
Entries = tuple[Value, Value, Value, Value, Value, Value]

_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def entries(C: FloatArray) -> Entries:
    """The distinct entries of ``C`` ``(..., 3, 3)`` (Python floats for one matrix: far
    cheaper to combine than numpy scalars)."""
    if C.ndim == 2:
        (c00, c01, c02), (_, c11, c12), (_, _, c22) = C.tolist()
        return c00, c01, c02, c11, c12, c22
    return tuple(C[..., i, j] for i, j in _UPPER)  # type: ignore[return-value]


def to_matrix(e: Entries, shape: tuple[int, ...] | None = None) -> FloatArray:
    """The symmetric ``(*shape, 3, 3)`` matrix with the given distinct entries (broadcast;
    ``shape`` defaults to the entries' broadcast shape)."""
    c00, c01, c02, c11, c12, c22 = e
    if shape is None:
        shapes = {getattr(v, "shape", ()) for v in e}
        shape = shapes.pop() if len(shapes) == 1 else np.broadcast_shapes(*shapes)
    return matrix([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]], shape)


def rotate(e: Entries, c: Value, s: Value) -> Entries:
    """``K C Kᵀ`` with ``K = blkdiag([[c, -s], [s, c]], 1)`` (Eq. 3's K, a rotation by θ with
    ``c = cos θ``, ``s = sin θ``)."""
    q00, q01, q02, q11, q12, q22 = e
    cc, ss, cs = c * c, s * s, c * s
    cs_q01 = 2.0 * cs * q01
    return (
        cc * q00 - cs_q01 + ss * q11,
        cs * (q00 - q11) + (cc - ss) * q01,
        c * q02 - s * q12,
        ss * q00 + cs_q01 + cc * q11,
        s * q02 + c * q12,
        q22,
    )


def shear(e: Entries, dx: Value, dy: Value) -> Entries:
    """``H C Hᵀ`` with ``H = [[1, 0, -dy], [0, 1, dx], [0, 0, 1]]`` (Eq. 3's H)."""
    p00, p01, p02, p11, p12, p22 = e
    r0 = p02 - dy * p22  # third column of H C
    r1 = p12 + dx * p22
    return (p00 - dy * (p02 + r0), p01 - dy * p12 + dx * r0, r0, p11 + dx * (p12 + r1), r1, p22)


def congruence_3x2(
    a: Value, e: Value, b: Value, f: Value, s00: Value, s01: Value, s11: Value
) -> Entries:
    """``J S Jᵀ`` for ``J = [[a, e], [b, f], [0, 1]]`` and a symmetric 2×2 ``S`` (entries
    ``s00, s01, s11``): a planar step ``(Δx, Δy, Δθ)`` from two inputs (distance, turn)."""
    r00, r01 = a * s00 + e * s01, a * s01 + e * s11  # first row of J S
    r10, r11 = b * s00 + f * s01, b * s01 + f * s11  # second row
    return (a * r00 + e * r01, b * r00 + f * r01, r01, b * r10 + f * r11, r11, s11)
