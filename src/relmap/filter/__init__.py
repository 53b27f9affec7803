"""The extended Kalman filter (lecture Eqs. 13-28) for any motion and measurement model
(:mod:`relmap.models`), one filter or a batch: the textbook steps (:mod:`.ekf`), readings of
landmarks with association and gating (:mod:`.landmarks`), whole logs (:mod:`.logs`, with the
odometry between readings composed first: :mod:`.segments`), and the noise of a filter from its
own innovations (:mod:`.autocalibration`)."""

from relmap.filter.ekf import (
    Belief,
    Correction,
    PoseUpdate,
    Update,
    correct,
    correct_pose,
    predict,
    update,
)
from relmap.filter.landmarks import (
    Association,
    LandmarkMap,
    LandmarkUpdate,
    Pairing,
    Status,
    correct_landmarks,
)
from relmap.filter.logs import Keep, Log, Trace, run

__all__ = [
    "Association",
    "Belief",
    "Correction",
    "Keep",
    "LandmarkMap",
    "LandmarkUpdate",
    "Log",
    "Pairing",
    "PoseUpdate",
    "Status",
    "Trace",
    "Update",
    "correct",
    "correct_landmarks",
    "correct_pose",
    "predict",
    "run",
    "update",
]
