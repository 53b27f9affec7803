"""The 2-connected blocks between two frames: the compiled Tarjan equals the Python one."""

from __future__ import annotations

import numpy as np
import pytest

from relmap import _numba
from relmap.errors import DisconnectedError
from relmap.network.blocks import _biconnected_components, _compiled_components, blocks_between

pytest.importorskip("numba")


def _random_network(rng, frames, ats):
    """Frames named by strings, ATs named in insertion order; chains, loops, parallels,
    self-loops and a separate component."""
    names = [f"f{k}" for k in range(frames)]
    ends = {}
    for k in range(ats):
        a, b = rng.integers(0, frames, 2)
        if rng.random() < 0.3 and k:  # grow a chain or a dangling branch
            b = (a + 1) % frames
        ends[f"A{k}"] = (names[a], names[b])
    ends["island"] = ("x", "y")
    incident = {}
    for nm, (s, d) in ends.items():
        incident.setdefault(s, []).append(nm)
        if d != s:
            incident.setdefault(d, []).append(nm)
    return incident, ends, names


@pytest.mark.parametrize("seed", range(30))
def test_compiled_blocks_equal_python_blocks(seed, monkeypatch):
    rng = np.random.default_rng(seed)
    frames = int(rng.integers(2, 40))
    incident, ends, names = _random_network(rng, frames, int(rng.integers(1, 2 * frames)))
    root = names[int(rng.integers(0, frames))]
    if root not in incident:
        root = next(iter(incident))
    assert _compiled_components(ends, root) == _biconnected_components(incident, ends, root)
    dst = names[int(rng.integers(0, frames))]

    def between():
        try:
            return blocks_between(incident, ends, root, dst)
        except DisconnectedError:
            return None

    monkeypatch.setattr(_numba, "LARGE", 0)  # the compiled path even for a small network
    compiled = between()
    monkeypatch.setenv("RELMAP_NUMBA", "0")
    python = between()
    assert compiled == python


def test_compiled_blocks_of_a_bridge_with_a_tail():
    ends = {"A": ("w", "t"), "B": ("w", "v"), "C": ("t", "v"), "D": ("t", "u"), "E": ("u", "v")}
    ends |= {"T": ("v", "z"), "S": ("z", "z")}
    blocks = _compiled_components(ends, "w")
    assert sorted(map(sorted, blocks)) == [["A", "B", "C", "D", "E"], ["T"]]
