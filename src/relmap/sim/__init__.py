"""Simulation: robots and maps with known noise (:mod:`.robots`), Monte Carlo checks of any
estimate (:mod:`.montecarlo`, the paper's §6.3), sweeps (:mod:`.study`), here or on a Dask
cluster (:mod:`.distributed`).

The names of :mod:`.robots` are also this package's (imported on first use, PEP 562, so that
``import relmap.sim.montecarlo`` does not import the filter): ``relmap.sim.simulate``, …
"""

from __future__ import annotations

import importlib
from typing import Any

_ROBOTS = (
    "Controller", "Patrol", "Scans", "Simulation", "random_at3s", "random_ats",
    "random_covariances", "random_landmarks", "random_poses", "simulate",
)  # fmt: skip

__all__ = list(_ROBOTS)


def __getattr__(name: str) -> Any:
    if name in _ROBOTS:
        value = getattr(importlib.import_module("relmap.sim.robots"), name)
    else:  # a module of the package
        try:
            value = importlib.import_module(f"relmap.sim.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"relmap.sim.{name}":
                raise
            raise AttributeError(f"module 'relmap.sim' has no attribute {name!r}") from None
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_ROBOTS])
