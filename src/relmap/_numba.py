"""Compiled kernels through numba, when numba can be used; numpy paths otherwise.

The EKF's per-reading arithmetic has a numba kernel beside its numpy path: the last of relmap's
numba kernels (the others moved into the compiled core, relmap._core; the EKF's will too).
``enabled()`` says which one runs: numba is importable and the environment variable
``RELMAP_NUMBA`` is not ``0`` (the tests set it to check that both paths agree). Kernels live in
modules that import numba at their top and are imported lazily, only when ``enabled()``, so
``import relmap`` never pays numba's import. Kernels are compiled on first use and cached on
disk (``cache=True``): later processes load them instead of compiling.

Loading numba is not free: its import and the first call of any kernel in a process (numba's
CPU target, which imports ``scipy.linalg``) cost about 0.5-1 s here (measured). So kernels
serve large problems (:data:`LARGE` items or more, where they repay that cost on first use)
and repeated work (an EKF's steps: callers that pass no size); small maps stay on numpy. A
one-shot command (``relmap demo``) runs inside :func:`one_shot`, which raises the size to
:data:`ONE_SHOT_LARGE` and keeps repeated work on numpy.
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Iterator

__all__ = ["LARGE", "ONE_SHOT_LARGE", "enabled", "one_shot"]

LARGE = 2000  #: problem size (ATs, frames, poses) from which the compiled kernels are used
ONE_SHOT_LARGE = 50_000  #: the same inside :func:`one_shot`
_one_shot = [False]


def enabled(size: int | None = None) -> bool:
    """Whether numba kernels run (numba importable, ``RELMAP_NUMBA`` not ``0``) — for a
    problem of ``size`` items, only when it is at least :data:`LARGE` (inside
    :func:`one_shot`: :data:`ONE_SHOT_LARGE`, and never for repeated work, ``size=None``)."""
    if _one_shot[0] and (size is None or size < ONE_SHOT_LARGE):
        return False
    if size is not None and size < LARGE:
        return False
    return os.environ.get("RELMAP_NUMBA", "1") != "0" and _importable()


@contextlib.contextmanager
def one_shot() -> Iterator[None]:
    """Within: the choices of :func:`enabled` for work done once in a short process."""
    before = _one_shot[0]
    _one_shot[0] = True
    try:
        yield
    finally:
        _one_shot[0] = before


@functools.cache
def _importable() -> bool:
    try:
        import numba  # noqa: F401
    except ImportError:  # pragma: no cover - numba is a dependency where it has wheels
        return False
    return True
