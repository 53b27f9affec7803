"""Prototype (issue 14): the correlated part of the reading error as first-order Gauss–Markov
bias states of the filter, scored against MRCLAM's ground truth. Measured: docs/consistency.md.

The readings are ``z = h(x, l) + b + v``: ``v`` white (σ_w), ``b`` an exponentially correlated
bias (stationary σ_c, time constant τ; ``b(t + Δt) = e^{-Δt/τ} b(t) + w``, var w
``σ_c²(1 - e^{-2Δt/τ})``), appended to the pose state of the EKF (an augmented state;
Bar-Shalom, Li & Kirubarajan 2001 §8.2; Gelb 1974 §4.6): ``--per landmark`` a range and a
bearing bias per landmark (2L states), ``robot`` one of each for the robot's sensor (2),
``mixed`` a range bias per landmark and one bearing bias (L + 1). ``--consider``: the
Schmidt–Kalman filter (the biases' covariance carried, their gain zero). Everything else is
``relmap.filter.ekf.run``'s filter (signatures, χ² gate 0.99, one stacked Joseph update per time
stamp, one reading per landmark and time stamp); ``--check`` confirms that with σ_c → 0 it
gives the C++ filter's states (at inflation 1) to rounding.

``--factor-consider``: not a new filter but relmap's own (the σ-factor gain, its states to
rounding) with the covariance its gain gives under the Gauss–Markov model whose structure
(correlated share, τ) comes from the autocorrelation of its innovations and whose total σ is
the calibrated one (:func:`run_factor`, a consider analysis of the gain): does the correlation
model give the σ-factor filter an honest covariance?

Noise, without ground truth: the odometry's k, the clock and ν are those of
``relmap.filter.autocalibration.calibrate`` (what ``relmap localize`` runs; cached in ``--cache``);
then (default) the bias model's (σ_w, σ_c, τ) for range and bearing by maximum likelihood of
the run's innovations (the calibration's Student-t likelihood, ν fixed; coordinate ascent in
log scale from σ_w = σ_c = σ/√2, τ = 10 s), with ``--fit-k`` the odometry's k with them; or
``--acf``: the correlated share and τ from the autocorrelation of the calibrated filter's
innovations over time (:func:`innovation_acf`, :func:`structure`), the total σ and the k by
maximum likelihood. ``--fixed`` gives the six numbers instead. Diagnostics that read the
ground truth (never the method): ``--oracle SHARE TAU_R TAU_B`` (k and σ of
``relmap.app.localize.calibrate_mrclam`` on the same robot's truth), ``--residuals`` (the
structure of the reading errors against the truth), ``--sim SEEDS`` (the simulated robot of
tests/test_autocalibration.py with known Gauss–Markov biases: what the likelihood recovers).

Pure numpy/Python (slow but exact): between two time stamps with readings the odometry
steps are composed in the frame of the first one (their Jacobian product and summed noise),
which is the stepwise EKF's prediction exactly; the pose at every filter time, for scoring,
from the same compositions. Robot 0 is Plaza (range-only).

Run: ``python benchmarks/study_bias.py [--robots 0 1 2 3 4 5] [--per landmark|robot|mixed]
[--fit-k | --acf | --fixed ... | --oracle ...] [--consider]``, ``--factor-consider [--per ...]``,
``--residuals``, ``--sim 1 2``.
"""

from __future__ import annotations

import argparse
import math
import os
import pickle
import time
from pathlib import Path

import numpy as np

from relmap.app.localize import localize_mrclam, localize_plaza, score
from relmap.filter import autocalibration, ekf
from relmap.io.datasets import read_mrclam, read_plaza

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("RELMAP_DATA", ROOT.parent / "shared" / "data"))
#: The fits' default tolerance: a log-scale step of a factor 1.02.
LOG_1_02 = math.log(1.02)
CHI2_2_99 = 9.210340371976184
CHI2_1_99 = 6.6348966010212145


def wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


# ----------------------------------------------------------------------------- odometry
def compose(log: ekf.Log, p: ekf.NoiseParameters):
    """Per filter time k: the time index ``base[k]`` of the last reading event strictly
    before k (0 at the start), the pose displacement ``D[k]`` from the pose at ``base[k]`` to k
    in the frame of the base pose, and its noise ``Q[k]`` (same frame): the stepwise EKF's
    prediction composed (x_k = x_b ⊕ D_k, P_k = F P_b Fᵀ + R_b Q_k R_bᵀ)."""
    T = len(log.t)
    events = np.zeros(T, bool)
    events[np.unique(log.reading_index)] = True
    ks, kt, kts = float(p.k_s), float(p.k_theta), float(p.k_theta_s)
    base = np.zeros(T, np.int64)
    D = np.zeros((T, 3))
    Q = np.zeros((T, 3, 3))
    dx = dy = dth = 0.0
    q = [0.0] * 6  # q00 q01 q02 q11 q12 q22
    b = 0
    mot = log.motion
    for k in range(T - 1):
        if events[k]:
            b, dx, dy, dth, q = k, 0.0, 0.0, 0.0, [0.0] * 6
        ds, dt_ = float(mot[k, 0]), float(mot[k, 1])
        a, bb = math.cos(0.5 * dt_), math.sin(0.5 * dt_)
        s00 = ks * abs(ds)
        s11 = kt * abs(dt_) + kts * abs(ds)
        e, f = -0.5 * ds * bb, 0.5 * ds * a
        c00 = a * a * s00 + e * e * s11
        c01 = a * bb * s00 + e * f * s11
        c11 = bb * bb * s00 + f * f * s11
        c02, c12 = e * s11, f * s11
        c, s = math.cos(dth), math.sin(dth)
        bx, by = ds * a, ds * bb
        ddx, ddy = c * bx - s * by, s * bx + c * by
        # Qc <- F Qc Fᵀ, F = [[1,0,-ddy],[0,1,ddx],[0,0,1]]
        q00, q01, q02, q11, q12, q22 = q
        n02 = q02 - ddy * q22
        n12 = q12 + ddx * q22
        n00 = q00 - 2 * ddy * q02 + ddy * ddy * q22
        n01 = q01 + ddx * q02 - ddy * q12 - ddy * ddx * q22
        n11 = q11 + 2 * ddx * q12 + ddx * ddx * q22
        # + G C Gᵀ, G = blkdiag(R(dth), 1)
        g00 = c * c00 - s * c01
        g01 = c * c01 - s * c11
        g02 = c * c02 - s * c12
        g10 = s * c00 + c * c01
        g11 = s * c01 + c * c11
        g12 = s * c02 + c * c12
        q = [n00 + g00 * c - g01 * s, n01 + g00 * s + g01 * c, n02 + g02,
             n11 + g10 * s + g11 * c, n12 + g12, q22 + s11]  # fmt: skip
        dx, dy, dth = dx + ddx, dy + ddy, dth + dt_
        base[k + 1] = b
        D[k + 1] = (dx, dy, dth)
        q00, q01, q02, q11, q12, q22 = q
        Q[k + 1] = ((q00, q01, q02), (q01, q11, q12), (q02, q12, q22))
    return base, D, Q


def compose_parts(log):
    """``compose`` with Q split into its parts of unit k_s, k_theta, k_theta_s (Q is linear in
    them): (base, D, (Q1, Q2, Q3))."""
    parts = [compose(log, ekf.NoiseParameters(*e, 0.0)) for e in np.eye(3)]
    return parts[0][0], parts[0][1], tuple(q[2] for q in parts)


def with_k(parts, k):
    base, D, Qs = parts
    return base, D, k[0] * Qs[0] + k[1] * Qs[1] + k[2] * Qs[2]


def apply(x, P, D, Q):
    """``x ⊕ D`` and ``F P Fᵀ + R Q Rᵀ`` (broadcast over leading axes of D, Q)."""
    c, s = np.cos(x[..., 2]), np.sin(x[..., 2])
    wx = c * D[..., 0] - s * D[..., 1]
    wy = s * D[..., 0] + c * D[..., 1]
    xn = np.stack([x[..., 0] + wx, x[..., 1] + wy, wrap(x[..., 2] + D[..., 2])], axis=-1)
    F = np.zeros((*D.shape[:-1], 3, 3))
    F[..., 0, 0] = F[..., 1, 1] = F[..., 2, 2] = 1.0
    F[..., 0, 2], F[..., 1, 2] = -wy, wx
    R = np.zeros_like(F)
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return xn, F, R


# ----------------------------------------------------------------------------- the filter
class Bias:
    """The reading-error model: white σ_w and Gauss–Markov (σ_c, τ) for range and bearing;
    ``per``: "landmark" (a bias per landmark) or "robot" (one bias)."""

    consider = False

    def __init__(self, sw, sc, tau, per="landmark"):
        self.sw = np.asarray(sw, float)  # (d,)
        self.sc = np.asarray(sc, float)
        self.tau = np.asarray(tau, float)
        self.per = per

    def __repr__(self):
        f = lambda a: "/".join(f"{v:.4g}" for v in a)  # noqa: E731
        return (f"Bias(σw {f(self.sw)}, σc {f(self.sc)}, τ {f(self.tau)} s, per {self.per}"
                f"{', considered' if self.consider else ''})")


def layout(bias: Bias, L, d):
    """The bias states of the augmented state (pose first): ``ir[l]``, ``ib[l]`` the state
    index of landmark l's range and bearing bias, the state's size n, and per bias state its
    stationary variance σ_c² and τ (n - 3,)."""
    if bias.per == "landmark":
        ir, ib = 3 + d * np.arange(L), 3 + d * np.arange(L) + 1
    elif bias.per == "robot":
        ir, ib = np.full(L, 3), np.full(L, 4)
    else:  # "mixed": range per landmark, bearing per robot
        ir, ib = 3 + np.arange(L), np.full(L, 3 + L)
    n = 3 + int(max(ir.max(), ib.max() if d == 2 else 0)) - 2
    sc2, tau = np.zeros(n), np.ones(n)
    sc2[ir], tau[ir] = bias.sc[0] ** 2, bias.tau[0]
    if d == 2:
        sc2[ib], tau[ib] = bias.sc[1] ** 2, bias.tau[1]
    return ir, ib, n, sc2[3:], tau[3:]


def pose_reading(x, landmark, z, d):
    """A reading's innovation ``z - h(x)`` (d,) at the pose ``x`` (sensor at the robot, the
    bearing wrapped) and its Jacobian in the pose (d, 3) (lecture Eq. 24's H)."""
    dx, dy = landmark[0] - x[0], landmark[1] - x[1]
    q = dx * dx + dy * dy
    r = math.sqrt(q)
    H = np.array([(-dx / r, -dy / r, 0.0), (dy / q, -dx / q, -1.0)])[:d]
    y = np.array([z[0] - r, wrap(z[1] - (math.atan2(dy, dx) - x[2])) if d == 2 else 0.0])
    return y[:d], H


def augmented(Hx, n, ir, ib, lk, d):
    """``H`` of the augmented state (d, n): the pose's and 1 at landmark lk's bias states."""
    H = np.zeros((d, n))
    H[:, :3] = Hx
    H[0, ir[lk]] = 1.0
    if d == 2:
        H[1, ib[lk]] = 1.0
    return H


def predict_augmented(P, F, RQR, phi, sc2):
    """The augmented covariance ``P`` [pose; biases] (n, n) predicted in place: the pose by its
    Jacobian ``F`` and noise ``RQR``, each bias decayed by ``phi`` towards its stationary
    variance ``sc2`` (first-order Gauss–Markov)."""
    P[:3, 3:] = F @ P[:3, 3:] * phi
    P[3:, :3] = P[:3, 3:].T
    P[:3, :3] = F @ P[:3, :3] @ F.T + RQR
    P[3:, 3:] = P[3:, 3:] * np.outer(phi, phi) + np.diag(sc2 * (1 - phi**2))


def at_every_time(comp, start, ev_idx, post_x, post_P):
    """The pose and its covariance at every filter time, each predicted (composed steps) from
    its base event's posterior ``post_x``, ``post_P`` (events at the times ``ev_idx``), or from
    the start where the base is no event."""
    base, D, Q = comp
    ev_of = np.full(len(base), -1, np.int64)
    ev_of[ev_idx] = np.arange(len(ev_idx))
    j = ev_of[base]
    bx = np.where(j[:, None] >= 0, post_x[np.maximum(j, 0)], start.mean)
    bP = np.where(j[:, None, None] >= 0, post_P[np.maximum(j, 0)], start.cov)
    xs, F, R = apply(bx, None, D, Q)
    Ps = F @ bP @ np.swapaxes(F, -1, -2) + R @ Q @ np.swapaxes(R, -1, -2)
    xs[ev_idx], Ps[ev_idx] = post_x, post_P  # the posteriors at the event times
    return xs, Ps


def run_bias(log, lm, p, start, bias: Bias, comp, *, d=2, keep_all=True, gate2=None):
    """The augmented-state EKF over ``log`` (signatures association, χ² gate, one stacked
    Joseph update per time stamp, one reading per landmark and time). Returns dict with
    loglik inputs (y, S, status per reading) and, with ``keep_all``, mean/cov at every time."""
    _, D, Q = comp
    L = len(lm)
    ir, ib, n, sc2, tau = layout(bias, L, d)
    x = np.zeros(n)
    x[:3] = start.mean
    P = np.zeros((n, n))
    P[:3, :3] = start.cov
    P[3:, 3:] = np.diag(sc2)
    Rw = np.diag(bias.sw**2)
    gate2 = gate2 or (CHI2_2_99 if d == 2 else CHI2_1_99)
    t = log.t
    ri = np.asarray(log.reading_index)
    z = np.asarray(log.z, float).reshape(len(ri), -1)
    sig = np.asarray(log.signature)
    M = len(ri)
    y_out = np.full((M, d), np.nan)
    S_out = np.full((M, d, d), np.nan)
    status = np.full(M, int(ekf.Status.ABSENT), np.int8)
    ev_idx, ev_lo = np.unique(ri, return_index=True)
    ev_hi = np.append(ev_lo[1:], M)
    post_x = np.zeros((len(ev_idx), 3))
    post_P = np.zeros((len(ev_idx), 3, 3))
    last_t = t[0]
    for e, (k, lo, hi) in enumerate(zip(ev_idx, ev_lo, ev_hi, strict=True)):
        # predict the pose from the last event (composed steps) and decay the biases
        xn, F, R = apply(x[:3], None, D[k], Q[k])
        x[:3] = xn
        phi = np.exp(-(t[k] - last_t) / tau)
        last_t = t[k]
        x[3:] *= phi
        predict_augmented(P, F, R @ Q[k] @ R.T, phi, sc2)
        # readings of this time stamp
        best = {}
        c, s = math.cos(x[2]), math.sin(x[2])
        for i in range(lo, hi):
            lk = int(sig[i])
            if lk < 0 or lk >= L:
                status[i] = int(ekf.Status.UNKNOWN)
                continue
            yv, Hx = pose_reading(x, lm[lk], z[i], d)
            H = augmented(Hx, n, ir, ib, lk, d)
            yv[0] -= x[ir[lk]]
            if d == 2:
                yv[1] = wrap(yv[1] - x[ib[lk]])
            HP = H @ P
            S = HP @ H.T + Rw
            d2 = float(yv @ np.linalg.solve(S, yv))
            y_out[i], S_out[i] = yv, S
            if d2 > gate2:
                status[i] = int(ekf.Status.GATED)
                continue
            if lk in best and best[lk][0] <= d2:
                status[i] = int(ekf.Status.LOST)
                continue
            if lk in best:
                status[best[lk][1]] = int(ekf.Status.LOST)
            best[lk] = (d2, i, H, yv)
        if best:
            idx = [v[1] for v in best.values()]
            for i in idx:
                status[i] = int(ekf.Status.USED)
            H = np.concatenate([v[2] for v in best.values()])
            yv = np.concatenate([v[3] for v in best.values()])
            m = len(idx)
            Rs = np.kron(np.eye(m), Rw)
            PHt = P @ H.T
            S = H @ PHt + Rs
            K = np.linalg.solve(S, PHt.T).T
            if bias.consider:  # Schmidt-Kalman: the biases are considered, not estimated
                K[3:] = 0.0
            x = x + K @ yv
            x[2] = wrap(x[2])
            IKH = np.eye(n) - K @ H
            P = IKH @ P @ IKH.T + K @ Rs @ K.T
            P = 0.5 * (P + P.T)
        post_x[e] = x[:3]
        post_P[e] = P[:3, :3]
        del c, s
    out = {"y": y_out, "S": S_out, "status": status}
    if keep_all:
        out["mean"], out["cov"] = at_every_time(comp, start, ev_idx, post_x, post_P)
    return out


def run_factor(log, lm, p, start, bias: Bias, comp, *, d=2):
    """relmap's σ-factor filter (signatures, its χ² gate on ``R``, the gain and Joseph update
    with ``inflation² R``: :func:`relmap.filter.ekf.run`'s states) and, for the same gain, the
    covariance of its error under the Gauss–Markov reading model ``bias`` (the gain's
    *consider* analysis: the augmented error [pose; biases] through ``(I - K_a H_a)`` with
    ``K_a = [K; 0]``, the biases decaying between time stamps). Returns the filter's mean and
    covariance and the considered covariance at every filter time."""
    _, D, Q = comp
    L = len(lm)
    ir, ib, n, sc2, tau = layout(bias, L, d)
    c2 = float(p.inflation) ** 2
    var = np.array([float(p.sigma_r) ** 2, float(p.sigma_b) ** 2])[:d]
    x = np.asarray(start.mean, float).copy()
    Pc = np.asarray(start.cov, float).copy()
    Pa = np.zeros((n, n))
    Pa[:3, :3] = Pc
    Pa[3:, 3:] = np.diag(sc2)
    gate2 = CHI2_2_99 if d == 2 else CHI2_1_99
    t = log.t
    ri = np.asarray(log.reading_index)
    z = np.asarray(log.z, float).reshape(len(ri), -1)
    sig = np.asarray(log.signature)
    ev_idx, ev_lo = np.unique(ri, return_index=True)
    ev_hi = np.append(ev_lo[1:], len(ri))
    post = np.zeros((len(ev_idx), 3)), np.zeros((len(ev_idx), 3, 3)), np.zeros((len(ev_idx), 3, 3))
    last_t = t[0]
    for e, (k, lo, hi) in enumerate(zip(ev_idx, ev_lo, ev_hi, strict=True)):
        x, F, R = apply(x, None, D[k], Q[k])
        RQR = R @ Q[k] @ R.T
        Pc = F @ Pc @ F.T + RQR
        phi = np.exp(-(t[k] - last_t) / tau)
        last_t = t[k]
        predict_augmented(Pa, F, RQR, phi, sc2)
        best = {}
        for i in range(lo, hi):
            lk = int(sig[i])
            if not 0 <= lk < L:
                continue
            yv, Hx = pose_reading(x, lm[lk], z[i], d)
            d2 = float(yv @ np.linalg.solve(Hx @ Pc @ Hx.T + np.diag(var), yv))
            if d2 > gate2 or (lk in best and best[lk][0] <= d2):
                continue
            best[lk] = (d2, Hx, augmented(Hx, n, ir, ib, lk, d), yv)
        if best:
            Hx = np.concatenate([v[1] for v in best.values()])
            Ha = np.concatenate([v[2] for v in best.values()])
            yv = np.concatenate([v[3] for v in best.values()])
            m = len(best)
            Rc = np.kron(np.eye(m), np.diag(c2 * var))
            K = np.linalg.solve(Hx @ Pc @ Hx.T + Rc, Hx @ Pc).T
            x = x + K @ yv
            x[2] = wrap(x[2])
            IKH = np.eye(3) - K @ Hx
            Pc = IKH @ Pc @ IKH.T + K @ Rc @ K.T
            Ka = np.zeros((n, len(yv)))
            Ka[:3] = K
            IKHa = np.eye(n) - Ka @ Ha
            Rw = np.kron(np.eye(m), np.diag(bias.sw**2))
            Pa = IKHa @ Pa @ IKHa.T + Ka @ Rw @ Ka.T
            Pa = 0.5 * (Pa + Pa.T)
        post[0][e], post[1][e], post[2][e] = x, Pc, Pa[:3, :3]
    xs, Ps = at_every_time(comp, start, ev_idx, post[0], post[1])
    return xs, Ps, at_every_time(comp, start, ev_idx, post[0], post[2])[1]


def loglik(out, nu, d=2):
    """The autocalibration's likelihood of the bias filter's innovations, each at the prior of
    its time stamp (this filter does not condition a reading on those before it)."""
    y = out["y"] if d == 2 else out["y"][:, 0]
    S = out["S"] if d == 2 else out["S"][:, 0, 0]
    tr = ekf.Trace(None, None, None, y, S, None, out["status"], None,
                   None, None, None, None, None, None, y, S)  # fmt: skip
    return float(autocalibration.loglik(tr, nu))


# ----------------------------------------------------------------------------- fitting
def ascend(f, x, tol, max_evals, *, keep_going):
    """Coordinate ascent of ``f`` from ``x`` in steps of log 2, halved whenever no move gains,
    until below ``tol`` or ``max_evals`` evaluations; ``keep_going``: a move that gains is
    repeated while it gains. Returns ``(x, f(x), evaluations)``."""
    best, step, evals = f(x), math.log(2.0), 1

    def moved(x, j, sgn):
        xt = x.copy()
        xt[j] += sgn * step
        return xt

    while step > tol and evals < max_evals:
        gained = False
        for j in range(len(x)):
            for sgn in (1, -1):
                xt = moved(x, j, sgn)
                v = f(xt)
                evals += 1
                if v > best + 1e-6:
                    x, best, gained = xt, v, True
                    while keep_going:  # the same way while it gains
                        xt = moved(x, j, sgn)
                        v = f(xt)
                        evals += 1
                        if not v > best + 1e-6:
                            break
                        x, best = xt, v
                    break
        if not gained:
            step /= 2
    return x, best, evals


def fit_bias(log, lm, p, start, comp, nu, sigma, d=2, per="landmark", iters=30, parts=None,
             x0=None, tol=LOG_1_02):
    """Maximum likelihood of (σ_w, σ_c, τ) for range (and bearing) by coordinate ascent in
    log scale, from σ_w = σ_c = σ/√2 and τ = 10 s (σ the calibration's reading σ)."""
    x = np.log(np.concatenate([np.asarray(sigma[:d]) / np.sqrt(2),
                               np.asarray(sigma[:d]) / np.sqrt(2), np.full(d, 10.0)]))  # fmt: skip
    if x0 is not None:
        x = np.log(np.asarray(x0, float))
    if parts is not None:  # the odometry's k too
        x = np.concatenate([x, np.log([float(p.k_s), float(p.k_theta), float(p.k_theta_s)])])

    def f(v):
        v = np.exp(v)
        b = Bias(v[:d], v[d:2 * d], v[2 * d:3 * d], per)
        c = comp if parts is None else with_k(parts, v[3 * d:])
        return loglik(run_bias(log, lm, p, start, b, c, d=d, keep_all=False), nu, d)

    x, best, evals = ascend(f, x, tol, 400, keep_going=True)
    v = np.exp(x)
    return Bias(v[:d], v[d:2 * d], v[2 * d:3 * d], per), best, evals, v[3 * d:]


#: Time lags (s) of the innovations' autocorrelation the structure is fitted to, and the half
#: width of their bins (a fraction of the lag).
ACF_LAGS = (0.25, 0.5, 1.0, 2.0, 5.0, 10.0)
ACF_BIN = 0.3


def innovation_acf(trace, t, d=2):
    """Autocorrelation of the normalized innovations of used readings of one landmark
    ``lag`` s apart (±ACF_BIN·lag), per component, clipped at ±3 robust σ:
    (d, len(ACF_LAGS))."""
    used = np.asarray(trace.status) == ekf.Status.USED
    y, S = np.asarray(trace.y), np.asarray(trace.S)
    if y.ndim == 1:
        y, S = y[:, None], S[:, None, None]
    tt, ll = np.asarray(t)[used], np.asarray(trace.landmark)[used]
    i, k = np.triu_indices(len(tt), 1)
    dt = tt[k] - tt[i]
    keep = (ll[i] == ll[k]) & (dt <= max(ACF_LAGS) * (1 + ACF_BIN))
    i, k, dt = i[keep], k[keep], dt[keep]
    out = np.zeros((d, len(ACF_LAGS)))
    for j in range(d):
        u = y[used, j] / np.sqrt(S[used, j, j])
        s = 1.4826 * np.median(np.abs(u - np.median(u)))
        u = np.clip(u / s, -3, 3)
        u = u - u.mean()
        for m, lag in enumerate(ACF_LAGS):
            sel = np.abs(dt - lag) <= ACF_BIN * lag
            out[j, m] = np.mean(u[i[sel]] * u[k[sel]]) / np.var(u)
    return out


def structure(acf):
    """``ρ(Δt) = a e^{-Δt/τ}`` fitted to each row of ``acf`` (least squares on log ρ over the
    lags with ρ > 0.05; a in [0.05, 0.98], τ in [0.5, 300] s): the correlated share a and τ."""
    lags = np.asarray(ACF_LAGS)
    a_out, tau_out = [], []
    for row in acf:
        ok = row > 0.05
        if ok.sum() < 2:
            a_out.append(0.05)
            tau_out.append(0.5)
            continue
        slope, icpt = np.polyfit(lags[ok], np.log(row[ok]), 1)
        tau_out.append(float(np.clip(-1.0 / slope if slope < 0 else 300.0, 0.5, 300.0)))
        a_out.append(float(np.clip(np.exp(icpt), 0.05, 0.98)))
    return np.array(a_out), np.array(tau_out)


def fit_total(log, lm, p, start, parts, nu, share, tau, per, d=2, tol=LOG_1_02):
    """With the structure (correlated share, τ) fixed: maximum likelihood of the readings'
    total σ and the odometry's k (coordinate ascent in log scale, from the calibration's)."""
    sig = [float(p.sigma_r), float(p.sigma_b)][:d]
    x = np.log([*sig, float(p.k_s), float(p.k_theta), max(float(p.k_theta_s), 1e-6)])

    def bias(v):
        s = np.asarray(v[:d])
        return Bias(s * np.sqrt(1 - share), s * np.sqrt(share), tau, per)

    def f(v):
        v = np.exp(v)
        c = with_k(parts, v[d:])
        return loglik(run_bias(log, lm, p, start, bias(v), c, d=d, keep_all=False), nu, d)

    x, best, evals = ascend(f, x, tol, 300, keep_going=False)
    v = np.exp(x)
    return bias(v), v[d:], best, evals


# ----------------------------------------------------------------------------- driver
def calibrated(robot, cache: Path):
    """The default `relmap localize` calibration and score of a robot (0: Plaza), cached."""
    f = cache / f"cal_{robot}.pkl"
    if f.exists():
        return pickle.loads(f.read_bytes())
    if robot == 0:
        data = read_plaza(DATA / "landmarks" / "plaza2")
        loc = localize_plaza(data)
    else:
        data = read_mrclam(DATA / "landmarks" / "mrclam6")
        loc = localize_mrclam(data, robot)
    cal = loc.calibration
    keep = {"cal": cal._replace(trace=None), "score": loc.score, "t": loc.t, "truth": loc.truth,
            "landmarks": loc.landmarks, "start_mean": loc.estimate.mean[0]}  # fmt: skip
    cache.mkdir(parents=True, exist_ok=True)
    f.write_bytes(pickle.dumps(keep))
    return keep


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--per", choices=("landmark", "robot", "mixed"), default="landmark")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/relmap_bias_cache"))
    ap.add_argument("--check", action="store_true")
    ap.add_argument("--fit-k", action="store_true", help="fit the odometry's k with the bias")
    ap.add_argument("--start", type=float, nargs="*", default=None,
                    help="σw_r σw_b σc_r σc_b τ_r τ_b to start the fit from")
    ap.add_argument("--fixed", type=float, nargs="*", default=None,
                    help="σw_r σw_b σc_r σc_b τ_r τ_b instead of the ML fit")
    ap.add_argument("--k", type=float, nargs=3, default=None, help="odometry k_s k_θ k_θs")
    ap.add_argument("--consider", action="store_true", help="Schmidt-Kalman (bias not estimated)")
    ap.add_argument("--acf", action="store_true",
                    help="structure from the innovations' autocorrelation, σ and k by ML")
    ap.add_argument("--residuals", action="store_true", help="ground-truth error structure")
    ap.add_argument("--factor-consider", action="store_true",
                    help="relmap's σ-factor filter with its error covariance under the "
                         "Gauss–Markov model of the innovations' autocorrelation")
    ap.add_argument("--oracle", type=float, nargs=3, default=None,
                    metavar=("SHARE", "TAU_R", "TAU_B"),
                    help="diagnostic: k and σ from the robot's ground truth, white share, τ")
    ap.add_argument("--scale", type=float, default=1.0,
                    help="--fixed: every σ times this, the χ² gate times its square")
    ap.add_argument("--kscale", type=float, default=1.0, help="--oracle: the truth's k times this")
    ap.add_argument("--sim", type=int, nargs="*", default=None, help="simulate these seeds")
    ap.add_argument("--steps", type=int, default=8000)
    a = ap.parse_args()
    Bias.consider = a.consider
    if a.residuals:
        residuals(a.robots)
        return
    if a.sim is not None:
        # the simulation's white σ (0.1 m, 0.02 rad) plus a bias of σ_c 0.15 m, 0.02 rad, τ 20 s
        sim(a.sim, a.steps, Bias([0.1, 0.02], [0.15, 0.02], [20.0, 20.0]), a.fit_k)
        return
    from relmap.app.localize import _start

    for robot in a.robots:
        t0 = time.time()
        c = calibrated(robot, a.cache)
        cal = c["cal"]
        d = 1 if robot == 0 else 2
        if robot == 0:
            data = read_plaza(DATA / "landmarks" / "plaza2")
        else:
            data = read_mrclam(DATA / "landmarks" / "mrclam6")
        rec = recording(data, robot)
        log = rec.log(*cal.clock)
        assert np.allclose(log.t, c["t"]), "log differs from the localization's"
        p = cal.parameters
        start = _start(c["truth"][0])
        comp = compose(log, p)
        lm = c["landmarks"]
        s0 = c["score"]
        print(f"robot {robot}: calibrated (inflation {cal.inflation:.2f}, ν {cal.nu:.1f}): "
              f"RMSE {s0.rmse_position:.3f} cov90 {s0.coverage_90:.2f} ANEES {s0.anees:.2f}",
              flush=True)  # fmt: skip
        sigma = (float(p.sigma_r), float(p.sigma_b))
        if a.check:  # the white model (σ_c → 0) is the C++ filter at inflation 1
            w = run_bias(log, lm, p, start, Bias(sigma[:d], [1e-9] * d, [10.0] * d), comp, d=d)
            tr = ekf.run(log, lm, p._replace(inflation=1.0), start=start,
                         landmark_signatures=np.arange(len(lm)),
                         sensor="range_only" if d == 1 else "range_bearing")  # fmt: skip
            print(f"  check: max |Δmean| {np.abs(w['mean'] - tr.mean).max():.2e}, max |Δcov| "
                  f"{np.abs(w['cov'] - tr.cov).max():.2e}, status equal "
                  f"{(w['status'] == tr.status).mean():.4f}", flush=True)  # fmt: skip
        if a.k is not None:
            p = p._replace(k_s=a.k[0], k_theta=a.k[1], k_theta_s=a.k[2])
            comp = compose(log, p)
        if a.oracle is not None:  # ground truth's noise: a diagnostic, not the method
            from relmap.app.localize import calibrate_mrclam

            g = calibrate_mrclam(data, robot)
            o, f = g.odometry, a.kscale
            p = p._replace(k_s=f * o.k_s, k_theta=f * o.k_theta, k_theta_s=f * o.k_theta_s)
            comp = compose(log, p)
            sh, tr, tb = a.oracle
            sg = np.array([g.sigma_range, g.sigma_bearing])
            a.fixed = [*(sg * np.sqrt(sh)), *(sg * np.sqrt(1 - sh)), tr, tb]
        if a.factor_consider:  # the σ-factor gain kept; its covariance under the GM model
            tr = ekf.run(log, lm, p, start=start, landmark_signatures=np.arange(len(lm)),
                         sensor="range_only" if d == 1 else "range_bearing")  # fmt: skip
            acf = innovation_acf(tr, log.t[log.reading_index], d)
            share, tau = structure(acf)
            sg = np.asarray(sigma[:d])
            b = Bias(sg * np.sqrt(1 - share), sg * np.sqrt(share), tau, a.per)
            mean, Pc, Pa = run_factor(log, lm, p, start, b, comp, d=d)
            from relmap.uncertain.at import AT

            sc, sa = score(AT(mean, Pc), c["truth"]), score(AT(mean, Pa), c["truth"])
            print("  innovation ACF at " + ", ".join(f"{v:g}" for v in ACF_LAGS) + " s: "
                  + "; ".join(" ".join(f"{v:.2f}" for v in row) for row in acf))
            print(f"  {b}; |Δmean| vs relmap {np.abs(mean - tr.mean).max():.1e}, |ΔP| "
                  f"{np.abs(Pc - tr.cov).max():.1e}\n  filter's P: {sc.rmse_position:.3f}/"
                  f"{sc.coverage_90:.2f}/{sc.anees:.2f}; considered: {sa.rmse_position:.3f}/"
                  f"{sa.coverage_90:.2f}/{sa.anees:.2f}; {time.time() - t0:.0f} s", flush=True)  # fmt: skip
            continue
        if a.acf:  # structure from the innovations' autocorrelation, the rest by ML
            tr = ekf.run(log, lm, p, start=start, landmark_signatures=np.arange(len(lm)),
                         sensor="range_only" if d == 1 else "range_bearing")  # fmt: skip
            acf = innovation_acf(tr, log.t[log.reading_index], d)
            share, tau = structure(acf)
            print("  innovation ACF at " + ", ".join(f"{v:g}" for v in ACF_LAGS) + " s: "
                  + "; ".join(" ".join(f"{v:.2f}" for v in row) for row in acf)
                  + f" → correlated share {np.round(share, 2)}, τ {np.round(tau, 1)} s")
            parts = compose_parts(log)
            b, k, ll, ev = fit_total(log, lm, p, start, parts, cal.nu, share, tau, a.per, d=d)
            comp = with_k(parts, k)
            print(f"  k fitted {np.round(k, 5)} (calibrated {float(p.k_s):.4g} "
                  f"{float(p.k_theta):.4g} {float(p.k_theta_s):.4g}); {ev} filters")  # fmt: skip
        elif a.fixed is not None:
            v = np.asarray(a.fixed)
            b = Bias(a.scale * v[:d], a.scale * v[d:2 * d], v[2 * d:], a.per)
            gate = (CHI2_1_99 if d == 1 else CHI2_2_99) * a.scale**2
            ll = loglik(run_bias(log, lm, p, start, b, comp, d=d, keep_all=False, gate2=gate),
                        cal.nu, d)  # fmt: skip
        else:
            parts = compose_parts(log) if a.fit_k else None
            b, ll, ev, k = fit_bias(log, lm, p, start, comp, cal.nu, sigma, d=d, per=a.per,
                                    parts=parts, x0=a.start)  # fmt: skip
            if a.fit_k:
                comp = with_k(parts, k)
                print(f"  k fitted {k} (calibrated {float(p.k_s):.4g} {float(p.k_theta):.4g} "
                      f"{float(p.k_theta_s):.4g})")  # fmt: skip
        gate = (CHI2_1_99 if d == 1 else CHI2_2_99) * (a.scale**2 if a.fixed else 1.0)
        out = run_bias(log, lm, p, start, b, comp, d=d, gate2=gate)
        from relmap.uncertain.at import AT

        s = score(AT(out["mean"], out["cov"]), c["truth"])
        used = int((out["status"] == 0).sum())
        print(f"  bias model {b} (ll {ll}): RMSE {s.rmse_position:.3f} cov90 "
              f"{s.coverage_90:.2f} ANEES {s.anees:.2f}; used {used}/{len(out['status'])}; "
              f"{time.time() - t0:.0f} s", flush=True)  # fmt: skip


def sim(seeds, steps, true: Bias, fit_k: bool) -> None:
    """The simulated robot of tests/test_autocalibration.py with Gauss–Markov reading biases
    per landmark: ML of (σ_w, σ_c, τ) (and the odometry's k with ``fit_k``) against the
    simulated ones, and the NEES of the bias filter at the fitted and at the simulated noise
    against the filter without bias states at the total σ."""
    import sys

    sys.path.insert(0, str(ROOT))
    from relmap.uncertain.at import AT
    from tests.filter.test_autocalibration import LANDMARKS, NOISE, simulate, start

    for seed in seeds:
        rec, truth = simulate(seed, steps=steps)
        rng = np.random.default_rng(1000 + seed)
        L = len(LANDMARKS)
        bias = np.zeros((L, 2))
        last = np.full(L, -np.inf)
        z = np.array(rec.z)
        for i, (t, lk) in enumerate(zip(rec.reading_t, rec.signature, strict=True)):
            phi = np.exp(-(t - last[lk]) / true.tau)  # 0 at a landmark's first reading
            bias[lk] = phi * bias[lk] + np.sqrt(1 - phi**2) * true.sc * rng.normal(size=2)
            last[lk] = t
            z[i] = z[i] + bias[lk]  # the simulation's white errors are σ_w = (0.1, 0.02)
        rec = rec._replace(z=z)
        log = rec.log()
        p = ekf.NoiseParameters(NOISE.k_s, NOISE.k_theta, NOISE.k_theta_s, 0.1, 0.02)
        comp = compose(log, p)
        st = start(0.0)
        parts = compose_parts(log) if fit_k else None
        b, ll, ev, k = fit_bias(log, LANDMARKS, p, st, comp, np.inf, np.hypot(true.sw, true.sc),
                                parts=parts, tol=math.log(1.05))  # fmt: skip
        tt = truth  # at the odometry times = the log's times (readings share them)
        assert len(log.t) == len(tt)

        def nees(bb, c=comp, log=log, p=p, st=st, tt=tt):
            o = run_bias(log, LANDMARKS, p, st, bb, c)
            s = score(AT(o["mean"], o["cov"]), tt)
            return s, loglik(o, np.inf)

        s_fit, _ = nees(b, comp if not fit_k else with_k(parts, k))
        s_true, ll_true = nees(true)
        white = Bias(np.hypot(true.sw, true.sc), [1e-9, 1e-9], [1.0, 1.0])
        s_white, _ = nees(white)
        print(f"seed {seed}: simulated {true}\n  fitted    {b} k {k} (ll {ll:.2f}, simulated "
              f"{ll_true:.2f}, {ev} filters)")  # fmt: skip
        for name, s in (("fitted", s_fit), ("simulated", s_true), ("no bias states", s_white)):
            print(f"  {name}: RMSE {s.rmse_position:.3f} coverage_90 {s.coverage_90:.2f} "
                  f"ANEES {s.anees:.2f}", flush=True)  # fmt: skip


def residuals(robots) -> None:
    """Diagnostic, ground truth: the structure of the reading errors (reading minus the
    prediction from the true pose, robust-clipped): per robot the share of their variance that
    is a per-landmark constant, the correlation of errors of one landmark ``lag`` s apart after
    removing it, and the correlation of errors of *different* landmarks read within 0.3 s."""
    from relmap.app.localize import _robot_log
    from relmap.models.range_bearing import RangeBearingSensor

    data = read_mrclam(DATA / "landmarks" / "mrclam6")
    sens = RangeBearingSensor(0.0, 0.0)
    lags = (0.25, 0.5, 2.0, 5.0, 10.0, 20.0, 60.0)
    for robot in robots:
        log = _robot_log(data, robot)
        lm, t = data.landmark_index(log.meas_subject), log.meas_t
        keep = (lm >= 0) & (t >= log.truth_t[0]) & (t <= log.truth_t[-1])
        pr = sens.predict(log.truth_at(t[keep]), data.landmark_xy[lm[keep]])
        r = np.column_stack([log.meas_range[keep], log.meas_bearing[keep]]) - pr
        r[:, 1] = wrap(r[:, 1])
        tt, ll = t[keep], lm[keep]
        i, k = np.triu_indices(len(tt), 1)
        dt = tt[k] - tt[i]
        near = dt <= max(lags) * 1.3
        i, k, dt = i[near], k[near], dt[near]
        for j, name in enumerate(("range", "bearing")):
            e = r[:, j]
            med = np.median(e)
            s = 1.4826 * np.median(np.abs(e - med))
            e = np.clip(e - med, -3 * s, 3 * s)
            means = np.array([e[ll == k].mean() for k in range(ll.max() + 1)] if len(e) else [])
            share = np.var(means[ll]) / np.var(e)
            e2 = e - means[ll]
            same = ll[i] == ll[k]
            ac = []
            for lag in lags:
                sel = same & (dt >= 0.7 * lag) & (dt <= 1.3 * lag)
                ac.append(np.mean(e2[i][sel] * e2[k][sel]) / np.var(e2))
            other = (~same) & (dt <= 0.3)
            cx = np.corrcoef(e[i][other], e[k][other])[0, 1]
            print(f"robot {robot} {name}: σ {np.std(e):.4f}, per-landmark constant share "
                  f"{share:.2f}; same landmark, lag " + ", ".join(
                      f"{lag:g} s {a:.2f}" for lag, a in zip(lags, ac, strict=True))
                  + f"; other landmarks ≤ 0.3 s {cx:.2f}", flush=True)  # fmt: skip


def recording(data, robot, associate="signatures"):
    """The autocalibration Recording of `relmap localize` (as localize_mrclam builds it for
    ``associate``: without signatures every reading is offered)."""
    import relmap.app.localize as L

    captured = {}

    def grab(what, rec, *args, **kw):
        captured["rec"] = rec
        raise StopIteration

    orig = L._localization
    L._localization = grab
    try:
        if robot == 0:
            L.localize_plaza(data, associate=associate)
        else:
            L.localize_mrclam(data, robot, associate=associate)
    except StopIteration:
        pass
    finally:
        L._localization = orig
    return captured["rec"]


if __name__ == "__main__":
    main()
