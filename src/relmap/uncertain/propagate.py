"""First-order propagation of uncertainty through any function, and the unscented transform.

The lecture's Eqs. (7)-(8): for ``y = f(x)`` with ``x ~ (x̂, Σx)``, to first order
``ŷ = f(x̂)`` and ``Σy = J Σx Jᵀ`` with ``J = ∂f/∂x`` at ``x̂``. The Jacobian can be given
(a matrix or a function of x) or computed by :func:`numerical_jacobian`, the one numeric
differentiator the test suite checks every analytic Jacobian against.

Functions are batched: ``f`` maps ``(..., n)`` to ``(..., m)`` and must accept extra leading
axes (it is evaluated on all perturbations at once). Non-Euclidean inputs or outputs (angles,
poses) are handled by giving their :class:`Chart` (``plus(x, δ)`` and ``minus(y1, y0)``):
:data:`SE2` is relmap's pose chart, which wraps headings; :data:`EUCLIDEAN` is the default.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2, se3
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain.gaussian import (
    _sqrt_psd,
    check_finite,
    congruence,
    real_array,
    validate_covariance,
)

__all__ = [
    "EUCLIDEAN",
    "SE2",
    "SE3",
    "Chart",
    "Moments",
    "numerical_jacobian",
    "propagate",
    "unscented",
]

Function = Callable[[FloatArray], FloatArray]


class Chart(NamedTuple):
    """How to perturb a quantity and how to difference two of them.

    ``plus(x, δ)`` moves x by a tangent vector δ; ``minus(y1, y0)`` is the δ with
    ``plus(y0, δ) = y1``. Both broadcast over leading axes. Points are vectors ``(..., n)``
    unless ``point_ndim`` says otherwise (2 for SE(3)'s ``(..., 4, 4)`` matrices, whose tangent
    has ``dof`` components).
    """

    plus: Callable[[FloatArray, FloatArray], FloatArray]
    minus: Callable[[FloatArray, FloatArray], FloatArray]
    point_ndim: int = 1
    dof: int | None = None


class Moments(NamedTuple):
    """Mean ``(..., m)`` and covariance ``(..., m, m)`` of a propagated quantity."""

    mean: FloatArray
    cov: FloatArray


def _add(x: FloatArray, delta: FloatArray) -> FloatArray:
    return x + delta


def _sub(y1: FloatArray, y0: FloatArray) -> FloatArray:
    return y1 - y0


#: Plain vectors: ``x + δ`` and ``y1 - y0``.
EUCLIDEAN = Chart(_add, _sub)

#: SE(2) poses ``(x, y, θ)`` in relmap's covariance chart (heading wrapped).
SE2 = Chart(se2.plus, se2.minus)

#: SE(3) poses ``(..., 4, 4)`` in relmap's covariance chart ``(δt, δφ)`` (left rotation).
SE3 = Chart(se3.plus, se3.minus, point_ndim=2, dof=se3.DOF)


def _checked_input(mean: ArrayLike, cov: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """The input mean (real, finite, at least one axis) and covariance (symmetric PSD,
    :func:`relmap.uncertain.gaussian.validate_covariance`) of :func:`propagate` and
    :func:`unscented`."""
    m = real_array(mean, "mean")
    if m.ndim == 0:
        raise ShapeError("mean must have shape (..., n); got a scalar")
    check_finite(m, "mean")
    return m, validate_covariance(cov)


def numerical_jacobian(
    f: Function,
    x: ArrayLike,
    *,
    step: float = 1e-6,
    chart_in: Chart = EUCLIDEAN,
    chart_out: Chart = EUCLIDEAN,
) -> FloatArray:
    """Central-difference Jacobian of ``f`` at ``x`` (``(..., n)``, or SE(3) poses
    ``(..., 4, 4)`` with ``chart_in=SE3``), shape ``(..., m, n)``.

    ``J[..., :, j] = minus(f(plus(x, h e_j)), f(plus(x, -h e_j))) / 2h``, perturbing in
    ``chart_in`` and differencing in ``chart_out``. All 2n evaluations go through ``f`` in one
    batched call. Truncation error is O(h²), rounding O(ε/h).
    """
    if not step > 0:
        raise ParameterError(f"step must be positive; got {step}")
    plus, minus = chart_in.plus, chart_out.minus
    x = np.asarray(x, dtype=np.float64)
    k = chart_in.point_ndim
    if x.ndim < k:
        raise ShapeError(f"x must have {k} trailing point axes; got shape {x.shape}")
    n = x.shape[-1] if chart_in.dof is None else chart_in.dof
    delta = step * np.eye(n)  # row j perturbs component j
    point = x.shape[x.ndim - k :]
    xb = np.broadcast_to(np.expand_dims(x, x.ndim - k), (*x.shape[: x.ndim - k], n, *point))
    f_plus = np.asarray(plus(xb, delta), dtype=np.float64)
    f_minus = np.asarray(plus(xb, -delta), dtype=np.float64)
    diff = minus(np.asarray(f(f_plus)), np.asarray(f(f_minus))) / (2.0 * step)  # (..., n, m)
    return np.swapaxes(diff, -1, -2)


def propagate(
    f: Function,
    mean: ArrayLike,
    cov: ArrayLike,
    *,
    jacobian: ArrayLike | Function | None = None,
    chart_in: Chart = EUCLIDEAN,
    chart_out: Chart = EUCLIDEAN,
) -> Moments:
    """First-order moments of ``y = f(x)``: ``ŷ = f(x̂)``, ``Σy = J Σx Jᵀ`` (lecture Eqs. 7-8).

    ``jacobian`` is the ``(..., m, n)`` matrix, a function of x returning it, or None for the
    numeric one (in the given charts). Exact when f is linear. (relmap's names: ``jacobian=``
    *gives* the one Jacobian to use, as here; a flag ``jacobians=True`` *asks* an operation to
    return its Jacobians too, as :func:`relmap.lie.se2.compose` and :func:`relmap.reverse`.)
    """
    mean, cov = _checked_input(mean, cov)
    if cov.shape[-2:] != (mean.shape[-1], mean.shape[-1]):
        raise ShapeError(
            f"cov must have shape (..., n, n) with n = {mean.shape[-1]}; got {cov.shape}"
        )
    if jacobian is None:
        J = numerical_jacobian(f, mean, chart_in=chart_in, chart_out=chart_out)
    elif callable(jacobian):
        J = np.asarray(jacobian(mean), dtype=np.float64)
    else:
        J = np.asarray(jacobian, dtype=np.float64)
    y = np.asarray(f(mean), dtype=np.float64)
    if J.shape[-2:] != (y.shape[-1], mean.shape[-1]):
        raise ShapeError(
            f"jacobian must have shape (..., {y.shape[-1]}, {mean.shape[-1]}); got {J.shape}"
        )
    return Moments(y, congruence(J, cov))


def unscented(
    f: Function,
    mean: ArrayLike,
    cov: ArrayLike,
    *,
    alpha: float = 1.0,
    beta: float = 2.0,
    kappa: float = 0.0,
    chart_in: Chart = EUCLIDEAN,
    chart_out: Chart = EUCLIDEAN,
) -> Moments:
    """Moments of ``y = f(x)`` by the scaled unscented transform (van der Merwe's sigma points).

    2n+1 sigma points ``x̂`` and ``chart_in.plus(x̂, ±√(n+λ)·Lᵢ)`` with ``L Lᵀ = Σx`` (a
    symmetric square root, so singular Σx is fine) and ``λ = α²(n+κ) - n``. Weights:
    ``Wm₀ = λ/(n+λ)``, ``Wc₀ = Wm₀ + 1 - α² + β``, ``Wᵢ = 1/(2(n+λ))``. The defaults
    ``α = 1, β = 2, κ = 0`` give non-negative weights (so Σy is PSD) and points at ±√n σ.
    Output mean and deviations are taken in ``chart_out`` around the central point, so angles
    average correctly.
    """
    plus, minus = chart_in.plus, chart_out.minus
    mean, cov = _checked_input(mean, cov)
    n = mean.shape[-1]
    lam = alpha * alpha * (n + kappa) - n
    if not n + lam > 0:
        raise ParameterError(f"alpha²·(n + kappa) must be positive; got {n + lam}")
    if cov.shape[-1] != n:
        raise ShapeError(f"cov must have shape (..., {n}, {n}); got {cov.shape}")
    L = _sqrt_psd(cov) * np.sqrt(n + lam)  # columns are the sigma directions
    offsets = np.swapaxes(L, -1, -2)  # (..., n, n): row i is column i of L
    batch = np.broadcast_shapes(mean.shape[:-1], offsets.shape[:-2])
    xb = np.broadcast_to(mean[..., None, :], (*batch, n, n))
    offsets = np.broadcast_to(offsets, (*batch, n, n))
    points = np.concatenate(
        [np.broadcast_to(mean, (*batch, n))[..., None, :], plus(xb, offsets), plus(xb, -offsets)],
        axis=-2,
    )
    y = np.asarray(f(points), dtype=np.float64)  # (..., 2n+1, m)
    w_mean = np.full(2 * n + 1, 1.0 / (2.0 * (n + lam)))
    w_cov = w_mean.copy()
    w_mean[0] = lam / (n + lam)
    w_cov[0] = w_mean[0] + 1.0 - alpha * alpha + beta
    y0 = y[..., :1, :]
    shift = np.einsum("k,...km->...m", w_mean, minus(y, np.broadcast_to(y0, y.shape)))
    y_mean = chart_out.plus(y0[..., 0, :], shift)
    d = minus(y, np.broadcast_to(y_mean[..., None, :], y.shape))
    cov_y = np.einsum("k,...ki,...kj->...ij", w_cov, d, d)
    return Moments(y_mean, cov_y)
