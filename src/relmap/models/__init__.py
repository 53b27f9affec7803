"""Models: where uncertain poses come from, behind one protocol (:mod:`.base`) — motion
(differential-drive odometry, :mod:`.odometry`; the planar arm of the lecture, :mod:`.arm`) and
sensing (range-bearing, range only, bearing only and Appendix B's polar ↔ Cartesian mappings,
:mod:`.range_bearing`; a full pose or a position fix, :mod:`.pose`) — and the decisions of §6
made ahead of time from them (field of view, doorway: :mod:`.decisions`)."""

from relmap.models.arm import PlanarArm
from relmap.models.base import Measurement, Model, Motion, RelativeMotion
from relmap.models.odometry import (
    AlphaNoise,
    DiffDrive,
    DistanceNoise,
    Integration,
    Odometry,
    WheelNoise,
    dead_reckon,
    increment,
    increments_from_velocities,
    step,
)
from relmap.models.pose import FullPose, PositionFix
from relmap.models.range_bearing import (
    POLAR,
    BearingOnly,
    RangeBearingSensor,
    RangeOnly,
    cartesian_to_polar,
    merge_polar,
    polar_to_cartesian,
)

__all__ = [
    "POLAR",
    "AlphaNoise",
    "BearingOnly",
    "DiffDrive",
    "DistanceNoise",
    "FullPose",
    "Integration",
    "Measurement",
    "Model",
    "Motion",
    "Odometry",
    "PlanarArm",
    "PositionFix",
    "RangeBearingSensor",
    "RangeOnly",
    "RelativeMotion",
    "WheelNoise",
    "cartesian_to_polar",
    "dead_reckon",
    "increment",
    "increments_from_velocities",
    "merge_polar",
    "polar_to_cartesian",
    "step",
]
