"""numba kernels of the block LDLᵀ factorization (the ``block`` backend of
:class:`relmap.network.sparse.SymmetricFactor`).

Matrices of ``n × n`` dense ``b × b`` blocks (a node's parameters together), the nodes already
in their fill-reducing order. L is stored by block columns: ``Lp`` (n+1) pointers, ``Li``
(nnzb,) sorted block rows strictly below the diagonal; numeric blocks live in one buffer
``X`` (n + nnzb, b, b): ``X[:n]`` the diagonal blocks D_J, ``X[n + p]`` the block L_{Li[p], J}
of the unit-block-diagonal factor ``A = L D Lᵀ``. Imported only when numba is enabled.
"""

from __future__ import annotations

import numba
import numpy as np

from relmap.typing import FloatArray, IntArray

#: reassociation lets LLVM vectorize the dense dot products (NaN and infinity checks stay)
_FAST = {"reassoc", "contract", "nsz"}

__all__ = [
    "adjacency",
    "block_pairs",
    "block_pattern",
    "etree_postorder",
    "factorize",
    "inverse_blocks",
    "panel_inverse_blocks",
    "panel_solve",
    "panels_to_blocks",
    "scatter_map",
    "selected_inverse",
    "solve",
    "structure",
]


@numba.njit(cache=True)
def _etree(n: int, adj_ptr: IntArray, adj: IntArray) -> IntArray:  # pragma: no cover
    """Parent of every node in the elimination tree (Liu's algorithm, path compression)."""
    parent = np.full(n, -1, np.int64)
    anc = np.full(n, -1, np.int64)
    for k in range(n):
        for p in range(adj_ptr[k], adj_ptr[k + 1]):
            i = adj[p]
            while i != -1 and i < k:
                nxt = anc[i]
                anc[i] = k
                if nxt == -1:
                    parent[i] = k
                i = nxt
    return parent


@numba.njit(cache=True)
def etree_postorder(n: int, adj_ptr: IntArray, adj: IntArray) -> IntArray:  # pragma: no cover
    """A postorder (new → old) of the elimination tree of the graph ``adj`` (CSR, symmetric)."""
    parent = _etree(n, adj_ptr, adj)
    head = np.full(n, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    for v in range(n - 1, -1, -1):  # children lists, in increasing order
        p = parent[v]
        if p >= 0:
            nxt[v] = head[p]
            head[p] = v
    post = np.empty(n, np.int64)
    stack = np.empty(n, np.int64)
    k = 0
    for root in range(n):
        if parent[root] != -1:
            continue
        top = 0
        stack[0] = root
        while top >= 0:
            v = stack[top]
            c = head[v]
            if c == -1:
                top -= 1
                post[k] = v
                k += 1
            else:
                head[v] = nxt[c]
                top += 1
                stack[top] = c
    return post


@numba.njit(cache=True)
def structure(
    n: int, adj_ptr: IntArray, adj: IntArray
) -> tuple[IntArray, IntArray]:  # pragma: no cover
    """Block pattern of L (``Lp``, ``Li``, rows sorted) for the graph ``adj`` (CSR, symmetric,
    in elimination order), by row subtrees of the elimination tree."""
    parent = _etree(n, adj_ptr, adj)
    mark = np.full(n, -1, np.int64)
    count = np.zeros(n, np.int64)
    for k in range(n):  # row k of L: walk from each A_ki (i < k) up the tree to k
        mark[k] = k
        for p in range(adj_ptr[k], adj_ptr[k + 1]):
            i = adj[p]
            while i < k and mark[i] != k:
                mark[i] = k
                count[i] += 1
                i = parent[i]
    Lp = np.zeros(n + 1, np.int64)
    for j in range(n):
        Lp[j + 1] = Lp[j] + count[j]
    Li = np.empty(Lp[n], np.int64)
    fill = Lp[:-1].copy()
    mark[:] = -1
    for k in range(n):
        mark[k] = k
        for p in range(adj_ptr[k], adj_ptr[k + 1]):
            i = adj[p]
            while i < k and mark[i] != k:
                mark[i] = k
                Li[fill[i]] = k
                fill[i] += 1
                i = parent[i]
    return Lp, Li


@numba.njit(cache=True)
def block_pattern(
    nodes: int, brow: IntArray, bcol: IntArray, b: int
) -> tuple[IntArray, IntArray, IntArray]:  # pragma: no cover
    """CSC ``(indices, indptr, position)`` of the dense b × b blocks at node pairs
    ``(brow, bcol)`` (K,), exactly as :meth:`relmap.network.sparse.SymmetricPattern.from_blocks`
    builds them: blocks sorted by (column, row), contribution ``[q = b·r + c][k]`` → its slot
    (a negative node drops the block: slot nnz)."""
    K = len(brow)
    cstart = np.zeros(nodes + 1, np.int64)
    for k in range(K):
        if brow[k] >= 0 and bcol[k] >= 0:
            cstart[bcol[k] + 1] += 1
    for J in range(nodes):
        cstart[J + 1] += cstart[J]
    order = np.empty(cstart[nodes], np.int64)
    fill = cstart[:-1].copy()
    for k in range(K):
        if brow[k] >= 0 and bcol[k] >= 0:
            order[fill[bcol[k]]] = k
            fill[bcol[k]] += 1
    uid = np.full(K, -1, np.int64)
    urow = np.empty(cstart[nodes], np.int64)
    ucount = np.zeros(nodes, np.int64)
    nu = 0
    for J in range(nodes):
        lo, hi = cstart[J], cstart[J + 1]
        for t in range(lo + 1, hi):  # insertion sort by row (columns hold few blocks)
            k = order[t]
            u = t
            while u > lo and brow[order[u - 1]] > brow[k]:
                order[u] = order[u - 1]
                u -= 1
            order[u] = k
        prev = -1
        for t in range(lo, hi):
            k = order[t]
            if brow[k] != prev:
                prev = brow[k]
                urow[nu] = prev
                nu += 1
                ucount[J] += 1
            uid[k] = nu - 1
    ustart = np.zeros(nodes + 1, np.int64)
    for J in range(nodes):
        ustart[J + 1] = ustart[J] + ucount[J]
    nnz = b * b * nu
    indptr = np.empty(b * nodes + 1, np.int64)
    indices = np.empty(nnz, np.int64)
    for J in range(nodes):
        for a in range(b):
            start = b * b * ustart[J] + a * b * ucount[J]
            indptr[J * b + a] = start
            for u in range(ustart[J], ustart[J + 1]):
                for r in range(b):
                    indices[start + b * (u - ustart[J]) + r] = b * urow[u] + r
    indptr[b * nodes] = nnz
    position = np.empty(b * b * K, np.int64)
    for k in range(K):
        u = uid[k]
        for q in range(b * b):
            if u < 0:
                position[q * K + k] = nnz
            else:
                J = bcol[k]
                r, c = q // b, q % b
                position[q * K + k] = (
                    b * b * ustart[J] + c * b * ucount[J] + b * (u - ustart[J]) + r
                )
    return indices, indptr, position


@numba.njit(cache=True)
def block_pairs(
    indptr: IntArray, indices: IntArray, b: int
) -> tuple[IntArray, IntArray]:  # pragma: no cover
    """The off-diagonal node pairs (row, column) of a CSC pattern of b × b blocks (both
    triangles, as stored), read from the first scalar of every block."""
    size = len(indptr) - 1
    count = 0
    for c in range(0, size, b):
        for p in range(indptr[c], indptr[c + 1]):
            r = indices[p]
            if r % b == 0 and r // b != c // b:
                count += 1
    rows = np.empty(count, np.int64)
    cols = np.empty(count, np.int64)
    t = 0
    for c in range(0, size, b):
        for p in range(indptr[c], indptr[c + 1]):
            r = indices[p]
            if r % b == 0 and r // b != c // b:
                rows[t] = r // b
                cols[t] = c // b
                t += 1
    return rows, cols


@numba.njit(cache=True)
def adjacency(
    n: int, rows: IntArray, cols: IntArray, rank: IntArray
) -> tuple[IntArray, IntArray]:  # pragma: no cover
    """CSR (pointers, neighbours) of the relabelled graph: edge (rank[rows], rank[cols])."""
    ptr = np.zeros(n + 1, np.int64)
    for t in range(len(rows)):
        ptr[rank[rows[t]] + 1] += 1
    for v in range(n):
        ptr[v + 1] += ptr[v]
    fill = ptr[:-1].copy()
    adj = np.empty(len(rows), np.int64)
    for t in range(len(rows)):
        v = rank[rows[t]]
        adj[fill[v]] = rank[cols[t]]
        fill[v] += 1
    return ptr, adj


@numba.njit(cache=True)
def scatter_map(
    indptr: IntArray, indices: IntArray, rank: IntArray, b: int, Lp: IntArray, Li: IntArray
) -> tuple[IntArray, IntArray]:  # pragma: no cover
    """For every CSC entry in a lower-triangle block (after relabelling nodes by ``rank``), its
    index in the data (``src``) and in the factor's flat block buffer (``dst``)."""
    size = len(indptr) - 1
    n = len(Lp) - 1
    bb = b * b
    pos = np.full(n, -1, np.int64)
    src = np.empty(len(indices), np.int64)
    dst = np.empty(len(indices), np.int64)
    t = 0
    for c0 in range(0, size, b):
        J = rank[c0 // b]
        for p in range(Lp[J], Lp[J + 1]):
            pos[Li[p]] = (n + p) * bb
        pos[J] = J * bb
        for c in range(c0, c0 + b):
            for p in range(indptr[c], indptr[c + 1]):
                r = indices[p]
                row = rank[r // b]
                if row >= J:
                    src[t] = p
                    dst[t] = pos[row] + (r % b) * b + c % b
                    t += 1
        for p in range(Lp[J], Lp[J + 1]):
            pos[Li[p]] = -1
    return src[:t], dst[:t]


@numba.njit(cache=True)
def factorize(
    Lp: IntArray,
    Li: IntArray,
    src: IntArray,
    dst: IntArray,
    data: FloatArray,
    X: FloatArray,
    Dinv: FloatArray,
    bt: tuple[int, ...],
) -> int:  # pragma: no cover
    """Left-looking block ``L D Lᵀ`` into ``X`` and ``Dinv`` (flat: (n + nnzb)·b², n·b²).

    ``bt`` is any tuple of length b (its length, known when compiling, lets the b × b loops
    unroll). The matrix's lower-triangle blocks are scattered from ``data`` by
    ``X[dst] = data[src]``. Returns -1, or the first block column whose pivot block D_J is
    not positive definite (the factorization is then incomplete).
    """
    b = len(bt)
    bb = b * b
    n = len(Lp) - 1
    X[:] = 0.0
    for t in range(len(src)):
        X[dst[t]] = data[src[t]]
    pos = np.zeros(n, np.int64)
    head = np.full(n, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    ptr = np.zeros(n, np.int64)
    W = np.empty(bb)
    C = np.empty(bb)
    V = np.empty(bb)
    for j in range(n):
        for p in range(Lp[j], Lp[j + 1]):
            pos[Li[p]] = (n + p) * bb
        pos[j] = j * bb
        k = head[j]
        while k != -1:
            k_next = nxt[k]
            p = ptr[k]  # Li[p] == j
            lo = (n + p) * bb
            do = k * bb
            for r in range(b):  # W = D_k L_jkᵀ
                for c in range(b):
                    s = 0.0
                    for t in range(b):
                        s += X[do + r * b + t] * X[lo + c * b + t]
                    W[r * b + c] = s
            for q in range(p, Lp[k + 1]):  # A_ij -= L_ik W for the rows i >= j of column k
                so = (n + q) * bb
                to = pos[Li[q]]
                for r in range(b):
                    for c in range(b):
                        V[c] = X[to + r * b + c]
                    for t in range(b):
                        a = X[so + r * b + t]
                        for c in range(b):
                            V[c] -= a * W[t * b + c]
                    for c in range(b):
                        X[to + r * b + c] = V[c]
            ptr[k] = p + 1
            if p + 1 < Lp[k + 1]:
                i = Li[p + 1]
                nxt[k] = head[i]
                head[i] = k
            k = k_next
        # D_j: symmetrize, Cholesky C (the positive-definiteness test), D_j⁻¹ = C⁻ᵀ C⁻¹
        do = j * bb
        for r in range(b):
            for c in range(r):
                v = 0.5 * (X[do + r * b + c] + X[do + c * b + r])
                X[do + r * b + c] = v
                X[do + c * b + r] = v
        for t in range(bb):
            C[t] = 0.0
            W[t] = 0.0
        for c in range(b):
            s = X[do + c * b + c]
            for t in range(c):
                s -= C[c * b + t] * C[c * b + t]
            if not s > 0.0:
                return j
            d = np.sqrt(s)
            C[c * b + c] = d
            for r in range(c + 1, b):
                s = X[do + r * b + c]
                for t in range(c):
                    s -= C[r * b + t] * C[c * b + t]
                C[r * b + c] = s / d
        for c in range(b):  # W = C⁻¹ (lower)
            W[c * b + c] = 1.0 / C[c * b + c]
            for r in range(c + 1, b):
                s = 0.0
                for t in range(c, r):
                    s -= C[r * b + t] * W[t * b + c]
                W[r * b + c] = s / C[r * b + r]
        io = j * bb
        for r in range(b):
            for c in range(r + 1):
                s = 0.0
                for t in range(r, b):
                    s += W[t * b + r] * W[t * b + c]
                Dinv[io + r * b + c] = s
                Dinv[io + c * b + r] = s
        for p in range(Lp[j], Lp[j + 1]):  # L_ij = (updated A_ij) D_j⁻¹
            lo = (n + p) * bb
            for r in range(b):
                for c in range(b):
                    V[c] = 0.0
                for t in range(b):
                    a = X[lo + r * b + t]
                    for c in range(b):
                        V[c] += a * Dinv[io + t * b + c]
                for c in range(b):
                    X[lo + r * b + c] = V[c]
        if Lp[j] < Lp[j + 1]:
            ptr[j] = Lp[j]
            i = Li[Lp[j]]
            nxt[j] = head[i]
            head[i] = j
    return -1


@numba.njit(cache=True)
def _solve_vector(
    Lp: IntArray, Li: IntArray, X: FloatArray, Dinv: FloatArray, y: FloatArray, bt: tuple[int, ...]
) -> None:  # pragma: no cover
    """``y ← A⁻¹ y`` in place for one right-hand side (n·b,)."""
    b = len(bt)
    bb = b * b
    n = len(Lp) - 1
    v = np.empty(b)
    w = np.empty(b)
    for j in range(n):  # L y = rhs
        for t in range(b):
            v[t] = y[j * b + t]
        for p in range(Lp[j], Lp[j + 1]):
            lo = (n + p) * bb
            io = Li[p] * b
            for r in range(b):
                s = 0.0
                for t in range(b):
                    s += X[lo + r * b + t] * v[t]
                y[io + r] -= s
    for j in range(n):  # D y = y
        io = j * bb
        for t in range(b):
            v[t] = y[j * b + t]
        for r in range(b):
            s = 0.0
            for t in range(b):
                s += Dinv[io + r * b + t] * v[t]
            y[j * b + r] = s
    for j in range(n - 1, -1, -1):  # Lᵀ x = y
        for r in range(b):
            w[r] = y[j * b + r]
        for p in range(Lp[j], Lp[j + 1]):
            lo = (n + p) * bb
            io = Li[p] * b
            for t in range(b):
                v[t] = y[io + t]
            for t in range(b):
                for r in range(b):
                    w[r] -= X[lo + t * b + r] * v[t]
        for r in range(b):
            y[j * b + r] = w[r]


@numba.njit(cache=True)
def solve(
    Lp: IntArray, Li: IntArray, X: FloatArray, Dinv: FloatArray, Y: FloatArray, bt: tuple[int, ...]
) -> None:  # pragma: no cover
    """``Y ← A⁻¹ Y`` in place, ``Y`` (n·b, q): q right-hand sides in the factor's order."""
    b = len(bt)
    bb = b * b
    n = len(Lp) - 1
    q = Y.shape[1]
    if q == 1:
        _solve_vector(Lp, Li, X, Dinv, Y[:, 0], bt)
        return
    for j in range(n):  # L y = rhs
        for p in range(Lp[j], Lp[j + 1]):
            lo = (n + p) * bb
            i = Li[p]
            for r in range(b):
                for t in range(b):
                    a = X[lo + r * b + t]
                    for c in range(q):
                        Y[i * b + r, c] -= a * Y[j * b + t, c]
    tmp = np.empty((b, q))
    for j in range(n):  # D y = y
        io = j * bb
        for r in range(b):
            for c in range(q):
                s = 0.0
                for t in range(b):
                    s += Dinv[io + r * b + t] * Y[j * b + t, c]
                tmp[r, c] = s
        for r in range(b):
            for c in range(q):
                Y[j * b + r, c] = tmp[r, c]
    for j in range(n - 1, -1, -1):  # Lᵀ x = y
        for p in range(Lp[j], Lp[j + 1]):
            lo = (n + p) * bb
            i = Li[p]
            for t in range(b):
                for r in range(b):
                    a = X[lo + t * b + r]
                    for c in range(q):
                        Y[j * b + r, c] -= a * Y[i * b + t, c]


@numba.njit(cache=True)
def selected_inverse(
    Lp: IntArray, Li: IntArray, X: FloatArray, Dinv: FloatArray, bt: tuple[int, ...]
) -> FloatArray:  # pragma: no cover
    """The blocks of ``Z = A⁻¹`` on L's pattern, in X's layout (flat, (n + nnzb)·b²), by the
    block Takahashi recursion ``Z_SJ = -Z_SS L_SJ``, ``Z_JJ = D_J⁻¹ - L_SJᵀ Z_SJ`` over block
    columns from last to first (L's pattern is chordal: Z_SS's blocks are all on it)."""
    b = len(bt)
    bb = b * b
    n = len(Lp) - 1
    Z = np.zeros_like(X)
    width = 0
    for j in range(n):
        width = max(width, Lp[j + 1] - Lp[j])
    acc = np.zeros(width * bb)
    for j in range(n - 1, -1, -1):
        p0 = Lp[j]
        m = Lp[j + 1] - p0
        acc[: m * bb] = 0.0
        for a in range(m):
            col = Li[p0 + a]  # l
            lo = (n + p0 + a) * bb  # L_lj
            zo = col * bb  # Z_ll
            ao = a * bb
            for r in range(b):  # acc_a -= Z_ll L_lj
                for t in range(b):
                    z = Z[zo + r * b + t]
                    for c in range(b):
                        acc[ao + r * b + c] -= z * X[lo + t * b + c]
            q = Lp[col]
            for a2 in range(a + 1, m):
                k = Li[p0 + a2]
                while Li[q] != k:
                    q += 1
                zo = (n + q) * bb  # Z_kl
                ko = (n + p0 + a2) * bb  # L_kj
                a2o = a2 * bb
                for r in range(b):
                    for t in range(b):
                        z = Z[zo + r * b + t]
                        for c in range(b):
                            acc[a2o + r * b + c] -= z * X[lo + t * b + c]  # Z_kl L_lj
                            acc[ao + t * b + c] -= z * X[ko + r * b + c]  # Z_klᵀ L_kj
        jo = j * bb
        for t in range(bb):
            Z[jo + t] = Dinv[jo + t]
        for a in range(m):
            lo = (n + p0 + a) * bb
            ao = a * bb
            for t in range(bb):
                Z[lo + t] = acc[ao + t]
            for t in range(b):  # Z_jj -= L_ajᵀ acc_a
                for r in range(b):
                    x = X[lo + t * b + r]
                    for c in range(b):
                        Z[jo + r * b + c] -= x * acc[ao + t * b + c]
        for r in range(b):
            for c in range(r):
                v = 0.5 * (Z[jo + r * b + c] + Z[jo + c * b + r])
                Z[jo + r * b + c] = v
                Z[jo + c * b + r] = v
    return Z


@numba.njit(cache=True)
def supernodes(Lp: IntArray, Li: IntArray) -> IntArray:  # pragma: no cover
    """First node of every fundamental supernode (then n): node j+1 joins j's supernode when
    its structure is j's without j+1 (parent j+1, one row fewer)."""
    n = len(Lp) - 1
    starts = np.empty(n + 1, np.int64)
    k = 0
    for j in range(n):
        joins = (
            j > 0
            and Lp[j] > Lp[j - 1]
            and Li[Lp[j - 1]] == j
            and Lp[j] - Lp[j - 1] == Lp[j + 1] - Lp[j] + 1
        )
        if not joins:
            starts[k] = j
            k += 1
    starts[k] = n
    return starts[: k + 1].copy()


@numba.njit(cache=True)
def panel_map(
    indptr: IntArray,
    indices: IntArray,
    rank: IntArray,
    b: int,
    Lp: IntArray,
    Li: IntArray,
    starts: IntArray,
    offset: IntArray,
) -> tuple[IntArray, IntArray]:  # pragma: no cover
    """For every CSC entry in a lower-triangle block, its index in the data (``src``) and in
    the supernodal panels (``dst``). Supernode s (nodes f..l-1, w = l-f) stores a dense
    row-major panel of (w + |R|)·b rows (nodes f..l-1, then its rows below, R) × w·b columns
    at ``offset[s]``."""
    size = len(indptr) - 1
    n = len(Lp) - 1
    S = len(starts) - 1
    sn_of = np.empty(n, np.int64)
    for s in range(S):
        for v in range(starts[s], starts[s + 1]):
            sn_of[v] = s
    pos = np.full(n, -1, np.int64)
    src = np.empty(len(indices), np.int64)
    dst = np.empty(len(indices), np.int64)
    t = 0
    for c0 in range(0, size, b):
        J = rank[c0 // b]
        s = sn_of[J]
        f, last = starts[s], starts[s + 1] - 1
        w = last + 1 - f
        for v in range(f, last + 1):
            pos[v] = v - f
        for p in range(Lp[last], Lp[last + 1]):
            pos[Li[p]] = w + p - Lp[last]
        u = J - f
        cols = w * b
        for c in range(c0, c0 + b):
            for p in range(indptr[c], indptr[c + 1]):
                r = indices[p]
                row = rank[r // b]
                if row >= J:
                    src[t] = p
                    dst[t] = offset[s] + (pos[row] * b + r % b) * cols + u * b + c % b
                    t += 1
    return src[:t], dst[:t]


@numba.njit(cache=True, fastmath=_FAST, inline="always")
def _subtract_products(
    P: FloatArray,
    Li: IntArray,
    relpos: IntArray,
    rd: int,
    wd: int,
    p: int,
    md: int,
    p2: int,
    do: int,
    so: int,
    cols: int,
    f: int,
    b: int,
    dcols: int,
) -> None:  # pragma: no cover
    """Panel s (at ``so``, ``cols`` wide, first node f) minus the products of descendant d's
    rows p..md (panel at ``do``, ``wd`` nodes, ``dcols`` wide) with its rows p..p2, in loops.
    Inlined: where the caller passes constant widths the loops have fixed lengths."""
    for t1 in range(p, md):
        R = relpos[Li[rd + t1 - wd]]
        for t2 in range(p, min(t1 + 1, p2)):
            U = Li[rd + t2 - wd] - f
            for a in range(b):
                ra = do + (t1 * b + a) * dcols
                row = so + (R * b + a) * cols + U * b
                for c in range(b):
                    rc = do + (t2 * b + c) * dcols
                    acc = 0.0
                    for k in range(dcols):
                        acc += P[ra + k] * P[rc + k]
                    P[row + c] -= acc


@numba.njit(cache=True, fastmath=_FAST, inline="always")
def _solve_rows_below(P: FloatArray, so: int, rows: int, cols: int) -> None:  # pragma: no cover
    """Rows cols..rows of the panel at ``so`` (``cols`` wide, its Cholesky diagonal block
    done) times L11⁻ᵀ, in place, row by row. Inlined: constant widths give fixed loops."""
    for r in range(cols, rows):
        ro = so + r * cols
        for c in range(cols):
            co = so + c * cols
            acc = P[ro + c]
            for k in range(c):
                acc -= P[ro + k] * P[co + k]
            P[ro + c] = acc / P[co + c]


@numba.njit(cache=True, fastmath=_FAST)
def factorize_supernodal(
    Lp: IntArray,
    Li: IntArray,
    starts: IntArray,
    offset: IntArray,
    src: IntArray,
    dst: IntArray,
    data: FloatArray,
    P: FloatArray,
    bt: tuple[int, ...],
) -> int:  # pragma: no cover
    """Left-looking supernodal Cholesky ``A = L Lᵀ`` in dense panels ``P`` (see
    :func:`panel_map`); :func:`panel_solve` solves with it, :func:`panels_to_blocks` turns it
    into the block ``L D Lᵀ`` of :func:`factorize`. Updates between panels go through BLAS
    (``np.dot``) when large, through loops when small. Returns -1, or a node whose pivot is not
    positive (LAPACK's Cholesky of a wide pivot block raises ``LinAlgError`` instead)."""
    b = len(bt)
    bb = b * b
    n = len(Lp) - 1
    S = len(starts) - 1
    P[:] = 0.0
    for t in range(len(src)):
        P[dst[t]] = data[src[t]]
    sn_of = np.empty(n, np.int64)
    for s in range(S):
        for v in range(starts[s], starts[s + 1]):
            sn_of[v] = s
    relpos = np.zeros(n, np.int64)
    head = np.full(S, -1, np.int64)
    nxt = np.full(S, -1, np.int64)
    ptr = np.zeros(S, np.int64)
    for s in range(S):
        f, last = starts[s], starts[s + 1] - 1
        w = last + 1 - f
        r0 = Lp[last]
        m = w + Lp[last + 1] - r0
        cols = w * b
        so = offset[s]
        for v in range(w):
            relpos[f + v] = v
        for p in range(r0, Lp[last + 1]):
            relpos[Li[p]] = w + p - r0
        d = head[s]
        while d != -1:
            d_next = nxt[d]
            fd, ld = starts[d], starts[d + 1] - 1
            wd = ld + 1 - fd
            rd = Lp[ld]
            md = wd + Lp[ld + 1] - rd
            dcols = wd * b
            do = offset[d]
            p = ptr[d]  # rows p.. of d are at or below s's first node
            p2 = p
            while p2 < md and Li[rd + p2 - wd] <= last:
                p2 += 1
            if (md - p) * (p2 - p) * dcols * bb >= 2048:
                A = P[do + p * b * dcols : do + md * b * dcols].reshape((md - p) * b, dcols)
                B = P[do + p * b * dcols : do + p2 * b * dcols].reshape((p2 - p) * b, dcols)
                C = np.dot(A, B.T)
                for t1 in range(p, md):
                    R = relpos[Li[rd + t1 - wd]]
                    for t2 in range(p, min(t1 + 1, p2)):
                        U = Li[rd + t2 - wd] - f
                        for a in range(b):
                            row = so + (R * b + a) * cols + U * b
                            crow = (t1 - p) * b + a
                            for c in range(b):
                                P[row + c] -= C[crow, (t2 - p) * b + c]
            elif wd == 1:  # a one-node descendant: b×b blocks, loops of fixed length
                _subtract_products(P, Li, relpos, rd, 1, p, md, p2, do, so, cols, f, b, b)
            else:
                _subtract_products(P, Li, relpos, rd, wd, p, md, p2, do, so, cols, f, b, dcols)
            ptr[d] = p2
            if p2 < md:
                e = sn_of[Li[rd + p2 - wd]]
                nxt[d] = head[e]
                head[e] = d
            d = d_next
        if cols >= 24:  # a wide panel: LAPACK's Cholesky, then L21 = A21 L11⁻ᵀ through BLAS
            D = P[so : so + cols * cols].reshape(cols, cols)
            for r in range(cols):
                for c in range(r):
                    D[c, r] = D[r, c]
                if not D[r, r] > 0.0:
                    return f + r // b
            L11 = np.linalg.cholesky(D)  # raises LinAlgError if not positive definite
            D[:, :] = L11
            if m > w:
                Linv = np.zeros((cols, cols))  # L11⁻¹, row by row
                for r in range(cols):
                    Linv[r, r] = 1.0
                    for k in range(r):
                        x = L11[r, k]
                        for c in range(k + 1):
                            Linv[r, c] -= x * Linv[k, c]
                    for c in range(r + 1):
                        Linv[r, c] /= L11[r, r]
                A21 = P[so + cols * cols : so + m * b * cols].reshape((m - w) * b, cols)
                A21[:, :] = np.dot(A21, Linv.T)
                ptr[s] = w
                e = sn_of[Li[r0]]
                nxt[s] = head[e]
                head[e] = s
            continue
        # dense Cholesky of the diagonal block (rows 0..cols-1), lower triangle, in place
        for r in range(cols):
            ro = so + r * cols
            for c in range(r + 1):
                co = so + c * cols
                acc = P[ro + c]
                for k in range(c):
                    acc -= P[ro + k] * P[co + k]
                if r == c:
                    if not acc > 0.0:
                        return f + r // b
                    P[ro + r] = np.sqrt(acc)
                else:
                    P[ro + c] = acc / P[co + c]
        # the rows below: L21 = A21 L11⁻ᵀ, row by row (one node: loops of fixed length)
        if w == 1:
            _solve_rows_below(P, so, m * b, b)
        else:
            _solve_rows_below(P, so, m * b, cols)
        if m > w:
            ptr[s] = w
            e = sn_of[Li[r0]]
            nxt[s] = head[e]
            head[e] = s
    return -1


@numba.njit(cache=True, inline="always")
def _on_paths(Lp: IntArray, Li: IntArray, nodes: IntArray) -> np.ndarray:  # pragma: no cover
    """Whether each node lies on an elimination-tree path from ``nodes`` to the root (a
    node's parent is the first row of its column in L)."""
    on_path = np.zeros(len(Lp) - 1, np.bool_)
    for a in range(len(nodes)):
        v = nodes[a]
        while v != -1 and not on_path[v]:
            on_path[v] = True
            v = Li[Lp[v]] if Lp[v + 1] > Lp[v] else -1
    return on_path


@numba.njit(cache=True)
def inverse_blocks(
    Lp: IntArray,
    Li: IntArray,
    X: FloatArray,
    Dinv: FloatArray,
    nodes: IntArray,
    bt: tuple[int, ...],
) -> FloatArray:  # pragma: no cover
    """The joint block ``(A⁻¹)[S, S]`` (k·b, k·b) of the nodes S (k,), in the factor's order.

    With ``A = L D Lᵀ``, ``A⁻¹[S, S] = Yᵀ D⁻¹ Y`` for ``Y = L⁻¹ E_S``, and Y is nonzero only on
    the elimination-tree paths from S to the root (a column's structure lies on its path): a
    forward solve over those paths, not the whole factor."""
    b = len(bt)
    bb = b * b
    n = len(Lp) - 1
    k = len(nodes)
    q = k * b
    path = np.flatnonzero(_on_paths(Lp, Li, nodes))
    count = len(path)
    where = np.full(n, -1, np.int64)
    where[path] = np.arange(count)
    Y = np.zeros((count, b, q))
    for a in range(k):
        for r in range(b):
            Y[where[nodes[a]], r, a * b + r] = 1.0
    out = np.zeros((q, q))
    tmp = np.empty((b, q))
    for t in range(count):
        j = path[t]
        yj = Y[t]
        for p in range(Lp[j], Lp[j + 1]):  # y_i -= L_ij y_j
            lo = (n + p) * bb
            yi = Y[where[Li[p]]]
            for r in range(b):
                for s in range(b):
                    x = X[lo + r * b + s]
                    for c in range(q):
                        yi[r, c] -= x * yj[s, c]
        io = j * bb
        for r in range(b):  # out += y_jᵀ D_j⁻¹ y_j
            for c in range(q):
                acc = 0.0
                for s in range(b):
                    acc += Dinv[io + r * b + s] * yj[s, c]
                tmp[r, c] = acc
        for c1 in range(q):
            for c2 in range(q):
                acc = 0.0
                for r in range(b):
                    acc += yj[r, c1] * tmp[r, c2]
                out[c1, c2] += acc
    return out


@numba.njit(cache=True, fastmath=_FAST)
def panel_inverse_blocks(
    Lp: IntArray,
    Li: IntArray,
    starts: IntArray,
    offset: IntArray,
    P: FloatArray,
    nodes: IntArray,
    bt: tuple[int, ...],
) -> FloatArray:  # pragma: no cover
    """:func:`inverse_blocks` straight from the supernodal factor ``A = L Lᵀ`` in ``P``:
    ``A⁻¹[S, S] = Yᵀ Y`` for ``Y = L⁻¹ E_S``, a forward solve over the elimination-tree paths
    from S to the root only (on each supernode, from the first of its nodes on a path: the
    rows above are zero in Y)."""
    b = len(bt)
    n = len(Lp) - 1
    k = len(nodes)
    q = k * b
    on_path = _on_paths(Lp, Li, nodes)
    Y = np.zeros((n * b, q)) if k else np.zeros((0, 0))
    for a in range(k):
        for r in range(b):
            Y[nodes[a] * b + r, a * b + r] = 1.0
    out = np.zeros((q, q))
    for s in range(len(starts) - 1):
        f, last = starts[s], starts[s + 1] - 1
        if not on_path[last]:  # a path through the supernode leaves it from its last node
            continue
        u0 = f
        while not on_path[u0]:
            u0 += 1
        w = last + 1 - f
        r0 = Lp[last]
        m = w + Lp[last + 1] - r0
        cols = w * b
        so = offset[s]
        y0 = f * b
        c0 = (u0 - f) * b
        for r in range(c0, cols):  # the diagonal block, from the path's first row
            ro = so + r * cols
            for c in range(q):
                acc = Y[y0 + r, c]
                for t in range(c0, r):
                    acc -= P[ro + t] * Y[y0 + t, c]
                Y[y0 + r, c] = acc / P[ro + r]
        for t in range(w, m):  # the rows below
            io = Li[r0 + t - w] * b
            for a in range(b):
                ro = so + (t * b + a) * cols
                for c in range(q):
                    acc = 0.0
                    for j in range(c0, cols):
                        acc += P[ro + j] * Y[y0 + j, c]
                    Y[io + a, c] -= acc
        for r in range(y0 + c0, y0 + cols):  # out += yᵀ y over the supernode's path rows
            for c1 in range(q):
                x = Y[r, c1]
                for c2 in range(q):
                    out[c1, c2] += x * Y[r, c2]
    return out


@numba.njit(cache=True, fastmath=_FAST)
def panels_to_blocks(
    Lp: IntArray,
    Li: IntArray,
    starts: IntArray,
    offset: IntArray,
    P: FloatArray,
    X: FloatArray,
    Dinv: FloatArray,
    bt: tuple[int, ...],
) -> None:  # pragma: no cover
    """The supernodal Cholesky factor in ``P`` as the block ``L D Lᵀ`` of :func:`factorize`
    in ``X`` and ``Dinv`` (so :func:`solve`, :func:`selected_inverse` and
    :func:`inverse_blocks` apply)."""
    b = len(bt)
    bb = b * b
    n = len(Lp) - 1
    S = len(starts) - 1
    # the block L D Lᵀ: L̃_IJ = L_IJ L_JJ⁻¹, D_J = L_JJ L_JJᵀ
    Linv = np.empty((b, b))
    for s in range(S):
        f, last = starts[s], starts[s + 1] - 1
        w = last + 1 - f
        m = w + Lp[last + 1] - Lp[last]
        cols = w * b
        so = offset[s]
        for u in range(w):
            J = f + u
            base = so + (u * b) * cols + u * b  # L_JJ
            Linv[:, :] = 0.0
            for c in range(b):
                Linv[c, c] = 1.0 / P[base + c * cols + c]
                for r in range(c + 1, b):
                    acc = 0.0
                    for k in range(c, r):
                        acc -= P[base + r * cols + k] * Linv[k, c]
                    Linv[r, c] = acc / P[base + r * cols + r]
            jo = J * bb
            for r in range(b):
                for c in range(b):
                    acc = 0.0
                    dd = 0.0
                    for k in range(max(r, c), b):
                        acc += Linv[k, r] * Linv[k, c]
                    for k in range(min(r, c) + 1):
                        dd += P[base + r * cols + k] * P[base + c * cols + k]
                    Dinv[jo + r * b + c] = acc
                    X[jo + r * b + c] = dd
            for t in range(u + 1, m):
                bo = so + (t * b) * cols + u * b
                lo = (n + Lp[J] + t - u - 1) * bb
                for r in range(b):
                    for c in range(b):
                        acc = 0.0
                        for k in range(c, b):
                            acc += P[bo + r * cols + k] * Linv[k, c]
                        X[lo + r * b + c] = acc


@numba.njit(cache=True, fastmath=_FAST)
def panel_solve(
    Lp: IntArray,
    Li: IntArray,
    starts: IntArray,
    offset: IntArray,
    P: FloatArray,
    y: FloatArray,
    bt: tuple[int, ...],
) -> None:  # pragma: no cover
    """``y ← A⁻¹ y`` in place (n·b,), factor's order, with the supernodal factor in ``P``."""
    b = len(bt)
    S = len(starts) - 1
    for s in range(S):  # L y = rhs
        f, last = starts[s], starts[s + 1] - 1
        w = last + 1 - f
        r0 = Lp[last]
        m = w + Lp[last + 1] - r0
        cols = w * b
        so = offset[s]
        y0 = f * b
        for r in range(cols):
            ro = so + r * cols
            acc = y[y0 + r]
            for k in range(r):
                acc -= P[ro + k] * y[y0 + k]
            y[y0 + r] = acc / P[ro + r]
        for t in range(w, m):
            io = Li[r0 + t - w] * b
            for a in range(b):
                ro = so + (t * b + a) * cols
                acc = 0.0
                for k in range(cols):
                    acc += P[ro + k] * y[y0 + k]
                y[io + a] -= acc
    for s in range(S - 1, -1, -1):  # Lᵀ x = y
        f, last = starts[s], starts[s + 1] - 1
        w = last + 1 - f
        r0 = Lp[last]
        m = w + Lp[last + 1] - r0
        cols = w * b
        so = offset[s]
        y0 = f * b
        for t in range(w, m):
            io = Li[r0 + t - w] * b
            for a in range(b):
                ro = so + (t * b + a) * cols
                x = y[io + a]
                for k in range(cols):
                    y[y0 + k] -= P[ro + k] * x
        for r in range(cols - 1, -1, -1):
            x = y[y0 + r] / P[so + r * cols + r]
            y[y0 + r] = x
            for k in range(r):
                y[y0 + k] -= P[so + r * cols + k] * x
