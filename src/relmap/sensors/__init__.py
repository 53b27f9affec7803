"""Sensors: range-bearing observation models and Appendix B's polar ↔ Cartesian mappings."""

from relmap.sensors.polar import (
    POLAR,
    RangeBearingSensor,
    cartesian_to_polar,
    merge_polar,
    polar_to_cartesian,
)

__all__ = [
    "POLAR",
    "RangeBearingSensor",
    "cartesian_to_polar",
    "merge_polar",
    "polar_to_cartesian",
]
