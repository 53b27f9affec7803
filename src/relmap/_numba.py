"""Compiled kernels through numba, when numba can be used; numpy paths otherwise.

Hot loops that numpy cannot express without a Python loop (a sparse block factorization, a
fused SE(3) kernel, the EKF's per-reading arithmetic) have a numba kernel beside their numpy
path. ``enabled()`` says which one runs: numba is importable and the environment variable
``RELMAP_NUMBA`` is not ``0`` (the tests set it to check that both paths agree). Kernels live in
modules that import numba at their top and are imported lazily, only when ``enabled()``, so
``import relmap`` never pays numba's import. Kernels are compiled on first use and cached on
disk (``cache=True``): later processes load them instead of compiling.

Loading numba is not free: its import and the first call of any kernel in a process (numba's
CPU target, which imports ``scipy.linalg``) cost about 0.5-0.8 s of CPU here (measured). So
kernels serve large problems only (:data:`LARGE` items or more), where they repay that cost
on their first use; small maps and short runs stay on numpy, and a command on them starts
as fast as before.
"""

from __future__ import annotations

import functools
import os

__all__ = ["LARGE", "enabled"]

LARGE = 2000  #: problem size (ATs, frames, poses) from which the compiled kernels are used


def enabled(size: int | None = None) -> bool:
    """Whether numba kernels run (numba importable, ``RELMAP_NUMBA`` not ``0``) — for a
    problem of ``size`` items, only when it is at least :data:`LARGE`."""
    if size is not None and size < LARGE:
        return False
    return os.environ.get("RELMAP_NUMBA", "1") != "0" and _importable()


@functools.cache
def _importable() -> bool:
    try:
        import numba  # noqa: F401
    except ImportError:  # pragma: no cover - numba is a dependency where it has wheels
        return False
    return True
