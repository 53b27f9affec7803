"""Sparse symmetric normal matrices: a pattern fixed once, refactorized every iteration.

The pattern is assembled once (CSC, both triangles) with a map from every contribution to its
slot, so each Gauss-Newton iteration fills the matrix with one ``np.bincount``. A fill-reducing
ordering is computed once, on the *node* graph (the frames; a frame's three parameters stay
together), with SuperLU's minimum-degree ordering.

Factorizations, chosen by measurement (see the closing notes of the relational-map issue):

- ``qdldl`` (Apache-2.0, a prebuilt wheel) when installed: sparse LDLᵀ that keeps its symbolic
  analysis between refactorizations — about 4× faster than SuperLU on city10000;
- otherwise SciPy's SuperLU in symmetric mode on the pre-ordered matrix (pure SciPy: nothing
  to compile, ever).

Marginal covariances of many frames come from the block Takahashi recursion (selected
inversion) on a factor whose pattern keeps each frame's 3×3 block together.
"""

from __future__ import annotations

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
        self._upper = self.indices <= cols  # upper triangle (row <= col), for qdldl
        self._upper_indices = self.indices[self._upper]
        self._upper_indptr = np.concatenate(
            [[0], np.cumsum(np.bincount(cols[self._upper], minlength=size))]
        ).astype(np.int32)
        self._perm: IntArray | None = None

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
        return _CSC(
            data[self._upper], self._upper_indices, self._upper_indptr, (self.size, self.size)
        )

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
    SuperLU's multiple minimum degree on AᵀA+... in symmetric mode (no pivoting, so its column
    permutation is a symmetric ordering), then each node's parameters follow in order.
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    labels, node_index = np.unique(node, return_inverse=True)
    k = len(labels)
    a, b = node_index[rows], node_index[cols]
    G = sp.csc_matrix((np.full(len(a), -1.0), (a, b)), shape=(k, k))
    G.sum_duplicates()
    G.data[:] = -1.0
    G.setdiag(np.asarray(abs(G).sum(axis=0)).ravel() + 1.0)  # diagonally dominant: no pivoting
    lu = splu(G, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    node_order = np.argsort(lu.perm_c)  # perm_c[i] = new position of node i
    rank = np.empty(k, dtype=np.int64)
    rank[node_order] = np.arange(k)
    return np.lexsort((np.arange(len(node)), rank[node_index]))


class SymmetricFactor:
    """Factorization of a symmetric positive-definite matrix with a fixed pattern.

    ``backend`` is ``"qdldl"``, ``"superlu"`` or ``"auto"`` (qdldl when installed).
    """

    def __init__(self, pattern: SymmetricPattern, backend: str = "auto") -> None:
        self.pattern = pattern
        if backend == "auto":
            try:
                import qdldl  # noqa: F401

                backend = "qdldl"
            except ImportError:
                backend = "superlu"
        if backend not in ("qdldl", "superlu"):
            raise ValueError(f"unknown sparse backend {backend!r}")
        self.backend = backend
        self._qdldl = None
        self._lu = None

    def factorize(self, data: FloatArray) -> None:
        """Factorize the matrix with the given CSC data (the pattern's)."""
        if self.backend == "qdldl":
            import qdldl

            upper = self.pattern.upper(data)
            if self._qdldl is None:
                self._qdldl = qdldl.Solver(upper, upper=True)
            else:
                self._qdldl.update(upper, upper=True)
        else:
            self._lu = _superlu(self.pattern, data)

    def solve(self, b: FloatArray) -> FloatArray:
        """``A⁻¹ b`` for a vector ``(size,)`` or a matrix of columns ``(size, k)``."""
        if self.backend == "qdldl":
            assert self._qdldl is not None, "factorize first"
            if b.ndim == 1:
                return np.asarray(self._qdldl.solve(b))
            return np.column_stack([self._qdldl.solve(np.ascontiguousarray(c)) for c in b.T])
        assert self._lu is not None, "factorize first"
        lu, perm = self._lu
        out = np.empty_like(b)
        out[perm] = lu.solve(np.ascontiguousarray(b[perm]))
        return out


def _superlu(pattern: SymmetricPattern, data: FloatArray):  # type: ignore[no-untyped-def]
    """SuperLU in symmetric mode on the matrix pre-ordered by the node ordering."""
    from scipy.sparse.linalg import splu

    perm = pattern.permutation
    A = pattern.matrix(data)[perm][:, perm].tocsc()
    lu = splu(A, permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    return lu, perm


def selected_inverse_blocks(
    pattern: SymmetricPattern, data: FloatArray, block: int = 3
) -> FloatArray:
    """The diagonal ``block × block`` blocks of ``A⁻¹`` (selected inversion), ``(nodes, b, b)``.

    Parameters must come in consecutive groups of ``block`` (one group per node). The matrix
    is factorized as ``A = L D Lᵀ`` (SuperLU, node-ordered, so L's pattern is block-aligned),
    then the Takahashi recursion ``Z_SJ = -Z_SS L̃_SJ``, ``Z_JJ = D̃_J⁻¹ - L̃_SJᵀ Z_SJ`` runs
    over block columns from last to first; only entries of Z on L's pattern are formed.
    """
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
    parent = np.where(count > 0, rowidx[np.minimum(colptr[:-1], max(len(rowidx) - 1, 0))], -1)
    # pointer jumping: depth = number of ancestors, in O(n log depth) vectorized steps
    depth = (parent >= 0).astype(np.int64)
    anc = np.where(parent >= 0, parent, np.arange(n))
    while True:
        more = depth[anc] * (anc != np.arange(n))
        if not more.any():
            return depth
        depth = depth + more
        anc = np.where(anc != np.arange(n), anc[anc], anc)
