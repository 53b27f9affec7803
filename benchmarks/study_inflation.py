"""How the whitening's inflation decides the filter's consistency, and how well the likelihood
recovers a simulated robot's noise: two diagnostics of ``relmap.filter.autocalibration`` (issue 14).

1. ``mrclam`` (the default): for each MRCLAM robot of ``../shared/data/landmarks/mrclam6``,
   the autocalibration of ``relmap localize`` (no ground truth), then the same filter with the
   update's σ factor (``NoiseParameters.inflation``) replaced by each of ``--factors``; each row
   is scored against the ground truth (RMSE, coverage of the 90% ellipse, ANEES; 1 when
   consistent) and shown beside what the filter sees without truth (:func:`self_consistency`);
   and the calibrated filter's covariance scaled by α afterwards, its gain kept: whether a
   covariance set apart from the gain could be consistent at the calibrated filter's RMSE. The ground truth is read here only to show where the calibrated factor lies
   against the consistent one; the method never reads it.
2. ``sim``: the simulated robot of ``tests/test_autocalibration.py`` (a square patrolled with
   turns in place, white reading errors, known noise) of ``--steps`` odometry steps, one run
   per seed, calibrated with the gate ``--gate``: the fitted parameters' relative errors, the
   calibration's time, twice the log-likelihood of the innovations at the fitted parameters
   less that at the simulated ones (χ² with as many dof as fitted fields when the likelihood is
   unbiased), and for the first seed the standard errors at the simulated noise.

Run: ``python benchmarks/study_inflation.py [mrclam] [--robots 1 2 3 4 5] [--factors 1 2 3 4 5]``
or ``python benchmarks/study_inflation.py sim [--steps 12000] [--seeds 1 2 3 4] [--gate 0.99]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from relmap.app.localize import localize_mrclam, score
from relmap.filter import autocalibration, ekf
from relmap.io.datasets import read_mrclam
from relmap.uncertain.at import AT

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("RELMAP_DATA", ROOT.parent / "shared" / "data"))


def mrclam(robots: list[int], factors: list[float]) -> None:
    data = read_mrclam(DATA / "landmarks" / "mrclam6")
    for robot in robots:
        auto = localize_mrclam(data, robot)
        cal = auto.calibration
        rho1 = cal.correlation[0]
        print(f"robot {robot}: calibrated σ factor {cal.inflation:.2f} (ρ1 {rho1:.2f})")
        scaled = []
        for a in (0.7, 0.5, 0.4, 0.3):
            sa = score(AT(auto.estimate.mean, a * auto.estimate.cov), auto.truth)
            scaled.append(f"α {a}: coverage_90 {sa.coverage_90:.2f}, ANEES {sa.anees:.2f}")
        print("  calibrated filter, covariance × α afterwards (gain kept): " + "; ".join(scaled))
        rows = [(cal.inflation, auto)]
        for c in factors:
            fixed = cal._replace(parameters=cal.parameters._replace(inflation=c), inflation=c)
            rows.append((c, localize_mrclam(data, robot, calibration=fixed)))
        for c, run in sorted(rows, key=lambda r: r[0]):
            s = run.score
            mark = "  ← calibrated" if run is auto else ""
            anis, windows = self_consistency(run.trace)
            print(f"  σ factor {c:5.2f}: RMSE {s.rmse_position:.3f} m, coverage_90 "
                  f"{s.coverage_90:.2f}, ANEES {s.anees:.2f}{mark}; no truth: NIS/dof "
                  f"{anis:.2f}, window variance ratio "
                  + " ".join(f"{m}: {r:.2f}" for m, r in windows.items()))  # fmt: skip


def self_consistency(trace: ekf.Trace, windows: tuple[int, ...] = (3, 10, 30)):
    """What the filter sees of its own consistency: the mean NIS per dof of used readings, and
    for each window m the mean square of sums of m consecutive normalized range innovations of
    one landmark (in reading order, non-overlapping, clipped at 4.5√m) over m (1 when white)."""
    st = np.asarray(trace.status)
    idx = np.flatnonzero(st == ekf.Status.USED)
    y, S = np.asarray(trace.y)[idx], np.asarray(trace.S)[idx]
    d2 = np.einsum("ni,ni->n", y, np.linalg.solve(S, y[..., None])[..., 0])
    u = y[:, 0] / np.sqrt(S[:, 0, 0])
    lm = np.asarray(trace.landmark)[idx]
    ratio = {}
    for m in windows:
        sums = []
        for k in np.unique(lm):
            v = u[lm == k]
            n = len(v) // m
            sums.extend(v[: n * m].reshape(n, m).sum(axis=1))
        sums = np.clip(np.asarray(sums), -4.5 * np.sqrt(m), 4.5 * np.sqrt(m))
        ratio[m] = float(np.mean(sums**2) / m)
    return float(d2.mean() / y.shape[1]), ratio


def sim(steps: int, seeds: list[int], gate: float) -> None:
    sys.path.insert(0, str(ROOT))
    from tests.filter.test_autocalibration import (
        LANDMARKS,
        NOISE,
        SIGMA_B,
        SIGMA_R,
        simulate,
        start,
    )

    signatures = np.arange(len(LANDMARKS))
    true = ekf.NoiseParameters(NOISE.k_s, NOISE.k_theta, NOISE.k_theta_s, SIGMA_R, SIGMA_B)
    free = ("k_s", "k_theta", "k_theta_s", "sigma_r", "sigma_b")
    for seed in seeds:
        rec, _ = simulate(seed, steps=steps)
        t0 = time.perf_counter()
        cal = autocalibration.calibrate(rec, LANDMARKS, start=start, gate=gate,
                                        landmark_signatures=signatures)  # fmt: skip
        took = time.perf_counter() - t0
        log = rec.log(*cal.clock)

        def loglik(p: ekf.NoiseParameters, nu: float, log: ekf.Log = log) -> float:
            tr = ekf.run(log, LANDMARKS, p._replace(nu=np.inf, inflation=1.0), start=start(0.0),
                         keep="summary", landmark_signatures=signatures, gate=gate)  # fmt: skip
            return float(autocalibration.loglik(tr, nu))

        p = cal.parameters
        err = ", ".join(f"{k} {100 * (getattr(p, k) / getattr(true, k) - 1):+.1f}%" for k in free)
        dll = 2 * (loglik(p, cal.nu) - loglik(true, np.inf))
        print(f"seed {seed}, {steps} steps, {len(rec.reading_t)} readings, gate {gate}: {err}; "
              f"ν {cal.nu:.0f}, delay {cal.delay}, σ factor {cal.inflation:.2f}; 2Δ log-likelihood "
              f"fitted - simulated {dll:.1f}; calibration {took:.1f} s", flush=True)  # fmt: skip
        if seed == seeds[0]:
            se = standard_errors(log, true, LANDMARKS, signatures, start, gate)
            print("  standard errors at the simulated noise (observed information, log scale): "
                  + ", ".join(f"{k} {100 * v:.1f}%" for k, v in se.items()), flush=True)


def standard_errors(log: ekf.Log, p: ekf.NoiseParameters, landmarks: np.ndarray,
                    signatures: np.ndarray, start, gate: float) -> dict[str, float]:  # fmt: skip
    """The standard errors of the fields' logarithms from the observed information (``-H⁻¹``
    of the log-likelihood over the logarithms, ``H`` by central differences of 5% at ``p``,
    one batch of filters): the spread a maximum-likelihood estimate of one run has."""
    free = ("k_s", "k_theta", "k_theta_s", "sigma_r", "sigma_b")
    x, h, n = np.log([float(getattr(p, k)) for k in free]), 0.05, 5
    eye = np.eye(n)
    pts = [x] + [x + s * h * eye[i] for i in range(n) for s in (-1, 1)]
    pairs = [(i, j) for i in range(n) for j in range(i)]
    pts += [x + h * (eye[i] + eye[j]) for i, j in pairs]
    pts = np.array(pts)
    cols = {k: np.full(len(pts), float(v)) for k, v in p._asdict().items()}
    for j, k in enumerate(free):
        cols[k] = np.exp(pts[:, j])
    q = ekf.NoiseParameters(**cols)
    tr = ekf.run(log, landmarks, q._replace(nu=np.full(len(pts), np.inf)), start=start(0.0),
                 keep="summary", landmark_signatures=signatures, gate=gate)  # fmt: skip
    f = np.asarray(autocalibration.loglik(tr, np.full(len(pts), float(p.nu))))
    f0, minus, plus = f[0], f[1 : 2 * n : 2], f[2 : 2 * n + 1 : 2]
    H = np.diag((plus - 2 * f0 + minus) / h**2)
    for (i, j), fij in zip(pairs, f[2 * n + 1 :], strict=True):
        H[i, j] = H[j, i] = (fij - plus[i] - plus[j] + f0) / h**2
    cov = np.linalg.inv(-H)
    return {k: float(np.sqrt(cov[j, j])) if cov[j, j] > 0 else float("nan")
            for j, k in enumerate(free)}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", nargs="?", choices=("mrclam", "sim"), default="mrclam")
    ap.add_argument("--robots", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--factors", type=float, nargs="+", default=[1.0, 2.0, 3.0, 4.0, 5.0])
    ap.add_argument("--steps", type=int, default=12000)
    ap.add_argument("--gate", type=float, default=0.99)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    a = ap.parse_args()
    if a.what == "mrclam":
        mrclam(a.robots, a.factors)
    else:
        sim(a.steps, a.seeds, a.gate)


if __name__ == "__main__":
    main()
