"""The numba minimum-degree node ordering: a permutation, its fill counted right, and fill
comparable to SuperLU's multiple minimum degree on real pose graphs."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")

from relmap.network._ordering import elimination_fill, minimum_degree
from relmap.network.sparse import _minimum_degree


def _dense_fill(k, a, b, order):
    """Strictly-lower nonzeros of the Cholesky factor of a random SPD matrix on the graph."""
    rng = np.random.default_rng(0)
    A = np.zeros((k, k))
    A[a, b] = A[b, a] = rng.uniform(0.1, 1.0, len(a))
    A += np.diag(np.abs(A).sum(axis=1) + 1.0)
    L = np.linalg.cholesky(A[np.ix_(order, order)])
    return int((np.abs(np.tril(L, -1)) > 1e-14).sum())


def _random_graph(rng, k, m):
    a = rng.integers(0, k, m)
    b = rng.integers(0, k, m)
    chain = np.arange(k - 1)
    return np.concatenate([a, chain]), np.concatenate([b, chain + 1])


@pytest.mark.parametrize("seed", range(8))
def test_order_is_a_permutation_and_its_fill_is_the_factors(seed):
    rng = np.random.default_rng(seed)
    k = int(rng.integers(1, 60))
    a, b = _random_graph(rng, k, int(rng.integers(0, 3 * k)))
    order, fill = minimum_degree(k, a, b)
    assert np.array_equal(np.sort(order), np.arange(k))
    assert fill == elimination_fill(k, a, b, order) == _dense_fill(k, a, b, order)
    natural = np.arange(k)
    assert elimination_fill(k, a, b, natural) == _dense_fill(k, a, b, natural)


def test_trees_and_cliques():
    # a star eliminated leaves first has no fill (the centre first would fill a clique)
    k = 7
    assert minimum_degree(k, np.zeros(k - 1, int), np.arange(1, k))[1] == k - 1
    a, b = np.triu_indices(k, 1)
    assert minimum_degree(k, a, b)[1] == k * (k - 1) // 2
    assert minimum_degree(1, [], [])[0].tolist() == [0]


@pytest.mark.parametrize(
    "name", ["posegraph2d/city10000.g2o", "posegraph2d/intel.g2o", "posegraph3d/sphere2500.g2o"]
)
def test_fill_close_to_superlu_mmd_on_real_graphs(data_dir, name):
    from relmap.io import read_graph

    graph = read_graph(data_dir / name)
    i, j = graph.edge_indices()
    k = len(graph.vertex_ids)
    _, fill = minimum_degree(k, i, j)
    mmd = elimination_fill(k, i, j, _minimum_degree(k, np.minimum(i, j), np.maximum(i, j)))
    assert fill <= 1.15 * mmd
