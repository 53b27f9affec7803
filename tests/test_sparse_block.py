"""The numba block LDLᵀ of relmap.network.sparse (``block`` backend) against dense algebra."""

from __future__ import annotations

import numpy as np
import pytest

from relmap import _numba
from relmap.io import read_graph, solve_graph
from relmap.network.sparse import (
    SymmetricFactor,
    SymmetricPattern,
    _BlockNumeric,
    selected_inverse_blocks,
)

pytestmark = pytest.mark.skipif(
    not _numba.enabled(), reason="numba kernels off (RELMAP_NUMBA=0) or numba missing"
)


def _system(nodes: int, i: np.ndarray, j: np.ndarray, b: int, seed: int):
    """A random SPD matrix of b×b blocks with the pattern of the edges (i, j) (+ diagonal)."""
    rng = np.random.default_rng(seed)
    diag = np.arange(nodes)
    brow = np.concatenate([i, i, j, j, diag])
    bcol = np.concatenate([i, j, i, j, diag])
    pattern = SymmetricPattern.from_blocks(nodes, brow, bcol, block=b)
    m = len(i)
    A = rng.standard_normal((m, b, b))
    B = rng.standard_normal((m, b, b))
    P = rng.standard_normal((nodes, b, b))
    blocks = [
        np.swapaxes(A, 1, 2) @ A,
        np.swapaxes(A, 1, 2) @ B,
        np.swapaxes(B, 1, 2) @ A,
        np.swapaxes(B, 1, 2) @ B,
        np.swapaxes(P, 1, 2) @ P + 0.1 * np.eye(b),
    ]
    values = np.concatenate([x.reshape(-1, b * b) for x in blocks]).T.reshape(-1)
    return pattern, pattern.assemble(values)


def _random_graph(nodes: int, edges: int, seed: int, chain: bool = True):
    rng = np.random.default_rng(seed)
    extra = rng.integers(0, nodes, size=(edges, 2))
    extra = extra[extra[:, 0] != extra[:, 1]]
    base = np.arange(nodes - 1) if chain else np.zeros(0, np.int64)
    return np.concatenate([base, extra[:, 0]]), np.concatenate([base + 1, extra[:, 1]])


def _dense_diagonal_blocks(dense: np.ndarray, b: int) -> np.ndarray:
    Z = np.linalg.inv(dense)
    n = len(dense) // b
    return np.array([Z[b * k : b * k + b, b * k : b * k + b] for k in range(n)])


def _check_joint_blocks(f: SymmetricFactor, Z: np.ndarray, b: int) -> None:
    """Joint blocks of A⁻¹ of a few nodes (the first, the last, one between) against Z = A⁻¹."""
    n = f.pattern.size // b
    for nodes in ([n - 1], [0, n - 1], [n // 2, 0, n - 1][:n]):
        idx = (b * np.array(nodes)[:, None] + np.arange(b)).reshape(-1)
        if len(set(nodes)) == len(nodes):
            sub = f.inverse_submatrix(idx)
            assert np.abs(sub - Z[np.ix_(idx, idx)]).max() < 1e-10 * np.abs(Z).max()


def _check(pattern: SymmetricPattern, data: np.ndarray, b: int) -> None:
    dense = pattern.matrix(data).toarray()
    rng = np.random.default_rng(7)
    rhs = rng.standard_normal(pattern.size)
    cols = rng.standard_normal((pattern.size, 5))
    scale = np.linalg.cond(dense)
    X_ref = np.linalg.solve(dense, cols)
    ref = _dense_diagonal_blocks(dense, b)
    for supernodal in (False, True):  # both numeric kernels, whichever the pattern would pick
        f = SymmetricFactor(pattern, "block")
        f._block = _BlockNumeric(pattern.blockchol, supernodal=supernodal)
        f.factorize(data)
        assert f.active == "block"
        Z = np.linalg.inv(dense)
        _check_joint_blocks(f, Z, b)  # supernodal: straight from the panels
        np.testing.assert_allclose(
            f.solve(rhs),
            np.linalg.solve(dense, rhs),
            rtol=0,
            atol=1e-13 * scale * np.abs(rhs).max(),
        )
        np.testing.assert_allclose(
            f.solve(cols), X_ref, rtol=0, atol=1e-13 * scale * np.abs(X_ref).max()
        )
        _check_joint_blocks(f, Z, b)  # from the block L D Lᵀ
        idx = np.array([pattern.size - 1, 0])  # not whole nodes: column solves
        sub = f.inverse_submatrix(idx)
        assert np.abs(sub - Z[np.ix_(idx, idx)]).max() < 1e-10 * np.abs(Z).max()
        for blocks in (
            selected_inverse_blocks(pattern, data, block=b, factor=f),  # the factor's numbers
            selected_inverse_blocks(pattern, data, block=b),  # without: SuperLU below LARGE
        ):
            err = np.abs(blocks - ref).max() / np.abs(ref).max()
            assert err < 1e-10
            np.testing.assert_array_equal(blocks, np.swapaxes(blocks, 1, 2))


@pytest.mark.parametrize("b", [3, 6])
@pytest.mark.parametrize(("nodes", "edges"), [(30, 20), (150, 160)])
def test_block_factor_solves_and_inverts_like_dense(nodes, edges, b):
    i, j = _random_graph(nodes, edges, seed=nodes + b)
    pattern, data = _system(nodes, i, j, b, seed=b)
    _check(pattern, data, b)
    # a refactorization on the same pattern reuses the symbolic analysis
    f = SymmetricFactor(pattern, "block")
    f.factorize(data)
    shifted = pattern.with_diagonal(data, np.full(pattern.size, 2.0))
    f.factorize(shifted)
    rhs = np.arange(pattern.size, dtype=float)
    dense = pattern.matrix(shifted).toarray()
    np.testing.assert_allclose(f.solve(rhs), np.linalg.solve(dense, rhs), rtol=1e-10)


@pytest.mark.parametrize(("rows", "cols", "b"), [(20, 20, 3), (12, 12, 6)])
def test_grid_patterns_with_wide_supernodes(rows, cols, b):
    # grids order into wide supernodes with rows below them: LAPACK's Cholesky and BLAS
    # updates in the supernodal kernel, not only its loops
    idx = np.arange(rows * cols).reshape(rows, cols)
    i = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    j = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    pattern, data = _system(rows * cols, i, j, b, seed=5)
    sym = pattern.blockchol
    starts = sym.panels()[0]
    width = np.diff(starts)
    below = np.diff(sym.Lp)[starts[1:] - 1]
    assert np.any((width * b >= 24) & (below > 0))
    _check(pattern, data, b)


@pytest.mark.parametrize("b", [3, 6])
def test_a_single_node(b):
    pattern, data = _system(1, np.zeros(0, np.int64), np.zeros(0, np.int64), b, seed=1)
    _check(pattern, data, b)


@pytest.mark.parametrize("b", [3, 6])
def test_disconnected_components_and_isolated_nodes(b):
    # three components (one a lone node) interleaved in the node numbering
    i = np.array([0, 3, 6, 1, 4, 1])
    j = np.array([3, 6, 0, 4, 7, 7])
    pattern, data = _system(9, i, j, b, seed=2)  # nodes 2, 5, 8: no edges
    _check(pattern, data, b)


def test_a_dense_pattern():
    nodes = 12
    i, j = np.triu_indices(nodes, 1)
    pattern, data = _system(nodes, i, j, 3, seed=4)
    _check(pattern, data, 3)


@pytest.mark.parametrize("b", [3, 6])
def test_not_positive_definite_falls_back(b):
    i, j = _random_graph(25, 15, seed=3)
    pattern, data = _system(25, i, j, b, seed=3)
    dense = pattern.matrix(data).toarray()
    shift = np.linalg.eigvalsh(dense)[0] + 0.05  # one negative eigenvalue, still invertible
    data = pattern.with_diagonal(data, np.full(pattern.size, -shift))
    dense = dense - shift * np.eye(pattern.size)
    f = SymmetricFactor(pattern, "block")
    f.factorize(data)
    assert f.active == "superlu"
    rhs = np.arange(pattern.size, dtype=float)
    np.testing.assert_allclose(f.solve(rhs), np.linalg.solve(dense, rhs), rtol=1e-6)
    blocks = selected_inverse_blocks(pattern, data, block=b, factor=f)
    ref = _dense_diagonal_blocks(dense, b)
    assert np.abs(blocks - ref).max() < 1e-6 * np.abs(ref).max()


def test_auto_is_block_for_large_patterns_with_numba_only(monkeypatch):
    i, j = _random_graph(10, 5, seed=0)
    for b in (3, 6):
        pattern, _ = _system(10, i, j, b, seed=0)
        assert SymmetricFactor(pattern).backend != "block"  # small: numba's start-up not repaid
        monkeypatch.setattr(_numba, "LARGE", 10)
        assert SymmetricFactor(pattern).backend == "block"
        monkeypatch.setenv("RELMAP_NUMBA", "0")
        assert SymmetricFactor(pattern).backend != "block"
        monkeypatch.delenv("RELMAP_NUMBA")
        monkeypatch.undo()


@pytest.mark.parametrize(
    ("folder", "name"),
    [("posegraph2d", "manhattanOlson3500.g2o"), ("posegraph3d", "sphere2500.g2o")],
)
def test_solve_graph_agrees_with_and_without_numba(monkeypatch, data_dir, folder, name):
    graph = read_graph(data_dir / folder / name)
    n = len(graph.vertex_ids)
    on = solve_graph(graph)
    assert on.factor is not None and on.factor.backend == "block"
    monkeypatch.setenv("RELMAP_NUMBA", "0")
    off = solve_graph(graph)
    assert off.factor is not None and off.factor.backend != "block"
    rel = abs(on.final_error - off.final_error) / off.final_error
    assert rel < 1e-9
    np.testing.assert_allclose(on.poses, off.poses, atol=1e-6)
    r_on, r_off = on.relative(0, n - 1), off.relative(0, n - 1)
    np.testing.assert_allclose(r_on.cov, r_off.cov, rtol=1e-5, atol=1e-12)
    m_off = off.marginals()
    monkeypatch.delenv("RELMAP_NUMBA")
    m_on = on.marginals()
    scale = np.linalg.norm(m_off, axis=(1, 2)).max()
    assert np.abs(m_on - m_off).max() < 1e-5 * scale
