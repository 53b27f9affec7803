"""SE(3) geometry on homogeneous matrices ``(..., 4, 4)``: compose, inverse, between, Exp/Log.

**Chart.** relmap's covariances and Jacobians for 3-D poses live on ``(δt, δφ)``: a translation
perturbation in the parent frame and a rotation perturbation applied on the left in the parent
frame, ``T' = (t + δt, Exp(δφ) R)`` — :func:`plus` / :func:`minus`. It reduces to the paper's
``(x, y, θ)`` chart in the plane and has no poles. Jacobians ``J_<out>_<in>`` (..., 6, 6) are
taken in this chart on both sides, so ``Σ_out = J Σ_in Jᵀ``.

**Lie algebra.** :func:`exp` / :func:`log` map a twist ``ξ = (ρ, φ)`` (translation part first)
to ``T = (J_l(φ) ρ, Exp(φ))``; :func:`adjoint` satisfies ``T Exp(ξ) = Exp(Ad_T ξ) T``. GTSAM's
``Pose3`` orders its tangent rotation first and perturbs on the right (body frame):
:func:`body_to_chart` converts.
"""

from __future__ import annotations

from typing import Literal, overload

import numpy as np

from relmap.errors import ShapeError
from relmap.lie import so3
from relmap.typing import ArrayLike, FloatArray

__all__ = [
    "DOF",
    "adjoint",
    "between",
    "body_to_chart",
    "compose",
    "exp",
    "from_parts",
    "identity",
    "inverse",
    "left_jacobian",
    "left_jacobian_inverse",
    "log",
    "minus",
    "plus",
]

DOF = 6


def _pose(T: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(T, dtype=np.float64)
    if arr.shape[-2:] != (4, 4):
        raise ShapeError(f"{name} must be homogeneous matrices (..., 4, 4); got {arr.shape}")
    return arr


def from_parts(t: ArrayLike, R: ArrayLike) -> FloatArray:
    """Homogeneous matrices (..., 4, 4) from translations (..., 3) and rotations (..., 3, 3)."""
    t = np.asarray(t, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64)
    if t.shape[-1:] != (3,) or R.shape[-2:] != (3, 3):
        raise ShapeError(
            f"need translations (..., 3) and rotations (..., 3, 3); got {t.shape}, {R.shape}"
        )
    batch = np.broadcast_shapes(t.shape[:-1], R.shape[:-2])
    out = np.zeros((*batch, 4, 4))
    out[..., :3, :3] = R
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def identity(batch_shape: tuple[int, ...] = ()) -> FloatArray:
    """The identity pose, (*batch_shape, 4, 4)."""
    return np.broadcast_to(np.eye(4), (*batch_shape, 4, 4)).copy()


def _blocks(A: FloatArray, B: FloatArray, C: FloatArray, D: FloatArray) -> FloatArray:
    shape = np.broadcast_shapes(A.shape[:-2], B.shape[:-2], C.shape[:-2], D.shape[:-2])
    out = np.empty((*shape, 6, 6))
    out[..., :3, :3], out[..., :3, 3:], out[..., 3:, :3], out[..., 3:, 3:] = A, B, C, D
    return out


@overload
def compose(a: ArrayLike, b: ArrayLike, *, jacobians: Literal[False] = ...) -> FloatArray: ...
@overload
def compose(
    a: ArrayLike, b: ArrayLike, *, jacobians: Literal[True]
) -> tuple[FloatArray, FloatArray, FloatArray]: ...
def compose(
    a: ArrayLike, b: ArrayLike, *, jacobians: bool = False
) -> FloatArray | tuple[FloatArray, FloatArray, FloatArray]:
    """``c = a b``; with Jacobians ``J_c_a = [[I, -[R_a t_b]×], [0, I]]``,
    ``J_c_b = blkdiag(R_a, R_a)`` (the 3-D H and K of Eq. 3)."""
    a, b = _pose(a, "a"), _pose(b, "b")
    c = a @ b
    if not jacobians:
        return c
    Ra = np.broadcast_to(a[..., :3, :3], (*c.shape[:-2], 3, 3))
    u = np.einsum("...ij,...j->...i", a[..., :3, :3], b[..., :3, 3])  # R_a t_b = t_c - t_a
    zero = np.zeros_like(Ra)
    eye = np.broadcast_to(np.eye(3), Ra.shape)
    return c, _blocks(eye, -so3.hat(u), zero, eye), _blocks(Ra, zero, zero, Ra)


@overload
def inverse(a: ArrayLike, *, jacobians: Literal[False] = ...) -> FloatArray: ...
@overload
def inverse(a: ArrayLike, *, jacobians: Literal[True]) -> tuple[FloatArray, FloatArray]: ...
def inverse(a: ArrayLike, *, jacobians: bool = False) -> FloatArray | tuple[FloatArray, FloatArray]:
    """``a⁻¹ = (-Rᵀ t, Rᵀ)``; with ``J = [[-Rᵀ, -Rᵀ [t]×], [0, -Rᵀ]]`` (the 3-D Eq. 7)."""
    a = _pose(a, "a")
    Rt = np.swapaxes(a[..., :3, :3], -1, -2)
    t = a[..., :3, 3]
    out = from_parts(-np.einsum("...ij,...j->...i", Rt, t), Rt)
    if not jacobians:
        return out
    return out, _blocks(-Rt, -Rt @ so3.hat(t), np.zeros_like(Rt), -Rt)


@overload
def between(a: ArrayLike, b: ArrayLike, *, jacobians: Literal[False] = ...) -> FloatArray: ...
@overload
def between(
    a: ArrayLike, b: ArrayLike, *, jacobians: Literal[True]
) -> tuple[FloatArray, FloatArray, FloatArray]: ...
def between(
    a: ArrayLike, b: ArrayLike, *, jacobians: bool = False
) -> FloatArray | tuple[FloatArray, FloatArray, FloatArray]:
    """``d = a⁻¹ b`` (b seen from a), with ``J_d_a`` and ``J_d_b = blkdiag(R_aᵀ, R_aᵀ)``."""
    if not jacobians:
        return compose(inverse(a), b)
    ai, J_inv = inverse(a, jacobians=True)
    d, J_d_ai, J_d_b = compose(ai, b, jacobians=True)
    return d, J_d_ai @ J_inv, J_d_b


def plus(T: ArrayLike, delta: ArrayLike) -> FloatArray:
    """Perturb in the chart: ``(t + δt, Exp(δφ) R)`` for ``δ = (δt, δφ)`` (..., 6)."""
    T = _pose(T, "T")
    d = np.asarray(delta, dtype=np.float64)
    if d.shape[-1:] != (6,):
        raise ShapeError(f"delta must have shape (..., 6); got {d.shape}")
    return from_parts(T[..., :3, 3] + d[..., :3], so3.exp(d[..., 3:]) @ T[..., :3, :3])


def minus(B: ArrayLike, A: ArrayLike) -> FloatArray:
    """The chart difference ``(t_B - t_A, Log(R_B R_Aᵀ))`` (..., 6); ``plus(A, minus(B, A))``
    is B."""
    B, A = _pose(B, "B"), _pose(A, "A")
    dphi = so3.log(B[..., :3, :3] @ np.swapaxes(A[..., :3, :3], -1, -2))
    dt = B[..., :3, 3] - A[..., :3, 3]
    dt, dphi = np.broadcast_arrays(dt, dphi)
    return np.concatenate([dt, dphi], axis=-1)


def exp(xi: ArrayLike) -> FloatArray:
    """``Exp(ρ, φ) = (J_l(φ) ρ, Exp(φ))`` (..., 4, 4) for twists ``ξ = (ρ, φ)`` (..., 6)."""
    xi = np.asarray(xi, dtype=np.float64)
    if xi.shape[-1:] != (6,):
        raise ShapeError(f"xi must have shape (..., 6); got {xi.shape}")
    rho, phi = xi[..., :3], xi[..., 3:]
    return from_parts(np.einsum("...ij,...j->...i", so3.left_jacobian(phi), rho), so3.exp(phi))


def log(T: ArrayLike) -> FloatArray:
    """The twist ``(ρ, φ)`` (..., 6) with ``Exp(ρ, φ) = T``."""
    T = _pose(T, "T")
    phi = so3.log(T[..., :3, :3])
    rho = np.einsum("...ij,...j->...i", so3.left_jacobian_inverse(phi), T[..., :3, 3])
    return np.concatenate([rho, phi], axis=-1)


_Q_SMALL = 1e-2  # below: series (the closed forms lose ~ε/θ² of Q's magnitude to cancellation)


def _q(xi: FloatArray) -> FloatArray:
    """Barfoot's ``Q(ρ, φ)`` (..., 3, 3): the top-right block of the SE(3) left Jacobian."""
    rho, phi = xi[..., :3], xi[..., 3:]
    theta = np.linalg.norm(phi, axis=-1)
    small = theta < _Q_SMALL
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    half = 2 * np.sin(t / 2)  # θ² + 2cos θ - 2 = (θ - 2 sin(θ/2))(θ + 2 sin(θ/2)), no cancellation
    # series to θ⁶; truncation below 1e-16 relative for θ < 1e-2
    c1 = np.where(small, 1 / 6 - t2 / 120 + t2**2 / 5040 - t2**3 / 362880, (t - np.sin(t)) / t**3)
    c2 = np.where(
        small,
        1 / 24 - t2 / 720 + t2**2 / 40320 - t2**3 / 3628800,
        (t - half) * (t + half) / (2 * t**4),
    )
    c3 = np.where(
        small,
        1 / 120 - t2 / 2520 + t2**2 / 120960 - t2**3 / 9979200,
        (2 * t - 3 * np.sin(t) + t * np.cos(t)) / (2 * t**5),
    )
    P, R = so3.hat(phi), so3.hat(rho)
    PR, RP = P @ R, R @ P
    PRP = PR @ P
    PPR = P @ PR
    c1, c2, c3 = c1[..., None, None], c2[..., None, None], c3[..., None, None]
    return 0.5 * R + c1 * (PR + RP + PRP) + c2 * (PPR + RP @ P - 3 * PRP) + c3 * (PRP @ P + P @ PRP)


def left_jacobian(xi: ArrayLike) -> FloatArray:
    """The SE(3) left Jacobian ``𝒥(ξ) = [[J_l(φ), Q(ρ, φ)], [0, J_l(φ)]]`` (..., 6, 6), for
    twists ``ξ = (ρ, φ)``: ``Exp(ξ + δ) ≈ Exp(𝒥 δ) Exp(ξ)``."""
    xi = np.asarray(xi, dtype=np.float64)
    if xi.shape[-1:] != (6,):
        raise ShapeError(f"xi must have shape (..., 6); got {xi.shape}")
    J = so3.left_jacobian(xi[..., 3:])
    return _blocks(J, _q(xi), np.zeros_like(J), J)


def left_jacobian_inverse(xi: ArrayLike) -> FloatArray:
    """``𝒥(ξ)⁻¹ = [[J⁻¹, -J⁻¹ Q J⁻¹], [0, J⁻¹]]`` (..., 6, 6): ``Log(Exp(ε) T) ≈ Log T + 𝒥⁻¹ ε``
    for ``ξ = Log T``."""
    xi = np.asarray(xi, dtype=np.float64)
    if xi.shape[-1:] != (6,):
        raise ShapeError(f"xi must have shape (..., 6); got {xi.shape}")
    Ji = so3.left_jacobian_inverse(xi[..., 3:])
    return _blocks(Ji, -Ji @ _q(xi) @ Ji, np.zeros_like(Ji), Ji)


def adjoint(T: ArrayLike) -> FloatArray:
    """``Ad_T = [[R, [t]× R], [0, R]]`` (..., 6, 6) with ``T Exp(ξ) = Exp(Ad_T ξ) T``."""
    T = _pose(T, "T")
    R, t = T[..., :3, :3], T[..., :3, 3]
    return _blocks(R, so3.hat(t) @ R, np.zeros_like(R), R)


def body_to_chart(T: ArrayLike) -> FloatArray:
    """``M`` (..., 6, 6) mapping GTSAM's body perturbation ``T Exp(ξ)``, ``ξ = (ω, v)`` (rotation
    first), to relmap's chart: to first order ``(δt, δφ) = (R v, R ω) = M ξ``, so
    ``Σ_chart = M Σ_gtsam Mᵀ`` with ``M = [[0, R], [R, 0]]``."""
    T = _pose(T, "T")
    R = T[..., :3, :3]
    zero = np.zeros_like(R)
    return _blocks(zero, R, R, zero)
