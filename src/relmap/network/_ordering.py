"""Fill-reducing ordering of a node graph by minimum degree, compiled with numba.

Imported only when :func:`relmap._numba.enabled`: it spares the command line SciPy's sparse
modules (0.15-0.45 s to import, measured), which the SuperLU ordering otherwise needs.

The elimination graph is kept explicitly: eliminating node v joins its remaining neighbours
into a clique (their adjacency lists become sorted unions). Neighbours whose closed
neighbourhoods become equal are merged into one supervariable and eliminated together, and
the next node is the one of least external degree (the sizes of the supervariables next to
it; ties: the lowest index), from a heap with lazy deletion — the devices behind multiple
minimum degree's quality (George & Liu, 1989). Measured fill (strictly-lower node blocks of
the factor) against SuperLU's MMD: city10000 112 013 vs 112 684, manhattanOlson3500 19 200 vs
19 007, intel 6 287 vs 6 498, parking-garage 10 652 vs 10 667, sphere2500 39 434 vs 35 811;
about 50 ms for city10000.
"""

from __future__ import annotations

import heapq

import numba
import numpy as np

from relmap.typing import IntArray

__all__ = ["elimination_fill", "minimum_degree"]


def minimum_degree(k: int, a: IntArray, b: IntArray) -> tuple[IntArray, int]:
    """Minimum-degree order of a graph of ``k`` nodes with edges ``(a[e], b[e])`` (new → old),
    and the number of strictly-lower node blocks of the factor in that order (its fill).
    Self-loops and repeated edges are allowed."""
    indptr, indices = _adjacency(k, a, b)
    order, fill = _eliminate(k, indptr, indices, np.empty(0, np.int64))
    return order, int(fill)


def elimination_fill(k: int, a: IntArray, b: IntArray, order: IntArray) -> int:
    """The number of strictly-lower node blocks of the factor in a given order (new → old)."""
    indptr, indices = _adjacency(k, a, b)
    return int(_eliminate(k, indptr, indices, np.asarray(order, dtype=np.int64))[1])


def _adjacency(k: int, a: IntArray, b: IntArray) -> tuple[IntArray, IntArray]:
    """Sorted adjacency lists (CSR) of the undirected graph, without self-loops."""
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    off = a != b
    keys = np.unique(np.concatenate([a[off] * k + b[off], b[off] * k + a[off]]))
    return np.searchsorted(keys // k, np.arange(k + 1)).astype(np.int64), keys % k


@numba.njit(cache=True)
def _union_without(x, y, u, v):  # type: ignore[no-untyped-def]
    """Sorted union of sorted arrays x and y, without the values u and v."""
    out = np.empty(len(x) + len(y), np.int64)
    i = j = n = 0
    while i < len(x) or j < len(y):
        if j == len(y) or (i < len(x) and x[i] < y[j]):
            w = x[i]
            i += 1
        elif i == len(x) or y[j] < x[i]:
            w = y[j]
            j += 1
        else:
            w = x[i]
            i += 1
            j += 1
        if w != u and w != v:
            out[n] = w
            n += 1
    return out[:n]


@numba.njit(cache=True)
def _without(x, w):  # type: ignore[no-untyped-def]
    """Sorted array x without the value w."""
    out = np.empty(len(x), np.int64)
    n = 0
    for e in x:
        if e != w:
            out[n] = e
            n += 1
    return out[:n]


@numba.njit(cache=True)
def _eliminate(k, indptr, indices, given):  # type: ignore[no-untyped-def]
    """Eliminate all nodes, in ``given`` order or by minimum external degree if it is empty.

    With the minimum-degree rule, nodes whose closed neighbourhoods become equal
    (indistinguishable) are merged into one supervariable, eliminated together, and degrees
    count the supervariables' sizes (external degree): the two devices behind the quality of
    multiple minimum degree (Liu, 1985; George & Liu, 1989).
    """
    adj = [indices[indptr[v] : indptr[v + 1]].copy() for v in range(k)]
    alive = np.ones(k, np.bool_)
    weight = np.ones(k, np.int64)
    member_next = np.full(k, -1, np.int64)  # linked list of each supervariable's members
    member_last = np.arange(k)
    degree = np.array([len(adj[v]) for v in range(k)], np.int64)
    order = np.empty(k, np.int64)
    heap = [degree[v] * k + v for v in range(k)]
    heapq.heapify(heap)
    merge = len(given) == 0
    fill = 0
    placed = 0
    while placed < k:
        if len(given):
            v = given[placed]
        else:
            while True:
                key = heapq.heappop(heap)
                v = key % k
                if alive[v] and key // k == degree[v]:
                    break
        alive[v] = False
        nbrs = adj[v]
        m = v
        while m >= 0:  # the supervariable's members, one after another
            order[placed] = m
            placed += 1
            m = member_next[m]
        d = 0
        for x in nbrs:
            d += weight[x]
        fill += weight[v] * d + weight[v] * (weight[v] - 1) // 2
        for u in nbrs:
            adj[u] = _union_without(adj[u], nbrs, u, v)
        if merge:
            # indistinguishable neighbours: equal closed neighbourhoods (all of nbrs are now a
            # clique, so compare adj[u] ∪ {u}); a hash finds the candidates
            h = np.empty(len(nbrs), np.int64)
            for t in range(len(nbrs)):
                u = nbrs[t]
                h[t] = adj[u].sum() + u + len(adj[u]) * k
            srt = np.argsort(h)
            for s0 in range(len(srt)):
                u = nbrs[srt[s0]]
                if not alive[u]:
                    continue
                for s1 in range(s0 + 1, len(srt)):
                    if h[srt[s1]] != h[srt[s0]]:
                        break
                    w = nbrs[srt[s1]]
                    if not alive[w] or len(adj[w]) != len(adj[u]):
                        continue
                    a_u = _without(adj[u], w)
                    a_w = _without(adj[w], u)
                    if len(a_u) != len(a_w) or not np.all(a_u == a_w):
                        continue
                    # merge w into u
                    alive[w] = False
                    weight[u] += weight[w]
                    member_next[member_last[u]] = w
                    member_last[u] = member_last[w]
                    for x in adj[w]:
                        adj[x] = _without(adj[x], w)
                    adj[w] = adj[w][:0]
            for u in nbrs:
                if alive[u]:
                    d = 0
                    for x in adj[u]:
                        d += weight[x]
                    degree[u] = d
                    heapq.heappush(heap, d * k + u)
        adj[v] = nbrs[:0]
    return order, fill
