"""Files: relational-map files (JSON/YAML), pose graphs (g2o and TORO in 2-D; g2o and the legacy
EDGE3 format in 3-D), loading either as a map, trajectories (:mod:`relmap.io.trajectory`,
:mod:`relmap.io.rosbag`), landmark-localization datasets (UTIAS MRCLAM, CMU Plaza).

Every format of maps, pose graphs and trajectories is registered once in
:mod:`relmap.io.formats`, by the module that reads it (imported here, so the registry is whole).
"""

from relmap.io import rosbag, trajectory  # noqa: F401  (they register their formats)
from relmap.io.datasets import (
    DatasetKind,
    Mrclam,
    Plaza,
    RobotLog,
    read_mrclam,
    read_plaza,
    recognise,
)
from relmap.io.mapfile import ATRecord, read_records, write_records
from relmap.io.maps import load_map, save_map, solve_graph
from relmap.io.posegraph import PoseGraph, read_graph, write_graph

__all__ = [
    "ATRecord",
    "DatasetKind",
    "Mrclam",
    "Plaza",
    "PoseGraph",
    "RobotLog",
    "load_map",
    "read_graph",
    "read_mrclam",
    "read_plaza",
    "read_records",
    "recognise",
    "save_map",
    "solve_graph",
    "write_graph",
    "write_records",
]
