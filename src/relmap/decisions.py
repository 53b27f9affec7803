"""``relmap.decisions``, the public name of :mod:`relmap.sensors.decisions` (field-of-view and
doorway decisions ahead of time, §6.1-6.2): the same functions and types, kept under the name
the README and earlier releases use."""

from relmap.sensors.decisions import DoorDecision, ViewDecision, in_view, through_door

__all__ = ["DoorDecision", "ViewDecision", "in_view", "through_door"]
