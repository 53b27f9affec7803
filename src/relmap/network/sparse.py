"""Sparse symmetric normal matrices: a pattern fixed once, refactorized every iteration.

The pattern is assembled once (CSC, both triangles) with a map from every contribution to its
slot, so each Gauss-Newton iteration fills the matrix with one ``np.bincount`` (or, with numba,
straight from the linearization kernel). A fill-reducing ordering is computed once, on the
*node* graph (the frames; a frame's parameters stay together), with SuperLU's minimum-degree
ordering.

Factorizations (:class:`SymmetricFactor`), chosen by measurement:

- ``block`` (relmap's own, numba; :mod:`relmap.network._blockchol`), the ``auto`` choice for
  patterns of uniform node blocks (b = 3 in the plane, 6 in 3-D) of :data:`relmap._numba.LARGE`
  nodes or more when numba is enabled: a block LDLᵀ whose symbolic analysis (ordering,
  elimination tree in postorder, block pattern of L, scatter maps) runs once per pattern. The
  numeric factorization is a left-looking supernodal Cholesky on dense panels (updates, pivot
  blocks and triangular solves of wide panels through BLAS on one thread) where columns are
  long, a left-looking block LDLᵀ in b × b loops where they are short; either ends as the block
  LDLᵀ that the compiled solves and the block Takahashi recursion read. Joint covariances of a
  few frames come from forward solves along their elimination-tree paths only;
- ``qdldl`` (Apache-2.0, a prebuilt wheel) when installed, for the rest: sparse LDLᵀ that keeps
  its symbolic analysis between refactorizations;
- ``supernodal`` (numpy and SciPy's LAPACK only) for 6×6-block patterns without numba: a
  multifrontal block Cholesky, small fronts in numpy batches, large ones through LAPACK;
- otherwise SciPy's SuperLU in symmetric mode on the pre-ordered matrix (pure SciPy: nothing
  to compile, ever).

Per factorization, measured on this 2-core machine while shared (5 runs, range and median):
city10000 (30k parameters, 1.07M entries in L) block 25–77 ms (median 51; interleaved with its
loop variant, process time: 23 against 27 ms), qdldl 46–87 (48), supernodal 61–101 (64),
SuperLU 132–174 (137); sphere2500 (15k parameters, 1.34M entries) block 31–54 (41), supernodal
55–143 (74), SuperLU 127–302 (186), qdldl 208–418 (368). Marginals of every frame (selected
inversion) on city10000: block 65–87 ms, the SuperLU path 0.82–1.14 s.

A matrix the block or supernodal Cholesky finds not positive definite is factorized by SuperLU
instead (LDLᵀ-like, no failure on a semi-definite Gauss-Newton matrix). Marginal covariances of
many frames come from the block Takahashi recursion (selected inversion) on a factor whose
pattern keeps each frame's block together.
"""

from __future__ import annotations

import contextlib
import functools
from typing import Any

import numpy as np

from relmap.typing import FloatArray, IntArray

__all__ = ["SymmetricFactor", "SymmetricPattern", "node_ordering", "selected_inverse_blocks"]


class _CSC:
    """The attributes of a CSC matrix that qdldl reads (data, indices, indptr, shape, nnz)."""

    __slots__ = ("data", "indices", "indptr", "nnz", "shape")

    def __init__(
        self, data: FloatArray, indices: IntArray, indptr: IntArray, shape: tuple[int, int]
    ):
        self.data, self.indices, self.indptr, self.shape = data, indices, indptr, shape
        self.nnz = len(data)


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
        K blocks rather than the block²·K scalars, so it costs a fraction of the general path.
        """
        b = block
        from relmap import _numba

        if _numba.enabled(nodes):
            from relmap.network import _blockchol as kernels

            indices, indptr, position = kernels.block_pattern(
                nodes, np.asarray(brow, dtype=np.int64), np.asarray(bcol, dtype=np.int64), b
            )
            pattern = cls.__new__(cls)
            pattern._setup(b * nodes, indices, indptr, position, np.repeat(np.arange(nodes), b))
            pattern.block = b
            return pattern
        keep = (brow >= 0) & (bcol >= 0)
        keys = bcol.astype(np.int64)[keep] * nodes + brow[keep]
        unique, inv = np.unique(keys, return_inverse=True)
        ucol, urow = unique // nodes, unique % nodes
        count = np.bincount(ucol, minlength=nodes)
        start = np.concatenate([[0], np.cumsum(count)[:-1]])  # first block of each block column
        rank = np.arange(len(unique)) - start[ucol]
        # scalar column (J, a) starts at b²·start[J] + a·b·count[J]
        col_start = (b * b * start)[:, None] + np.arange(b)[None, :] * (b * count)[:, None]
        indptr = np.concatenate([col_start.reshape(-1), [b * b * len(unique)]])
        # rows: column (J, a) lists, for each block of column J in order, its b rows
        order = np.argsort(ucol, kind="stable")  # already sorted; kept for clarity
        per_col_rows = (b * urow[order])[:, None] + np.arange(b)  # (blocks, b)
        indices = np.empty(b * b * len(unique), dtype=np.int64)
        for a in range(b):
            # the slots of column (J, a) are col_start[J, a] + b·rank + r
            slot = col_start[ucol, a][:, None] + b * rank[:, None] + np.arange(b)
            indices[slot.reshape(-1)] = per_col_rows.reshape(-1)
        # contribution (q = b·r + c, k) → slot of scalar (b·I + r, b·J + c)
        kb = np.full(len(brow), -1, dtype=np.int64)
        kb[keep] = inv
        q = np.arange(b * b)
        r_, c_ = q // b, q % b
        slot = col_start[ucol[kb], :][:, c_].T + b * rank[kb][None, :] + r_[:, None]  # (b², K)
        position = np.where(kb[None, :] >= 0, slot, len(indices)).reshape(-1)
        node = np.repeat(np.arange(nodes), b)
        pattern = cls.__new__(cls)
        pattern._setup(b * nodes, indices, indptr, position, node)
        pattern.block = b
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
        self.indices = indices.astype(np.int32)
        self.indptr = indptr.astype(np.int32)
        self.position = position
        self.nnz = len(indices)
        cols = np.repeat(np.arange(size), np.diff(self.indptr))
        on_diag = np.flatnonzero(self.indices == cols)
        self.has_diagonal = np.zeros(size, bool)
        self.has_diagonal[cols[on_diag]] = True
        self.diagonal_position = np.zeros(size, dtype=np.int64)
        self.diagonal_position[cols[on_diag]] = on_diag
        self.node = np.arange(size) if node is None else np.asarray(node)
        self._upper_part: tuple[np.ndarray, IntArray, IntArray] | None = None  # for qdldl
        self._perm: IntArray | None = None
        self.block: int | None = None  #: parameters per node when nodes are uniform blocks
        self._supernodal: _Supernodal | None = None
        self._blockchol: _BlockSymbolic | None = None

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

    def upper(self, data: FloatArray) -> _CSC:
        """The upper triangle in CSC (qdldl's input): a light stand-in for a SciPy matrix."""
        if self._upper_part is None:  # computed once, on first use
            cols = np.repeat(np.arange(self.size), np.diff(self.indptr))
            upper = self.indices <= cols  # row <= col
            indptr = np.concatenate([[0], np.cumsum(np.bincount(cols[upper], minlength=self.size))])
            self._upper_part = (upper, self.indices[upper], indptr.astype(np.int32))
        upper, indices, indptr = self._upper_part
        return _CSC(data[upper], indices, indptr, (self.size, self.size))

    @property
    def supernodal(self) -> _Supernodal:
        """The symbolic analysis for the supernodal Cholesky, computed once."""
        if self._supernodal is None:
            self._supernodal = _Supernodal(self)
        return self._supernodal

    @property
    def blockchol(self) -> _BlockSymbolic:
        """The symbolic analysis for the numba block LDLᵀ, computed once (uniform blocks only)."""
        if self._blockchol is None:
            self._blockchol = _BlockSymbolic(self)
        return self._blockchol

    @property
    def permutation(self) -> IntArray:
        """Fill-reducing ordering of the parameters (new → old), nodes kept together."""
        if self._perm is None:
            cols = np.repeat(np.arange(self.size), np.diff(self.indptr))
            self._perm = node_ordering(self.node, self.indices, cols)
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
    """Factorization of a symmetric positive-definite matrix with a fixed pattern.

    ``backend`` is ``"block"``, ``"supernodal"``, ``"qdldl"``, ``"superlu"`` or ``"auto"``:
    the numba block LDLᵀ for patterns of uniform node blocks with at least
    :data:`relmap._numba.LARGE` nodes when numba is enabled; else the numpy supernodal Cholesky
    for blocks of 6 or more (3-D pose graphs in the standard layout); else qdldl when
    installed; else SuperLU. Timings: see the module notes. A matrix the block or supernodal
    Cholesky finds not positive definite is factorized by SuperLU instead (:attr:`active`
    says which holds the factorization).
    """

    def __init__(self, pattern: SymmetricPattern, backend: str = "auto") -> None:
        self.pattern = pattern
        if backend == "auto":
            backend = _auto_backend(pattern)
        if backend not in BACKENDS:
            raise ValueError(f"unknown sparse backend {backend!r}")
        if backend == "block" and pattern.block is None:
            raise ValueError("the block backend needs a pattern of uniform node blocks")
        self.backend = backend
        self._active = backend  # the backend that holds the current factorization
        self._qdldl = None
        self._lu = None
        self._block: _BlockNumeric | None = None

    @property
    def active(self) -> str:
        """The backend holding the current factorization (``superlu`` after a fallback)."""
        return self._active

    def factorize(self, data: FloatArray) -> None:
        """Factorize the matrix with the given CSC data (the pattern's)."""
        self._active = self.backend
        if self.backend == "block":
            if self._block is None:
                self._block = _BlockNumeric(self.pattern.blockchol)
            try:
                self._block.factorize(data)
                return
            except np.linalg.LinAlgError:
                self._active = "superlu"
        if self.backend == "supernodal":
            try:
                self.pattern.supernodal.factorize(data)
                return
            except np.linalg.LinAlgError:
                self._active = "superlu"
        if self._active == "qdldl":
            import qdldl

            upper = self.pattern.upper(data)
            if self._qdldl is None:
                self._qdldl = qdldl.Solver(upper, upper=True)
            else:
                self._qdldl.update(upper, upper=True)
        else:
            self._lu = _superlu(self.pattern, data)

    def inverse_submatrix(self, idx: IntArray) -> FloatArray:
        """``A⁻¹[idx][:, idx]`` (k, k) for parameter indices ``idx`` (k,), symmetrized.

        The block factor forms it from the elimination-tree paths of the nodes when ``idx``
        lists whole nodes (block by block, each in order); otherwise k column solves."""
        idx = np.asarray(idx, dtype=np.int64)
        b = self.pattern.block
        if self._active == "block" and b is not None and len(idx) and len(idx) % b == 0:
            groups = idx.reshape(-1, b)
            whole = np.all(groups == groups[:, :1] + np.arange(b)) and np.all(groups[:, 0] % b == 0)
            if whole and len(np.unique(groups[:, 0])) == len(groups):
                assert self._block is not None
                out = self._block.inverse_blocks(groups[:, 0] // b)
                return 0.5 * (out + out.T)
        E = np.zeros((self.pattern.size, len(idx)))
        E[idx, np.arange(len(idx))] = 1.0
        sub = self.solve(E)[idx, :]
        return 0.5 * (sub + sub.T)

    def solve(self, b: FloatArray) -> FloatArray:
        """``A⁻¹ b`` for a vector ``(size,)`` or a matrix of columns ``(size, k)``."""
        if self._active == "block":
            assert self._block is not None
            return self._block.solve(b)
        if self._active == "supernodal":
            return self.pattern.supernodal.solve(b)
        if self._active == "qdldl":
            assert self._qdldl is not None, "factorize first"
            if b.ndim == 1:
                return np.asarray(self._qdldl.solve(b))
            return np.column_stack([self._qdldl.solve(np.ascontiguousarray(c)) for c in b.T])
        assert self._lu is not None, "factorize first"
        lu, perm = self._lu
        out = np.empty_like(b)
        out[perm] = lu.solve(np.ascontiguousarray(b[perm]))
        return out


BACKENDS = ("block", "supernodal", "qdldl", "superlu")  #: accepted by SymmetricFactor, with "auto"


def _auto_backend(pattern: SymmetricPattern) -> str:
    """The ``auto`` rule of :class:`SymmetricFactor` (see its docstring)."""
    from relmap import _numba

    if pattern.block is not None and _numba.enabled(pattern.size // pattern.block):
        return "block"
    if pattern.block is not None and pattern.block >= 6:
        return "supernodal"
    try:
        import qdldl  # noqa: F401
    except ImportError:
        return "superlu"
    return "qdldl"


def _superlu(pattern: SymmetricPattern, data: FloatArray):  # type: ignore[no-untyped-def]
    """SuperLU in symmetric mode on the matrix pre-ordered by the node ordering."""
    from scipy.sparse.linalg import splu

    perm = pattern.permutation
    A = pattern.matrix(data)[perm][:, perm].tocsc()
    lu = splu(A, permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    return lu, perm


def selected_inverse_blocks(
    pattern: SymmetricPattern,
    data: FloatArray,
    block: int = 3,
    factor: SymmetricFactor | None = None,
) -> FloatArray:
    """The diagonal ``block × block`` blocks of ``A⁻¹`` (selected inversion), ``(nodes, b, b)``.

    Parameters must come in consecutive groups of ``block`` (one group per node). The matrix
    is factorized as ``A = L D Lᵀ`` (SuperLU, node-ordered, so L's pattern is block-aligned),
    then the Takahashi recursion ``Z_SJ = -Z_SS L̃_SJ``, ``Z_JJ = D̃_J⁻¹ - L̃_SJᵀ Z_SJ`` runs
    over block columns from last to first; only entries of Z on L's pattern are formed.

    With numba, the block LDLᵀ of :class:`SymmetricFactor`'s ``block`` backend and its compiled
    recursion instead; ``factor``, when it holds that factorization of this ``data``, is
    reused (no new factorization). A matrix that is not positive definite falls back to the
    SuperLU path.
    """
    from relmap import _numba

    held = factor is not None and factor.pattern is pattern and factor.active == "block"
    if pattern.block == block and (held or _numba.enabled(pattern.size // block)):
        numeric = factor._block if held else None  # type: ignore[union-attr]
        if numeric is None:
            numeric = _BlockNumeric(pattern.blockchol)
            try:
                numeric.factorize(data)
            except np.linalg.LinAlgError:
                numeric = None
        if numeric is not None:
            return numeric.diagonal_inverse_blocks()
    n = pattern.size // block
    lu, perm = _superlu(pattern, data)
    # SuperLU factors Pr A Pc = L U; with diagonal pivots Pr = Pc, the postorder of its
    # elimination tree, which moves whole node blocks (checked: the factor must stay
    # block-aligned for the block recursion).
    inner = np.argsort(np.asarray(lu.perm_c))  # new → old within the pre-ordered matrix
    order = perm[inner]  # new → original parameter
    groups = order.reshape(n, block)
    if not (
        np.all(groups // block == groups[:, :1] // block) and np.all(np.diff(groups, axis=1) == 1)
    ):
        raise RuntimeError("the factor's ordering split a node's parameters")  # pragma: no cover
    d = lu.U.diagonal()
    Lc = lu.L.tocoo()
    r, c, vals = Lc.row, Lc.col, Lc.data
    strict = r > c
    r, c, vals = r[strict], c[strict], vals[strict]
    # block structure of L (strict lower blocks)
    br, bc = r // block, c // block
    off = br > bc
    keys = np.unique(bc[off] * n + br[off])
    colptr = np.searchsorted(keys // n, np.arange(n + 1))
    rowidx = keys % n
    Lb = np.zeros((len(keys), block, block))
    slot = np.searchsorted(keys, bc[off] * n + br[off])
    Lb[slot, r[off] % block, c[off] % block] = vals[off]
    Ljj = np.broadcast_to(np.eye(block), (n, block, block)).copy()
    on = ~off
    Ljj[bc[on], r[on] % block, c[on] % block] = vals[on]
    Ljj_inv = np.linalg.inv(Ljj)
    Lt = Lb @ Ljj_inv[keys // n]  # L̃_kJ = L_kJ L_JJ⁻¹
    Dt = Ljj * d.reshape(n, 1, block) @ np.swapaxes(Ljj, -1, -2)  # D̃_J = L_JJ D_J L_JJᵀ
    Dinv = np.linalg.inv(Dt)
    # Z on L's pattern, stored as slots: [diagonal blocks (n) | blocks (k, J), k > J] and their
    # transposes after them, so that any block Z_kl of Z_SS is one slot away.
    nb = len(keys)
    slots = n + nb
    ptr, gather = _gather_plan(colptr, rowidx, n)
    Z = np.zeros((2 * slots, block, block))
    count = np.diff(colptr)
    # Columns at equal depth in the elimination tree do not depend on each other (each reads
    # only its ancestors' blocks): process them together, grouped by their number of blocks.
    depth = _etree_depth(colptr, rowidx, n)
    order = np.lexsort((count, depth))
    cuts = np.flatnonzero(np.diff(depth[order]) | np.diff(count[order])) + 1
    for group in np.split(order, cuts):
        m = int(count[group[0]])
        if m == 0:
            Z[group] = Z[slots + group] = Dinv[group]
            continue
        g = len(group)
        cells = ptr[group][:, None] + np.arange(m * m)  # (g, m²) into the gather plan
        mb = m * block
        Zss = Z[gather[cells]].reshape(g, m, m, block, block).transpose(0, 1, 3, 2, 4)
        below = colptr[group][:, None] + np.arange(m)  # (g, m) this column's blocks
        LS = Lt[below].reshape(g, mb, block)
        ZSJ = -(Zss.reshape(g, mb, mb) @ LS)  # Z_SJ = -Z_SS L̃_SJ
        blocks = ZSJ.reshape(g, m, block, block)
        Z[n + below] = blocks
        Z[slots + n + below] = np.swapaxes(blocks, -1, -2)
        ZJJ = Dinv[group] - np.swapaxes(LS, -1, -2) @ ZSJ  # D̃⁻¹ - L̃_SJᵀ Z_SJ
        Z[group] = ZJJ
        Z[slots + group] = np.swapaxes(ZJJ, -1, -2)
    Zd = Z[:n]
    out = np.empty_like(Zd)
    out[groups[:, 0] // block] = Zd
    return 0.5 * (out + np.swapaxes(out, -1, -2))


def _gather_plan(colptr: IntArray, rowidx: IntArray, n: int) -> tuple[IntArray, IntArray]:
    """For each block column J, the slots of the |S_J|² blocks Z_kl (k, l ∈ S_J, row-major) in
    the slot store of :func:`selected_inverse_blocks`; all columns at once, no Python loop.
    The factor's pattern is chordal, so every such block is on it."""
    nb = len(rowidx)
    slots = n + nb
    count = np.diff(colptr)
    ptr = np.concatenate([[0], np.cumsum(count * count)])
    J = np.repeat(np.arange(n), count * count)
    local = np.arange(ptr[-1]) - ptr[J]
    c = count[J]
    k = rowidx[colptr[J] + local // c]
    m = rowidx[colptr[J] + local % c]
    hi, lo = np.maximum(k, m), np.minimum(k, m)
    stored = np.repeat(np.arange(n), count) * n + rowidx  # keys of (row, column) blocks, sorted
    pos = np.searchsorted(stored, lo * n + hi)
    idx = np.where(k == m, k, n + pos)
    idx = np.where(k < m, idx + slots, idx)  # above the diagonal: the stored block's transpose
    return ptr, idx


def _etree_depth(colptr: IntArray, rowidx: IntArray, n: int) -> IntArray:
    """Depth of each block column in the elimination tree (parent = first block below)."""
    count = np.diff(colptr)
    if not len(rowidx):  # no off-diagonal blocks (e.g. a single node): all are roots
        return np.zeros(n, dtype=np.int64)
    parent = np.where(count > 0, rowidx[np.minimum(colptr[:-1], len(rowidx) - 1)], -1)
    # pointer jumping: depth = number of ancestors, in O(n log depth) vectorized steps
    depth = (parent >= 0).astype(np.int64)
    anc = np.where(parent >= 0, parent, np.arange(n))
    while True:
        more = depth[anc] * (anc != np.arange(n))
        if not more.any():
            return depth
        depth = depth + more
        anc = np.where(anc != np.arange(n), anc[anc], anc)


def _node_graph(pattern: SymmetricPattern) -> tuple[IntArray, IntArray, IntArray, int]:
    """Node index of every parameter, and the node pairs (a < b) that meet in the matrix."""
    labels, node_index = np.unique(pattern.node, return_inverse=True)
    k = len(labels)
    cols = np.repeat(np.arange(pattern.size), np.diff(pattern.indptr))
    a, b = node_index[pattern.indices], node_index[cols]
    off = a < b
    pairs = np.unique(a[off].astype(np.int64) * k + b[off])
    return node_index, pairs // k, pairs % k, k


def _minimum_degree(k: int, a: IntArray, b: IntArray) -> IntArray:
    """Multiple minimum degree ordering of a graph of k nodes with edges (a, b) (new → old), by
    SuperLU (MMD on AᵀA+... in symmetric mode, no pivoting, so its column permutation is a
    symmetric ordering). SuperLU orders the columns before it factorizes, so an incomplete LU
    that drops every off-diagonal entry yields the same ordering as the complete one at half
    the cost (city10000: 13.5 against 27.9 ms)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import spilu

    G = sp.csc_matrix(
        (np.full(2 * len(a), -1.0), (np.concatenate([a, b]), np.concatenate([b, a]))),
        shape=(k, k),
    )
    G.sum_duplicates()
    G.data[:] = -1.0
    G.setdiag(np.asarray(abs(G).sum(axis=0)).ravel() + 1.0)  # diagonally dominant: no pivoting
    lu = spilu(
        G,
        drop_tol=1e10,
        fill_factor=1.0,
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )
    return np.argsort(lu.perm_c)  # perm_c[i] = new position of node i


@functools.cache
def _blas_controller() -> Any:
    """threadpoolctl's view of the loaded BLAS libraries (None without threadpoolctl)."""
    import scipy.linalg.lapack  # noqa: F401  (SciPy's own BLAS must be loaded to be seen)

    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:
        return None
    return ThreadpoolController()


def _one_blas_thread() -> contextlib.AbstractContextManager[object]:
    """BLAS on one thread while the supernodal factor works: its dense blocks are small, and
    threads only synchronize (measured on sphere2500: the whole solve 3.1 s with OpenBLAS's
    default threads on 2 cores, 1.6 s on one)."""
    controller = _blas_controller()
    if controller is None:
        return contextlib.nullcontext()
    return controller.limit(limits=1, user_api="blas")


class _Supernodal:
    """Multifrontal supernodal Cholesky ``A = L Lᵀ`` on the node (frame) structure.

    The symbolic analysis runs once per pattern: a minimum-degree ordering of the node graph,
    its elimination tree in postorder, supernodes (chains of nodes whose columns share one row
    structure, up to a few explicit zeros), and for each the map of its frontal matrix. A
    numerical factorization is then dense LAPACK/BLAS work on the fronts: Cholesky of the
    pivot block, the block below it, and the Schur complement added into the parent's front
    (only lower triangles are read). The leaves of the supernodal tree (most of the supernodes,
    small and of a few shapes) are done all at once per shape with batched NumPy; the rest one
    by one, where the fronts are large enough for BLAS to carry the cost.
    """

    def __init__(self, pattern: SymmetricPattern, relax: int = 16) -> None:
        node_index, a, b, k = _node_graph(pattern)
        order = _minimum_degree(k, a, b) if len(a) else np.arange(k)
        rank = np.empty(k, dtype=np.int64)
        rank[order] = np.arange(k)
        parent, children = _elimination_tree(k, rank[a], rank[b])
        post = _postorder(parent, children)  # new → rank-ordered node
        relabel = np.empty(k, dtype=np.int64)
        relabel[post] = np.arange(k)
        ra, rb = relabel[rank[a]], relabel[rank[b]]
        lo, hi = np.minimum(ra, rb), np.maximum(ra, rb)
        parent = np.where(parent[post] >= 0, relabel[np.maximum(parent[post], 0)], -1)
        struct = _structures(k, lo, hi, parent)
        count = np.array([len(s) for s in struct], dtype=np.int64)
        start = _supernodes(parent, count, relax)  # first node of each supernode, then k
        # scalar layout: nodes in the new order, each node's parameters consecutive
        node_of_new = order[post]
        sizes = np.bincount(node_index, minlength=k)
        by_node = np.argsort(node_index, kind="stable")
        first = np.concatenate([[0], np.cumsum(sizes)])
        new_sizes = sizes[node_of_new]
        offset = np.concatenate([[0], np.cumsum(new_sizes)])
        perm = np.concatenate([by_node[first[v] : first[v + 1]] for v in node_of_new])
        self.size = pattern.size
        self.perm = perm.astype(np.int64)
        inv = np.empty_like(self.perm)
        inv[self.perm] = np.arange(len(perm))
        S = len(start) - 1
        sn_of_node = np.repeat(np.arange(S), np.diff(start))
        col0, col1 = offset[start[:-1]], offset[start[1:]]
        fronts: list[IntArray] = []
        for s in range(S):
            below = sorted(struct[start[s + 1] - 1])
            rows = [np.arange(offset[v], offset[v + 1]) for v in below]
            fronts.append(np.concatenate([np.arange(col0[s], col1[s]), *rows]).astype(np.int64))
        width = (col1 - col0).astype(np.int64)
        front_len = np.array([len(f) for f in fronts], dtype=np.int64)
        sparent = np.full(S, -1, dtype=np.int64)
        for s in range(S):
            p = parent[start[s + 1] - 1]
            if p >= 0:
                sparent[s] = sn_of_node[p]
        # the child's rows in its parent's front: lower-triangle entries (flat, child / parent)
        # (C-flat source, Fortran-flat source, C-flat destination)
        maps: list[tuple[IntArray, IntArray, IntArray] | None] = []
        tril: dict[int, tuple[IntArray, IntArray]] = {}
        for s in range(S):
            p = sparent[s]
            if p < 0:
                maps.append(None)
                continue
            loc = np.searchsorted(fronts[p], fronts[s][width[s] :])
            r = len(loc)
            if r not in tril:
                tril[r] = np.tril_indices(r)
            ia, ib = tril[r]
            maps.append((ia * r + ib, ib * r + ia, loc[ia] * front_len[p] + loc[ib]))
        # the lower triangle of A, entry by entry, into the fronts (C-flat positions)
        cols = np.repeat(np.arange(pattern.size), np.diff(pattern.indptr))
        r_new, c_new = inv[pattern.indices], inv[cols]
        lower = np.flatnonzero(r_new >= c_new)
        r_new, c_new = r_new[lower], c_new[lower]
        sn = np.repeat(sn_of_node, new_sizes)[c_new]
        front_start = np.concatenate([[0], np.cumsum(front_len)])
        big = np.int64(pattern.size + 1)
        keys = np.concatenate([s * big + f for s, f in enumerate(fronts)])
        local_r = np.searchsorted(keys, sn * big + r_new) - front_start[sn]
        flat = local_r * front_len[sn] + (c_new - col0[sn])
        by_sn = np.argsort(sn, kind="stable")
        a_src, a_dst = lower[by_sn], flat[by_sn]
        a_ptr = np.searchsorted(sn[by_sn], np.arange(S + 1))
        # leaves of the supernodal tree, batched by shape (width, front size)
        has_child = np.zeros(S, bool)
        has_child[sparent[sparent >= 0]] = True
        leaves = np.flatnonzero(~has_child)
        self.inner = np.flatnonzero(has_child)
        shapes: dict[tuple[int, int], list[int]] = {}
        for s in leaves.tolist():
            shapes.setdefault((int(width[s]), int(front_len[s])), []).append(s)
        self.groups = []
        u_offset = 0
        leaf_u: dict[int, list[tuple[IntArray, IntArray]]] = {}  # parent → (V index, dst)
        for (w, m), ids in shapes.items():
            r = m - w
            dst = np.concatenate(
                [g * m * m + a_dst[a_ptr[s] : a_ptr[s + 1]] for g, s in enumerate(ids)]
            )
            src = np.concatenate([a_src[a_ptr[s] : a_ptr[s + 1]] for s in ids])
            idx = np.array([fronts[s] for s in ids])  # (g, m) scalar indices of the fronts
            self.groups.append((w, m, dst, src, idx[:, :w], idx[:, w:]))
            for g, s in enumerate(ids):
                if maps[s] is not None:
                    u_src, _, dst_p = maps[s]  # type: ignore[misc]
                    leaf_u.setdefault(int(sparent[s]), []).append(
                        (pattern.nnz + u_offset + g * r * r + u_src, dst_p)
                    )
            u_offset += len(ids) * r * r
        # inner fronts start from A's entries and the leaves' Schur complements (one bincount)
        src_parts, dst_parts = [], []
        for s in self.inner.tolist():
            src_parts.append(a_src[a_ptr[s] : a_ptr[s + 1]])
            dst_parts.append(a_dst[a_ptr[s] : a_ptr[s + 1]])
            for u_src, dst_p in leaf_u.get(s, ()):
                src_parts.append(u_src)
                dst_parts.append(dst_p)
        self.inner_src = np.concatenate(src_parts) if src_parts else np.zeros(0, np.int64)
        self.inner_dst = np.concatenate(dst_parts) if dst_parts else np.zeros(0, np.int64)
        self.inner_ptr = self._pointers(leaf_u, a_ptr)
        self.width, self.front_len, self.sparent = width, front_len, sparent
        self.col0, self.col1 = col0, col1
        self.rows = [f[width[s] :] for s, f in enumerate(fronts)]
        self.maps = maps
        self.nnz_L = int((width * (width + 1) // 2 + width * (front_len - width)).sum())
        self._leaf: list[tuple[FloatArray, FloatArray]] = []
        self._inner: dict[int, tuple[FloatArray, FloatArray]] = {}

    def _pointers(self, leaf_u: dict, a_ptr: IntArray) -> IntArray:  # type: ignore[type-arg]
        lengths = [
            int(a_ptr[s + 1] - a_ptr[s]) + sum(len(u) for u, _ in leaf_u.get(s, ()))
            for s in self.inner.tolist()
        ]
        return np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)

    def factorize(self, data: FloatArray) -> None:
        """Numerical factorization; raises :class:`numpy.linalg.LinAlgError` if not SPD."""
        with _one_blas_thread():
            self._factorize(data)

    def _factorize(self, data: FloatArray) -> None:
        from scipy.linalg.blas import dsyrk
        from scipy.linalg.lapack import dpotrf, dtrtri

        data = np.asarray(data, dtype=np.float64)
        leaf, parts = [], [data]
        for w, m, dst, src, _, _ in self.groups:
            F = np.zeros(len(dst) and (dst[-1] // (m * m) + 1) * m * m)
            F[dst] = data[src]
            F = F.reshape(-1, m, m)
            L = np.linalg.cholesky(F[:, :w, :w])
            Linv = np.linalg.inv(L)
            L21 = F[:, w:, :w] @ np.swapaxes(Linv, -1, -2)
            leaf.append((Linv, L21))
            parts.append((F[:, w:, w:] - L21 @ np.swapaxes(L21, -1, -2)).reshape(-1))
        values = np.concatenate(parts)[self.inner_src]
        pending: dict[int, list[tuple[FloatArray, IntArray, IntArray]]] = {}
        inner = {}
        ptr = self.inner_ptr
        for t, s in enumerate(self.inner.tolist()):
            m, w = int(self.front_len[s]), int(self.width[s])
            F = np.bincount(
                self.inner_dst[ptr[t] : ptr[t + 1]], values[ptr[t] : ptr[t + 1]], minlength=m * m
            ).reshape(m, m)
            flat = F.reshape(-1)
            for U, u_src, dst in pending.pop(s, ()):
                flat[dst] += U.reshape(-1)[u_src]
            c, info = dpotrf(F[:w, :w], lower=1, clean=1)
            if info != 0:
                raise np.linalg.LinAlgError("the matrix is not positive definite")
            Linv, _ = dtrtri(c, lower=1)
            L21 = F[w:, :w] @ Linv.T
            inner[s] = (Linv, L21)
            p = int(self.sparent[s])
            if p >= 0:  # the Schur complement's lower triangle (Fortran order, from BLAS)
                _, u_src, dst = self.maps[s]  # type: ignore[misc]
                U = dsyrk(-1.0, L21, beta=1.0, c=F[w:, w:], lower=1)
                pending.setdefault(p, []).append((U.T, u_src, dst))
        self._leaf, self._inner = leaf, inner

    def solve(self, b: FloatArray) -> FloatArray:
        """``A⁻¹ b`` for ``b`` (size,) or (size, k)."""
        with _one_blas_thread():
            return self._solve(b)

    def _solve(self, b: FloatArray) -> FloatArray:
        vector = b.ndim == 1
        y = np.array(b, dtype=np.float64)[self.perm]
        if vector:
            y = y[:, None]
        for (_, _, _, _, cols, rows), (Linv, L21) in zip(self.groups, self._leaf, strict=True):
            ys = Linv @ y[cols]  # (g, w, q)
            y[cols] = ys
            below = (L21 @ ys).reshape(-1, y.shape[1])
            for q in range(y.shape[1]):
                y[:, q] -= np.bincount(rows.reshape(-1), below[:, q], minlength=len(y))
        col0, col1, rows_of = self.col0, self.col1, self.rows
        order = self.inner.tolist()
        for s in order:  # L y = b
            Linv, L21 = self._inner[s]
            ys = Linv @ y[col0[s] : col1[s]]
            y[col0[s] : col1[s]] = ys
            if len(L21):
                y[rows_of[s]] -= L21 @ ys
        for s in reversed(order):  # Lᵀ x = y
            Linv, L21 = self._inner[s]
            rhs = y[col0[s] : col1[s]]
            if len(L21):
                rhs = rhs - L21.T @ y[rows_of[s]]
            y[col0[s] : col1[s]] = Linv.T @ rhs
        for (_, _, _, _, cols, rows), (Linv, L21) in zip(self.groups, self._leaf, strict=True):
            rhs = y[cols] - np.swapaxes(L21, -1, -2) @ y[rows]
            y[cols] = np.swapaxes(Linv, -1, -2) @ rhs
        out = np.empty_like(y)
        out[self.perm] = y
        return out[:, 0] if vector else out


def _elimination_tree(k: int, a: IntArray, b: IntArray) -> tuple[IntArray, list[list[int]]]:
    """Parent of every node in the elimination tree of the graph with edges (a, b), by Liu's
    algorithm with path compression, and the children lists."""
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.lexsort((lo, hi))
    lo, hi = lo[order].tolist(), hi[order].tolist()
    parent = [-1] * k
    anc = [-1] * k
    for r, c in zip(lo, hi, strict=True):  # for each column c, its rows r < c
        while r != -1 and r < c:
            nxt = anc[r]
            anc[r] = c
            if nxt == -1:
                parent[r] = c
            r = nxt
    children: list[list[int]] = [[] for _ in range(k)]
    for v, p in enumerate(parent):
        if p >= 0:
            children[p].append(v)
    return np.array(parent, dtype=np.int64), children


def _postorder(parent: IntArray, children: list[list[int]]) -> IntArray:
    """A postorder of the forest (children before parents, each subtree contiguous)."""
    out: list[int] = []
    roots = [v for v in range(len(parent)) if parent[v] < 0]
    for root in roots:
        stack = [(root, 0)]
        while stack:
            v, i = stack.pop()
            if i < len(children[v]):
                stack.append((v, i + 1))
                stack.append((children[v][i], 0))
            else:
                out.append(v)
    return np.array(out, dtype=np.int64)


def _structures(k: int, lo: IntArray, hi: IntArray, parent: IntArray) -> list[set[int]]:
    """Row structure (nodes below the diagonal) of every column of the Cholesky factor."""
    above: list[list[int]] = [[] for _ in range(k)]
    for r, c in zip(lo.tolist(), hi.tolist(), strict=True):
        above[r].append(c)
    struct: list[set[int]] = [set() for _ in range(k)]
    par = parent.tolist()
    for v in range(k):
        s = struct[v]
        s.update(above[v])
        s.discard(v)
        p = par[v]
        if p >= 0:
            struct[p] |= s
    return struct


def _supernodes(parent: IntArray, count: IntArray, relax: int, fill: float = 0.25) -> IntArray:
    """First node of every supernode (and the total): a chain v-1 → v of the postordered tree
    is merged when the structures nest exactly (a fundamental supernode), or when the supernode
    stays within ``relax`` nodes and at most a fraction ``fill`` of its stored blocks are
    explicit zeros (a relaxed supernode: fewer, wider dense kernels)."""
    k = len(parent)
    starts = [0]
    sum_count = int(count[0]) if k else 0
    cnt = count.tolist()
    par = parent.tolist()
    for v in range(1, k):
        if par[v - 1] == v:
            w = v - starts[-1] + 1  # width if v joins
            s = sum_count + cnt[v]
            stored = w * (w - 1) // 2 + w * cnt[v]
            zeros = stored - s
            if zeros == 0 or (w <= relax and zeros <= fill * (stored + w)):
                sum_count = s
                continue
        starts.append(v)
        sum_count = cnt[v]
    starts.append(k)
    return np.array(starts, dtype=np.int64)


class _BlockSymbolic:
    """Symbolic analysis of the numba block LDLᵀ (:mod:`relmap.network._blockchol`), once per
    pattern of uniform ``b × b`` node blocks: a minimum-degree ordering of the node graph, its
    elimination tree in postorder, the block pattern of L (row subtrees), and the map of every
    lower-triangle entry of the matrix into the factor's block buffer."""

    def __init__(self, pattern: SymmetricPattern) -> None:
        from relmap.network import _blockchol as kernels

        b = pattern.block
        if b is None:
            raise ValueError("the block factorization needs a pattern of uniform node blocks")
        n = pattern.size // b
        indptr, indices = pattern.indptr.astype(np.int64), pattern.indices.astype(np.int64)
        a, c = kernels.block_pairs(indptr, indices, b)  # both triangles
        upper = a < c
        order = _minimum_degree(n, a[upper], c[upper]) if len(a) else np.arange(n)
        rank = np.empty(n, dtype=np.int64)
        rank[order] = np.arange(n)
        post = kernels.etree_postorder(n, *kernels.adjacency(n, a, c, rank))  # new → md order
        order = order[post]  # new → original node
        rank[order] = np.arange(n)
        Lp, Li = kernels.structure(n, *kernels.adjacency(n, a, c, rank))
        self.pattern = pattern
        self.n, self.b, self.Lp, self.Li = n, b, Lp, Li
        self.order = order
        self.perm = (b * order[:, None] + np.arange(b)).reshape(-1)  # scalar new → old
        # The supernodal kernel pays for its dense panels where columns are long: when the
        # work per entry of L (Σ count² / Σ count, in blocks) is 20 or more (measured: city10000
        # 28 and sphere2500 34 gain from it, 23 against 27 ms and 31 against 74 ms;
        # manhattanOlson3500 12 loses, 4.1 against 2.7 ms).
        count = np.diff(Lp).astype(np.float64)
        self.supernodal = bool(count.sum() and (count**2).sum() >= 20.0 * count.sum())
        self._rank, self._panels = rank, None
        self._map: tuple[IntArray, IntArray] | None = None
        self.nnz_L = int(b * b * len(Li) + n * b * (b + 1) // 2)  #: scalars in L (one triangle)
        if self.supernodal:
            self.panels()

    def block_map(self) -> tuple[IntArray, IntArray]:
        """The lower-triangle entries of the matrix (new block row >= new block column): their
        indices in the data and in the block buffer (src, dst); computed once."""
        if self._map is None:
            from relmap.network import _blockchol as kernels

            p = self.pattern
            indptr, indices = p.indptr.astype(np.int64), p.indices.astype(np.int64)
            self._map = kernels.scatter_map(indptr, indices, self._rank, self.b, self.Lp, self.Li)
        return self._map

    def panels(self) -> tuple[IntArray, IntArray, IntArray, IntArray]:
        """Fundamental supernodes (first node of each, then n), the offsets of their dense
        panels, and the map of the matrix's entries into them (src, dst); computed once."""
        if self._panels is None:
            from relmap.network import _blockchol as kernels

            p, b, Lp, Li = self.pattern, self.b, self.Lp, self.Li
            starts = kernels.supernodes(Lp, Li)
            width = np.diff(starts)
            rows = width + np.diff(Lp)[starts[1:] - 1]
            offset = np.concatenate([[0], np.cumsum(rows * width * b * b)]).astype(np.int64)
            src, dst = kernels.panel_map(
                p.indptr.astype(np.int64),
                p.indices.astype(np.int64),
                self._rank,
                b,
                Lp,
                Li,
                starts,
                offset,
            )
            self._panels = (starts, offset, src, dst)
        return self._panels


class _BlockNumeric:
    """One numerical block LDLᵀ factorization on a :class:`_BlockSymbolic` analysis."""

    def __init__(self, sym: _BlockSymbolic, supernodal: bool | None = None) -> None:
        self.sym = sym
        bb = sym.b * sym.b
        self.X = np.empty((sym.n + len(sym.Li)) * bb)
        self.Dinv = np.empty(sym.n * bb)
        self.supernodal = sym.supernodal if supernodal is None else supernodal
        self._panels = np.empty(sym.panels()[1][-1]) if self.supernodal else None
        self._blocks_ready = False
        self._bt = (0,) * sym.b  # its length specializes the kernels to b

    def factorize(self, data: FloatArray) -> None:
        """Numerical factorization; raises :class:`numpy.linalg.LinAlgError` if not SPD."""
        from relmap.network import _blockchol as kernels

        s = self.sym
        data = np.asarray(data, dtype=np.float64)
        if self._panels is not None:
            starts, offset, src, dst = s.panels()
            with _one_blas_thread():
                bad = kernels.factorize_supernodal(
                    s.Lp, s.Li, starts, offset, src, dst, data, self._panels, self._bt
                )
            self._blocks_ready = False  # X, Dinv are formed from the panels when needed
        else:
            src, dst = s.block_map()
            bad = kernels.factorize(s.Lp, s.Li, src, dst, data, self.X, self.Dinv, self._bt)
            self._blocks_ready = True
        if bad >= 0:
            raise np.linalg.LinAlgError("the matrix is not positive definite")

    def _blocks(self) -> None:
        """The block L D Lᵀ (X, Dinv) from the supernodal panels, once per factorization."""
        if not self._blocks_ready:
            from relmap.network import _blockchol as kernels

            s = self.sym
            starts, offset, _, _ = s.panels()
            kernels.panels_to_blocks(
                s.Lp, s.Li, starts, offset, self._panels, self.X, self.Dinv, self._bt
            )
            self._blocks_ready = True

    def solve(self, rhs: FloatArray) -> FloatArray:
        """``A⁻¹ rhs`` for ``rhs`` (size,) or (size, k)."""
        from relmap.network import _blockchol as kernels

        s = self.sym
        vector = rhs.ndim == 1
        Y = np.asarray(rhs, dtype=np.float64)[s.perm]
        Y = np.ascontiguousarray(Y[:, None] if vector else Y)
        if vector and not self._blocks_ready:  # straight from the panels
            starts, offset, _, _ = s.panels()
            kernels.panel_solve(s.Lp, s.Li, starts, offset, self._panels, Y[:, 0], self._bt)
        else:
            self._blocks()
            kernels.solve(s.Lp, s.Li, self.X, self.Dinv, Y, self._bt)
        out = np.empty_like(Y)
        out[s.perm] = Y
        return out[:, 0] if vector else out

    def inverse_blocks(self, nodes: IntArray) -> FloatArray:
        """The joint block (k·b, k·b) of ``A⁻¹`` of the given nodes (k,), pattern's order."""
        from relmap.network import _blockchol as kernels

        s = self.sym
        rank = np.empty(s.n, dtype=np.int64)
        rank[s.order] = np.arange(s.n)
        new = rank[np.asarray(nodes, dtype=np.int64)]
        if not self._blocks_ready:  # straight from the panels
            starts, offset, _, _ = s.panels()
            return kernels.panel_inverse_blocks(
                s.Lp, s.Li, starts, offset, self._panels, new, self._bt
            )
        return kernels.inverse_blocks(s.Lp, s.Li, self.X, self.Dinv, new, self._bt)

    def diagonal_inverse_blocks(self) -> FloatArray:
        """The diagonal blocks of ``A⁻¹`` per node, in the pattern's node order, (n, b, b)."""
        from relmap.network import _blockchol as kernels

        self._blocks()
        s = self.sym
        Z = kernels.selected_inverse(s.Lp, s.Li, self.X, self.Dinv, self._bt)
        out = np.empty((s.n, s.b, s.b))
        out[s.order] = Z[: s.n * s.b * s.b].reshape(s.n, s.b, s.b)
        return out
