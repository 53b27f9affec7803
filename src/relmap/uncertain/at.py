"""Approximate transformations (ATs): uncertain SE(2) relative poses, and how they combine.

An AT on the edge ``A → B`` says where frame B is, expressed in frame A: a mean ``(x, y, θ)``
(metres, radians, θ in [-π, π)) and a 3×3 covariance on ``(x, y, θ)`` in the **parent frame A**,
exactly the convention of Smith & Cheeseman (1986). Every AT may carry leading batch axes
(mean ``(..., 3)``, covariance ``(..., 3, 3)``), and every operation broadcasts them like numpy.

- :func:`compound` (``a @ b``, ⊕): serial ATs, Eqs. (1)-(4); uncertainty grows.
- :func:`reverse` (``a.reverse()``, ᴿ): the inverse, Eqs. (5)-(7).
- :func:`merge` (⊗): parallel ATs, Eqs. (8)-(10); uncertainty shrinks (a static Kalman update).
- :func:`compound_chain`: every prefix of a long chain at once, with no Python loop.

ATs are immutable values: operations return new ATs. User input is validated once, in
:class:`AT`'s constructor; results of relmap's own operations skip the check.

The four functions take an :class:`~relmap.AT3` as well: what AT and AT3 share (storage,
stacking, indexing, sampling, the ellipse, the argument checks) is their base
:class:`relmap.uncertain.pose.UncertainPose`, and each function calls the kind's own operation
(SE(2) here, on the fused 3×3 entries of :mod:`relmap.uncertain._sym3`; SE(3) in
:mod:`relmap.uncertain.at3`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, overload

import numpy as np

from relmap._layout import compact, components_outermost, stack_last
from relmap.errors import ParameterError, ShapeError
from relmap.lie import SE2, se2
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain import _sym3 as sym3
from relmap.uncertain import gaussian
from relmap.uncertain import moments as _moments
from relmap.uncertain.gaussian import DEFAULT_RTOL
from relmap.uncertain.moments import MomentsMethod
from relmap.uncertain.pose import (
    UncertainPose,
    broadcast_error,
    chain_axis,
    check_result,
    checked_cross_cov,
    common_batch,
    same_kind,
)

__all__ = ["AT", "compound", "compound_chain", "merge", "reverse"]


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
    @property
    def mean(self) -> FloatArray:
        """``(..., 3)`` read-only array ``(x, y, θ)``."""
        return self._mean

    def __repr__(self) -> str:
        if self.ndim:
            return f"AT(batch_shape={self.batch_shape})"
        x, y, t = self._mean
        sx, sy, st = self.sigmas
        return f"AT(mean=[{x:.6g}, {y:.6g}, {t:.6g}], sigmas=[{sx:.3g}, {sy:.3g}, {st:.3g}])"

    def _position(self) -> FloatArray:
        return self._mean[..., :2]

    # ------------------------------------------------------------------ operations
    def to_body(self) -> FloatArray:
        """The covariance in the body convention of GTSAM/manif: ``M⁻¹ Σ M⁻ᵀ``, ``(..., 3, 3)``."""
        t = self._mean[..., 2]
        return sym3.to_matrix(sym3.rotate(sym3.entries(self._cov), np.cos(t), -np.sin(t)))

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

    # --------------------------------------------------- the operations (relmap.uncertain.pose)
    def _compound(self, other: AT, cross_cov: FloatArray | None) -> AT:
        try:
            mean, cov = _compound_arrays(self._mean, self._cov, other._mean, other._cov)
        except ValueError:
            raise broadcast_error("compound", self.batch_shape, other.batch_shape) from None
        if cross_cov is not None:
            _, H, K = se2.compose(self._mean, other._mean, jacobians=True)
            HXK = H @ cross_cov @ np.swapaxes(K, -1, -2)
            cov = cov + HXK + np.swapaxes(HXK, -1, -2)
        check_result("compound", mean, cov)
        return AT._trusted(mean, cov)

    def _reverse(self, jacobian: bool) -> AT | tuple[AT, FloatArray]:
        inv = se2.inverse(self._mean)
        # R = H(x', y') · blkdiag(-R(θ)ᵀ, -1): the signs cancel in the sandwich.
        t = self._mean[..., 2]
        e = sym3.shear(
            sym3.rotate(sym3.entries(self._cov), np.cos(t), -np.sin(t)), inv[..., 0], inv[..., 1]
        )
        cov = sym3.to_matrix(e)
        check_result("reverse", inv, cov)
        out = AT._trusted(inv, cov)
        if jacobian:
            return out, se2.inverse(self._mean, jacobians=True)[1]
        return out

    @classmethod
    def _merge(cls, ats: Sequence[AT], atol: float) -> AT:
        result = ats[0]
        for k, b in enumerate(ats[1:], start=1):
            result = _merge_pair(result, b, atol, k)
        check_result("merge", result._mean, result._cov)
        return result

    def _chain(self, axis: int) -> AT:
        mean, cov = _scan(np.moveaxis(self._mean, axis, 0), np.moveaxis(self._cov, axis, 0))
        check_result("compound_chain", mean, cov)
        return AT._trusted(np.moveaxis(mean, 0, axis), np.moveaxis(cov, 0, axis))


_TWO_PI = 2.0 * np.pi


# ------------------------------------------------------------------------ operations
def compound(
    a: AT,
    b: AT,
    *,
    cross_cov: ArrayLike | None = None,
    moments: MomentsMethod = "first_order",
) -> AT:
    """Compound ``a ⊕ b``: b's frame given relative to a's, expressed in a's parent (Eqs. 1-4).

    ``C = H C_a Hᵀ + K C_b Kᵀ`` with H, K of Eq. (3). The paper assumes a and b independent;
    for a dependent pair (§3.2) give ``cross_cov = E[δa δbᵀ]`` (``(..., 3, 3)``), which adds
    ``H C_ab Kᵀ + K C_abᵀ Hᵀ``. Batch axes broadcast. Two :class:`AT3` compound in 3-D
    (:func:`relmap.uncertain.at3.compound3`, 6×6 ``cross_cov``).

    ``moments`` (SE(2) only): ``"first_order"`` (default) is Eqs. (1)-(4); ``"exact"`` the
    exact mean and covariance for Gaussian a, b (:func:`relmap.uncertain.moments.compound_moments`);
    ``"unscented"`` the unscented transform (:func:`relmap.uncertain.moments.unscented_compound`).
    """
    kind = same_kind((a, b))
    dof = kind.group.dof
    X = None if cross_cov is None else checked_cross_cov(a.cov, b.cov, cross_cov, dof)
    if moments == "first_order":
        return a._compound(b, X)
    _moments.check_method(moments)
    _second_order_for(kind, moments)
    f = _moments.compound_moments if moments == "exact" else _moments.unscented_compound
    mean, cov = f(a.mean, a.cov, b.mean, b.cov, cross_cov=X)
    check_result(f"compound (moments={moments!r})", mean, cov)
    return AT._trusted(mean, cov)


def _second_order_for(kind: type[UncertainPose], method: str) -> None:
    """Moments beyond first order exist for SE(2) (:mod:`relmap.uncertain.moments`) only."""
    if kind.group is not SE2:
        raise ParameterError(f"moments={method!r} is available for SE(2) ATs only")


def _compound_arrays(
    mean_a: FloatArray, cov_a: FloatArray, mean_b: FloatArray, cov_b: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Eqs. (1)-(4) on raw arrays: ``H C_a Hᵀ + K C_b Kᵀ`` written out elementwise."""
    mean, c, s, dx, dy = se2._compose_terms(mean_a, mean_b)
    sheared, rotated = (
        sym3.shear(sym3.entries(cov_a), dx, dy),
        sym3.rotate(sym3.entries(cov_b), c, s),
    )
    total = tuple(p + q for p, q in zip(sheared, rotated, strict=True))
    return mean, sym3.to_matrix(total)  # type: ignore[arg-type]


@overload
def reverse(a: AT, *, jacobian: Literal[False] = ...) -> AT: ...
@overload
def reverse(a: AT, *, jacobian: Literal[True]) -> tuple[AT, FloatArray]: ...
def reverse(a: AT, *, jacobian: bool = False) -> AT | tuple[AT, FloatArray]:
    """Reverse ``Aᴿ``: where A's parent frame is, seen from A's child frame (Eqs. 5-7).

    ``C' = R C Rᵀ`` with R of Eq. (7). With ``jacobian=True`` also returns R (``(..., 3, 3)``);
    the cross-covariance of A with its own reversal is then ``C_A Rᵀ``, which
    :func:`compound` accepts as ``cross_cov``. An :class:`AT3` reverses in 3-D.
    """
    same_kind((a,))
    return a._reverse(bool(jacobian))  # type: ignore[no-any-return]


def merge(
    *ats: AT,
    atol: float = 1e-9,
    cross_cov: ArrayLike | None = None,
    joint_cov: ArrayLike | None = None,
) -> AT:
    """Merge parallel ATs of the same relation ``A ⊗ B ⊗ …`` (Eqs. 8-10); order-independent.

    Pairwise Kalman update ``K = C₁ (C₁ + C₂)⁻¹``, ``x̂ = x̂₁ + K (x̂₂ ⊟ x̂₁)`` with the heading
    innovation wrapped, and the covariance in Joseph form ``(I - K) C₁ (I - K)ᵀ + K C₂ Kᵀ``
    (Eq. 9's ``C₁ - K C₁`` cancels catastrophically when C₁ is large: with C₁ = 10¹² I it
    loses about 1%). Components with zero variance (exactly known) are allowed. When
    ``C₁ + C₂`` is singular the update uses a generalized inverse, provided the means agree,
    within ``atol`` (metres/radians), along the directions both know exactly; otherwise
    :class:`InconsistentMergeError` is raised. The inputs are assumed independent unless
    ``cross_cov`` or ``joint_cov`` says otherwise. :class:`AT3` inputs merge in 3-D
    (:func:`relmap.uncertain.at3.merge3`).

    **Correlated ATs** (the paper's §4.2 extension): ``cross_cov`` (``(..., dof, dof)``,
    ``E[δA δBᵀ]``, two ATs) or ``joint_cov`` (``(..., dof·k, dof·k)``, k ATs, diagonal blocks
    their own covariances) give the best linear unbiased merge:
    ``K = (C₁ - C₁₂) S⁺``, ``S = C₁ + C₂ - C₁₂ - C₂₁``, covariance
    ``C₁ - K (C₁ - C₁₂)ᵀ``; for k ATs the same from the differences ``d_j = x̂_j ⊟ x̂₁``:
    ``x̂ = x̂₁ - Cov(e₁, d) Cov(d)⁺ d`` (generalized least squares with the joint
    covariance, written so that exactly known components are allowed). A joint covariance
    that is not symmetric PSD, or whose diagonal blocks differ from the ATs' covariances,
    raises a :class:`relmap.errors.CovarianceError` (or :class:`~relmap.errors.ShapeError`)
    naming it.
    """
    if not ats:
        raise ShapeError("merge needs at least one AT")
    atol = gaussian.check_tolerance(atol, "atol")

    if cross_cov is not None or joint_cov is not None:
        return _merge_correlated(ats, cross_cov, joint_cov, atol)  # type: ignore[return-value]
    kind = same_kind(ats)
    if len(ats) == 1:
        return ats[0]
    common_batch("merge", ats)
    return kind._merge(ats, atol)  # type: ignore[return-value]


def _merge_correlated(
    ats: Sequence[UncertainPose],
    cross_cov: ArrayLike | None,
    joint_cov: ArrayLike | None,
    atol: float,
) -> UncertainPose:
    """:func:`merge` of ATs with a cross-covariance (two) or a joint covariance (k)."""
    from relmap.errors import NotPositiveSemidefiniteError

    kind = same_kind(ats)
    group, k = ats[0].group, len(ats)
    b = group.dof
    if cross_cov is not None and joint_cov is not None:
        raise ParameterError("give cross_cov (two ATs) or joint_cov (any number), not both")
    shape = common_batch("merge", ats)
    if cross_cov is not None:
        if k != 2:
            raise ShapeError(f"cross_cov is for two ATs; got {k} (give joint_cov instead)")
        X = np.asarray(cross_cov, dtype=np.float64)
        if X.shape[-2:] != (b, b):
            raise ShapeError(f"cross_cov must have shape (..., {b}, {b}); got {X.shape}")
        gaussian.check_finite(X, "cross_cov")
        # the gains on the covariances' own batch shape (once for a covariance shared by all)
        C1, C2 = compact(ats[0].cov, 2), compact(ats[1].cov, 2)
        own = gaussian.broadcast("merge", C1.shape[:-2], C2.shape[:-2], X.shape[:-2])
        C1, C2, X = (np.broadcast_to(M, (*own, b, b)) for M in (C1, C2, X))
        joint = np.block([[C1, X], [np.swapaxes(X, -1, -2), C2]])
        name = "the joint covariance of the two ATs (with cross_cov)"
    else:
        joint = np.asarray(joint_cov, dtype=np.float64)
        if joint.shape[-2:] != (b * k, b * k):
            raise ShapeError(
                f"joint_cov of {k} ATs must have shape (..., {b * k}, {b * k}); got {joint.shape}"
            )
        own = gaussian.broadcast(
            "merge", joint.shape[:-2], *(compact(a.cov, 2).shape[:-2] for a in ats)
        )
        joint = np.broadcast_to(joint, (*own, b * k, b * k))
        name = "joint_cov"
        for i, a in enumerate(ats):
            block = joint[..., b * i : b * i + b, b * i : b * i + b]
            if not np.allclose(block, compact(a.cov, 2), rtol=1e-9, atol=1e-12):
                raise ShapeError(
                    f"joint_cov's diagonal block {i} differs from the covariance of AT #{i}"
                )
    if gaussian.broadcast("merge", own, shape) != shape:
        raise ShapeError(f"{name} has batch shape {own}; the ATs' is {shape}")
    try:
        joint = gaussian.validate_covariance(joint, name=name)
    except NotPositiveSemidefiniteError as exc:
        raise NotPositiveSemidefiniteError(
            f"{exc}: the cross-covariances are impossible for these ATs' covariances"
        ) from None
    # BLUE from the first AT and the differences d_j = z_j ⊟ z_1 (x cancels from them):
    # x̂ = z_1 - K d, C = C_1 - K Xᵀ, K = Cov(e_1, d) Cov(d)⁺, X = Cov(e_1, d).
    K, X, null = gaussian.difference_merge_gain(joint, b, k)
    mean0 = np.broadcast_to(ats[0].mean, (*shape, *group.point_shape))
    d = np.concatenate(
        [np.broadcast_to(group.minus(a.mean, ats[0].mean), (*shape, b)) for a in ats[1:]], -1
    )
    gaussian.check_agreement(d, null, atol=atol, what="the correlated ATs")
    mean = group.plus(mean0, -np.einsum("...ij,...j->...i", K, d))
    C = joint[..., :b, :b] - K @ np.swapaxes(X, -1, -2)
    C = 0.5 * (C + np.swapaxes(C, -1, -2))
    return kind._trusted(mean, C)


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


def compound_chain(steps: AT, *, axis: int = -1, moments: MomentsMethod = "first_order") -> AT:
    """Every prefix of the chain ``A₁ ⊕ A₂ ⊕ … ⊕ Aₙ`` laid along batch ``axis`` of ``steps``.

    Returns an AT of the same batch shape whose element k along ``axis`` is
    ``A₁ ⊕ … ⊕ A_k`` (frame k in the chain's first parent frame): the same as compounding one
    step at a time, with independent steps (Eq. 4's assumption), but without a Python loop over
    the steps.

    Compounding is associative, to first order exactly (the H Jacobians telescope), so the
    prefixes come from a parallel scan: compound neighbouring pairs, recurse on the pairs'
    results, then fill in the even prefixes, each level one vectorized compound. It costs about
    two batched compounds in all (O(n) work, log₂ n levels) and every covariance is a sum of
    congruences of PSD matrices, so it stays PSD to rounding as in sequential compounding.

    ``moments="exact"`` gives instead the exact mean and covariance of every prefix for
    Gaussian steps (:func:`relmap.uncertain.moments.chain_moments`, O(n log n));
    ``moments="unscented"`` the unscented transform one step at a time, as repeated
    ``compound(..., moments="unscented")`` (:func:`relmap.uncertain.moments.unscented_chain`, a loop
    over the steps).

    An :class:`AT3` chain is compounded in 3-D (:func:`relmap.uncertain.at3.compound_chain3`; first
    order
    only).
    """
    kind = same_kind((steps,))
    if moments != "first_order":
        _moments.check_method(moments)
        _second_order_for(kind, moments)
    axis = chain_axis(steps, axis, "compound_chain")
    if moments == "first_order":
        return steps._chain(axis)
    f = _moments.chain_moments if moments == "exact" else _moments.unscented_chain
    mean, cov = f(steps.mean, steps.cov, axis=axis)
    check_result(f"compound_chain (moments={moments!r})", mean, cov)
    return AT._trusted(mean, cov)


def _scan(mean: FloatArray, cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inclusive prefix compounds along axis 0 (recursive pairing; depth log₂ n), on the nine
    distinct numbers of each AT kept as separate arrays until the end."""
    parts = (mean[..., 0], mean[..., 1], mean[..., 2], *sym3.entries(cov))
    x, y, t, *entries = _scan_parts(parts)
    return stack_last([x, y, t], mean.shape[:-1]), sym3.to_matrix(tuple(entries))  # type: ignore[arg-type]


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
    """:func:`_compound_arrays` on parts ``(x, y, θ, c00, c01, c02, c11, c12, c22)`` of wrapped
    poses: their headings sum within [-2π, 2π), so one shift wraps them."""
    xa, ya, ta, *ca = a
    xb, yb, tb, *cb = b
    c, s = np.cos(ta), np.sin(ta)
    dx = c * xb - s * yb
    dy = s * xb + c * yb
    t = ta + tb
    np.subtract(t, _TWO_PI, out=t, where=t >= np.pi)
    np.add(t, _TWO_PI, out=t, where=t < -np.pi)
    sheared = sym3.shear(tuple(ca), dx, dy)  # type: ignore[arg-type]
    rotated = sym3.rotate(tuple(cb), c, s)  # type: ignore[arg-type]
    return (xa + dx, ya + dy, t, *(u + w for u, w in zip(sheared, rotated, strict=True)))
