"""Robots: differential-drive odometry with covariance, and the planar arm of the lecture."""

from relmap.robot.arm import PlanarArm
from relmap.robot.motion import (
    AlphaNoise,
    DiffDrive,
    DistanceNoise,
    WheelNoise,
    dead_reckon,
    increment,
    increments_from_velocities,
    step,
)

__all__ = [
    "AlphaNoise",
    "DiffDrive",
    "DistanceNoise",
    "PlanarArm",
    "WheelNoise",
    "dead_reckon",
    "increment",
    "increments_from_velocities",
    "step",
]
