"""SE(2) geometry on ``(x, y, θ)`` arrays: compose, inverse, between, exp/log, adjoint.

Geometry only, no covariance. Every function takes poses as float arrays of shape ``(..., 3)``
holding ``(x, y, θ)``, broadcasts leading batch axes like numpy, and returns θ wrapped to
[-π, π).

**Jacobian chart.** Jacobians are plain partial derivatives with respect to the ``(x, y, θ)``
parameters, the chart of Smith & Cheeseman (1986) in which relmap stores covariances (translation
and heading perturbed in the *parent* frame). So ``Σ_out = J Σ_in Jᵀ`` holds directly, as in the
paper's Eq. (4). Jacobians are named ``J_<out>_<in>`` and returned only when asked for
(``jacobians=True``), each of shape ``(..., 3, 3)``.

The Lie-algebra functions :func:`exp`, :func:`log` and :func:`adjoint` use the right (body)
convention of GTSAM and manif, tangent ordered ``(vx, vy, ω)``; :func:`body_to_chart` converts a
body-frame perturbation into the paper's chart.
"""

from __future__ import annotations

import math
from typing import Any, Literal, overload

import numpy as np

from relmap._layout import matrix, stack_last
from relmap.errors import ShapeError
from relmap.typing import ArrayLike, FloatArray

__all__ = [
    "DOF",
    "adjoint",
    "angle_difference",
    "between",
    "body_to_chart",
    "compose",
    "exp",
    "identity",
    "inverse",
    "log",
    "minus",
    "plus",
    "wrap_angle",
]

#: Degrees of freedom of SE(2): the length of a pose vector and of its tangent.
DOF = 3

_TWO_PI = 2.0 * np.pi


def _pose(a: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != DOF:
        raise ShapeError(f"{name} must have shape (..., 3) holding (x, y, θ); got {arr.shape}")
    return arr


def wrap_angle(theta: ArrayLike) -> FloatArray:
    """Wrap angles (radians) to [-π, π); elementwise, any shape."""
    if isinstance(theta, float) and -np.pi <= theta < np.pi:  # one angle in range: at once
        return np.array(theta)
    theta = np.asarray(theta, dtype=np.float64)
    # Angles already in range are returned untouched: shifting by π would cost them an ulp of π.
    inside = (theta >= -np.pi) & (theta < np.pi)
    if inside.all():
        return theta.copy()
    # θ - 2π k, k = ⌊(θ + π)/2π⌋ (not np.mod, many times slower on large arrays)
    wrapped = theta - _TWO_PI * np.floor((theta + np.pi) / _TWO_PI)
    # rounding can land a result on +π (or a hair outside): folded back
    wrapped = np.where(wrapped >= np.pi, wrapped - _TWO_PI, wrapped)
    wrapped = np.where(wrapped < -np.pi, wrapped + _TWO_PI, wrapped)
    return np.where(inside, theta, wrapped)


def angle_difference(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """``a − b`` wrapped to [-π, π): the signed smallest rotation taking angle b to angle a."""
    return wrap_angle(np.subtract(a, b, dtype=np.float64))


def identity(batch_shape: tuple[int, ...] = ()) -> FloatArray:
    """The identity pose ``(0, 0, 0)``, shape ``(*batch_shape, 3)``."""
    return np.zeros((*batch_shape, DOF))


def _compose_terms(a: FloatArray, b: FloatArray) -> tuple[FloatArray, Any, Any, Any, Any]:
    """``a ∘ b`` and the pieces its Jacobians and covariance are made of: ``(a ∘ b, cos θ_a,
    sin θ_a, Δx, Δy)`` with ``(Δx, Δy) = R(θ_a) t_b`` (the trigonometry is computed once);
    the pieces are arrays, or floats for two single poses."""
    c: Any
    s: Any
    if a.ndim == 1 and b.ndim == 1:  # two poses: Python floats, far cheaper to combine, and
        xa, ya, ta = a.tolist()  # math's cos and sin (bitwise numpy's here, and faster)
        xb, yb, tb = b.tolist()
        c, s = math.cos(ta), math.sin(ta)
    else:
        xa, ya, ta = a[..., 0], a[..., 1], a[..., 2]
        xb, yb, tb = b[..., 0], b[..., 1], b[..., 2]
        c, s = np.cos(ta), np.sin(ta)
    dx = c * xb - s * yb  # b's translation rotated into a's parent frame
    dy = s * xb + c * yb
    shape = a.shape[:-1] if a.shape == b.shape else np.broadcast_shapes(a.shape[:-1], b.shape[:-1])
    out = stack_last([xa + dx, ya + dy, wrap_angle(ta + tb)], shape)
    return out, c, s, dx, dy


@overload
def compose(a: ArrayLike, b: ArrayLike, *, jacobians: Literal[False] = ...) -> FloatArray: ...
@overload
def compose(
    a: ArrayLike, b: ArrayLike, *, jacobians: Literal[True]
) -> tuple[FloatArray, FloatArray, FloatArray]: ...
def compose(
    a: ArrayLike, b: ArrayLike, *, jacobians: bool = False
) -> FloatArray | tuple[FloatArray, FloatArray, FloatArray]:
    """Compose ``c = a ∘ b``: frame b given in frame a, expressed in a's parent (Eq. 1).

    With ``jacobians=True`` returns ``(c, J_c_a, J_c_b)``, the paper's H and K (Eq. 3):
    ``J_c_a = [[1, 0, -(y_c - y_a)], [0, 1, x_c - x_a], [0, 0, 1]]`` and
    ``J_c_b = blkdiag(R(θ_a), 1)``.
    """
    out, c, s, dx, dy = _compose_terms(_pose(a, "a"), _pose(b, "b"))
    if not jacobians:
        return out
    shape = out.shape[:-1]
    J_c_a = matrix([[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]], shape)
    J_c_b = matrix([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], shape)
    return out, J_c_a, J_c_b


@overload
def inverse(a: ArrayLike, *, jacobians: Literal[False] = ...) -> FloatArray: ...
@overload
def inverse(a: ArrayLike, *, jacobians: Literal[True]) -> tuple[FloatArray, FloatArray]: ...
def inverse(a: ArrayLike, *, jacobians: bool = False) -> FloatArray | tuple[FloatArray, FloatArray]:
    """Invert ``a``: where a's parent frame is, seen from a (the paper's reversal, Eq. 5).

    With ``jacobians=True`` returns ``(a_inv, J_inv_a)``, the paper's R of Eq. (7):
    ``[[-cos θ, -sin θ, y'], [sin θ, -cos θ, -x'], [0, 0, -1]]``.
    """
    a = _pose(a, "a")
    x, y, t = a[..., 0], a[..., 1], a[..., 2]
    c, s = np.cos(t), np.sin(t)
    xi = -x * c - y * s
    yi = x * s - y * c
    out = stack_last([xi, yi, wrap_angle(-t)], t.shape)
    if not jacobians:
        return out
    J = matrix([[-c, -s, yi], [s, -c, -xi], [0.0, 0.0, -1.0]], out.shape[:-1])
    return out, J


@overload
def between(a: ArrayLike, b: ArrayLike, *, jacobians: Literal[False] = ...) -> FloatArray: ...
@overload
def between(
    a: ArrayLike, b: ArrayLike, *, jacobians: Literal[True]
) -> tuple[FloatArray, FloatArray, FloatArray]: ...
def between(
    a: ArrayLike, b: ArrayLike, *, jacobians: bool = False
) -> FloatArray | tuple[FloatArray, FloatArray, FloatArray]:
    """The relative pose ``d = a⁻¹ ∘ b``: frame b seen from frame a (a, b in a common parent).

    With ``jacobians=True`` returns ``(d, J_d_a, J_d_b)`` with
    ``J_d_a = [[-c, -s, y_d], [s, -c, -x_d], [0, 0, -1]]`` and ``J_d_b = blkdiag(R(θ_a)ᵀ, 1)``.
    """
    a = _pose(a, "a")
    b = _pose(b, "b")
    ta = a[..., 2]
    c, s = np.cos(ta), np.sin(ta)
    ex = b[..., 0] - a[..., 0]
    ey = b[..., 1] - a[..., 1]
    xd = c * ex + s * ey
    yd = -s * ex + c * ey
    shape = np.broadcast_shapes(a.shape[:-1], b.shape[:-1])
    out = stack_last([xd, yd, angle_difference(b[..., 2], ta)], shape)
    if not jacobians:
        return out
    shape = out.shape[:-1]
    J_d_a = matrix([[-c, -s, yd], [s, -c, -xd], [0.0, 0.0, -1.0]], shape)
    J_d_b = matrix([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]], shape)
    return out, J_d_a, J_d_b


def plus(a: ArrayLike, delta: ArrayLike) -> FloatArray:
    """Perturb ``a`` by ``delta`` in the covariance chart: ``(x, y, θ) + δ``, θ wrapped.

    This is the chart in which relmap's covariances and Jacobians live (parent-frame
    translation, heading about the frame's own origin).
    """
    a = _pose(a, "a")
    delta = _pose(delta, "delta")
    out = a + delta
    out[..., 2] = wrap_angle(out[..., 2])
    return out


def minus(b: ArrayLike, a: ArrayLike) -> FloatArray:
    """Chart difference ``b ⊟ a = (x_b - x_a, y_b - y_a, wrap(θ_b - θ_a))``; undoes :func:`plus`."""
    a = _pose(a, "a")
    b = _pose(b, "b")
    out = b - a
    out[..., 2] = wrap_angle(out[..., 2])
    return out


def body_to_chart(a: ArrayLike) -> FloatArray:
    """``M = blkdiag(R(θ), 1)``, shape ``(..., 3, 3)``: maps a body-frame perturbation to the chart.

    A perturbation ``a ∘ Exp(ξ)`` (GTSAM, manif, g2o) equals, to first order, the chart
    perturbation ``a + M ξ``; hence ``Σ_chart = M Σ_body Mᵀ``. Note that M is not the full SE(2)
    adjoint (which would also mix the heading into the translation).
    """
    a = _pose(a, "a")
    t = a[..., 2]
    c, s = np.cos(t), np.sin(t)
    return matrix([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], t.shape)


# exp/log are written in forms without cancellation (1 - cos ω = 2 sin²(ω/2)), accurate to
# rounding for every ω ≠ 0. Only below _TINY, where ω² underflows, are the limits used; they are
# exact there to float64 rounding (the next series terms are O(ω²) relative).
_TINY = 1e-150


def exp(xi: ArrayLike) -> FloatArray:
    """Exponential map of the Lie algebra, ``ξ = (vx, vy, ω)`` → pose (GTSAM's ``Pose2.Expmap``).

    ``t = V(ω) v`` with ``V = [[sin ω/ω, -(1-cos ω)/ω], [(1-cos ω)/ω, sin ω/ω]]``.
    """
    xi = _pose(xi, "xi")
    vx, vy, w = xi[..., 0], xi[..., 1], xi[..., 2]
    tiny = np.abs(w) < _TINY
    w_safe = np.where(tiny, 1.0, w)
    sin_over = np.where(tiny, 1.0, np.sin(w_safe) / w_safe)
    cos_over = np.where(tiny, 0.5 * w, 2.0 * np.sin(0.5 * w_safe) ** 2 / w_safe)
    x = sin_over * vx - cos_over * vy
    y = cos_over * vx + sin_over * vy
    return stack_last([x, y, wrap_angle(w)], w.shape)


def log(a: ArrayLike) -> FloatArray:
    """Logarithm map, pose → ``ξ = (vx, vy, ω)`` with ω in [-π, π) (GTSAM's ``Pose2.Logmap``).

    ``v = V(ω)⁻¹ t`` with ``V⁻¹ = [[h, ω/2], [-ω/2, h]]``, ``h = (ω/2) cot(ω/2)``.
    """
    a = _pose(a, "a")
    w = wrap_angle(a[..., 2])
    half = 0.5 * np.where(np.abs(w) < _TINY, 1.0, w)
    h = np.where(np.abs(w) < _TINY, 1.0, half * np.cos(half) / np.sin(half))
    x, y = a[..., 0], a[..., 1]
    return stack_last([h * x + 0.5 * w * y, -0.5 * w * x + h * y, w], w.shape)


def adjoint(a: ArrayLike) -> FloatArray:
    """Adjoint matrix ``Ad_a``, shape ``(..., 3, 3)``, with ``a ∘ Exp(ξ) = Exp(Ad_a ξ) ∘ a``.

    ``Ad_a = [[c, -s, y], [s, c, -x], [0, 0, 1]]`` (GTSAM's ``Pose2.AdjointMap``).
    """
    a = _pose(a, "a")
    x, y, t = a[..., 0], a[..., 1], a[..., 2]
    c, s = np.cos(t), np.sin(t)
    return matrix([[c, -s, y], [s, c, -x], [0.0, 0.0, 1.0]], t.shape)
