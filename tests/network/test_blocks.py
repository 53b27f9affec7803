"""The 2-connected blocks of relmap.network.blocks against a plain recursive Tarjan."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from relmap.errors import DisconnectedError
from relmap.network.blocks import _biconnected_components, blocks_between


def _reference_blocks(ends: dict[str, tuple[str, str]], root: str) -> set[frozenset[str]]:
    """Tarjan's biconnected components of root's component, written plainly (recursive)."""
    incident: dict[str, list[str]] = {}
    for nm, (s, d) in ends.items():
        if s != d:
            incident.setdefault(s, []).append(nm)
            incident.setdefault(d, []).append(nm)
    disc: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: set[frozenset[str]] = set()

    def visit(v: str, via: str | None) -> None:
        disc[v] = low[v] = len(disc)
        for nm in incident.get(v, []):
            if nm == via:
                continue
            s, d = ends[nm]
            w = d if s == v else s
            if w not in disc:
                stack.append(nm)
                visit(w, nm)
                low[v] = min(low[v], low[w])
                if low[w] >= disc[v]:  # v separates w's subtree
                    block = set()
                    while True:
                        e = stack.pop()
                        block.add(e)
                        if e == nm:
                            break
                    out.add(frozenset(block))
            elif disc[w] < disc[v]:
                stack.append(nm)
                low[v] = min(low[v], disc[w])

    visit(root, None)
    return out


def _random_network(rng, frames, ats):
    """Frames named by strings; chains, loops, parallels, self-loops, a separate component."""
    names = [f"f{k}" for k in range(frames)]
    ends = {}
    for k in range(ats):
        a, b = rng.integers(0, frames, 2)
        if rng.random() < 0.3 and k:  # grow a chain or a dangling branch
            b = (a + 1) % frames
        ends[f"A{k}"] = (names[a], names[b])
    ends["island"] = ("x", "y")
    return ends, names


@pytest.mark.parametrize("seed", range(40))
def test_blocks_equal_the_reference_tarjan(seed):
    rng = np.random.default_rng(seed)
    frames = int(rng.integers(2, 60))
    ends, names = _random_network(rng, frames, int(rng.integers(1, 2 * frames)))
    root = names[int(rng.integers(0, frames))]
    blocks = _biconnected_components(ends, root)
    assert sum(map(len, blocks)) == len({nm for blk in blocks for nm in blk})  # a partition
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * frames + 100))
    try:
        assert set(map(frozenset, blocks)) == _reference_blocks(ends, root)
    finally:
        sys.setrecursionlimit(limit)


def test_blocks_of_a_bridge_with_a_tail_and_a_self_loop():
    ends = {"A": ("w", "t"), "B": ("w", "v"), "C": ("t", "v"), "D": ("t", "u"), "E": ("u", "v")}
    ends |= {"T": ("v", "z"), "S": ("z", "z"), "P": ("z", "q"), "P2": ("q", "z")}
    blocks = _biconnected_components(ends, "w")
    assert sorted(map(sorted, blocks)) == [["A", "B", "C", "D", "E"], ["P", "P2"], ["T"]]
    incident: dict[str, list[str]] = {}
    for nm, (s, d) in ends.items():
        incident.setdefault(s, []).append(nm)
        if d != s:
            incident.setdefault(d, []).append(nm)
    way = blocks_between(incident, ends, "t", "q")
    assert [(b.entry, b.exit, sorted(b.names)) for b in way] == [
        ("t", "v", ["A", "B", "C", "D", "E"]),
        ("v", "z", ["T"]),
        ("z", "q", ["P", "P2"]),
    ]
    with pytest.raises(DisconnectedError):
        blocks_between(incident | {"x": []}, ends, "t", "x")


def test_a_long_chain_needs_no_recursion():
    n = 200_000
    ends = {f"e{k}": (k, k + 1) for k in range(n)}
    blocks = _biconnected_components(ends, 0)
    assert len(blocks) == n and all(len(b) == 1 for b in blocks)
