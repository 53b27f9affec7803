"""What relmap's text-table readers share (:mod:`relmap.io.posegraph`,
:mod:`relmap.io.datasets`): a number read strictly, the error at the line of the first bad row,
and the read-only arrays their results hold."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from relmap.errors import FileFormatError
from relmap.typing import ArrayLike

__all__ = ["fail_at", "frozen", "is_number", "strict_float"]

_NUMBER = re.compile(r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")


def strict_float(token: str) -> float:
    """``token`` as a float, as numpy's C text parser reads it: Python's ``float`` syntax
    without its digit separators (``1_000`` is refused); ``ValueError`` otherwise."""
    if "_" in token:
        raise ValueError(token)
    return float(token)


def is_number(token: str) -> bool:
    """Whether ``token`` is a decimal number as tables write them (``-1.5e3``; not ``nan``,
    ``inf``, ``0x10``, ``1_0``): how a format tells a row of numbers from a record tag."""
    return _NUMBER.fullmatch(token) is not None


def fail_at(path: Path, bad: ArrayLike, lines: Sequence[int] | np.ndarray, message: str) -> None:
    """Raise :class:`FileFormatError` ``message`` at the line of the first row flagged in
    ``bad`` (rows numbered like ``lines``, 1-based file lines); nothing if none is flagged."""
    flagged = np.flatnonzero(bad)
    if flagged.size:
        raise FileFormatError(path, message, line=int(lines[int(flagged[0])]))


def frozen(arr: np.ndarray) -> np.ndarray:
    """``arr`` contiguous and read-only (a reader's result cannot be modified in place)."""
    arr = np.ascontiguousarray(arr)
    arr.flags.writeable = False
    return arr
