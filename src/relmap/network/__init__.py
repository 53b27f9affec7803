"""Relational maps: networks of ATs, and the AT between any two of their frames (§5)."""

from relmap.network.graph import RelationalMap
from relmap.network.parts import Edge, JointGroup
from relmap.network.query import Estimate

__all__ = ["Edge", "Estimate", "JointGroup", "RelationalMap"]
