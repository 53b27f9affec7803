"""Models: where uncertain poses come from — motion (differential-drive odometry, the planar
arm of the lecture) and sensing (range-bearing, Appendix B's polar ↔ Cartesian mappings) — and
the decisions of §6 made ahead of time from them (field of view, doorway)."""

from relmap.models.arm import PlanarArm
from relmap.models.odometry import (
    AlphaNoise,
    DiffDrive,
    DistanceNoise,
    WheelNoise,
    dead_reckon,
    increment,
    increments_from_velocities,
    step,
)
from relmap.models.range_bearing import (
    POLAR,
    RangeBearingSensor,
    cartesian_to_polar,
    merge_polar,
    polar_to_cartesian,
)

__all__ = [
    "POLAR",
    "AlphaNoise",
    "DiffDrive",
    "DistanceNoise",
    "PlanarArm",
    "RangeBearingSensor",
    "WheelNoise",
    "cartesian_to_polar",
    "dead_reckon",
    "increment",
    "increments_from_velocities",
    "merge_polar",
    "polar_to_cartesian",
    "step",
]
