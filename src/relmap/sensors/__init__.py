"""Sensors: range-bearing observation models and Appendix B's polar ↔ Cartesian mappings
(:mod:`relmap.sensors.polar`), and decisions ahead of time from an uncertain relative pose —
the field of view and the doorway (:mod:`relmap.sensors.decisions`, public name
:mod:`relmap.decisions`), integrated by :mod:`relmap.sensors.quadrature`."""

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
