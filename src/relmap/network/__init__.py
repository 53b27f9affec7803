"""Relational maps: networks of ATs, and the AT between any two of their frames (§5)."""

from relmap.network.graph import Edge, JointGroup, RelationalMap
from relmap.network.query import Estimate

__all__ = ["Edge", "Estimate", "JointGroup", "RelationalMap"]
