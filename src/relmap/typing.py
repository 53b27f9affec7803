"""Array type aliases used in relmap's signatures.

Shapes are written in docstrings as ``(..., 3)``: leading batch axes, then the trailing axes the
function works on.
"""

from __future__ import annotations

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
SeedLike = np.random.Generator | int | None
