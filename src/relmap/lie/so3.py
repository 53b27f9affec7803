"""SO(3) geometry: rotation matrices, unit quaternions, Exp/Log, and Euler angles with poles.

Rotations are 3×3 matrices ``(..., 3, 3)`` inside relmap; quaternions are scalar-last
``(qx, qy, qz, qw)`` as g2o, ROS and SciPy write them, normalized with ``qw ≥ 0``. Rotation
vectors ``φ`` (axis × angle, radians) are the tangent: ``Exp(φ)`` is Rodrigues' formula.

Small-angle branches: below ``|φ| < _SMALL`` (a float64 threshold of 1e-4) the closed forms of
Exp/Log and their Jacobians lose digits to cancellation; their Taylor series, truncated after the
terms listed at each branch, are exact to float64 rounding there. Near ``|φ| = π`` Log is taken
from the symmetric part of R, where ``sin`` vanishes.

Euler angles (roll, pitch, yaw) use ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (fixed axes x, then y,
then z; the aerospace / ROS ``rpy`` convention). At pitch = ±π/2 roll and yaw are not separable
(gimbal lock): :func:`to_euler` reports the pole instead of returning arbitrary angles.
"""

from __future__ import annotations

import numpy as np

from relmap.errors import ParameterError, ShapeError
from relmap.typing import ArrayLike, FloatArray

__all__ = [
    "ROTATION_ATOL",
    "exp",
    "from_euler",
    "from_quaternion",
    "hat",
    "left_jacobian",
    "left_jacobian_inverse",
    "log",
    "to_euler",
    "to_quaternion",
]

_SMALL = 1e-4

#: Tolerance on |q| - 1 (and on |RᵀR - I| for matrices): what numbers written with four or more
#: digits reach. Within it the input is normalized; beyond it, it is likely not a rotation.
ROTATION_ATOL = 1e-3


def _vec3(v: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(v, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise ShapeError(f"{name} must have shape (..., 3); got {arr.shape}")
    return arr


def hat(v: ArrayLike) -> FloatArray:
    """The skew matrix ``[v]×`` (..., 3, 3) with ``[v]× w = v × w``."""
    v = _vec3(v, "v")
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -z, y
    out[..., 1, 0], out[..., 1, 2] = z, -x
    out[..., 2, 0], out[..., 2, 1] = -y, x
    return out


def _coefficients(theta: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``A = sin θ/θ``, ``B = (1 - cos θ)/θ²``, ``C = (θ - sin θ)/θ³`` without cancellation."""
    small = theta < _SMALL
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    # series: A = 1 - θ²/6 + θ⁴/120, B = 1/2 - θ²/24 + θ⁴/720, C = 1/6 - θ²/120 + θ⁴/5040
    A = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, np.sin(t) / t)
    B = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, 2 * np.sin(t / 2) ** 2 / (t * t))
    C = np.where(small, 1 / 6 - t2 / 120 + t2 * t2 / 5040, (t - np.sin(t)) / (t * t * t))
    return A, B, C


def exp(phi: ArrayLike) -> FloatArray:
    """``Exp(φ) = I + A [φ]× + B [φ]×²`` (Rodrigues), (..., 3, 3)."""
    phi = _vec3(phi, "phi")
    theta = np.linalg.norm(phi, axis=-1)
    A, B, _ = _coefficients(theta)
    K = hat(phi)
    return np.eye(3) + A[..., None, None] * K + B[..., None, None] * (K @ K)


def log(R: ArrayLike) -> FloatArray:
    """The rotation vector φ (..., 3) with ``Exp(φ) = R``, |φ| ≤ π."""
    R = np.asarray(R, dtype=np.float64)
    if R.shape[-2:] != (3, 3):
        raise ShapeError(f"R must have shape (..., 3, 3); got {R.shape}")
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    w = np.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1
    )
    theta = np.arctan2(0.5 * np.linalg.norm(w, axis=-1), cos)  # accurate near 0 and near π
    A, _, _ = _coefficients(theta)
    near_pi = theta > np.pi - 1e-3
    out = w / (2 * A[..., None])
    if np.any(near_pi):
        # near π, sin θ vanishes: R's symmetric part is I + (1 - cos θ)(n nᵀ - I), so n nᵀ is
        # known; take the column with the largest diagonal, and the axis's sign from w. Only
        # the rotations near π go through this (elsewhere 1 - cos θ may be 0).
        out = np.array(out, copy=True)
        Rp, cp, wp, tp = R[near_pi], cos[near_pi], w[near_pi], theta[near_pi]
        S = 0.5 * (Rp + np.swapaxes(Rp, -1, -2))
        nn = (S - cp[:, None, None] * np.eye(3)) / (1 - cp)[:, None, None]
        diag = np.diagonal(nn, axis1=-2, axis2=-1)
        k = np.argmax(diag, axis=-1)
        col = np.take_along_axis(nn, k[:, None, None], axis=-1)[..., 0]
        n = col / np.sqrt(np.take_along_axis(diag, k[:, None], -1))
        sign = np.where(np.einsum("...i,...i->...", n, wp) < 0, -1.0, 1.0)
        out[near_pi] = (sign * tp)[:, None] * n
    return out


def left_jacobian(phi: ArrayLike) -> FloatArray:
    """``J_l(φ) = I + B [φ]× + C [φ]×²``: ``Exp(φ + δ) ≈ Exp(J_l δ) Exp(φ)``, (..., 3, 3)."""
    phi = _vec3(phi, "phi")
    _, B, C = _coefficients(np.linalg.norm(phi, axis=-1))
    K = hat(phi)
    return np.eye(3) + B[..., None, None] * K + C[..., None, None] * (K @ K)


def left_jacobian_inverse(phi: ArrayLike) -> FloatArray:
    """``J_l(φ)⁻¹ = I - [φ]×/2 + D [φ]×²`` with ``D = (1 - θ sin θ/(2(1 - cos θ)))/θ²``."""
    phi = _vec3(phi, "phi")
    theta = np.linalg.norm(phi, axis=-1)
    small = theta < _SMALL
    t = np.where(small, 1.0, theta)
    # series: D = 1/12 + θ²/720 + θ⁴/30240
    D = np.where(
        small,
        1 / 12 + theta**2 / 720 + theta**4 / 30240,
        (1 - t * np.sin(t) / (4 * np.sin(t / 2) ** 2)) / (t * t),
    )
    K = hat(phi)
    return np.eye(3) - 0.5 * K + D[..., None, None] * (K @ K)


def from_quaternion(q: ArrayLike, *, atol: float = ROTATION_ATOL) -> FloatArray:
    """Rotation matrices (..., 3, 3) from quaternions ``(qx, qy, qz, qw)`` (..., 4).

    Quaternions are normalized; one whose norm differs from 1 by more than ``atol`` raises
    :class:`ParameterError` (it is likely not a rotation at all).
    """
    q = np.asarray(q, dtype=np.float64)
    if q.ndim == 0 or q.shape[-1] != 4:
        raise ShapeError(f"quaternions must have shape (..., 4) (qx, qy, qz, qw); got {q.shape}")
    norm = np.linalg.norm(q, axis=-1)
    bad = np.abs(norm - 1) > atol
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ParameterError(
            f"quaternion{list(idx) if idx else ''} has norm {norm[idx]:.6g}, not 1 "
            f"(tolerance {atol:g})"
        )
    x, y, z, w = np.moveaxis(q / norm[..., None], -1, 0)
    out = np.empty((*q.shape[:-1], 3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - z * w)
    out[..., 0, 2] = 2 * (x * z + y * w)
    out[..., 1, 0] = 2 * (x * y + z * w)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - x * w)
    out[..., 2, 0] = 2 * (x * z - y * w)
    out[..., 2, 1] = 2 * (y * z + x * w)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def to_quaternion(R: ArrayLike) -> FloatArray:
    """Unit quaternions ``(qx, qy, qz, qw)`` (..., 4) with ``qw ≥ 0`` from rotation matrices
    (Shepperd's method: the largest of the four candidates, so no division by a small number)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R, axis1=-2, axis2=-1)
    d = np.diagonal(R, axis1=-2, axis2=-1)
    cands = np.stack(
        [1 + tr, 1 + 2 * d[..., 0] - tr, 1 + 2 * d[..., 1] - tr, 1 + 2 * d[..., 2] - tr], -1
    )
    k = np.argmax(cands, axis=-1)
    s = np.sqrt(np.take_along_axis(cands, k[..., None], -1)[..., 0]) * 2  # 4·|component|
    r21, r12 = R[..., 2, 1], R[..., 1, 2]
    r02, r20 = R[..., 0, 2], R[..., 2, 0]
    r10, r01 = R[..., 1, 0], R[..., 0, 1]
    q = np.empty((*R.shape[:-2], 4))
    options = [
        ((r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s, s / 4),
        (s / 4, (r01 + r10) / s, (r02 + r20) / s, (r21 - r12) / s),
        ((r01 + r10) / s, s / 4, (r12 + r21) / s, (r02 - r20) / s),
        ((r02 + r20) / s, (r12 + r21) / s, s / 4, (r10 - r01) / s),
    ]
    for i, comps in enumerate(options):
        sel = k == i
        for j in range(4):
            q[..., j] = np.where(sel, comps[j], q[..., j] if i else 0.0)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)


def from_euler(rpy: ArrayLike) -> FloatArray:
    """``R = Rz(yaw) Ry(pitch) Rx(roll)`` (..., 3, 3) from ``(roll, pitch, yaw)`` (..., 3)."""
    rpy = _vec3(rpy, "roll, pitch, yaw")
    r, p, y = rpy[..., 0], rpy[..., 1], rpy[..., 2]
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    out = np.empty((*rpy.shape[:-1], 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2] = (
        cy * cp,
        cy * sp * sr - sy * cr,
        cy * sp * cr + sy * sr,
    )
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2] = (
        sy * cp,
        sy * sp * sr + cy * cr,
        sy * sp * cr - cy * sr,
    )
    out[..., 2, 0], out[..., 2, 1], out[..., 2, 2] = -sp, cp * sr, cp * cr
    return out


def to_euler(R: ArrayLike, *, pole_tolerance: float = 1e-6) -> FloatArray:
    """``(roll, pitch, yaw)`` (..., 3) of rotation matrices, pitch in [-π/2, π/2].

    Within ``pole_tolerance`` (rad) of pitch = ±π/2 roll and yaw are not determined (only their
    difference or sum is): :class:`ParameterError` says so rather than return arbitrary angles.
    """
    R = np.asarray(R, dtype=np.float64)
    pitch = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    pole = np.abs(np.abs(pitch) - np.pi / 2) <= pole_tolerance
    if pole.any():
        idx = tuple(int(i) for i in np.argwhere(pole)[0])
        raise ParameterError(
            f"rotation{list(idx) if idx else ''} is at the Euler pole (pitch = ±90°, gimbal lock): "
            "roll and yaw are not separable there"
        )
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)
