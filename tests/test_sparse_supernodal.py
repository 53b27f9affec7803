"""The supernodal Cholesky of relmap.network.sparse against SuperLU and dense algebra."""

from __future__ import annotations

import numpy as np
import pytest

from relmap.network.sparse import SymmetricFactor, SymmetricPattern


def _random_block_system(nodes: int, edges: int, b: int, seed: int):
    """A random SPD matrix with the pattern of a random connected graph of b×b blocks."""
    rng = np.random.default_rng(seed)
    chain = np.arange(nodes - 1)
    extra = rng.integers(0, nodes, size=(edges, 2))
    extra = extra[extra[:, 0] != extra[:, 1]]
    i = np.concatenate([chain, extra[:, 0]])
    j = np.concatenate([chain + 1, extra[:, 1]])
    brow = np.concatenate([i, i, j, j])
    bcol = np.concatenate([i, j, i, j])
    pattern = SymmetricPattern.from_blocks(nodes, brow, bcol, block=b)
    # values: Jᵀ J of random block rows (diagonally loaded), laid out [entry q][block k]
    m = len(i)
    A = rng.standard_normal((m, b, b))
    B = rng.standard_normal((m, b, b))
    blocks = [
        np.swapaxes(A, 1, 2) @ A + np.eye(b),
        np.swapaxes(A, 1, 2) @ B,
        np.swapaxes(B, 1, 2) @ A,
        np.swapaxes(B, 1, 2) @ B + np.eye(b),
    ]
    values = np.concatenate([x.reshape(m, b * b) for x in blocks]).T.reshape(-1)
    return pattern, pattern.assemble(values)


@pytest.mark.parametrize(("nodes", "edges", "b"), [(40, 30, 6), (300, 250, 6), (200, 200, 3)])
def test_supernodal_solves_like_superlu_and_dense(nodes, edges, b):
    pattern, data = _random_block_system(nodes, edges, b, seed=nodes)
    dense = pattern.matrix(data).toarray()
    np.testing.assert_allclose(dense, dense.T)
    sn = SymmetricFactor(pattern, "supernodal")
    lu = SymmetricFactor(pattern, "superlu")
    sn.factorize(data)
    lu.factorize(data)
    rng = np.random.default_rng(1)
    rhs = rng.standard_normal(pattern.size)
    cols = rng.standard_normal((pattern.size, 12))
    x = sn.solve(rhs)
    np.testing.assert_allclose(dense @ x, rhs, atol=1e-9 * np.abs(rhs).max())
    np.testing.assert_allclose(x, lu.solve(rhs), rtol=1e-8, atol=1e-10)
    X = sn.solve(cols)
    np.testing.assert_allclose(X, np.linalg.solve(dense, cols), rtol=1e-8, atol=1e-10)
    # refactorization with new values on the same pattern (the symbolic analysis is reused)
    data2 = pattern.with_diagonal(data, np.full(pattern.size, 3.0))
    sn.factorize(data2)
    np.testing.assert_allclose(
        sn.solve(rhs), np.linalg.solve(dense + 3.0 * np.eye(pattern.size), rhs), rtol=1e-8
    )


def test_auto_backend_is_supernodal_for_3d_blocks_only(monkeypatch):
    monkeypatch.setenv("RELMAP_NUMBA", "0")  # with numba, auto is the block LDLᵀ
    p6, _ = _random_block_system(10, 5, 6, seed=0)
    p3, _ = _random_block_system(10, 5, 3, seed=0)
    assert SymmetricFactor(p6).backend == "supernodal"
    assert SymmetricFactor(p3).backend in ("qdldl", "superlu")


def test_a_matrix_that_is_not_positive_definite_falls_back_to_superlu():
    pattern, data = _random_block_system(30, 20, 6, seed=3)
    dense = pattern.matrix(data).toarray()
    shift = np.linalg.eigvalsh(dense)[0] + 0.5  # one negative eigenvalue, still invertible
    data = pattern.with_diagonal(data, np.full(pattern.size, -shift))
    f = SymmetricFactor(pattern, "supernodal")
    f.factorize(data)
    rhs = np.arange(pattern.size, dtype=float)
    np.testing.assert_allclose(
        f.solve(rhs), np.linalg.solve(dense - shift * np.eye(pattern.size), rhs), rtol=1e-6
    )


@pytest.mark.parametrize("seed", range(4))
def test_minimum_degree_from_the_incomplete_lu_is_superlus_complete_one(seed):
    """The ordering is SuperLU's MMD, taken from an ILU that drops everything: the complete LU
    orders its columns the same way (the ordering precedes the factorization)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    from relmap.network.sparse import _minimum_degree

    rng = np.random.default_rng(seed)
    k = 300
    a = np.concatenate([np.arange(k - 1), rng.integers(0, k, 200)])
    b = np.concatenate([np.arange(1, k), rng.integers(0, k, 200)])
    keep = a != b
    a, b = a[keep], b[keep]
    G = sp.csc_matrix(
        (np.full(2 * len(a), -1.0), (np.concatenate([a, b]), np.concatenate([b, a]))),
        shape=(k, k),
    )
    G.sum_duplicates()
    G.data[:] = -1.0
    G.setdiag(np.asarray(abs(G).sum(axis=0)).ravel() + 1.0)
    lu = splu(G, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    np.testing.assert_array_equal(_minimum_degree(k, a, b), np.argsort(lu.perm_c))
