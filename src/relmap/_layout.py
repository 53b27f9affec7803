"""Memory layout of small per-element vectors and matrices over large batches.

relmap's batched algebra works component by component (``C[..., 0, 2]``, ``pose[..., 1]``). In
numpy's default layout each component of a ``(N, 3, 3)`` array is strided by 72 bytes, so every
elementwise pass drags whole cache lines for one number. The arrays built here keep their
logical shape ``(..., k)`` or ``(..., r, c)`` but store the trailing axes outermost, so each
component is one contiguous block: elementwise passes run about twice as fast. The arrays are
ordinary ndarrays (views); nothing outside relmap needs to know.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from relmap.typing import FloatArray

Entry = FloatArray | float


def stack_last(parts: Sequence[Entry], shape: tuple[int, ...]) -> FloatArray:
    """``(*shape, len(parts))`` array whose component i is ``parts[i]`` (broadcast)."""
    if shape == ():  # one vector: its components are scalars
        return np.array(parts, dtype=np.float64)
    out = np.empty((len(parts), *shape))
    for i, part in enumerate(parts):
        out[i] = part
    return np.moveaxis(out, 0, -1)


def matrix(rows: Sequence[Sequence[Entry]], shape: tuple[int, ...]) -> FloatArray:
    """``(*shape, r, c)`` array with entry ``[..., i, j] = rows[i][j]`` (broadcast)."""
    if shape == ():  # one matrix: its entries are scalars
        return np.array(rows, dtype=np.float64)
    out = np.empty((len(rows), len(rows[0]), *shape))
    for i, row in enumerate(rows):
        for j, value in enumerate(row):
            out[i, j] = value
    return np.moveaxis(out, (0, 1), (-2, -1))


def components_outermost(arr: FloatArray, k: int) -> FloatArray:
    """A copy of ``arr`` with its trailing ``k`` axes stored outermost (same logical shape)."""
    axes = tuple(range(-k, 0))
    front = tuple(range(k))
    return np.moveaxis(np.ascontiguousarray(np.moveaxis(arr, axes, front)), front, axes)


def compact(arr: FloatArray, core: int) -> FloatArray:
    """The smallest view of ``arr`` that broadcasts back to it: every batch axis (all but the
    last ``core``) with stride 0 cut to length 1. A covariance shared by a batch (an AT built
    from one covariance) then costs one computation, not one per element."""
    index = tuple(
        slice(0, 1) if stride == 0 and n > 1 else slice(None)
        for n, stride in zip(arr.shape[: arr.ndim - core], arr.strides, strict=False)
    )
    return arr[index] if index and any(s != slice(None) for s in index) else arr
