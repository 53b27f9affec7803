"""relmap: spatial uncertainty for robotics.

Uncertain relative poses (approximate transformations, ATs) after Smith & Cheeseman, "On the
Representation and Estimation of Spatial Uncertainty" (IJRR 1986): compounding (``a @ b``),
reversal (``a.reverse()``), merging (``merge(a, b)``), confidence ellipses, first-order and
unscented propagation, and Monte Carlo checks of every estimate.

Convention (everywhere): an AT on the edge ``A → B`` is where frame B is in frame A, mean
``(x, y, θ)`` with θ in [-π, π), covariance 3×3 on ``(x, y, θ)`` in the parent frame A.
In 3-D (:class:`AT3`) the mean is a translation and a rotation and the covariance is 6×6 on
``(δx, δy, δz, δφx, δφy, δφz)``: translation in the parent frame, rotation applied on the left.

Nothing heavy is imported with the package: each name below is imported from its module on first
use (PEP 562), so ``import relmap`` and the ``relmap`` command's start-up stay light.
"""

from __future__ import annotations

import importlib

from relmap._version import __version__

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (mypy knows the name)
if TYPE_CHECKING:
    from typing import Any

    from relmap import (
        app,
        errors,
        evaluate,
        filter,
        io,
        lie,
        models,
        network,
        sim,
        uncertain,
        viz,
    )  # fmt: skip
    from relmap.network.graph import RelationalMap
    from relmap.network.query import Estimate
    from relmap.uncertain.algebra import compound, compound_chain, merge, reverse
    from relmap.uncertain.at import AT
    from relmap.uncertain.at3 import AT3
    from relmap.uncertain.gaussian import Ellipse

#: The public names and the module each comes from.
_NAMES = {
    "AT": "relmap.uncertain.at",
    "AT3": "relmap.uncertain.at3",
    "compound": "relmap.uncertain.algebra",
    "compound_chain": "relmap.uncertain.algebra",
    "merge": "relmap.uncertain.algebra",
    "reverse": "relmap.uncertain.algebra",
    "Ellipse": "relmap.uncertain.gaussian",
    "Estimate": "relmap.network.query",
    "RelationalMap": "relmap.network.graph",
}
#: The public submodules, available as attributes of the package.
_MODULES = (
    "app", "errors", "evaluate", "filter", "io", "lie", "models", "network", "sim", "uncertain",
    "viz",
)  # fmt: skip


def __getattr__(name: str) -> Any:
    if name in _NAMES:
        value = getattr(importlib.import_module(_NAMES[name]), name)
    else:  # a subpackage (_MODULES) or a module of relmap's
        try:
            value = importlib.import_module(f"relmap.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"relmap.{name}":
                raise
            raise AttributeError(f"module 'relmap' has no attribute {name!r}") from None
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


__all__ = [
    "AT",
    "AT3",
    "Ellipse",
    "Estimate",
    "RelationalMap",
    "__version__",
    "app",
    "compound",
    "compound_chain",
    "errors",
    "evaluate",
    "filter",
    "io",
    "lie",
    "merge",
    "models",
    "network",
    "reverse",
    "sim",
    "uncertain",
    "viz",
]
