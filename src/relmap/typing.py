"""Array type aliases used in relmap's signatures.

Shapes are written in docstrings as ``(..., 3)``: leading batch axes, then the trailing axes the
function works on.
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np
import numpy.typing as npt

__all__ = ["ArrayLike", "FloatArray", "IntArray", "SeedLike"]

#: A float64 array (any shape; the docstring states which).
FloatArray = npt.NDArray[np.float64]

#: An int64 array of indices.
IntArray = npt.NDArray[np.int64]

#: Anything numpy can turn into a float array.
ArrayLike = npt.ArrayLike

#: What relmap accepts wherever randomness is drawn: a Generator, a seed, or None (fresh entropy).
#: Written as a string, so that importing relmap's modules does not import ``numpy.random``
#: (≈ 25 ms; it is imported where randomness is first drawn).
SeedLike: TypeAlias = "np.random.Generator | int | None"
