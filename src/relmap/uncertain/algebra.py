"""The algebra of uncertain poses, one set of functions for both kinds: an :class:`relmap.AT`
(SE(2)) and an :class:`relmap.AT3` (SE(3)) compound, reverse and merge through the same names.

- :func:`compound` (``a @ b``, ⊕): serial poses, Eqs. (1)-(4); uncertainty grows.
- :func:`reverse` (``a.reverse()``, ᴿ): the inverse, Eqs. (5)-(7).
- :func:`merge` (⊗): parallel poses, Eqs. (8)-(10); uncertainty shrinks (a static Kalman update).
- :func:`compound_chain`: every prefix of a long chain at once.

Each function checks its arguments once — one kind (:func:`~relmap.uncertain.pose.same_kind`), a
cross-covariance (:func:`~relmap.uncertain.pose.checked_cross_cov`), a chain's axis — and then
calls the kind's own operation, written in the kind's module (:mod:`relmap.uncertain.at`,
:mod:`relmap.uncertain.at3`); no function asks ``isinstance``. The moments beyond first order
(SE(2) only) come from :mod:`relmap.uncertain.moments`.

A flag ``jacobians=True`` asks an operation to return its Jacobians as well, as in
:mod:`relmap.lie` (``se2.compose(a, b, jacobians=True)``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, TypeVar, overload

import numpy as np

from relmap._layout import compact
from relmap.errors import NotPositiveSemidefiniteError, ParameterError, ShapeError
from relmap.lie.group import SE2
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain import gaussian
from relmap.uncertain import moments as _moments
from relmap.uncertain.moments import MomentsMethod
from relmap.uncertain.pose import (
    UncertainPose,
    chain_axis,
    check_result,
    checked_cross_cov,
    common_batch,
    same_kind,
)

__all__ = ["compound", "compound_chain", "merge", "reverse"]

P = TypeVar("P", bound=UncertainPose)


def compound(
    a: P,
    b: P,
    *,
    cross_cov: ArrayLike | None = None,
    moments: MomentsMethod | str = MomentsMethod.FIRST_ORDER,
) -> P:
    """Compound ``a ⊕ b``: b's frame given relative to a's, expressed in a's parent (Eqs. 1-4).

    ``C = H C_a Hᵀ + K C_b Kᵀ`` with H, K of Eq. (3). The paper assumes a and b independent;
    for a dependent pair (§3.2) give ``cross_cov = E[δa δbᵀ]`` (``(..., dof, dof)``), which adds
    ``H C_ab Kᵀ + K C_abᵀ Hᵀ``. Batch axes broadcast. Two :class:`~relmap.AT3` compound in 3-D:
    ``C = J_a C_a J_aᵀ + J_b C_b J_bᵀ`` with ``J_a = [[I, -[R_a t_b]×], [0, I]]``,
    ``J_b = blkdiag(R_a, R_a)`` (:func:`relmap.lie.se3.compose`), 6×6 ``cross_cov``.

    ``moments`` (a :class:`~relmap.uncertain.moments.MomentsMethod`; SE(2) only beyond the
    first order): ``"first_order"`` (default) is Eqs. (1)-(4); ``"exact"`` the exact mean and
    covariance for Gaussian a, b (:func:`relmap.uncertain.moments.compound_moments`);
    ``"unscented"`` the unscented transform (:func:`relmap.uncertain.moments.unscented_compound`).
    """
    kind = same_kind((a, b))
    method = MomentsMethod.parse(moments, "moments")
    X = None if cross_cov is None else checked_cross_cov(a.cov, b.cov, cross_cov, kind.group.dof)
    if method is MomentsMethod.FIRST_ORDER:
        return a._compound(b, X)
    _second_order_for(kind, method)
    f = _moments.compound_moments if method is MomentsMethod.EXACT else _moments.unscented_compound
    mean, cov = f(a.mean, a.cov, b.mean, b.cov, cross_cov=X)
    check_result(f"compound (moments={method.value!r})", mean, cov)
    return kind._trusted(mean, cov)  # type: ignore[return-value]


def _second_order_for(kind: type[UncertainPose], method: MomentsMethod) -> None:
    """Moments beyond first order exist for SE(2) (:mod:`relmap.uncertain.moments`) only."""
    if kind.group is not SE2:
        raise ParameterError(f"moments={method.value!r} is available for SE(2) ATs only")


@overload
def reverse(a: P, *, jacobians: Literal[False] = ...) -> P: ...
@overload
def reverse(a: P, *, jacobians: Literal[True]) -> tuple[P, FloatArray]: ...
def reverse(a: P, *, jacobians: bool = False) -> P | tuple[P, FloatArray]:
    """Reverse ``Aᴿ``: where A's parent frame is, seen from A's child frame (Eqs. 5-7).

    ``C' = R C Rᵀ`` with R of Eq. (7) (in 3-D, R the inverse's Jacobian,
    :func:`relmap.lie.se3.inverse`). With ``jacobians=True`` also returns R
    (``(..., dof, dof)``); the cross-covariance of A with its own reversal is then ``C_A Rᵀ``,
    which :func:`compound` accepts as ``cross_cov``.
    """
    same_kind((a,))
    return a._reverse(bool(jacobians))


def merge(
    *ats: P,
    atol: float = 1e-9,
    cross_cov: ArrayLike | None = None,
    joint_cov: ArrayLike | None = None,
) -> P:
    """Merge parallel ATs of the same relation ``A ⊗ B ⊗ …`` (Eqs. 8-10); order-independent.

    Pairwise Kalman update ``K = C₁ (C₁ + C₂)⁻¹``, ``x̂ = x̂₁ + K (x̂₂ ⊟ x̂₁)`` with the heading
    innovation wrapped, and the covariance in Joseph form ``(I - K) C₁ (I - K)ᵀ + K C₂ Kᵀ``
    (Eq. 9's ``C₁ - K C₁`` cancels catastrophically when C₁ is large: with C₁ = 10¹² I it
    loses about 1%). Components with zero variance (exactly known) are allowed. When
    ``C₁ + C₂`` is singular the update uses a generalized inverse, provided the means agree,
    within ``atol`` (metres/radians), along the directions both know exactly; otherwise
    :class:`InconsistentMergeError` is raised. The inputs are assumed independent unless
    ``cross_cov`` or ``joint_cov`` says otherwise. :class:`AT3` inputs merge in 3-D, fused in
    the chart at a common pose that is iterated to a fixed point symmetric in the inputs (the
    rotation chart is curved: pairwise fusion in each AT's own chart would depend on the order).

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
        return _merge_correlated(ats, cross_cov, joint_cov, atol)
    kind = same_kind(ats)
    if len(ats) == 1:
        return ats[0]
    common_batch("merge", ats)
    return kind._merge(ats, atol)  # type: ignore[return-value]


def _merge_correlated(
    ats: Sequence[P], cross_cov: ArrayLike | None, joint_cov: ArrayLike | None, atol: float
) -> P:
    """:func:`merge` of ATs with a cross-covariance (two) or a joint covariance (k)."""
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
    return kind._trusted(mean, C)  # type: ignore[return-value]


def compound_chain(
    steps: P, *, axis: int = -1, moments: MomentsMethod | str = MomentsMethod.FIRST_ORDER
) -> P:
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

    An :class:`AT3` chain is compounded in 3-D, one batched compound per step along ``axis``
    (vectorized across the chains; first order only).
    """
    kind = same_kind((steps,))
    method = MomentsMethod.parse(moments, "moments")
    if method is not MomentsMethod.FIRST_ORDER:
        _second_order_for(kind, method)
    axis = chain_axis(steps, axis, "compound_chain")
    if method is MomentsMethod.FIRST_ORDER:
        return steps._chain(axis)
    f = _moments.chain_moments if method is MomentsMethod.EXACT else _moments.unscented_chain
    mean, cov = f(steps.mean, steps.cov, axis=axis)
    check_result(f"compound_chain (moments={method.value!r})", mean, cov)
    return kind._trusted(mean, cov)  # type: ignore[return-value]
