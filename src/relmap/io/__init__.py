"""Files: relational-map files (JSON/YAML) now; pose-graph formats and dataset readers to come."""

from relmap.io.mapfile import ATRecord, read_records, write_records

__all__ = ["ATRecord", "read_records", "write_records"]
