"""Fused numba kernels for :mod:`relmap.at3`: compound (with or without cross-covariance),
reversal, chains.

Imported by :mod:`relmap.at3` only when :func:`relmap._numba.enabled`; the numpy kernels there
are the fallback and the reference. Per element the whole first-order propagation runs in
registers (3×3 blocks as 9-tuples, row-major; the Jacobians' structure written out as in the
numpy path: a shear by ``[u]×`` and a rotation) and each input and output is read or written
once from memory; the loop over a batch is vectorized (see "loads and stores").

Array conventions (relmap's storage, :mod:`relmap._layout`): the batched kernels take
C-contiguous entry-major planes, poses ``(4, 4, N)`` and covariances ``(6, 6, N)``, and return
new C-contiguous planes of the same shapes (a single pair stays on the numpy path: a kernel
would save microseconds and cost numba's start-up, :mod:`relmap._numba`). Output covariances
are exactly symmetric (their diagonal blocks are averaged with their transposes, as in the
numpy path). The operations and their order follow the numpy path, without ``fastmath``, so
results agree with it to rounding (bitwise in the cases measured).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types

# The kernels (compound_batched, compound_cross_batched, reverse_batched, compound_chain,
# compound_chain_scan) are module attributes made on first access: see __getattr__ below.

_inline = numba.njit(cache=True, fastmath=False, inline="always")

# Compiled signatures, of read-only arrays (AT3's; writable ones convert to them): the kernels
# take C-contiguous planes (relmap's own layout; at3 copies other views first), so nothing is
# compiled at call time. A kernel is compiled, or loaded from numba's on-disk cache, the first
# time it is looked up here (module ``__getattr__``), not at import.
_C3 = types.Array(types.float64, 3, "C", readonly=True)
_P3 = types.UniTuple(types.float64[:, :, ::1], 2)
_C4 = types.Array(types.float64, 4, "C", readonly=True)
_P4 = types.UniTuple(types.float64[:, :, :, ::1], 2)
_SIGNATURES = {
    "compound_batched": [_P3(_C3, _C3, _C3, _C3)],
    "compound_cross_batched": [_P3(_C3, _C3, _C3, _C3, _C3)],
    "reverse_batched": [_P3(_C3, _C3)],
    "compound_chain": [_P4(_C4, _C4)],
    "compound_chain_scan": [_P4(_C4, _C4)],
}


def __getattr__(name: str) -> object:
    """Compile (or load) the kernel ``name`` from its Python source ``_name``, once."""
    if name not in _SIGNATURES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    kernel = numba.njit(_SIGNATURES[name], cache=True, fastmath=False, nogil=True)(
        globals()["_" + name]
    )
    globals()[name] = kernel
    return kernel


# 3×3 blocks and vectors as tuples -----------------------------------------------------------


@_inline
def _mm(a, b):  # type: ignore[no-untyped-def]
    """a @ b."""
    return (
        a[0] * b[0] + a[1] * b[3] + a[2] * b[6],
        a[0] * b[1] + a[1] * b[4] + a[2] * b[7],
        a[0] * b[2] + a[1] * b[5] + a[2] * b[8],
        a[3] * b[0] + a[4] * b[3] + a[5] * b[6],
        a[3] * b[1] + a[4] * b[4] + a[5] * b[7],
        a[3] * b[2] + a[4] * b[5] + a[5] * b[8],
        a[6] * b[0] + a[7] * b[3] + a[8] * b[6],
        a[6] * b[1] + a[7] * b[4] + a[8] * b[7],
        a[6] * b[2] + a[7] * b[5] + a[8] * b[8],
    )


@_inline
def _mmt(a, b):  # type: ignore[no-untyped-def]
    """a @ bᵀ."""
    return (
        a[0] * b[0] + a[1] * b[1] + a[2] * b[2],
        a[0] * b[3] + a[1] * b[4] + a[2] * b[5],
        a[0] * b[6] + a[1] * b[7] + a[2] * b[8],
        a[3] * b[0] + a[4] * b[1] + a[5] * b[2],
        a[3] * b[3] + a[4] * b[4] + a[5] * b[5],
        a[3] * b[6] + a[4] * b[7] + a[5] * b[8],
        a[6] * b[0] + a[7] * b[1] + a[8] * b[2],
        a[6] * b[3] + a[7] * b[4] + a[8] * b[5],
        a[6] * b[6] + a[7] * b[7] + a[8] * b[8],
    )


@_inline
def _tr(a):  # type: ignore[no-untyped-def]
    return (a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8])


@_inline
def _add(a, b):  # type: ignore[no-untyped-def]
    return (
        a[0] + b[0], a[1] + b[1], a[2] + b[2],
        a[3] + b[3], a[4] + b[4], a[5] + b[5],
        a[6] + b[6], a[7] + b[7], a[8] + b[8],
    )  # fmt: skip


@_inline
def _sub(a, b):  # type: ignore[no-untyped-def]
    return (
        a[0] - b[0], a[1] - b[1], a[2] - b[2],
        a[3] - b[3], a[4] - b[4], a[5] - b[5],
        a[6] - b[6], a[7] - b[7], a[8] - b[8],
    )  # fmt: skip


@_inline
def _sym(a):  # type: ignore[no-untyped-def]
    """(a + aᵀ) / 2, exactly symmetric."""
    return _half(_add(a, _tr(a)))


@_inline
def _half(a):  # type: ignore[no-untyped-def]
    return (
        a[0] * 0.5, a[1] * 0.5, a[2] * 0.5,
        a[3] * 0.5, a[4] * 0.5, a[5] * 0.5,
        a[6] * 0.5, a[7] * 0.5, a[8] * 0.5,
    )  # fmt: skip


@_inline
def _mv(a, v):  # type: ignore[no-untyped-def]
    """a @ v."""
    return (
        a[0] * v[0] + a[1] * v[1] + a[2] * v[2],
        a[3] * v[0] + a[4] * v[1] + a[5] * v[2],
        a[6] * v[0] + a[7] * v[1] + a[8] * v[2],
    )


@_inline
def _hat(u):  # type: ignore[no-untyped-def]
    """[u]× (its zeros take part in the products, as in the numpy path)."""
    return (0.0, -u[2], u[1], u[2], 0.0, -u[0], -u[1], u[0], 0.0)


# the propagation on blocks ----------------------------------------------------------------


@_inline
def _shear(A, B, D, S):  # type: ignore[no-untyped-def]
    """Blocks (0, 0) and (0, 1) of ``Ja C Jaᵀ``, ``Ja = [[I, -S], [0, I]]``: with
    ``E = B - S D``, ``(A - S Bᵀ - E Sᵀ, E)``; block (1, 1) stays D."""
    E = _sub(B, _mm(S, D))
    return _sub(_sub(A, _mmt(S, B)), _mmt(E, S)), E


@_inline
def _rotate(A, B, D, R):  # type: ignore[no-untyped-def]
    """The blocks (0, 0), (0, 1), (1, 1) of ``blkdiag(R, R) C blkdiag(R, R)ᵀ``."""
    return _mmt(_mm(R, A), R), _mmt(_mm(R, B), R), _mmt(_mm(R, D), R)


@_inline
def _compound(ra, ta, rb, tb, Aa, Ba, Da, Ab, Bb, Db):  # type: ignore[no-untyped-def]
    """Mean (R, t) and the unsymmetrized blocks (0, 0), (0, 1), (1, 1) of ``a ⊕ b``'s
    covariance, and ``S = [Ra tb]×`` (for the cross terms)."""
    u = _mv(ra, tb)
    R = _mm(ra, rb)
    t = (u[0] + ta[0], u[1] + ta[1], u[2] + ta[2])
    S = _hat(u)
    top0, E = _shear(Aa, Ba, Da, S)
    W0, W1, W2 = _rotate(Ab, Bb, Db, ra)
    return R, t, S, _add(top0, W0), _add(E, W1), _add(Da, W2)


@_inline
def _cross(ra, S, X00, X01, X10, X11):  # type: ignore[no-untyped-def]
    """Blocks (0, 0), (0, 1), (1, 1) of ``K + Kᵀ``, ``K = Ja X Jbᵀ``."""
    Y00, Y01, Y10, Y11 = _mmt(X00, ra), _mmt(X01, ra), _mmt(X10, ra), _mmt(X11, ra)
    K00 = _sub(Y00, _mm(S, Y10))
    K01 = _sub(Y01, _mm(S, Y11))
    return _add(K00, _tr(K00)), _add(K01, _tr(Y10)), _add(Y11, _tr(Y11))


@_inline
def _reverse(r, t, A, B, D):  # type: ignore[no-untyped-def]
    """``(Rᵀ, -Rᵀ t)`` and the unsymmetrized blocks of ``J C Jᵀ``,
    ``J = -blkdiag(Rᵀ, Rᵀ) [[I, [t]×], [0, I]]`` (a shear by ``u = -t``, then Rᵀ)."""
    rt = _tr(r)
    v = _mv(rt, t)
    S = _hat((-t[0], -t[1], -t[2]))
    top0, E = _shear(A, B, D, S)
    W0, W1, W2 = _rotate(top0, E, D, rt)
    return rt, (-v[0], -v[1], -v[2]), W0, W1, W2


# loads and stores -------------------------------------------------------------------------
# A batched kernel reads its inputs straight from the C-contiguous planes (every entry one
# sequential stream) and stages the results of a chunk of _W elements in one scratch array
# ``buf`` (rows, _W), copied out one entry (a contiguous run) at a time. With unsigned indices
# (no negative-index wrapping) and the results in one array, LLVM vectorizes the loop across
# the chunk (it checks at run time that buf does not overlap the inputs). Measured at
# N = 10⁵ (compound): writing the ~52 result planes straight from the loop instead is ~3x
# slower (not vectorized, and many concurrent write streams); staging the inputs in buf as
# well, ~1.35x slower.

_W = 256  # elements per chunk: the scratch (48 rows, 96 kB) stays in the L2 cache
# scratch rows: a pose's entries (i < 3, j < 4) at row + 4 i + j, a covariance's at row + 6 i + j
_TO, _CO = 0, 12  # the results (the batched kernels' buf has these _ROWS rows only)
_TB, _CB = 48, 60  # a staged step (the one-chain-at-a-time scan)
_ROWS, _SCAN_ROWS = 48, 96


@_inline
def _blk(b, r, n):  # type: ignore[no-untyped-def]
    """The 3×3 block starting at row r of a covariance staged in ``buf``, element n."""
    return (
        b[r, n], b[r + 1, n], b[r + 2, n],
        b[r + 6, n], b[r + 7, n], b[r + 8, n],
        b[r + 12, n], b[r + 13, n], b[r + 14, n],
    )  # fmt: skip


@_inline
def _rot(b, r, n):  # type: ignore[no-untyped-def]
    """The rotation of a pose staged at row r, element n."""
    return (
        b[r, n], b[r + 1, n], b[r + 2, n],
        b[r + 4, n], b[r + 5, n], b[r + 6, n],
        b[r + 8, n], b[r + 9, n], b[r + 10, n],
    )  # fmt: skip


@_inline
def _trans(b, r, n):  # type: ignore[no-untyped-def]
    return (b[r + 3, n], b[r + 7, n], b[r + 11, n])


@_inline
def _pblk(X, i, j, k, m):  # type: ignore[no-untyped-def]
    """The 3×3 block at (i, j) of element (k, m) of 4-D planes X (r, c, K, M)."""
    return (
        X[i, j, k, m], X[i, j + 1, k, m], X[i, j + 2, k, m],
        X[i + 1, j, k, m], X[i + 1, j + 1, k, m], X[i + 1, j + 2, k, m],
        X[i + 2, j, k, m], X[i + 2, j + 1, k, m], X[i + 2, j + 2, k, m],
    )  # fmt: skip


@_inline
def _ptr(X, k, m):  # type: ignore[no-untyped-def]
    """The translation of element (k, m) of 4-D pose planes."""
    return (X[0, 3, k, m], X[1, 3, k, m], X[2, 3, k, m])


@_inline
def _as4(X):  # type: ignore[no-untyped-def]
    """(r, c, N) planes as (r, c, 1, N) (a view)."""
    return X.reshape((X.shape[0], X.shape[1], 1, X.shape[2]))


@_inline
def _put(b, r, n, x):  # type: ignore[no-untyped-def]
    b[r, n], b[r + 1, n], b[r + 2, n] = x[0], x[1], x[2]
    b[r + 6, n], b[r + 7, n], b[r + 8, n] = x[3], x[4], x[5]
    b[r + 12, n], b[r + 13, n], b[r + 14, n] = x[6], x[7], x[8]


@_inline
def _store(b, n, R, t, W0, W1, W2):  # type: ignore[no-untyped-def]
    """Stage the pose (R, t) and the covariance with blocks W0, W1 (W1ᵀ below), W2 at rows
    _TO and _CO; W0 and W2 are made exactly symmetric."""
    b[_TO, n], b[_TO + 1, n], b[_TO + 2, n], b[_TO + 3, n] = R[0], R[1], R[2], t[0]
    b[_TO + 4, n], b[_TO + 5, n], b[_TO + 6, n], b[_TO + 7, n] = R[3], R[4], R[5], t[1]
    b[_TO + 8, n], b[_TO + 9, n], b[_TO + 10, n], b[_TO + 11, n] = R[6], R[7], R[8], t[2]
    _put(b, _CO, n, _sym(W0))
    _put(b, _CO + 3, n, W1)
    _put(b, _CO + 18, n, _tr(W1))
    _put(b, _CO + 21, n, _sym(W2))


@_inline
def _stage_in(buf, row, X, rows, s, w):  # type: ignore[no-untyped-def]
    """Copy entries (i < rows, all j) of elements s..s+w of planes X into buf from ``row``."""
    c = X.shape[1]
    for i in range(rows):
        for j in range(c):
            _copy(buf[row + c * i + j], X[i, j, s : s + w], w)


@_inline
def _stage_out(buf, To, Co, s, w):  # type: ignore[no-untyped-def]
    """Copy the staged results of elements s..s+w into To (4, 4, N), Co (6, 6, N)."""
    for i in range(3):
        for j in range(4):
            _copy(To[i, j, s : s + w], buf[_TO + 4 * i + j], w)
    To[3, :3, s : s + w] = 0.0
    To[3, 3, s : s + w] = 1.0
    for i in range(6):
        for j in range(6):
            _copy(Co[i, j, s : s + w], buf[_CO + 6 * i + j], w)


@_inline
def _copy(dst, src, w):  # type: ignore[no-untyped-def]
    """dst[:w] = src[:w] (unsigned indices: no negative-index wrapping, so it vectorizes)."""
    for n in range(w):
        k = np.uint64(n)
        dst[k] = src[k]


@_inline
def _compound_chunk(buf, Ta, Ca, Tb, Cb, ka, kb, s, w):  # type: ignore[no-untyped-def]
    """Stage ``a ⊕ b`` for elements s..s+w of a chunk: a at (ka, m) of 4-D planes Ta, Ca, b at
    (kb, m) of Tb, Cb."""
    for q in range(w):
        n, m = np.uint64(q), np.uint64(s + q)
        R, t, _, W0, W1, W2 = _compound(
            _pblk(Ta, 0, 0, ka, m), _ptr(Ta, ka, m), _pblk(Tb, 0, 0, kb, m), _ptr(Tb, kb, m),
            _pblk(Ca, 0, 0, ka, m), _pblk(Ca, 0, 3, ka, m), _pblk(Ca, 3, 3, ka, m),
            _pblk(Cb, 0, 0, kb, m), _pblk(Cb, 0, 3, kb, m), _pblk(Cb, 3, 3, kb, m),
        )  # fmt: skip
        _store(buf, n, R, t, W0, W1, W2)


# kernels ------------------------------------------------------------------------------------


def _compound_batched(Ta, Ca, Tb, Cb):  # type: ignore[no-untyped-def]
    """``a ⊕ b`` over N elements: Ta, Tb (4, 4, N), Ca, Cb (6, 6, N) → new (4, 4, N),
    (6, 6, N)."""
    N = Ta.shape[2]
    To = np.empty((4, 4, N))
    Co = np.empty((6, 6, N))
    Ta, Ca, Tb, Cb = _as4(Ta), _as4(Ca), _as4(Tb), _as4(Cb)
    buf = np.empty((_ROWS, _W))
    z = np.uint64(0)
    for s in range(0, N, _W):
        w = min(_W, N - s)
        _compound_chunk(buf, Ta, Ca, Tb, Cb, z, z, s, w)
        _stage_out(buf, To, Co, s, w)
    return To, Co


def _compound_cross_batched(Ta, Ca, Tb, Cb, X):  # type: ignore[no-untyped-def]
    """:func:`compound_batched` of a dependent pair, X (6, 6, N) = ``E[δa δbᵀ]``."""
    N = Ta.shape[2]
    To = np.empty((4, 4, N))
    Co = np.empty((6, 6, N))
    Ta, Ca, Tb, Cb, X = _as4(Ta), _as4(Ca), _as4(Tb), _as4(Cb), _as4(X)
    buf = np.empty((_ROWS, _W))
    z = np.uint64(0)
    for s in range(0, N, _W):
        w = min(_W, N - s)
        for q in range(w):
            n, m = np.uint64(q), np.uint64(s + q)
            ra = _pblk(Ta, 0, 0, z, m)
            R, t, S, W0, W1, W2 = _compound(
                ra, _ptr(Ta, z, m), _pblk(Tb, 0, 0, z, m), _ptr(Tb, z, m),
                _pblk(Ca, 0, 0, z, m), _pblk(Ca, 0, 3, z, m), _pblk(Ca, 3, 3, z, m),
                _pblk(Cb, 0, 0, z, m), _pblk(Cb, 0, 3, z, m), _pblk(Cb, 3, 3, z, m),
            )  # fmt: skip
            Y0, Y1, Y2 = _cross(
                ra, S, _pblk(X, 0, 0, z, m), _pblk(X, 0, 3, z, m),
                _pblk(X, 3, 0, z, m), _pblk(X, 3, 3, z, m),
            )  # fmt: skip
            _store(buf, n, R, t, _add(W0, Y0), _add(W1, Y1), _add(W2, Y2))
        _stage_out(buf, To, Co, s, w)
    return To, Co


def _reverse_batched(T, C):  # type: ignore[no-untyped-def]
    """``Aᴿ`` over N elements: T (4, 4, N), C (6, 6, N) → new (4, 4, N), (6, 6, N)."""
    N = T.shape[2]
    To = np.empty((4, 4, N))
    Co = np.empty((6, 6, N))
    T, C = _as4(T), _as4(C)
    buf = np.empty((_ROWS, _W))
    z = np.uint64(0)
    for s in range(0, N, _W):
        w = min(_W, N - s)
        for q in range(w):
            n, m = np.uint64(q), np.uint64(s + q)
            R, t, W0, W1, W2 = _reverse(
                _pblk(T, 0, 0, z, m), _ptr(T, z, m),
                _pblk(C, 0, 0, z, m), _pblk(C, 0, 3, z, m), _pblk(C, 3, 3, z, m),
            )  # fmt: skip
            _store(buf, n, R, t, W0, W1, W2)
        _stage_out(buf, To, Co, s, w)
    return To, Co


def _compound_chain(T, C):  # type: ignore[no-untyped-def]
    """Every prefix of M chains of L steps, step-major: T (4, 4, L, M), C (6, 6, L, M) → new
    planes of the same shapes whose [..., k, m] is ``step[0, m] ⊕ … ⊕ step[k, m]``, compounded
    in that order with the arithmetic of one batched compound per step (so the values are the
    same; prefix 0 is step 0 as it is)."""
    L, M = T.shape[2], T.shape[3]
    To = np.empty((4, 4, L, M))
    Co = np.empty((6, 6, L, M))
    To[:, :, 0] = T[:, :, 0]  # prefix 0 is step 0 as it is
    Co[:, :, 0] = C[:, :, 0]
    # _W chains at a time, one step of all of them at a time (contiguous, step-major),
    # vectorized across the chains as in compound_batched
    buf = np.empty((_ROWS, _W))
    for s in range(0, M, _W):
        w = min(_W, M - s)
        for k in range(1, L):
            # prefix k = prefix k-1 (read from To, just written, still in cache) ⊕ step k
            _compound_chunk(buf, To, Co, T, C, np.uint64(k - 1), np.uint64(k), s, w)
            _stage_out(buf, To[:, :, k], Co[:, :, k], s, w)
    return To, Co


def _compound_chain_scan(T, C):  # type: ignore[no-untyped-def]
    """:func:`compound_chain` one chain at a time, the running prefix in registers (a
    sequential scan: not vectorized), each chain staged _W steps at a time: for fewer chains
    than lanes worth vectorizing across (relmap.at3 chooses)."""
    L, M = T.shape[2], T.shape[3]
    To = np.empty((4, 4, L, M))
    Co = np.empty((6, 6, L, M))
    buf = np.zeros((_SCAN_ROWS, _W))
    for m in range(M):
        Tm, Cm, Tom, Com = T[:, :, :, m], C[:, :, :, m], To[:, :, :, m], Co[:, :, :, m]
        R, t = _rot(buf, _TO, 0), _trans(buf, _TO, 0)  # (typed; set at step 0)
        A, B, D = _blk(buf, _CO, 0), _blk(buf, _CO + 3, 0), _blk(buf, _CO + 21, 0)
        for s in range(0, L, _W):
            w = min(_W, L - s)
            if s == 0:  # prefix 0 is step 0 as it is
                _stage_in(buf, _TO, Tm, 3, 0, 1)
                _stage_in(buf, _CO, Cm, 6, 0, 1)
                R, t = _rot(buf, _TO, 0), _trans(buf, _TO, 0)
                A, B, D = _blk(buf, _CO, 0), _blk(buf, _CO + 3, 0), _blk(buf, _CO + 21, 0)
            _stage_in(buf, _TB, Tm, 3, s, w)
            _stage_in(buf, _CB, Cm, 6, s, w)
            for n in range(1 if s == 0 else 0, w):
                R, t, _, W0, W1, W2 = _compound(
                    R, t, _rot(buf, _TB, n), _trans(buf, _TB, n), A, B, D,
                    _blk(buf, _CB, n), _blk(buf, _CB + 3, n), _blk(buf, _CB + 21, n),
                )  # fmt: skip
                A, B, D = _sym(W0), W1, _sym(W2)
                _store(buf, n, R, t, A, B, D)
            _stage_out(buf, Tom, Com, s, w)
    return To, Co
