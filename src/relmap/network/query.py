"""``RelationalMap.query``: the AT between any two frames, by the paper's reduction or optimally.

Methods:

- ``"reduce"``: the paper's procedure (§5) — compound, merge, Delta-Y — evaluated once, and
  reported as an expression over the map's AT names, e.g. ``(Aᴿ ⊕ B) ⊗ C ⊗ (D ⊕ E)``.
- ``"optimal"``: the paper's "general method": every frame of the part of the network that
  matters estimated jointly by nonlinear least squares, the AT read off the joint covariance.
- ``"auto"``: where no loop lies between the two frames (every block on the way is a single
  AT), compounding is already the exact first-order answer and ``"reduce"`` is used; wherever
  a loop matters, ``"optimal"`` is used. The estimate reports the method actually used.

Only the 2-connected blocks on the way between the two frames are used (see
:mod:`relmap.network.blocks`); consecutive blocks share one frame, and their ATs compound.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from relmap.at import AT, compound, reverse
from relmap.at3 import AT3
from relmap.errors import ParameterError
from relmap.network.blocks import blocks_between
from relmap.network.reduce import reduce_network

if TYPE_CHECKING:
    from relmap.network.graph import RelationalMap

__all__ = ["METHODS", "Estimate", "query"]

Frame = Hashable
METHODS = ("auto", "reduce", "optimal")


class Estimate(NamedTuple):
    """The estimated AT of frame ``dst`` seen from frame ``src``, and how it was obtained."""

    at: AT | AT3
    method: str  #: "reduce" or "optimal": the method actually used
    expression: str | None  #: the reduction evaluated (AT names, ⊕ ⊗ ᴿ); None when optimal
    src: Frame
    dst: Frame
    dropped: tuple[str, ...] = ()  #: ATs deleted by best deletion (reduce)
    definitions: dict[str, str] = {}  #: Delta-Y star ATs in the expression (reduce)  # noqa: RUF012
    iterations: int | None = None  #: Gauss-Newton/LM iterations (optimal)


def _position_trace(at: AT | AT3) -> float:
    """Trace of the position covariance (m²): (x, y), or (x, y, z) in 3-D."""
    k = 2 if isinstance(at, AT) else 3
    return float(np.trace(at.cov[:k, :k]))


def query(
    g: RelationalMap,
    src: Frame,
    dst: Frame,
    *,
    method: str = "auto",
    on_irreducible: str = "raise",
    criterion: Callable[[AT | AT3], float] = _position_trace,
) -> Estimate:
    """The AT of frame ``dst`` seen from frame ``src`` (mean in ``src``'s frame, covariance
    on ``(x, y, θ)`` in ``src``'s frame).

    ``method`` is ``"auto"``, ``"reduce"`` or ``"optimal"`` (see the module docstring).
    ``on_irreducible`` (reduce only) is ``"raise"`` or ``"drop"``: delete the loop-forming AT
    whose deletion minimizes ``criterion`` of the result (default: trace of the position
    covariance, m²) when even Delta-Y cannot reduce the network. Raises
    :class:`relmap.errors.UnknownFrameError` or :class:`relmap.errors.DisconnectedError`.
    """
    if method not in METHODS:
        raise ParameterError(f"method must be one of {', '.join(METHODS)}; got {method!r}")
    g._check_frame(src)
    g._check_frame(dst)
    incident = {f: list(names) for f, names in g._incident.items()}
    ends = {e.name: (e.src, e.dst) for e in g.edges()}
    blocks = blocks_between(incident, ends, src, dst)
    if not blocks:
        return Estimate(g.at_type.identity(), "reduce", "I", src, dst)
    if method == "auto":
        method = "reduce" if all(len(b.names) == 1 for b in blocks) else "optimal"
    order = {name: i for i, name in enumerate(g._edges)}
    names = sorted((n for b in blocks for n in b.names), key=order.__getitem__)
    if method == "reduce":
        in_play = set(names)
        groups = [(grp.names, grp.cov) for grp in g.groups if in_play & set(grp.names)]
        result = reduce_network(
            [(n, g._edges[n].src, g._edges[n].dst, g._edges[n].at) for n in names],
            src,
            dst,
            on_irreducible=on_irreducible,
            criterion=criterion,
            groups=groups,
        )
        return Estimate(
            result.at, "reduce", result.expression, src, dst, result.dropped, result.definitions
        )

    from relmap.network.optimal import solve_relative  # scipy.sparse: imported only when used

    total: AT | AT3 | None = None
    iterations = 0
    for part in _solve_regions(g, blocks):
        if len(part.names) == 1:
            e = g._edges[part.names[0]]
            at = e.at if e.src == part.entry else reverse(e.at)
        else:
            solved = solve_relative(g, part.names, part.entry, part.exit)
            at, iterations = solved.at, max(iterations, solved.iterations)
        total = at if total is None else compound(total, at)
    assert total is not None
    return Estimate(total, "optimal", None, src, dst, iterations=iterations)


class _Region(NamedTuple):
    entry: Frame
    exit: Frame
    names: tuple[str, ...]


def _solve_regions(g: RelationalMap, blocks: list) -> list[_Region]:  # type: ignore[type-arg]
    """Blocks to solve one by one; blocks tied by a dependent group are solved together."""
    regions = [_Region(b.entry, b.exit, b.names) for b in blocks]
    block_of = {n: i for i, r in enumerate(regions) for n in r.names}
    spans: list[list[int]] = []
    for grp in g.groups:
        touched = sorted({block_of[n] for n in grp.names if n in block_of})
        if len(touched) > 1:
            spans.append([touched[0], touched[-1]])
    merged: list[list[int]] = []
    for lo, hi in sorted(spans):
        if merged and lo <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi])
    for lo, hi in reversed(merged):
        lo_region, hi_region = regions[lo], regions[hi]
        fused = tuple(n for r in regions[lo : hi + 1] for n in r.names)
        regions[lo : hi + 1] = [_Region(lo_region.entry, hi_region.exit, fused)]
    return regions
