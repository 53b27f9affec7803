"""numba kernels of :func:`relmap.ekf.correct_landmarks` (one to one; signatures or Mahalanobis).

Imported by :mod:`relmap.ekf` only when ``relmap._numba.enabled()``. One kernel call does the
whole correction of one filter (:func:`correct_one`) or of a batch, the loop over its filters
inside (:func:`correct_batch`): association, gate, one-to-one pairing, the 3×3 update and the
statuses — the formulas of ekf.py's single-filter path (``_exact_pairs``, ``_disc_candidates``,
``_update_one``), so the results are those of the numpy paths to rounding.

Per filter (:func:`_run`, the loop over filters inside):

1. Readings: ABSENT (``valid`` false), INVALID (range not in (0, ∞), bearing not finite), the
   others usable (UNKNOWN until paired).
2. Unique landmark signatures (each reading's one landmark from a table of the signatures, or
   by bisection): when no two readings name the same landmark, every pair is taken in one
   pass, USED inside the gate and GATED outside. Otherwise:
3. Phase 1, pairs inside the gate: each usable reading against its allowed landmarks (with
   shared signatures every landmark of equal signature, without signatures all), skipping, for
   constant sensor noise, landmarks outside the reading's disc (ekf.py's single-filter notes:
   no landmark outside it can be inside the gate). When the readings' cheapest pairs inside
   the gate name distinct landmarks, those are the greedy pairing (cheapest first, ties to the
   lowest reading then landmark); else a stable sort by d², then one scan.
4. Phase 2, the readings left, against the allowed landmarks not taken, paired the same way
   (GATED); the others LOST if some landmark was allowed, else UNKNOWN; d² to the paired or
   nearest allowed landmark. This is the greedy run over the whole reading×landmark matrix
   going on after the pairs inside the gate (which come first). A single reading left skips
   the landmarks its range alone puts farther than the best so far (d² ≥ v_r²/(λ + σr²)).
5. The 3×3 update over the used pairs (``_update_one``).

sin, cos and the innovations' atan are fdlibm's polynomials (compiled with FMAs), accurate to
an ulp or two, cheaper than libm's calls; everything else is the plain arithmetic of ekf.py's
formulas, without FMAs (those moved the states of ill-conditioned random updates by up to 7e-12
from the numpy paths, more than the tests' 1e-12).

A filter returns FALLBACK when the numpy path must decide (a landmark at the sensor, an
innovation covariance not positive definite, an ill-conditioned update, a phase-2 pair inside
the gate, which the disc bound excludes); the caller then runs the numpy path.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from relmap._numba_math import wrap as _wrap

UPDATED, FALLBACK, UNCHANGED = 0, 1, 2
USED, GATED, UNKNOWN, INVALID, ABSENT, LOST = 0, 1, 2, 3, 4, 5
_SLACK = 1.0 + 1e-6  # as ekf._SLACK
_DISC_GROW = 1.0 + 1e-9  # as 1 + ekf._DISC_SLACK
_ILL_CONDITIONED = 1e5  # as ekf._ILL_CONDITIONED
_SMALL_SORT = 24


@numba.njit(cache=True, inline="always")
def _stable_order(ed, n, eo):
    """``eo[:n]`` ← the entries 0..n-1 ordered by ``ed``, ties in entry order (a stable sort;
    insertion sort below _SMALL_SORT entries)."""
    if n > _SMALL_SORT:
        eo[:n] = np.argsort(ed[:n], kind="mergesort")
    else:
        for i in range(n):
            k = i
            v = ed[i]
            while k > 0 and ed[eo[k - 1]] > v:
                eo[k] = eo[k - 1]
                k -= 1
            eo[k] = i


@numba.njit(cache=True, inline="always")
def _accumulate(s_a, n1, s2, swr, swi, sur, sui, sdr, sdi, ir, ux, uy, vr, vb, var_r, var_b):
    """The sums of the 3×3 update (ekf._update_one) with one more used pair: its terms from
    :func:`_terms` (inverse range ``ir``, unit vector ``u``, innovations, variances)."""
    w0, w1 = 1.0 / var_r, 1.0 / var_b
    wq, e2 = w1 * ir * ir, w1 * vb
    q = w0 - wq
    wr_ = w1 * ir
    a_, b_ = w0 * vr, e2 * ir  # (a_ + i b_)·u
    return (
        s_a + (w0 + wq),
        n1 + w1,
        s2 + e2,
        swr + q * (ux * ux - uy * uy),
        swi + q * (ux * uy + uy * ux),
        sur + wr_ * ux,
        sui + wr_ * uy,
        sdr + (a_ * ux - b_ * uy),
        sdi + (a_ * uy + b_ * ux),
    )


@numba.njit(cache=True, inline="always")
def _greedy(ed, ej, el, n, eo, row_state, col_taken, state, status, lm, d2, st, used_at, mark):
    """Greedy one-to-one pairing, cheapest first: the entries (reading ``ej``, landmark ``el``,
    d² ``ed``) in stable d² order, each taken when its reading is open (``row_state`` 1) and
    its landmark free; a taken reading gets ``state``, its landmark, d² and ``status`` in
    ``lm``, ``d2``, ``st`` (and its entry in ``used_at`` when ``mark``)."""
    _stable_order(ed, n, eo)
    for i in range(n):
        e = eo[i]
        j, lk = ej[e], el[e]
        if row_state[j] != 1 or col_taken[lk]:
            continue
        row_state[j] = state
        col_taken[lk] = True
        if mark:
            used_at[j] = e
        lm[j], d2[j], st[j] = lk, ed[e], status


@numba.njit(cache=True)
def signature_mode(lsig, keys, order):
    """Fill ``keys`` (landmark signatures sorted) and ``order`` (their rows); 1 if the landmark
    signatures are unique (readings then find their landmark by bisection), 2 if shared."""
    L = len(lsig)
    increasing = True
    for i in range(1, L):
        if not lsig[i] > lsig[i - 1]:
            increasing = False
            break
    if increasing:
        for i in range(L):
            keys[i] = lsig[i]
            order[i] = i
        return 1
    idx = np.argsort(lsig, kind="mergesort")
    for i in range(L):
        order[i] = idx[i]
        keys[i] = lsig[idx[i]]
    for i in range(1, L):
        if keys[i] == keys[i - 1]:
            return 2
    return 1


# fdlibm's atan (s_atan.c) on |t| < 7/16: atan t = t - t (s1 + s2), error below one ulp
_AT = (
    3.33333333333329318027e-01, -1.99999999998764832476e-01, 1.42857142725034663711e-01,
    -1.11111104054623557880e-01, 9.09088713343650656196e-02, -7.69187620504482999495e-02,
    6.66107313738753120669e-02, -5.83357013379057348645e-02, 4.97687799461593236017e-02,
    -3.65315727442169155270e-02, 1.62858201153657823623e-02,
)  # fmt: skip
_A0, _A1, _A2, _A3, _A4, _A5, _A6, _A7, _A8, _A9, _A10 = _AT


@numba.njit(cache=True, fastmath={"contract"})  # FMAs: the polynomials' latency halved
def atan2(y, x):
    """math.atan2, faster for the small angles of innovations: atan(y/x) by fdlibm's
    polynomial when x > 0 and |y/x| < 7/16 (math.atan2 otherwise)."""
    if x > 0.0:
        t = y / x
        if -0.4375 < t < 0.4375:
            z = t * t
            w = z * z
            s1 = z * (_A0 + w * (_A2 + w * (_A4 + w * (_A6 + w * (_A8 + w * _A10)))))
            s2 = w * (_A1 + w * (_A3 + w * (_A5 + w * (_A7 + w * _A9))))
            return t - t * (s1 + s2)
    return math.atan2(y, x)


# fdlibm's sin and cos (k_sin.c, k_cos.c on [-π/4, π/4], e_rem_pio2.c's reduction by π/2 in
# two steps of 33 bits), errors below one ulp: libm's sincos is a call, this is inlined
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11
_INVPIO2 = 6.36619772367581382433e-01
_PIO2_1, _PIO2_1T = 1.57079632673412561417e00, 6.07710050650619224932e-11
_PIO2_2, _PIO2_2T = 6.07710050630396597660e-11, 2.02226624879595063154e-21


@numba.njit(cache=True, fastmath={"contract"})  # FMAs: the polynomials' latency halved
def sincos(a):
    """``(sin a, cos a)``: fdlibm's kernels for |a| < 10⁵ (math.sin, math.cos otherwise)."""
    if not -1e5 < a < 1e5:
        return math.sin(a), math.cos(a)
    fn = math.floor(a * _INVPIO2 + 0.5)
    r = a - fn * _PIO2_1
    w = fn * _PIO2_1T
    t = r  # second step: exact enough whatever the cancellation for |a| < 10⁵
    w = fn * _PIO2_2
    r = t - w
    w = fn * _PIO2_2T - ((t - r) - w)
    x = r - w
    y = (r - x) - w  # x + y: a - fn π/2
    z = x * x
    v = z * x
    q = _S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))
    sn = x - ((z * (0.5 * y - v * q) - y) - v * _S1)
    q = z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    hz = 0.5 * z
    w = 1.0 - hz
    cs = w + (((1.0 - w) - hz) + (z * q - x * y))
    n = int(fn) & 3
    if n == 0:
        return sn, cs
    if n == 1:
        return cs, -sn
    if n == 2:
        return -sn, -cs
    return -cs, sn


@numba.njit(cache=True, inline="always")
def _variances(r, sr, sb, model):
    if model == 0:
        return sr * sr, sb * sb
    scale = r if model == 1 else r * r
    a, b = sr * scale, sb * scale
    return a * a, b * b


@numba.njit(cache=True, inline="always")
def _terms(fr, lx, ly, zr, ec, es, sr, sb, model):
    """``(ok, d², 1/ρ, ux, uy, v_r, v_φ, σr², σφ²)`` of one reading against one landmark
    (ekf._exact_pairs); ``fr`` the frame (sx, sy, st, h, cbar_re, cbar_im, gbar_re, gbar_im,
    p22, ax, ay)."""
    dx, dy = lx - fr[0], ly - fr[1]
    r = math.sqrt(dx * dx + dy * dy)
    ir = 1.0 / r
    ux, uy = dx * ir, dy * ir
    u2r, u2i = ux * ux - uy * uy, ux * uy + uy * ux  # u·u
    cwr = fr[4] * u2r - fr[5] * u2i  # cbar·u²
    cwi = fr[4] * u2i + fr[5] * u2r
    gur = fr[6] * ux - fr[7] * uy  # gbar·u
    gui = fr[6] * uy + fr[7] * ux
    var_r, var_b = _variances(r, sr, sb, model)
    h = fr[3]
    uvu = h + cwr
    s00 = uvu + var_r
    s01 = gur - cwi * ir
    s11 = ((2.0 * h - uvu) * ir - 2 * gui) * ir + (fr[8] + var_b)
    det = s00 * s11 - s01 * s01
    if not (det > 0.0 and s11 > 0.0):
        return False, 0.0, ir, ux, uy, 0.0, 0.0, var_r, var_b
    wr = ec * ux + es * uy  # e·conj(u)
    wi = es * ux - ec * uy
    vr, vb = zr - r, atan2(wi, wr)
    i11 = 1.0 / s11
    x = vr - s01 * i11 * vb  # d² = x² s11/det + v_φ²/s11: S⁻¹ factored as in ekf._predict
    return True, x * x * (s11 / det) + vb * vb * i11, ir, ux, uy, vr, vb, var_r, var_b


@numba.njit(cache=True)
def _run(mean, cov, z, valid, sig, lm, lsig, par, out_lm, out_st, out_d2, out_mean, out_cov):
    """The corrections of B filters (see the module notes): mean (B, 3), cov (B, 3, 3), z
    (B, m, 2), valid and sig (B, m) or (B, 0) when absent; outputs (B, m), out_mean (3, B) and
    out_cov (3, 3, B). Returns -1 if some filter needs the numpy path (FALLBACK), else how
    many filters were updated. One function with the loop over filters inside: numba counts
    references to every array a function takes, atomically, at every call."""
    B, m, L = z.shape[0], z.shape[1], lm.shape[0]
    ok, sigmode, keys, order, xs, by_x = _prepare(lm, lsig, sig.shape[1] > 0)
    # unique integer signatures of a small span: a table signature - tab_lo → row (or -1)
    tab_lo = keys[0] if L and sigmode == 1 else 0
    use_table = sigmode == 1 and L > 0 and keys[L - 1] - tab_lo <= 64 * L + 1024
    n_table = keys[L - 1] - tab_lo + 1 if use_table else 0
    table = np.full(n_table, -1, np.int64)
    if use_table:
        for i in range(L):
            table[keys[i] - tab_lo] = order[i]
    if not ok:
        return -1
    mx, my, mt, sr, sb, model, gate2 = par[0], par[1], par[2], par[3], par[4], int(par[5]), par[6]
    cap = m * L
    ej, el, eo = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64)
    ed, et, found = np.empty(cap), np.empty((cap, 7)), np.empty(L, np.int64)
    ecs, lid, used_at = np.empty((m, 2)), np.empty(m, np.int64), np.empty(m, np.int64)
    row_state, col_taken = np.empty(m, np.int64), np.empty(L, np.bool_)
    updated = 0
    for f in range(B):
        x, y, t = mean[f, 0], mean[f, 1], mean[f, 2]
        p00, p01, p02 = cov[f, 0, 0], cov[f, 0, 1], cov[f, 0, 2]
        p11, p12, p22 = cov[f, 1, 1], cov[f, 1, 2], cov[f, 2, 2]
        c, s = math.cos(t), math.sin(t)
        ax, ay = c * mx - s * my, s * mx + c * my
        v00 = p00 - 2 * ay * p02 + ay * ay * p22
        v01 = p01 + ax * p02 - ay * p12 - ax * ay * p22
        v11 = p11 + 2 * ax * p12 + ax * ax * p22
        sx, sy, st = x + ax, y + ay, _wrap(t + mt)
        h = 0.5 * (v00 + v11)
        cbr, cbi = 0.5 * (v00 - v11), -v01
        gbr, gbi = p02 - ay * p22, -(p12 + ax * p22)
        fr = (sx, sy, st, h, cbr, cbi, gbr, gbi, p22, ax, ay)
        lo_i, hi_i = 0, L  # (helpers taking arrays are written out here: numba would
        while lo_i < hi_i:  # count references to their arrays, atomically, at every call)
            mid = (lo_i + hi_i) >> 1
            if xs[mid] < sx:
                lo_i = mid + 1
            else:
                hi_i = mid
        i = lo_i
        while i < L and xs[i] == sx:  # a landmark at the sensor has no bearing: numpy raises
            if lm[by_x[i], 1] == sy:
                return -1
            i += 1
        has_valid = valid.shape[1] > 0
        any_usable = False
        for j in range(m):
            out_lm[f, j] = -1
            out_d2[f, j] = np.inf
            r, b = z[f, j, 0], z[f, j, 1]
            row_state[j] = 0  # 0 unusable, 1 usable, 2 used, 3 paired outside the gate
            if has_valid and not valid[f, j]:
                out_st[f, j] = ABSENT
            elif 0.0 < r < np.inf and -np.inf < b < np.inf:
                out_st[f, j] = UNKNOWN
                row_state[j] = 1
                any_usable = True
                a = b + st
                sn, cs = sincos(a)
                ecs[j, 0], ecs[j, 1] = cs, sn
                if sigmode == 1:
                    sj = sig[f, j]
                    if use_table:
                        k = sj - tab_lo
                        lid[j] = table[k] if 0 <= k < n_table else -1
                    else:  # bisection in the sorted signatures
                        lo_i, hi_i = 0, L
                        while lo_i < hi_i:
                            mid = (lo_i + hi_i) >> 1
                            if keys[mid] < sj:
                                lo_i = mid + 1
                            else:
                                hi_i = mid
                        lid[j] = order[lo_i] if lo_i < L and keys[lo_i] == sj else -1
            else:
                out_st[f, j] = INVALID
        if not any_usable:
            for i in range(3):
                out_mean[i, f] = mean[f, i]
                for k in range(3):
                    out_cov[i, k, f] = cov[f, i, k]
            continue
        for lk in range(L):
            col_taken[lk] = False
        # ---- unique signatures: each reading has its one landmark; when no two readings
        # name the same one, the greedy pairing takes every pair (USED inside the gate, GATED
        # outside), in one pass; else the general pairing below
        fused = sigmode == 1
        s_a = n1 = s2 = 0.0
        swr = swi = sur = sui = sdr = sdi = 0.0
        count = 0
        if fused:
            for j in range(m):
                if row_state[j] != 1 or lid[j] < 0:
                    continue
                lk = lid[j]
                if col_taken[lk]:
                    fused = False
                    break
                col_taken[lk] = True
                ok, d2, ir, ux, uy, vr, vb, var_r, var_b = _terms(
                    fr, lm[lk, 0], lm[lk, 1], z[f, j, 0], ecs[j, 0], ecs[j, 1], sr, sb, model
                )
                if not ok:
                    return -1
                out_lm[f, j], out_d2[f, j] = lk, d2
                if not d2 <= gate2:
                    out_st[f, j] = GATED
                    row_state[j] = 3
                    continue
                out_st[f, j] = USED
                row_state[j] = 2
                count += 1
                s_a, n1, s2, swr, swi, sur, sui, sdr, sdi = _accumulate(
                    s_a, n1, s2, swr, swi, sur, sui, sdr, sdi, ir, ux, uy, vr, vb, var_r, var_b
                )
            if not fused:  # undone
                for lk in range(L):
                    col_taken[lk] = False
                for j in range(m):
                    if row_state[j] >= 2:
                        row_state[j] = 1
                        out_lm[f, j], out_d2[f, j], out_st[f, j] = -1, np.inf, UNKNOWN
        if not fused:
            # ---- phase 1: pairs inside the gate
            disc_mode = model == 0 and sigmode != 1
            k2 = gate2 * _SLACK
            lam = max(h + math.sqrt(cbr * cbr + cbi * cbi), 0.0)
            g2 = 2.0 * math.sqrt(gbr * gbr + gbi * gbi)
            pb = p22 + sb * sb
            tau2 = k2 * (lam + sr * sr)
            tau = math.sqrt(tau2)
            n = 0
            clash = False
            for j in range(m):
                if row_state[j] != 1:
                    continue
                zr = z[f, j, 0]
                ec, es = ecs[j, 0], ecs[j, 1]
                nf = 0
                if sigmode == 1:
                    if lid[j] >= 0:
                        found[0] = lid[j]
                        nf = 1
                elif disc_mode:  # the landmarks in the reading's disc (by x, then by row)
                    px, py = sx + zr * ec, sy + zr * es
                    lo = zr - tau
                    disc = zr + zr + tau
                    disc *= disc
                    if lo > 0.0:
                        near = tau2 + zr * k2 * (lam / lo + g2 + (zr + tau) * pb)
                        if near < disc:
                            disc = near
                    disc *= _DISC_GROW
                    R = math.sqrt(disc)
                    # the landmarks of x within px ± R: branchless bisections (first x ≥ px - R,
                    # first x > px + R)
                    first, last, v, w, k = 0, 0, px - R, px + R, L
                    while k > 1:
                        half = k >> 1
                        first = first + half if xs[first + half] < v else first
                        last = last + half if xs[last + half] <= w else last
                        k -= half
                    first += xs[first] < v
                    last += xs[last] <= w
                    for i in range(first, last):
                        lk = by_x[i]
                        if sigmode == 2 and sig[f, j] != lsig[lk]:
                            continue
                        qx, qy = lm[lk, 0] - px, lm[lk, 1] - py
                        if qx * qx + qy * qy <= disc:
                            k = nf
                            while k > 0 and found[k - 1] > lk:
                                found[k] = found[k - 1]
                                k -= 1
                            found[k] = lk
                            nf += 1
                else:
                    for lk in range(L):
                        if sigmode == 2 and sig[f, j] != lsig[lk]:
                            continue
                        found[nf] = lk
                        nf += 1
                be = -1
                for i in range(nf):
                    lk = found[i]
                    ok, d2, ir, ux, uy, vr, vb, var_r, var_b = _terms(
                        fr, lm[lk, 0], lm[lk, 1], zr, ec, es, sr, sb, model
                    )
                    if not ok:
                        return -1
                    if d2 <= gate2:
                        ej[n], el[n], ed[n] = j, lk, d2
                        et[n, 0], et[n, 1], et[n, 2], et[n, 3] = ir, ux, uy, vr
                        et[n, 4], et[n, 5], et[n, 6] = vb, var_r, var_b
                        if be < 0 or d2 < ed[be]:
                            be = n
                        n += 1
                # the reading's cheapest pair inside the gate (the first of equal d²)
                if be >= 0 and not clash:
                    lk = el[be]
                    if col_taken[lk]:
                        clash = True
                    else:
                        col_taken[lk] = True
                        row_state[j] = 2
                        used_at[j] = be
                        out_lm[f, j], out_d2[f, j], out_st[f, j] = lk, ed[be], USED
            # The greedy pairing, cheapest first: when the readings' cheapest pairs name distinct
            # landmarks, the greedy run takes exactly those (taken above); else, undone, a stable
            # sort of the pairs (by reading, then landmark) by d², then one scan.
            if clash:
                for j in range(m):
                    if row_state[j] == 2:
                        row_state[j] = 1
                        col_taken[out_lm[f, j]] = False
                        out_lm[f, j], out_d2[f, j], out_st[f, j] = -1, np.inf, UNKNOWN
                _greedy(ed, ej, el, n, eo, row_state, col_taken, 2, USED,
                        out_lm[f], out_d2[f], out_st[f], used_at, True)  # fmt: skip
            # ---- the 3×3 update over the used pairs (ekf._update_one)
            s_a = n1 = s2 = 0.0
            swr = swi = sur = sui = sdr = sdi = 0.0
            count = 0
            for j in range(m):
                if row_state[j] != 2:
                    continue
                count += 1
                e = used_at[j]
                ir, ux, uy, vr = et[e, 0], et[e, 1], et[e, 2], et[e, 3]
                vb, var_r, var_b = et[e, 4], et[e, 5], et[e, 6]
                s_a, n1, s2, swr, swi, sur, sui, sdr, sdi = _accumulate(
                    s_a, n1, s2, swr, swi, sur, sui, sdr, sdi, ir, ux, uy, vr, vb, var_r, var_b
                )
            # ---- phase 2: the readings left, against the landmarks left
            # One reading left (the usual case): its cheapest free landmark is its pair; d² is
            # computed only where the range alone does not exclude it, d² ≥ v_r²/S_rr ≥
            # v_r²/(λ + σr²) (Cauchy-Schwarz; λ the top eigenvalue of V)
            n_left, jl = 0, -1
            for j in range(m):
                if row_state[j] == 1:
                    n_left += 1
                    jl = j
            if n_left == 1 and sigmode != 1:
                j = jl
                zr = z[f, j, 0]
                ec, es = ecs[j, 0], ecs[j, 1]
                best = bfree = np.inf
                lfree = -1
                allowed = False
                var_r = sr * sr
                for lk in range(L):
                    if sigmode == 2 and sig[f, j] != lsig[lk]:
                        continue
                    allowed = True
                    qx, qy = lm[lk, 0] - sx, lm[lk, 1] - sy
                    rl = math.sqrt(qx * qx + qy * qy)
                    if model != 0:
                        var_r = _variances(rl, sr, sb, model)[0]
                    dv = zr - rl
                    if dv * dv * (1.0 - 1e-9) > (best if col_taken[lk] else bfree) * (lam + var_r):
                        continue
                    ok, d2 = _terms(fr, lm[lk, 0], lm[lk, 1], zr, ec, es, sr, sb, model)[:2]
                    if not ok:
                        return -1
                    if d2 < best:
                        best = d2
                    if not col_taken[lk]:
                        if d2 <= gate2:
                            return -1  # excluded by the disc bound: let numpy decide
                        if d2 < bfree:
                            bfree, lfree = d2, lk
                if lfree >= 0:
                    col_taken[lfree] = True
                    out_lm[f, j], out_d2[f, j], out_st[f, j] = lfree, bfree, GATED
                elif allowed:
                    out_st[f, j] = LOST
                    out_d2[f, j] = best
                row_state[j] = 4  # done
            n = 0
            for j in range(m):
                if row_state[j] != 1:
                    continue
                zr = z[f, j, 0]
                ec, es = ecs[j, 0], ecs[j, 1]
                best = np.inf
                allowed = False
                if sigmode == 1:
                    lo_l, hi_l = max(lid[j], 0), lid[j] + 1
                else:
                    lo_l, hi_l = 0, L
                for lk in range(lo_l, hi_l):
                    if sigmode == 2 and sig[f, j] != lsig[lk]:
                        continue
                    ok, d2 = _terms(fr, lm[lk, 0], lm[lk, 1], zr, ec, es, sr, sb, model)[:2]
                    if not ok:
                        return -1
                    allowed = True
                    if d2 < best:
                        best = d2
                    if not col_taken[lk]:
                        if d2 <= gate2:
                            return -1  # excluded by the disc bound: let numpy decide
                        ej[n], el[n], ed[n] = j, lk, d2
                        n += 1
                if allowed:
                    out_st[f, j] = LOST
                    out_d2[f, j] = best
            # the greedy pairing, cheapest first: entries are by reading, then landmark; when
            # the readings' cheapest entries (the first of equal d²) name distinct landmarks, the
            # greedy run takes exactly those; else a stable sort by d², then one scan
            prev = -1
            for e in range(n):
                j = ej[e]
                if j != prev:
                    used_at[j] = e
                    prev = j
                elif ed[e] < ed[used_at[j]]:
                    used_at[j] = e
            clash = False
            prev = -1
            for e in range(n):
                j = ej[e]
                if j != prev:
                    prev = j
                    lk = el[used_at[j]]
                    if col_taken[lk]:
                        clash = True
                        break
                    col_taken[lk] = True
            if not clash:
                prev = -1
                for e in range(n):
                    j = ej[e]
                    if j != prev:
                        prev = j
                        q = used_at[j]
                        row_state[j] = 3
                        out_lm[f, j], out_d2[f, j], out_st[f, j] = el[q], ed[q], GATED
            else:
                prev = -1
                for e in range(n):  # undo the marks of this pass
                    j = ej[e]
                    if j != prev:
                        prev = j
                        col_taken[el[used_at[j]]] = False
                _greedy(ed, ej, el, n, eo, row_state, col_taken, 3, GATED,
                        out_lm[f], out_d2[f], out_st[f], used_at, False)  # fmt: skip
        if count == 0:
            for i in range(3):
                out_mean[i, f] = mean[f, i]
                for k in range(3):
                    out_cov[i, k, f] = cov[f, i, k]
            continue
        a00, a11, a01 = 0.5 * (s_a + swr), 0.5 * (s_a - swr), 0.5 * swi
        c0, c1, b0, b1 = sui, -sur, -sdr, -sdi
        a02 = -ay * a00 + ax * a01 - c0
        a12 = -ay * a01 + ax * a11 - c1
        a22 = ay * ay * a00 - 2 * ax * ay * a01 + ax * ax * a11 - 2 * (ax * c1 - ay * c0) + n1
        b2 = ax * b1 - ay * b0 - s2
        m00 = a00 * p00 + a01 * p01 + a02 * p02
        m11 = a01 * p01 + a11 * p11 + a12 * p12
        m22 = a02 * p02 + a12 * p12 + a22 * p22
        if not m00 + m11 + m22 <= _ILL_CONDITIONED:
            return -1
        m00 += 1.0
        m11 += 1.0
        m22 += 1.0
        m01 = a00 * p01 + a01 * p11 + a02 * p12
        m02 = a00 * p02 + a01 * p12 + a02 * p22
        m10 = a01 * p00 + a11 * p01 + a12 * p02
        m12 = a01 * p02 + a11 * p12 + a12 * p22
        m20 = a02 * p00 + a12 * p01 + a22 * p02
        m21 = a02 * p01 + a12 * p11 + a22 * p12
        i00, i10, i20 = m11 * m22 - m12 * m21, m12 * m20 - m10 * m22, m10 * m21 - m11 * m20
        rd = 1.0 / (m00 * i00 + m01 * i10 + m02 * i20)
        w00, w01, w02 = i00 * rd, (m02 * m21 - m01 * m22) * rd, (m01 * m12 - m02 * m11) * rd
        w10, w11, w12 = i10 * rd, (m00 * m22 - m02 * m20) * rd, (m02 * m10 - m00 * m12) * rd
        w20, w21, w22 = i20 * rd, (m01 * m20 - m00 * m21) * rd, (m00 * m11 - m01 * m10) * rd
        g00 = p00 * w00 + p01 * w10 + p02 * w20
        g01 = p00 * w01 + p01 * w11 + p02 * w21
        g02 = p00 * w02 + p01 * w12 + p02 * w22
        g10 = p01 * w00 + p11 * w10 + p12 * w20
        g11 = p01 * w01 + p11 * w11 + p12 * w21
        g12 = p01 * w02 + p11 * w12 + p12 * w22
        g20 = p02 * w00 + p12 * w10 + p22 * w20
        g21 = p02 * w01 + p12 * w11 + p22 * w21
        g22 = p02 * w02 + p12 * w12 + p22 * w22
        y0 = w00 * b0 + w01 * b1 + w02 * b2
        y1 = w10 * b0 + w11 * b1 + w12 * b2
        y2 = w20 * b0 + w21 * b1 + w22 * b2
        r0 = b0 - (m00 * y0 + m01 * y1 + m02 * y2)
        r1 = b1 - (m10 * y0 + m11 * y1 + m12 * y2)
        r2 = b2 - (m20 * y0 + m21 * y1 + m22 * y2)
        y0, y1, y2 = (
            y0 + (w00 * r0 + w01 * r1 + w02 * r2),
            y1 + (w10 * r0 + w11 * r1 + w12 * r2),
            y2 + (w20 * r0 + w21 * r1 + w22 * r2),
        )
        k00 = g00 * a00 + g01 * a01 + g02 * a02
        k01 = g00 * a01 + g01 * a11 + g02 * a12
        k02 = g00 * a02 + g01 * a12 + g02 * a22
        k10 = g10 * a00 + g11 * a01 + g12 * a02
        k11 = g10 * a01 + g11 * a11 + g12 * a12
        k12 = g10 * a02 + g11 * a12 + g12 * a22
        k20 = g20 * a00 + g21 * a01 + g22 * a02
        k21 = g20 * a01 + g21 * a11 + g22 * a12
        k22 = g20 * a02 + g21 * a12 + g22 * a22
        j00, j01, j02 = 1.0 - k00, -k01, -k02
        j10, j11, j12 = -k10, 1.0 - k11, -k12
        j20, j21, j22 = -k20, -k21, 1.0 - k22
        t00 = j00 * p00 + j01 * p01 + j02 * p02
        t01 = j00 * p01 + j01 * p11 + j02 * p12
        t02 = j00 * p02 + j01 * p12 + j02 * p22
        t10 = j10 * p00 + j11 * p01 + j12 * p02
        t11 = j10 * p01 + j11 * p11 + j12 * p12
        t12 = j10 * p02 + j11 * p12 + j12 * p22
        t20 = j20 * p00 + j21 * p01 + j22 * p02
        t21 = j20 * p01 + j21 * p11 + j22 * p12
        t22 = j20 * p02 + j21 * p12 + j22 * p22
        c00 = (t00 * j00 + t01 * j01 + t02 * j02) + (k00 * g00 + k01 * g01 + k02 * g02)
        c01 = (t00 * j10 + t01 * j11 + t02 * j12) + (k00 * g10 + k01 * g11 + k02 * g12)
        c02 = (t00 * j20 + t01 * j21 + t02 * j22) + (k00 * g20 + k01 * g21 + k02 * g22)
        c11 = (t10 * j10 + t11 * j11 + t12 * j12) + (k10 * g10 + k11 * g11 + k12 * g12)
        c12 = (t10 * j20 + t11 * j21 + t12 * j22) + (k10 * g20 + k11 * g21 + k12 * g22)
        c22 = (t20 * j20 + t21 * j21 + t22 * j22) + (k20 * g20 + k21 * g21 + k22 * g22)
        out_mean[0, f] = x + (p00 * y0 + p01 * y1 + p02 * y2)
        out_mean[1, f] = y + (p01 * y0 + p11 * y1 + p12 * y2)
        out_mean[2, f] = _wrap(t + (p02 * y0 + p12 * y1 + p22 * y2))
        out_cov[0, 0, f], out_cov[0, 1, f], out_cov[0, 2, f] = c00, c01, c02
        out_cov[1, 0, f], out_cov[1, 1, f], out_cov[1, 2, f] = c01, c11, c12
        out_cov[2, 0, f], out_cov[2, 1, f], out_cov[2, 2, f] = c02, c12, c22
        updated += 1
    return updated


@numba.njit(cache=True)
def _prepare(lm, lsig, has_sig):
    """Landmarks finite?, their x sorted and rows in that order, and the signature lookup:
    (ok, sigmode, keys, order, xs, by_x)."""
    L = lm.shape[0]
    keys = np.empty(L, np.int64)
    order = np.empty(L, np.int64)
    xs = np.empty(L)
    by_x = np.argsort(lm[:, 0], kind="mergesort")
    for lk in range(L):
        if not (np.isfinite(lm[lk, 0]) and np.isfinite(lm[lk, 1])):
            return False, 0, keys, order, xs, by_x
        xs[lk] = lm[by_x[lk], 0]
    sigmode = signature_mode(lsig, keys, order) if has_sig else 0
    return True, sigmode, keys, order, xs, by_x


@numba.njit(cache=True)
def correct_one(mean, cov, z, valid, sig, lm, lsig, par, out_int, out_d2, out_state):
    """One filter: ``par`` = (mount x, y, θ, σr, σφ, noise model 0/1/2, χ²), ``valid`` and
    ``sig`` of length 0 when absent. Writes landmark rows then statuses to ``out_int`` (2m),
    d² to ``out_d2`` (m), the state to ``out_state`` (x, y, θ, Σ row by row); returns UPDATED,
    UNCHANGED or FALLBACK."""
    m = z.shape[0]
    out_mean, out_cov = np.empty((3, 1)), np.empty((3, 3, 1))
    n = _run(
        mean[None, :], cov[None, :, :], z[None, :, :], valid[None, :], sig[None, :], lm, lsig,
        par, out_int[None, :m], out_int[None, m:], out_d2[None, :], out_mean, out_cov,
    )  # fmt: skip
    if n < 0:
        return FALLBACK
    if n == 0:
        return UNCHANGED
    for i in range(3):
        out_state[i] = out_mean[i, 0]
        for k in range(3):
            out_state[3 + 3 * i + k] = out_cov[i, k, 0]
    return UPDATED


@numba.njit(cache=True)
def correct_batch(mean, cov, z, valid, sig, lm, lsig, par, out_lm, out_st, out_d2, out_mean,
                  out_cov):  # fmt: skip
    """B filters (see :func:`_run`): FALLBACK if some filter needs the numpy path, else
    UPDATED."""
    n = _run(mean, cov, z, valid, sig, lm, lsig, par, out_lm, out_st, out_d2, out_mean, out_cov)
    return FALLBACK if n < 0 else UPDATED


@numba.njit(cache=True)
def compound_batch(mean, cov, step, out_mean, out_cov):
    """ekf._compound_one for B poses, mean (B, 3) and cov (B, 3, 3), and one step ``(Δx, Δy,
    Δθ, c00, c01, c02, c11, c12, c22)``: into out_mean (3, B) and out_cov (3, 3, B)."""
    xb, yb, tb = step[0], step[1], step[2]
    q00, q01, q02, q11, q12, q22 = step[3], step[4], step[5], step[6], step[7], step[8]
    for b in range(mean.shape[0]):
        xa, ya, ta = mean[b, 0], mean[b, 1], mean[b, 2]
        p00, p01, p02 = cov[b, 0, 0], cov[b, 0, 1], cov[b, 0, 2]
        p11, p12, p22 = cov[b, 1, 1], cov[b, 1, 2], cov[b, 2, 2]
        c, s = math.cos(ta), math.sin(ta)
        dx, dy = c * xb - s * yb, s * xb + c * yb
        r0 = p02 - dy * p22
        r1 = p12 + dx * p22
        cc, ss, cs = c * c, s * s, c * s
        cs_q01 = 2.0 * cs * q01
        out_mean[0, b] = xa + dx
        out_mean[1, b] = ya + dy
        out_mean[2, b] = _wrap(ta + tb)
        c00 = p00 - dy * (p02 + r0) + (cc * q00 - cs_q01 + ss * q11)
        c01 = p01 - dy * p12 + dx * r0 + (cs * (q00 - q11) + (cc - ss) * q01)
        c02 = r0 + (c * q02 - s * q12)
        c11 = p11 + dx * (p12 + r1) + (ss * q00 + cs_q01 + cc * q11)
        c12 = r1 + (s * q02 + c * q12)
        out_cov[0, 0, b], out_cov[0, 1, b], out_cov[0, 2, b] = c00, c01, c02
        out_cov[1, 0, b], out_cov[1, 1, b], out_cov[1, 2, b] = c01, c11, c12
        out_cov[2, 0, b], out_cov[2, 1, b], out_cov[2, 2, b] = c02, c12, p22 + q22
