"""Compiled kernels through numba, when numba can be used; numpy paths otherwise.

Hot loops that numpy cannot express without a Python loop (a sparse block factorization, a
fused SE(3) kernel, the EKF's per-reading arithmetic) have a numba kernel beside their numpy
path. ``enabled()`` says which one runs: numba is importable and the environment variable
``RELMAP_NUMBA`` is not ``0`` (the tests set it to check that both paths agree). Kernels live in
modules that import numba at their top and are imported lazily, only when ``enabled()``, so
``import relmap`` never pays numba's import. Kernels are compiled on first use and cached on
disk (``cache=True``): later processes load them instead of compiling.
"""

from __future__ import annotations

import functools
import os

__all__ = ["enabled"]


def enabled() -> bool:
    """Whether numba kernels run (numba importable, ``RELMAP_NUMBA`` not ``0``)."""
    return os.environ.get("RELMAP_NUMBA", "1") != "0" and _importable()


@functools.cache
def _importable() -> bool:
    try:
        import numba  # noqa: F401
    except ImportError:  # pragma: no cover - numba is a dependency where it has wheels
        return False
    return True
