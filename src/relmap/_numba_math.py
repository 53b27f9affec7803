"""Scalar helpers shared by relmap's numba kernels (imported only by kernel modules, which
import numba themselves: see :mod:`relmap._numba`)."""

from __future__ import annotations

import math

import numba

__all__ = ["wrap"]

_PI = math.pi
_TWO_PI = 2.0 * math.pi


@numba.njit(cache=True, inline="always")
def wrap(x: float) -> float:  # pragma: no cover
    """An angle wrapped to [-π, π), as :func:`relmap.lie.se2.wrap_angle`."""
    if -_PI <= x < _PI:
        return x
    w = (x + _PI) % _TWO_PI - _PI
    if w >= _PI:
        w -= _TWO_PI
    return w
