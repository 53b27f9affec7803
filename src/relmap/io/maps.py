"""Load any supported file as a RelationalMap, and save a map."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from relmap.errors import ParameterError
from relmap.io import formats
from relmap.io.mapfile import ATRecord
from relmap.io.posegraph import PoseGraph
from relmap.io.textfile import Input
from relmap.network.graph import RelationalMap

if TYPE_CHECKING:
    from relmap.network.losses import LossChoice
    from relmap.network.optimal import Progress, Solution

__all__ = ["load_map", "save_map", "solve_graph"]


def load_map(path: str | os.PathLike[str] | Input) -> RelationalMap:
    """A map from a map file (JSON or YAML) or a pose graph (g2o 2-D/3-D, TORO, legacy
    ``EDGE3``), told apart by content (:mod:`relmap.io.formats`). Pose-graph vertex ids become
    integer frames, their poses the initial guess; a 3-D graph gives a map of
    :class:`relmap.AT3`. The file is read once (:func:`relmap.io.textfile.read_input`): a pipe,
    gzip, a BOM and CRLF are accepted."""
    fmt, content = formats.read(path, (formats.Kind.MAP, formats.Kind.GRAPH))
    if fmt.holds is formats.Kind.GRAPH:
        return RelationalMap.from_posegraph(content)
    return RelationalMap.from_records(content)


def save_map(
    path: str | os.PathLike[str], g: RelationalMap, *, description: str | None = None
) -> None:
    """Write a map as a map file (JSON for ``.json``, YAML otherwise), atomically.

    Frames must be strings or integers (numpy integers are written as integers), so that
    :func:`load_map` reads back the same map; other frames raise
    :class:`relmap.errors.ParameterError` before anything is written. Dependent groups are not
    representable in map files yet and raise :class:`relmap.errors.ParameterError`.
    """
    if g.groups:
        raise ParameterError("map files cannot hold dependent ATs (joint groups) yet")
    records = [ATRecord(e.name, e.src, e.dst, e.at) for e in g.edges()]
    formats.writer("map", formats.Kind.MAP)(path, records, description=description)


def solve_graph(
    graph: PoseGraph,
    *,
    progress: Progress | None = None,
    max_iterations: int = 100,
    rtol: float | None = None,
    loss: LossChoice = None,
) -> Solution:
    """Optimize a whole pose graph from the file's initial guess (the network layer's
    :func:`relmap.network.optimal.solve_frames` on the graph's arrays; the same as
    ``RelationalMap.from_posegraph(graph).solve()``). The anchor is the first ``FIX`` vertex
    if the file has one, else the first vertex; it stays at its file pose. Poses come in
    :attr:`PoseGraph.vertex_ids` order; :meth:`Solution.relative` and friends take vertex
    ids. A vertex without edges, or a part of the graph not linked to the anchor, is refused
    with a :class:`relmap.errors.SolverError` naming them. ``loss``
    (:mod:`relmap.network.losses`): one for every edge, or by edge name (``e{k}``, k in file
    order); the weights it gave each edge are :attr:`Solution.weights`.
    """
    from relmap.network.optimal import solve_frames

    i, j = graph.edge_indices()
    anchor = int(graph.index_of(graph.fixed[:1])[0]) if len(graph.fixed) else 0
    return solve_frames(
        graph.vertex_ids.tolist(),
        i,
        j,
        graph.measurements,
        graph.poses,
        anchor,
        progress=progress,
        max_iterations=max_iterations,
        rtol=rtol,
        loss=loss,
    )
