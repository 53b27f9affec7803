"""The part of a network that can influence the AT between two frames.

A relational map splits into 2-connected blocks joined at single frames (articulation points).
Only the blocks on the way from the source to the destination frame matter: anything hanging
off the way at a single frame (a dangling chain, a dangling loop) cannot change the relation
between the two frames, and consecutive blocks meet at one frame, so the answer is the
compound of one AT per block.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Hashable, Iterable, Mapping
from typing import NamedTuple

import numpy as np

from relmap.errors import DisconnectedError

__all__ = ["Block", "blocks_between"]

Frame = Hashable


class Block(NamedTuple):
    """A 2-connected block on the way: enter at ``entry``, leave at ``exit``; its AT names."""

    entry: Frame
    exit: Frame
    names: tuple[str, ...]


def blocks_between(
    incident: Mapping[Frame, Iterable[str]],
    ends: Mapping[str, tuple[Frame, Frame]],
    src: Frame,
    dst: Frame,
) -> list[Block]:
    """The blocks on the way from ``src`` to ``dst``, in order (empty if ``src == dst``).

    ``incident`` maps each frame to the names of its ATs, in the order of ``ends``, which maps
    each name to its ``(src, dst)`` frames. Self-loops are ignored. Raises
    :class:`DisconnectedError` when no chain of ATs links the frames. Iterative Tarjan (no
    recursion limit), O(frames + ATs); compiled (:mod:`relmap.network._tarjan`) for large
    maps when numba is enabled (:func:`relmap._numba.enabled`), with the same blocks in the
    same order.
    """
    if src == dst:
        return []
    from relmap import _numba

    if _numba.enabled(len(ends)):
        blocks = _compiled_components(ends, src)
    else:
        blocks = _biconnected_components(incident, ends, src)
    frames_of = [{f for nm in blk for f in ends[nm]} for blk in blocks]
    # Block-cut tree search: from src, through blocks and the frames they share, to dst.
    blocks_at: dict[Frame, list[int]] = {}
    for b, frames in enumerate(frames_of):
        for f in frames:
            blocks_at.setdefault(f, []).append(b)
    if dst not in blocks_at or src not in blocks_at:
        raise DisconnectedError(f"no chain of ATs links frame {src!r} to frame {dst!r}")
    came_from: dict[object, object] = {("f", src): None}
    queue: deque[tuple[str, object]] = deque([("f", src)])
    while queue:
        node = queue.popleft()
        if node == ("f", dst):
            break
        kind, key = node
        nexts = (
            [("b", b) for b in blocks_at[key]]
            if kind == "f"
            else [("f", f) for f in frames_of[key]]  # type: ignore[index]
        )
        for nxt in nexts:
            if nxt not in came_from:
                came_from[nxt] = node
                queue.append(nxt)
    if ("f", dst) not in came_from:
        raise DisconnectedError(f"no chain of ATs links frame {src!r} to frame {dst!r}")
    path: list[tuple[str, object]] = []
    node: object = ("f", dst)
    while node is not None:
        path.append(node)  # type: ignore[arg-type]
        node = came_from[node]
    path.reverse()  # f, b, f, b, ..., f
    return [
        Block(path[i - 1][1], path[i + 1][1], tuple(blocks[path[i][1]]))  # type: ignore[index]
        for i in range(1, len(path), 2)
    ]


def _compiled_components(ends: Mapping[str, tuple[Frame, Frame]], root: Frame) -> list[list[str]]:
    """:func:`_biconnected_components` on integer frames, compiled (same lists, same order)."""
    from relmap.network._tarjan import blocks

    names = list(ends)
    index: dict[Frame, int] = {root: 0}
    a = np.array([index.setdefault(s, len(index)) for s, _ in ends.values()], dtype=np.int64)
    b = np.array([index.setdefault(d, len(index)) for _, d in ends.values()], dtype=np.int64)
    return [[names[e] for e in block.tolist()] for block in blocks(len(index), a, b, 0)]


def _biconnected_components(
    incident: Mapping[Frame, Iterable[str]],
    ends: Mapping[str, tuple[Frame, Frame]],
    root: Frame,
) -> list[list[str]]:
    """Edge sets of the 2-connected blocks of ``root``'s connected component."""
    disc: dict[Frame, int] = {root: 0}
    low: dict[Frame, int] = {root: 0}
    clock = 1
    edge_stack: list[str] = []
    components: list[list[str]] = []
    stack = [(root, None, iter(incident[root]))]
    while stack:
        v, parent_edge, it = stack[-1]
        advanced = False
        for name in it:
            if name == parent_edge:
                continue
            a, b = ends[name]
            w = b if a == v else a
            if w == v:
                continue  # a self-loop relates a frame to itself: no information here
            if w not in disc:
                edge_stack.append(name)
                disc[w] = low[w] = clock
                clock += 1
                stack.append((w, name, iter(incident[w])))
                advanced = True
                break
            if disc[w] < disc[v]:  # back edge (or a parallel AT to the parent)
                edge_stack.append(name)
                low[v] = min(low[v], disc[w])
        if advanced:
            continue
        stack.pop()
        if stack:
            u = stack[-1][0]
            low[u] = min(low[u], low[v])
            if low[v] >= disc[u]:  # u separates v's subtree: close a block
                component = []
                while True:
                    name = edge_stack.pop()
                    component.append(name)
                    if name == parent_edge:
                        break
                components.append(component)
    return components
