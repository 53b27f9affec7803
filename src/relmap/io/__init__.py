"""Files: relational-map files (JSON/YAML), 2-D pose graphs (g2o, TORO); dataset readers to come."""

from relmap.io.mapfile import ATRecord, read_records, write_records
from relmap.io.posegraph import PoseGraph, read_graph, write_graph

__all__ = ["ATRecord", "PoseGraph", "read_graph", "read_records", "write_graph", "write_records"]
