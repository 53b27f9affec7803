"""The sparse Cholesky of relmap.network.sparse (relmap._core) against dense numpy algebra."""

from __future__ import annotations

import numpy as np
import pytest

from relmap.errors import SolverError
from relmap.io import read_graph, solve_graph
from relmap.network.sparse import SymmetricFactor, SymmetricPattern, selected_inverse_blocks


def _random_graph(nodes: int, edges: int, seed: int, chain: bool = True):
    rng = np.random.default_rng(seed)
    extra = rng.integers(0, nodes, size=(edges, 2))
    extra = extra[extra[:, 0] != extra[:, 1]]
    base = np.arange(nodes - 1) if chain else np.zeros(0, np.int64)
    return np.concatenate([base, extra[:, 0]]), np.concatenate([base + 1, extra[:, 1]])


def _system(nodes: int, i: np.ndarray, j: np.ndarray, b: int, seed: int):
    """A random SPD matrix of b×b blocks with the pattern of the edges (i, j) and the diagonal:
    a sum of Jᵀ J over random block rows, laid out [entry q][block k] for from_blocks."""
    rng = np.random.default_rng(seed)
    diag = np.arange(nodes)
    brow = np.concatenate([i, i, j, j, diag])
    bcol = np.concatenate([i, j, i, j, diag])
    pattern = SymmetricPattern.from_blocks(nodes, brow, bcol, block=b)
    m = len(i)
    A, B = rng.standard_normal((m, b, b)), rng.standard_normal((m, b, b))
    P = rng.standard_normal((nodes, b, b))
    T = np.swapaxes
    blocks = [T(A, 1, 2) @ A, T(A, 1, 2) @ B, T(B, 1, 2) @ A, T(B, 1, 2) @ B]
    blocks.append(T(P, 1, 2) @ P + 0.1 * np.eye(b))
    values = np.concatenate([x.reshape(-1, b * b) for x in blocks]).T.reshape(-1)
    return pattern, pattern.assemble(values)


def _check(pattern: SymmetricPattern, data: np.ndarray, b: int) -> None:
    """Solves, joint blocks and selected inversion against np.linalg on the dense matrix."""
    dense = pattern.matrix(data).toarray()
    np.testing.assert_array_equal(dense, dense.T)
    Z = np.linalg.inv(dense)
    scale = np.abs(dense).sum(axis=1).max() * np.abs(Z).sum(axis=1).max()  # cond, ∞-norm
    f = SymmetricFactor(pattern)
    f.factorize(data)
    rng = np.random.default_rng(7)
    rhs, cols = rng.standard_normal(pattern.size), rng.standard_normal((pattern.size, 5))
    for y in (rhs, cols):
        ref = np.linalg.solve(dense, y)
        np.testing.assert_allclose(f.solve(y), ref, rtol=0, atol=1e-13 * scale * abs(ref).max())
    n = pattern.size // b
    for nodes in ([n - 1], [0, n - 1], [n // 2, 0, n - 1][:n], [n // 3]):
        nodes = list(dict.fromkeys(nodes))
        idx = (b * np.array(nodes)[:, None] + np.arange(b)).reshape(-1)
        sub = f.inverse_submatrix(idx)
        assert np.abs(sub - Z[np.ix_(idx, idx)]).max() < 1e-10 * np.abs(Z).max()
    idx = np.array([pattern.size - 1, 0])  # any parameters, not whole nodes
    sub = f.inverse_submatrix(idx)
    assert np.abs(sub - Z[np.ix_(idx, idx)]).max() < 1e-10 * np.abs(Z).max()
    ref = np.array([Z[b * k : b * k + b, b * k : b * k + b] for k in range(n)])
    for blocks in (
        selected_inverse_blocks(pattern, data, block=b, factor=f),  # the factor's numbers
        selected_inverse_blocks(pattern, data, block=b),  # a factorization of its own
    ):
        assert np.abs(blocks - ref).max() / np.abs(ref).max() < 1e-10
        np.testing.assert_array_equal(blocks, np.swapaxes(blocks, 1, 2))
    # the factor itself: L Lᵀ = P A Pᵀ, in the ordering it reports
    perm = f.core.ordering()
    L = np.linalg.cholesky(dense[np.ix_(perm, perm)])
    assert f.nnz_L >= np.count_nonzero(np.abs(np.tril(L)) > 1e-12 * np.abs(L).max())


@pytest.mark.parametrize("b", [1, 3, 6])
@pytest.mark.parametrize(("nodes", "edges"), [(30, 20), (120, 130)])
def test_factor_solves_and_inverts_like_dense(nodes, edges, b):
    i, j = _random_graph(nodes, edges, seed=nodes + b)
    _check(*_system(nodes, i, j, b, seed=b), b)


@pytest.mark.parametrize("b", [3, 6])
@pytest.mark.parametrize(("rows", "cols"), [(9, 9), (3, 30)])
def test_grid_patterns_with_wide_supernodes(rows, cols, b):
    """Grids fill in: wide supernodes near the root, long updates between them."""
    k = np.arange(rows * cols).reshape(rows, cols)
    i = np.concatenate([k[:, :-1].ravel(), k[:-1, :].ravel()])
    j = np.concatenate([k[:, 1:].ravel(), k[1:, :].ravel()])
    _check(*_system(rows * cols, i, j, b, seed=rows), b)


@pytest.mark.parametrize("split", ["scalar", "reversed", "some"])
def test_orderings_that_split_or_reverse_the_frames(split):
    """The symbolic analysis works on runs of columns with equal patterns (a frame's
    parameters, kept together by the ordering); orderings that break those runs up entirely,
    reverse them inside each frame, or split a few frames give the same numbers."""
    b, nodes = 3, 60
    i, j = _random_graph(nodes, 50, seed=11)
    pattern, data = _system(nodes, i, j, b, seed=4)
    rng = np.random.default_rng(3)
    frames = np.asarray(pattern.permutation).reshape(-1, b)[:, 0] // b  # the frames' order
    inner = np.tile(np.arange(b), (nodes, 1))
    if split == "scalar":
        perm = rng.permutation(pattern.size)
    else:
        if split == "reversed":
            inner = inner[:, ::-1]
        perm = (b * frames[:, None] + inner).reshape(-1)
        if split == "some":  # move the middle parameter of every fourth frame to the end
            moved = perm.reshape(nodes, b)[::4, 1]
            perm = np.concatenate([perm[~np.isin(perm, moved)], moved])
    pattern._perm = np.ascontiguousarray(perm, dtype=np.int64)
    _check(pattern, data, b)


def test_a_dense_pattern_is_one_supernode():
    nodes = 12
    i, j = np.triu_indices(nodes, 1)
    pattern, data = _system(nodes, i, j, 3, seed=3)
    _check(pattern, data, 3)
    f = SymmetricFactor(pattern)
    f.factorize(data)
    assert f.core.supernodes == 1


@pytest.mark.parametrize("b", [3, 6])
def test_a_single_node_and_disconnected_components(b):
    _check(*_system(1, np.zeros(0, np.int64), np.zeros(0, np.int64), b, seed=1), b)
    i, j = _random_graph(40, 10, seed=5, chain=False)  # components and isolated nodes
    _check(*_system(40, i, j, b, seed=2), b)


def test_the_general_scalar_pattern():
    """Contributions by scalar (row, col), duplicates summed, a negative index dropped."""
    rng = np.random.default_rng(4)
    n = 24
    M = rng.standard_normal((40, n)) * (rng.random((40, n)) < 0.15)
    A = M.T @ M + np.eye(n) + np.kron(np.eye(n // 2), [[0.0, 0.1], [0.1, 0.0]])  # nodes of 2
    r, c = np.nonzero(A)
    rows = np.concatenate([r, r, [-1]])
    cols = np.concatenate([c, c, [0]])
    values = np.concatenate([0.5 * A[r, c], 0.5 * A[r, c], [99.0]])
    pattern = SymmetricPattern(n, rows, cols, node=np.arange(n) // 2)
    data = pattern.assemble(values)
    np.testing.assert_allclose(pattern.matrix(data).toarray(), A, rtol=1e-15)
    f = SymmetricFactor(pattern)
    f.factorize(data)
    np.testing.assert_allclose(f.solve(np.eye(n)), np.linalg.inv(A), atol=1e-10)
    blocks = f.inverse_blocks(np.arange(24).reshape(12, 2))
    ref = np.linalg.inv(A)
    for g in range(12):
        np.testing.assert_allclose(blocks[g], ref[2 * g : 2 * g + 2, 2 * g : 2 * g + 2], atol=1e-12)


@pytest.mark.parametrize("b", [1, 3, 6])
def test_the_block_pattern_puts_every_contribution_where_it_belongs(b):
    """from_blocks against a dense sum of the blocks: duplicate blocks summed, blocks with a
    negative node dropped, rows sorted in every column, one pair per distinct block."""
    rng = np.random.default_rng(b)
    nodes, K = 9, 40
    brow, bcol = rng.integers(-1, nodes, K), rng.integers(-1, nodes, K)
    values = rng.standard_normal((b * b, K))  # [entry q = b·r + c][block k]
    pattern = SymmetricPattern.from_blocks(nodes, brow, bcol, block=b)
    dense = np.zeros((b * nodes, b * nodes))
    for k in np.flatnonzero((brow >= 0) & (bcol >= 0)):
        r, c = b * brow[k], b * bcol[k]
        dense[r : r + b, c : c + b] += values[:, k].reshape(b, b)
    got = pattern.matrix(pattern.assemble(values.reshape(-1))).toarray()
    np.testing.assert_allclose(got, dense, rtol=1e-15, atol=0)
    for c in range(b * nodes):
        rows = pattern.indices[pattern.indptr[c] : pattern.indptr[c + 1]]
        assert np.all(np.diff(rows) > 0)
    kept = {(int(r), int(c)) for r, c in zip(brow, bcol, strict=True) if r >= 0 and c >= 0}
    assert pattern._pairs is not None
    pairs = list(zip(*(p // b for p in pattern._pairs), strict=True))
    assert len(pairs) == len(kept) and set(pairs) == kept
    assert pattern.nnz == b * b * len(kept)


def test_refactorization_reuses_the_analysis():
    i, j = _random_graph(80, 60, seed=9)
    pattern, data = _system(80, i, j, 3, seed=9)
    f = SymmetricFactor(pattern)
    f.factorize(data)
    core = f.core
    shifted = pattern.with_diagonal(data, np.full(pattern.size, 3.0))
    f.factorize(shifted)
    assert f.core is core
    dense = pattern.matrix(shifted).toarray()
    rhs = np.arange(pattern.size, dtype=float)
    np.testing.assert_allclose(f.solve(rhs), np.linalg.solve(dense, rhs), rtol=1e-9)


@pytest.mark.parametrize("b", [3, 6])
def test_a_matrix_that_is_not_positive_definite_is_refused(b):
    """Indefinite and semi-definite matrices are a SolverError naming the parameter, and the
    factor refuses to answer until a positive-definite matrix is factorized."""
    i, j = _random_graph(20, 10, seed=b)
    pattern, data = _system(20, i, j, b, seed=b)
    f = SymmetricFactor(pattern)
    indefinite = data.copy()
    indefinite[pattern.diagonal_position[0]] = -1.0
    with pytest.raises(SolverError, match="not positive definite at parameter"):
        f.factorize(indefinite)
    with pytest.raises(RuntimeError, match="factorize"):
        f.solve(np.ones(pattern.size))
    f.factorize(data)
    dense = pattern.matrix(data).toarray()
    np.testing.assert_allclose(dense @ f.solve(np.ones(pattern.size)), 1.0, atol=1e-9)
    # Jᵀ J of one relative measurement between two frames, J = [I, -I]: rank b of 2b, the
    # second frame's pivots exactly zero (a pose graph without its anchor)
    two = SymmetricPattern.from_blocks(2, np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1]), b)
    eye = np.eye(b).reshape(-1)
    semi = two.assemble(np.stack([eye, -eye, -eye, eye], axis=1).reshape(-1))
    with pytest.raises(SolverError, match="not positive definite"):
        SymmetricFactor(two).factorize(semi)


def test_bad_arguments_are_refused():
    i, j = _random_graph(10, 5, seed=1)
    pattern, data = _system(10, i, j, 3, seed=1)
    f = SymmetricFactor(pattern)
    with pytest.raises(ValueError, match="shape"):
        f.factorize(data[:-1])
    f.factorize(data)
    with pytest.raises(ValueError):
        f.solve(np.ones(pattern.size + 1))
    with pytest.raises(IndexError):
        f.inverse_submatrix(np.array([pattern.size]))


@pytest.mark.real_data
@pytest.mark.parametrize(
    ("folder", "name"), [("posegraph2d", "ring.g2o"), ("posegraph3d", "smallGrid3D.g2o")]
)
def test_marginals_of_a_real_graph_equal_the_dense_inverse(data_dir, folder, name):
    sol = solve_graph(read_graph(data_dir / folder / name))
    assert sol.factor is not None
    pattern, data = sol.factor.pattern, sol._data
    dense = pattern.matrix(data).toarray()
    Z = np.linalg.inv(dense)
    tol = 10 * np.finfo(float).eps * np.linalg.cond(dense)  # ring: cond 1.3e9
    b = sol.group.dof
    blocks = selected_inverse_blocks(pattern, data, block=b, factor=sol.factor)
    ref = np.array([Z[b * k : b * k + b, b * k : b * k + b] for k in range(len(blocks))])
    assert np.abs(blocks - ref).max() < tol * np.abs(ref).max()
    mid = b * (len(blocks) // 2)
    idx = np.array([0, 1, 2, mid, mid + 2, pattern.size - 1])
    sub = sol.factor.inverse_submatrix(idx)
    assert np.abs(sub - Z[np.ix_(idx, idx)]).max() < tol * np.abs(Z).max()
