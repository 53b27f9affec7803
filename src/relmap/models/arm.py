"""The lecture's planar arm (Eqs. 1-8): joint-angle uncertainty → gripper-position uncertainty.

Two joints (shoulder q1, elbow q2) move in the robot's vertical (x, z) plane; the wrist is slaved
so the gripper stays horizontal, so the grip point sits at a constant offset ``(gx, gz)`` from
the wrist:

    x = sx + L0 cos q1 + L1 cos(q1 + q2) + gx
    z = sz + L0 sin q1 + L1 sin(q1 + q2) + gz                                      (1), (2)

First-order propagation (Eqs. 7-8): ``p̂ = f(q̂)``, ``Σp = J Σq Jᵀ`` with the manipulator
Jacobian ``J = ∂f/∂q``. Metres and radians.
"""

from __future__ import annotations

import numpy as np

from relmap.errors import ParameterError, ShapeError
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain import gaussian
from relmap.uncertain.gaussian import Ellipse
from relmap.uncertain.propagate import Moments, propagate

__all__ = ["PlanarArm"]


class PlanarArm:
    """Link lengths ``L0, L1`` (> 0), shoulder position ``(sx, sz)`` and grip offset ``(gx, gz)``
    in the robot frame."""

    __slots__ = ("L0", "L1", "grip", "shoulder")

    def __init__(
        self,
        L0: float,
        L1: float,
        shoulder: ArrayLike = (0.0, 0.0),
        grip: ArrayLike = (0.0, 0.0),
    ) -> None:
        for name, v in (("L0", L0), ("L1", L1)):
            if not np.isfinite(v) or v <= 0:
                raise ParameterError(f"link length {name} must be positive; got {v}")
        sh, gr = np.asarray(shoulder, float), np.asarray(grip, float)
        if sh.shape != (2,) or gr.shape != (2,):
            raise ShapeError("shoulder and grip are 2-D points (x, z)")
        gaussian.check_finite(np.concatenate([sh, gr]), "shoulder/grip")
        for name, v in (("L0", float(L0)), ("L1", float(L1)), ("shoulder", sh), ("grip", gr)):
            object.__setattr__(self, name, v)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError("PlanarArm is immutable")

    def forward(self, q: ArrayLike) -> FloatArray:
        """Grip point ``(x, z)`` (..., 2) for joint angles ``q = (q1, q2)`` (..., 2) (Eqs. 1-2)."""
        q = _angles(q)
        q1, q12 = q[..., 0], q[..., 0] + q[..., 1]
        x = self.shoulder[0] + self.L0 * np.cos(q1) + self.L1 * np.cos(q12) + self.grip[0]
        z = self.shoulder[1] + self.L0 * np.sin(q1) + self.L1 * np.sin(q12) + self.grip[1]
        return np.stack([x, z], axis=-1)

    def jacobian(self, q: ArrayLike) -> FloatArray:
        """The manipulator Jacobian ``∂(x, z)/∂(q1, q2)`` (..., 2, 2) (Eq. 3)."""
        q = _angles(q)
        q1, q12 = q[..., 0], q[..., 0] + q[..., 1]
        J = np.empty((*q.shape[:-1], 2, 2))
        J[..., 0, 0] = -self.L0 * np.sin(q1) - self.L1 * np.sin(q12)
        J[..., 0, 1] = -self.L1 * np.sin(q12)
        J[..., 1, 0] = self.L0 * np.cos(q1) + self.L1 * np.cos(q12)
        J[..., 1, 1] = self.L1 * np.cos(q12)
        return J

    def gripper(self, q: ArrayLike, cov_q: ArrayLike) -> Moments:
        """Mean and covariance of the grip point (Eqs. 7-8) for joint angles ``q`` with
        covariance ``cov_q`` (..., 2, 2): e.g. ``diag(σ1², σ2²)`` (Eq. 5) or
        :func:`relmap.uncertain.gaussian.rotated_covariance` (Eq. 6)."""
        cov = gaussian.validate_covariance(cov_q, dim=2, name="joint covariance")
        return propagate(self.forward, _angles(q), cov, jacobian=self.jacobian)

    def gripper_ellipse(self, q: ArrayLike, cov_q: ArrayLike, probability: float = 0.9) -> Ellipse:
        """The ``probability`` confidence ellipse of the grip point, in the (x, z) plane."""
        m = self.gripper(q, cov_q)
        return gaussian.ellipse(m.mean, m.cov, probability)


def _angles(q: ArrayLike) -> FloatArray:
    arr = np.asarray(q, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != 2:
        raise ShapeError(f"joint angles must have shape (..., 2); got {arr.shape}")
    gaussian.check_finite(arr, "joint angles")
    return arr
