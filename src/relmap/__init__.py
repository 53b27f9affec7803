"""relmap: spatial uncertainty for robotics.

Uncertain relative poses (approximate transformations, ATs) after Smith & Cheeseman, "On the
Representation and Estimation of Spatial Uncertainty" (IJRR 1986): compounding (``a @ b``),
reversal (``a.reverse()``), merging (``merge(a, b)``), confidence ellipses, first-order and
unscented propagation, and Monte Carlo checks of every estimate.

Convention (everywhere): an AT on the edge ``A → B`` is where frame B is in frame A, mean
``(x, y, θ)`` with θ in [-π, π), covariance 3×3 on ``(x, y, θ)`` in the parent frame A.
In 3-D (:class:`AT3`) the mean is a translation and a rotation and the covariance is 6×6 on
``(δx, δy, δz, δφx, δφy, δφz)``: translation in the parent frame, rotation applied on the left.
"""

import importlib
from typing import Any

from relmap import errors, gaussian, lie, moments
from relmap.at import AT, compound, compound_chain, merge, reverse
from relmap.at3 import AT3
from relmap.gaussian import Ellipse
from relmap.network import Estimate, RelationalMap

__version__ = "0.1.0"

_LAZY = ("decisions", "montecarlo", "propagate")  # imported on first use: a faster start-up


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return importlib.import_module(f"relmap.{name}")
    raise AttributeError(f"module 'relmap' has no attribute {name!r}")


__all__ = [
    "AT",
    "AT3",
    "Ellipse",
    "Estimate",
    "RelationalMap",
    "__version__",
    "compound",
    "compound_chain",
    "decisions",
    "errors",
    "gaussian",
    "lie",
    "merge",
    "moments",
    "montecarlo",
    "propagate",
    "reverse",
]
