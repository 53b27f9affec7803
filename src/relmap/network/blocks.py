"""The part of a network that can influence the AT between two frames.

A relational map splits into 2-connected blocks joined at single frames (articulation points).
Only the blocks on the way from the source to the destination frame matter: anything hanging
off the way at a single frame (a dangling chain, a dangling loop) cannot change the relation
between the two frames, and consecutive blocks meet at one frame, so the answer is the
compound of one AT per block.
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Hashable, Iterable, Mapping
from typing import NamedTuple

import numpy as np

from relmap import _core
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

    ``ends`` maps each AT's name to its ``(src, dst)`` frames; ``incident`` (each frame's AT
    names in the order of ``ends``) follows from it, and the search visits a frame's ATs in
    that order. Self-loops are ignored. Raises
    :class:`DisconnectedError` when no chain of ATs links the frames. The blocks come from
    Tarjan's depth-first search in relmap's compiled core, O(frames + ATs).
    """
    if src == dst:
        return []
    blocks = _biconnected_components(ends, src)
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


def _biconnected_components(
    ends: Mapping[str, tuple[Frame, Frame]], root: Frame
) -> list[list[str]]:
    """Edge sets of the 2-connected blocks of ``root``'s connected component, in the order
    Tarjan's search closes them (relmap._core.biconnected_blocks on integer frames)."""
    names = list(ends)
    index: dict[Frame, int] = {root: 0}
    a = np.array([index.setdefault(s, len(index)) for s, _ in ends.values()], dtype=np.int64)
    b = np.array([index.setdefault(d, len(index)) for _, d in ends.values()], dtype=np.int64)
    edges, bounds = _core.biconnected_blocks(len(index), a, b, 0)
    cuts = bounds.tolist()
    order = edges.tolist()
    return [[names[e] for e in order[lo:hi]] for lo, hi in itertools.pairwise(cuts)]
