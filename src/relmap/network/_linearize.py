"""numba kernels of the Gauss-Newton linearization (:mod:`relmap.network.optimal`).

One pass over the ATs computes each residual, its weighted Jacobian products and gradient, and
adds them straight into the normal matrix's CSC data and the gradient (no intermediate arrays,
no ``bincount``); in 3-D one pass computes the residuals and their Jacobians first
(:func:`se3_residuals`, the formulas of :func:`relmap.network.optimal._residual` and
:mod:`relmap.lie`), then :func:`hessian_blocks` adds them up. Imported only when numba is
enabled.
"""

from __future__ import annotations

import numba
import numpy as np

from relmap._numba_math import wrap as _wrap
from relmap.typing import FloatArray, IntArray

__all__ = ["hessian_blocks", "planar", "se3_residuals"]

_inline = numba.njit(cache=True, fastmath=False, inline="always")

# 3×3 blocks (row-major 9-tuples) and 3-vectors as tuples (moved here from relmap._at3_kernels,
# whose SE(3) kernels became relmap._core's)


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


@numba.njit(cache=True)
def planar(
    poses: FloatArray,
    i: IntArray,
    j: IntArray,
    z: FloatArray,
    W: FloatArray,
    position: IntArray,
    g_index: IntArray,
    nnz: int,
    size: int,
) -> tuple[float, FloatArray, FloatArray]:  # pragma: no cover
    """(cost, CSC data (nnz,), gradient (size,)) of the planar ATs ``i → j``.

    ``poses`` (n, 3), ``z`` (m, 3), ``W`` (m, 3, 3) information; ``position`` (m, 36) the data
    slot of each contribution, ordered [AT][block (ii, ij, ji, jj)][entry r·3+c] (slot ``nnz``
    discards); ``g_index`` (2·3·m) the gradient slot, [frame (i, j)][component][AT] (slot
    ``size`` discards). The closed forms of ``_System._blocks``, AT by AT.
    """
    m = len(i)
    data = np.zeros(nnz + 1)
    grad = np.zeros(size + 1)
    cost = 0.0
    Hii = np.empty(9)
    Hij = np.empty(9)
    Hjj = np.empty(9)
    for k in range(m):
        a_, b_ = i[k], j[k]
        xi, yi, ti = poses[a_, 0], poses[a_, 1], poses[a_, 2]
        xj, yj, tj = poses[b_, 0], poses[b_, 1], poses[b_, 2]
        c, s = np.cos(ti), np.sin(ti)
        dx, dy = xj - xi, yj - yi
        r0 = c * dx + s * dy - z[k, 0]
        r1 = -s * dx + c * dy - z[k, 1]
        r2 = _wrap(_wrap(tj - ti) - z[k, 2])
        w00, w01, w02 = W[k, 0, 0], W[k, 0, 1], W[k, 0, 2]
        w11, w12, w22 = W[k, 1, 1], W[k, 1, 2], W[k, 2, 2]
        wr0 = w00 * r0 + w01 * r1 + w02 * r2
        wr1 = w01 * r0 + w11 * r1 + w12 * r2
        wr2 = w02 * r0 + w12 * r1 + w22 * r2
        cost += r0 * wr0 + r1 * wr1 + r2 * wr2
        cc, ss, cs = c * c, s * s, c * s
        a = cc * w00 - 2 * cs * w01 + ss * w11
        b = cs * (w00 - w11) + (cc - ss) * w01
        e02 = c * w02 - s * w12
        d11 = ss * w00 + 2 * cs * w01 + cc * w11
        e12 = s * w02 + c * w12
        f = w22
        u0 = -dy * a + dx * b + e02
        u1 = -dy * b + dx * d11 + e12
        u2 = -dy * e02 + dx * e12 + f
        Hjj[0], Hjj[1], Hjj[2] = a, b, e02
        Hjj[3], Hjj[4], Hjj[5] = b, d11, e12
        Hjj[6], Hjj[7], Hjj[8] = e02, e12, f
        Hij[0], Hij[1], Hij[2] = -a, -b, -e02
        Hij[3], Hij[4], Hij[5] = -b, -d11, -e12
        Hij[6], Hij[7], Hij[8] = -u0, -u1, -u2
        Hii[0], Hii[1], Hii[2] = a, b, u0
        Hii[3], Hii[4], Hii[5] = b, d11, u1
        Hii[6], Hii[7], Hii[8] = u0, u1, -dy * u0 + dx * u1 + u2
        for q in range(9):
            data[position[k, q]] += Hii[q]
            data[position[k, 9 + q]] += Hij[q]
            data[position[k, 18 + q]] += Hij[3 * (q % 3) + q // 3]
            data[position[k, 27 + q]] += Hjj[q]
        gj0 = c * wr0 - s * wr1
        gj1 = s * wr0 + c * wr1
        gj2 = wr2
        grad[g_index[k]] -= gj0
        grad[g_index[m + k]] -= gj1
        grad[g_index[2 * m + k]] -= -dy * gj0 + dx * gj1 + gj2
        grad[g_index[3 * m + k]] += gj0
        grad[g_index[4 * m + k]] += gj1
        grad[g_index[5 * m + k]] += gj2
    return cost, data[:nnz], grad[:size]


@numba.njit(cache=True)
def hessian_blocks(
    Ji: FloatArray,
    Jj: FloatArray,
    W: FloatArray,
    r: FloatArray,
    position: IntArray,
    g_index: IntArray,
    nnz: int,
    size: int,
    bt: tuple[int, ...],
) -> tuple[float, FloatArray, FloatArray]:  # pragma: no cover
    """(cost, CSC data (nnz,), gradient (size,)) from the residuals ``r`` (m, b) and their
    Jacobians ``Ji``, ``Jj`` (m, b, b), information ``W`` (m, b, b).

    ``position`` (m, b², 4) gives the data slot of each contribution, [AT][entry q][block t
    (ii, ij, ji, jj)] (slot ``nnz`` discards); ``g_index`` (2·b·m): [frame (i, j)][component]
    [AT] (slot ``size`` discards); ``bt`` any tuple of length b (the loops unroll to it).
    """
    m, b = Ji.shape[0], len(bt)
    data = np.zeros(nnz + 1)
    grad = np.zeros(size + 1)
    cost = 0.0
    WJi = np.empty((b, b))
    WJj = np.empty((b, b))
    Wr = np.empty(b)
    for k in range(m):
        for u in range(b):
            s = 0.0
            for v in range(b):
                s += W[k, u, v] * r[k, v]
            Wr[u] = s
            cost += r[k, u] * s
            for c in range(b):
                si = 0.0
                sj = 0.0
                for v in range(b):
                    si += W[k, u, v] * Ji[k, v, c]
                    sj += W[k, u, v] * Jj[k, v, c]
                WJi[u, c] = si
                WJj[u, c] = sj
        for a in range(b):
            gi = 0.0
            gj = 0.0
            for u in range(b):
                gi += Ji[k, u, a] * Wr[u]
                gj += Jj[k, u, a] * Wr[u]
            grad[g_index[a * m + k]] += gi
            grad[g_index[(b + a) * m + k]] += gj
            for c in range(b):
                hii = 0.0
                hij = 0.0
                hji = 0.0
                hjj = 0.0
                for u in range(b):
                    xi, xj = Ji[k, u, a], Jj[k, u, a]
                    hii += xi * WJi[u, c]
                    hij += xi * WJj[u, c]
                    hji += xj * WJi[u, c]
                    hjj += xj * WJj[u, c]
                q = a * b + c
                data[position[k, q, 0]] += hii
                data[position[k, q, 1]] += hij
                data[position[k, q, 2]] += hji
                data[position[k, q, 3]] += hjj
    return cost, data[:nnz], grad[:size]


_SMALL = 1e-4  # relmap.lie.so3's threshold for the small-angle series


@numba.njit(cache=True, inline="always")
def _rotation(T, k):  # type: ignore[no-untyped-def]  # pragma: no cover
    """The rotation of pose k of T (n, 4, 4) as a row-major 9-tuple."""
    return (
        T[k, 0, 0], T[k, 0, 1], T[k, 0, 2],
        T[k, 1, 0], T[k, 1, 1], T[k, 1, 2],
        T[k, 2, 0], T[k, 2, 1], T[k, 2, 2],
    )  # fmt: skip


@numba.njit(cache=True)
def se3_residuals(
    poses: FloatArray, i: IntArray, j: IntArray, z: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:  # pragma: no cover
    """Residuals ``r = d ⊟ z`` (m, 6) of ``d = T_i⁻¹ T_j`` against measured z (m, 4, 4), poses
    (n, 4, 4), and their chart Jacobians with respect to the poses of i and j (m, 6, 6):

    ``r = (t_d - t_z, Log(R_d R_zᵀ))``,
    ``J_i = [[-R_iᵀ, [t_d]× R_iᵀ], [0, -J_l⁻¹(r_φ) R_iᵀ]]``,
    ``J_j = blkdiag(R_iᵀ, J_l⁻¹(r_φ) R_iᵀ)``

    (:func:`relmap.lie.se3.between`'s Jacobians, with ``R_iᵀ [t_i]× = [R_iᵀ t_i]× R_iᵀ``
    folded in, times the residual's Jacobian). Log and J_l⁻¹ as in :mod:`relmap.lie.so3`,
    with its small-angle series and its branch near π; 3×3 algebra on tuples (the
    helpers above)."""
    m = len(i)
    r = np.empty((m, 6))
    Ji = np.zeros((m, 6, 6))
    Jj = np.zeros((m, 6, 6))
    for k in range(m):
        a, b = i[k], j[k]
        Rt = _tr(_rotation(poses, a))
        td = _mv(Rt, (poses[b, 0, 3] - poses[a, 0, 3], poses[b, 1, 3] - poses[a, 1, 3],
                      poses[b, 2, 3] - poses[a, 2, 3]))  # fmt: skip
        phi = _log(_mmt(_mm(Rt, _rotation(poses, b)), _rotation(z, k)))  # Log(R_d R_zᵀ)
        theta = np.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
        if theta < _SMALL:
            D = 1 / 12 + theta**2 / 720 + theta**4 / 30240
        else:
            h = np.sin(theta / 2)
            D = (1 - theta * np.sin(theta) / (4 * h * h)) / (theta * theta)
        K = _hat(phi)
        KK = _mm(K, K)
        JlRt = _mm(  # J_l⁻¹(φ) R_iᵀ, J_l⁻¹ = I - [φ]×/2 + D [φ]×²
            (
                1.0 - 0.5 * K[0] + D * KK[0], -0.5 * K[1] + D * KK[1], -0.5 * K[2] + D * KK[2],
                -0.5 * K[3] + D * KK[3], 1.0 - 0.5 * K[4] + D * KK[4], -0.5 * K[5] + D * KK[5],
                -0.5 * K[6] + D * KK[6], -0.5 * K[7] + D * KK[7], 1.0 - 0.5 * K[8] + D * KK[8],
            ),
            Rt,
        )  # fmt: skip
        S = _mm(_hat(td), Rt)
        for u in range(3):
            r[k, u] = td[u] - z[k, u, 3]
            r[k, 3 + u] = phi[u]
            for v in range(3):
                q = 3 * u + v
                Ji[k, u, v] = -Rt[q]
                Jj[k, u, v] = Rt[q]
                Ji[k, u, 3 + v] = S[q]
                Ji[k, 3 + u, 3 + v] = -JlRt[q]
                Jj[k, 3 + u, 3 + v] = JlRt[q]
    return r, Ji, Jj


@numba.njit(cache=True, inline="always")
def _log(R):  # type: ignore[no-untyped-def]  # pragma: no cover
    """:func:`relmap.lie.so3.log` of one rotation (a row-major 9-tuple), as a 3-tuple."""
    cos = min(max((R[0] + R[4] + R[8] - 1) / 2, -1.0), 1.0)
    w0, w1, w2 = R[7] - R[5], R[2] - R[6], R[3] - R[1]
    theta = np.arctan2(0.5 * np.sqrt(w0 * w0 + w1 * w1 + w2 * w2), cos)
    if theta > np.pi - 1e-3:  # sin θ vanishes: the axis from the symmetric part
        best, kb = -np.inf, 0
        for q in range(3):
            dq = (R[4 * q] - cos) / (1 - cos)
            if dq > best:
                best, kb = dq, q
        s = np.sqrt(best)
        n0 = (0.5 * (R[kb] + R[3 * kb]) - (cos if kb == 0 else 0.0)) / (1 - cos) / s
        n1 = (0.5 * (R[3 + kb] + R[3 * kb + 1]) - (cos if kb == 1 else 0.0)) / (1 - cos) / s
        n2 = (0.5 * (R[6 + kb] + R[3 * kb + 2]) - (cos if kb == 2 else 0.0)) / (1 - cos) / s
        f = -theta if n0 * w0 + n1 * w1 + n2 * w2 < 0 else theta
        return (f * n0, f * n1, f * n2)
    if theta < _SMALL:
        A = 1 - theta * theta / 6 + theta**4 / 120
    else:
        A = np.sin(theta) / theta
    return (w0 / (2 * A), w1 / (2 * A), w2 / (2 * A))
