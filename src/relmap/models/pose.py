"""Readings of the pose itself: a full pose (the paper's sensing, §4) and a position fix (GPS).

:class:`FullPose` reads ``z = x`` (GPS with a compass, or any sensing of where the robot is):
``H = I``, and the EKF's correction with it is the paper's merge (Eqs. 8-10) of the prior with
the reading. :class:`PositionFix` reads ``z = (x, y)`` with ``R = σ² I``. Both are
:class:`relmap.models.base.Measurement` models of a planar pose ``(x, y, θ)`` in relmap's chart.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np

from relmap.models.base import Measurement, positive
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain.gaussian import validate_covariance

__all__ = ["FullPose", "PositionFix"]


@dataclasses.dataclass(frozen=True)
class FullPose(Measurement):
    """``z = x``, a pose ``(x, y, θ)`` read with covariance ``cov`` (..., 3, 3) in relmap's
    chart (translation along the world's axes, heading about the robot)."""

    cov: ArrayLike
    dim: ClassVar[int] = 3
    angles: ClassVar[tuple[int, ...]] = (2,)

    def __post_init__(self) -> None:
        object.__setattr__(self, "cov", validate_covariance(self.cov, dim=3, name="cov"))

    def h(self, x: FloatArray, landmark: FloatArray | None = None) -> FloatArray:
        return np.asarray(x, dtype=np.float64)

    def jacobians(
        self, x: FloatArray, landmark: FloatArray | None = None
    ) -> tuple[FloatArray, None]:
        return np.broadcast_to(np.eye(3), (*np.shape(x)[:-1], 3, 3)), None

    def noise(self, z: FloatArray) -> FloatArray:
        return np.broadcast_to(self.cov, np.broadcast_shapes(self.cov.shape, (*z.shape, 3)))


@dataclasses.dataclass(frozen=True)
class PositionFix(Measurement):
    """``z = (x, y)``, the position read with ``R = σ² I`` (``sigma`` in metres)."""

    sigma: float | FloatArray
    noise_parameters: ClassVar[tuple[str, ...]] = ("sigma",)

    def __post_init__(self) -> None:
        object.__setattr__(self, "sigma", positive(self.sigma, "sigma"))

    def h(self, x: FloatArray, landmark: FloatArray | None = None) -> FloatArray:
        return np.asarray(x, dtype=np.float64)[..., :2]

    def jacobians(
        self, x: FloatArray, landmark: FloatArray | None = None
    ) -> tuple[FloatArray, None]:
        return np.broadcast_to(np.eye(2, 3), (*np.shape(x)[:-1], 2, 3)), None

    def noise(self, z: FloatArray) -> FloatArray:
        s2 = np.square(self.sigma)
        return np.multiply.outer(s2 + np.zeros(np.shape(z)[:-1]), np.eye(2))
