"""Sparse symmetric normal matrices: a pattern fixed once, refactorized every iteration.

The pattern is assembled once (CSC, both triangles; a pattern of dense blocks by the core's
``block_pattern``) with a map from every contribution to its slot, so each Gauss-Newton
iteration adds the contributions straight into their slots (the core's normal equations, or
``np.bincount`` in :meth:`SymmetricPattern.assemble`). A fill-reducing ordering is computed
once, on the *node* graph (the frames; a frame's parameters stay together), by multiple
minimum degree.

The factorization is relmap's compiled core (``relmap._core.SparseCholesky``, C++, one
implementation): a supernodal left-looking Cholesky ``A = L Lᵀ`` whose symbolic analysis
(elimination tree in postorder, row structure, supernodes, the map of the matrix into dense
panels) runs once per pattern, then solves, joint covariances of a few frames from forward
solves along their elimination-tree paths, and every frame's marginal by Takahashi's selected
inversion on L's pattern. A matrix that is not positive definite (a direction that no AT
constrains) is refused with :class:`relmap.errors.SolverError`: there is no second
factorization to fall back on, and a Gauss-Newton matrix is singular only when the problem is.
"""

from __future__ import annotations

import numpy as np

from relmap import _core
from relmap.errors import SolverError
from relmap.typing import FloatArray, IntArray

__all__ = ["SymmetricFactor", "SymmetricPattern", "node_ordering", "selected_inverse_blocks"]


class SymmetricPattern:
    """The sparsity pattern of a symmetric ``size × size`` matrix, in CSC, fixed once.

    Built from the (row, col) of every contribution (duplicates allowed, both triangles; a
    negative index marks a contribution to drop, e.g. of a fixed parameter); :meth:`assemble`
    then sums contributions into the CSC data array with one ``bincount``. ``node`` (size,)
    names the node (frame) of every parameter, for the ordering.
    """

    def __init__(
        self, size: int, rows: IntArray, cols: IntArray, node: IntArray | None = None
    ) -> None:
        keep = (rows >= 0) & (cols >= 0)
        keys = cols.astype(np.int64)[keep] * size + rows[keep]  # column-major = CSC order
        unique, kept_position = np.unique(keys, return_inverse=True)
        position = np.full(len(rows), len(unique), dtype=np.int64)  # dropped → spare slot
        position[keep] = kept_position
        indptr = np.searchsorted(unique // size, np.arange(size + 1))
        self._setup(size, unique % size, indptr, position, node)

    @classmethod
    def from_blocks(
        cls, nodes: int, brow: IntArray, bcol: IntArray, block: int = 3
    ) -> SymmetricPattern:
        """The pattern of dense ``block × block`` blocks at node pairs ``(brow, bcol)`` (K,).

        Contributions are ordered ``[entry q = block·r + c][k]`` for block k (a negative node
        drops the block): the layout :class:`relmap.network.optimal` fills. Built from the
        K blocks rather than the block²·K scalars, by relmap's compiled core
        (``relmap._core.block_pattern``: two counting sorts, no comparison sort).
        """
        c = np.ascontiguousarray
        indptr, indices, position, urow, ucol = _core.block_pattern(
            nodes, c(brow, dtype=np.int64), c(bcol, dtype=np.int64), block
        )
        pattern = cls.__new__(cls)
        node = np.repeat(np.arange(nodes), block)
        pattern._setup(block * nodes, indices, indptr, position, node)
        pattern.block = block
        pattern._pairs = (block * urow, block * ucol)  # one parameter pair per block (ordering)
        return pattern

    def _setup(
        self,
        size: int,
        indices: IntArray,
        indptr: IntArray,
        position: IntArray,
        node: IntArray | None,
    ) -> None:
        self.size = size
        self.indices = np.ascontiguousarray(indices, dtype=np.int64)
        self.indptr = np.ascontiguousarray(indptr, dtype=np.int64)
        self.position = position
        self.nnz = len(indices)
        cols = np.repeat(np.arange(size), np.diff(self.indptr))
        on_diag = np.flatnonzero(self.indices == cols)
        self.has_diagonal = np.zeros(size, bool)
        self.has_diagonal[cols[on_diag]] = True
        self.diagonal_position = np.zeros(size, dtype=np.int64)
        self.diagonal_position[cols[on_diag]] = on_diag
        self.node = np.arange(size) if node is None else np.asarray(node)
        self._perm: IntArray | None = None
        #: parameter pairs (rows, cols) whose nodes meet, for the ordering (None: every entry)
        self._pairs: tuple[IntArray, IntArray] | None = None
        self.block: int | None = None  #: parameters per node when nodes are uniform blocks

    def assemble(self, values: FloatArray) -> FloatArray:
        """CSC data from the contributions' values (in the order the pattern was built)."""
        data = np.bincount(self.position, weights=values, minlength=self.nnz + 1)[: self.nnz]
        return data.astype(np.float64, copy=False)

    def diagonal(self, data: FloatArray) -> FloatArray:
        """The matrix diagonal (zero where no contribution touches it)."""
        return np.where(self.has_diagonal, data[self.diagonal_position], 0.0)

    def with_diagonal(self, data: FloatArray, extra: FloatArray) -> FloatArray:
        """A copy of ``data`` with ``extra`` added to the diagonal (which must be present)."""
        out = data.copy()
        out[self.diagonal_position] += extra
        return out

    def matrix(self, data: FloatArray):  # type: ignore[no-untyped-def]
        """The matrix as ``scipy.sparse.csc_matrix``."""
        import scipy.sparse as sp

        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))

    @property
    def permutation(self) -> IntArray:
        """Fill-reducing ordering of the parameters (new → old), nodes kept together."""
        if self._perm is None:
            if self._pairs is None:
                cols = np.repeat(np.arange(self.size), np.diff(self.indptr))
                self._pairs = (self.indices, cols)
            self._perm = node_ordering(self.node, *self._pairs)
        return self._perm


def node_ordering(node: IntArray, rows: IntArray, cols: IntArray) -> IntArray:
    """Minimum-degree ordering of parameters grouped by node (new → old).

    The node graph (an edge wherever two nodes' parameters meet in the matrix) is ordered by
    :func:`_minimum_degree`, then each node's parameters follow in order.
    """
    labels, node_index = np.unique(node, return_inverse=True)
    k = len(labels)
    a, b = node_index[rows], node_index[cols]
    off = a != b
    node_order = _minimum_degree(k, a[off], b[off]) if off.any() else np.arange(k)
    rank = np.empty(k, dtype=np.int64)
    rank[node_order] = np.arange(k)
    return np.lexsort((np.arange(len(node)), rank[node_index]))


class SymmetricFactor:
    """The Cholesky factorization of a symmetric positive-definite matrix with a fixed pattern.

    The symbolic analysis (relmap._core) runs once, on the first :meth:`factorize`; every
    later call only refactorizes numerically.
    """

    def __init__(self, pattern: SymmetricPattern) -> None:
        self.pattern = pattern
        self._core: _core.SparseCholesky | None = None
        self._ready = False

    @property
    def core(self) -> _core.SparseCholesky:
        """The compiled factorization (symbolic analysis on first use)."""
        if self._core is None:
            p = self.pattern
            perm = np.ascontiguousarray(p.permutation, dtype=np.int64)
            self._core = _core.SparseCholesky(p.indptr, p.indices, perm)
        return self._core

    @property
    def nnz_L(self) -> int:
        """Entries of L (one triangle with the diagonal)."""
        return int(self.core.nnz_L)

    def factorize(self, data: FloatArray) -> None:
        """Factorize the matrix with the given CSC data (the pattern's, symmetric).

        Raises :class:`relmap.errors.SolverError` if the matrix is not positive definite."""
        data = np.ascontiguousarray(data, dtype=np.float64)
        if data.shape != (self.pattern.nnz,):
            raise ValueError(f"data must have shape ({self.pattern.nnz},), not {data.shape}")
        self._ready = False
        bad = self.core.factorize(data)
        if bad >= 0:
            k = int(self.core.ordering()[bad])
            raise SolverError(
                f"the normal matrix is not positive definite at parameter {k} (node "
                f"{self.pattern.node[k]}): a direction that no measurement constrains"
            )
        self._ready = True

    def _check(self) -> _core.SparseCholesky:
        if not self._ready:
            raise RuntimeError("factorize a positive-definite matrix first")
        return self.core

    def _indices(self, idx: IntArray) -> IntArray:
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= self.pattern.size):
            raise IndexError(f"parameter index out of range 0 … {self.pattern.size - 1}")
        return idx

    def solve(self, b: FloatArray) -> FloatArray:
        """``A⁻¹ b`` for a vector ``(size,)`` or a matrix of columns ``(size, k)``."""
        core = self._check()
        b = np.asarray(b, dtype=np.float64)
        if b.shape[:1] != (self.pattern.size,) or b.ndim > 2:
            raise ValueError(f"b must be ({self.pattern.size},) or ({self.pattern.size}, k)")
        out = core.solve(np.ascontiguousarray(b.reshape(len(b), -1)))
        return out[:, 0] if b.ndim == 1 else out

    def inverse_submatrix(self, idx: IntArray) -> FloatArray:
        """``A⁻¹[idx][:, idx]`` (k, k) for parameter indices ``idx`` (k,), symmetrized: forward
        solves along the elimination-tree paths of the parameters only."""
        out = self._check().inverse_submatrix(self._indices(idx))
        return 0.5 * (out + out.T)

    def inverse_blocks(self, groups: IntArray) -> FloatArray:
        """``A⁻¹[g][:, g]`` (m, b, b) for groups ``g`` of parameter indices (m, b) whose every
        pair is on the factor's pattern (e.g. the parameters of one frame): Takahashi's
        selected inversion, only the entries of ``A⁻¹`` on L's pattern formed."""
        groups = self._indices(np.asarray(groups).reshape(len(groups), -1))
        out = self._check().selected_inverse_blocks(groups)
        return 0.5 * (out + np.swapaxes(out, -1, -2))


def selected_inverse_blocks(
    pattern: SymmetricPattern,
    data: FloatArray,
    block: int = 3,
    factor: SymmetricFactor | None = None,
) -> FloatArray:
    """The diagonal ``block × block`` blocks of ``A⁻¹`` (selected inversion), ``(nodes, b, b)``.

    Parameters must come in consecutive groups of ``block`` (one group per node). ``factor``,
    when it holds the factorization of this ``data`` on this pattern, is reused.
    """
    if pattern.size % block:
        raise ValueError(f"{pattern.size} parameters do not form blocks of {block}")
    if factor is None or factor.pattern is not pattern or not factor._ready:
        factor = SymmetricFactor(pattern)
        factor.factorize(data)
    return factor.inverse_blocks(np.arange(pattern.size).reshape(-1, block))


def _minimum_degree(k: int, a: IntArray, b: IntArray) -> IntArray:
    """Multiple minimum degree ordering (new → old) of the graph of k nodes with edges (a, b),
    by relmap's compiled core (supervariables, external degrees; see src/core/ordering.hpp)."""
    return _core.minimum_degree(
        k, np.ascontiguousarray(a, dtype=np.int64), np.ascontiguousarray(b, dtype=np.int64)
    )
