"""Which statistic could set the autocalibrated filter's covariance scale without ground truth?
Two diagnostics of ``relmap localize`` on MRCLAM (issue 14's signatures bands; measured:
docs/consistency.md).

1. ``odometry``: the autocalibrated filter (signatures) with the odometry's ``k_s`` (or all
   three k) multiplied by each of ``--scales``, everything else kept: RMSE, coverage_90 and
   ANEES against the ground truth. Does the odometry noise the likelihood fits set the
   covariance's consistency, and at what cost in accuracy?
2. ``forward-backward``: a truth-free consistency check. The same filter run backward in time
   over the same log (odometry steps reversed, ``(-Δs, -Δθ)``, readings in reverse order;
   started from the forward filter's last pose with 4× its covariance) is an estimate of the
   pose from the future readings only. Where the two filters' errors are independent, the
   difference ``d`` of their positions at a time has covariance ``P_f + P_b`` and
   ``α̂ = mean dᵀ(P_f + P_b)⁻¹d / 2`` is the factor by which both overstate (α̂ < 1) or
   understate their covariance. With ``--gaps`` G > 0 the forward filter is taken at t - G and
   the backward at t + G, each predicted to t by odometry alone (so that readings of the
   same few seconds do not enter both). Times within 45 s of the start and 110 s of the end
   are left out (the backward filter's start is the forward's end). Printed: α̂, the mean
   squared position and heading differences against the mean trace of ``P_f + P_b``, the
   correlation of the two filters' errors (truth), and the forward filter's covariance scaled
   by α̂, scored against the truth.
3. ``held-out``: a truth-free score of the covariance, the predictive likelihood of readings
   the filter did not use. The landmarks are split into ``--folds`` groups (by row modulo the
   number of folds); for each group the filter runs without its readings, and each of them is
   scored by the Student-t density (the calibrated ν) of its innovation at the state just
   before its time, ``S = H P Hᵀ + R``. A proper score: in expectation highest when ``P`` is
   the covariance of the filter's error, if the held-out readings' errors are independent of
   it. Printed per ``--scales`` factor of ``k_s``: the mean log-density per reading against
   the first factor's.

4. ``thinned``: the run's readings thinned to at most one per landmark every ``--spacings`` T
   seconds (the first of each landmark kept, then the first at least T after the last kept),
   so that the readings the likelihood sees are nearly white (range errors correlate 0.2-0.4
   five seconds apart, against 0.8-0.9 at 0.25 s); autocalibrated and filtered on the thinned
   readings alone. Does the likelihood fit an honest ``k_s`` once its readings are white?
5. ``window``: the whiteness stage's variance factor taken over the filter's own window, not
   over an infinite mean. A filter whose prior range variance is ``H P Hᵀ`` averages about
   ``N = c² σ_r² / (H P Hᵀ)_rr`` readings (the median over used readings); the variance
   factor of the mean of ``N`` correlated readings is ``1 + 2 Σ_k (1 - k/N) ρ_k`` with the
   innovations' own ``ρ_k`` (lags 1-60, :func:`relmap.filter.autocalibration.innovation_correlation`).
   Iterated four times from c = 1 (N grows with c), then scored.

Ground truth is read only to score. Run: ``python benchmarks/study_covariance_scale.py
odometry [--robots 1 2 3 4 5] [--scales 1 0.5 0.25 0.1] [--all-k]`` or ``python
benchmarks/study_covariance_scale.py forward-backward [--gaps 0 5 10 20]`` or ``python
benchmarks/study_covariance_scale.py held-out [--scales 2 1 0.5 0.25 0.1] [--folds 5]`` or
``python benchmarks/study_covariance_scale.py thinned [--spacings 2 5 10]`` or ``python
benchmarks/study_covariance_scale.py window``.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from study_bias import recording

from relmap.app.localize import Localization, _start, localize_mrclam, score
from relmap.filter import autocalibration, ekf
from relmap.io.datasets import read_mrclam
from relmap.lie import se2
from relmap.models import DistanceNoise, RangeBearingSensor
from relmap.uncertain import gaussian
from relmap.uncertain.at import AT

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("RELMAP_DATA", ROOT.parent / "shared" / "data"))


def fmt(s) -> str:
    return f"{s.rmse_position:.3f}/{s.coverage_90:.2f}/{s.anees:.2f}"


def odometry(data, robots: list[int], scales: list[float], all_k: bool) -> None:
    for robot in robots:
        auto = localize_mrclam(data, robot)
        cal = auto.calibration
        p = cal.parameters
        print(f"robot {robot}: k_s {float(p.k_s):.4g}, k_theta {float(p.k_theta):.4g}, "
              f"k_theta_s {float(p.k_theta_s):.4g}, σ factor {float(p.inflation):.2f}; "
              f"calibrated {fmt(auto.score)}", flush=True)  # fmt: skip
        row = []
        for b in scales:
            names = ("k_s", "k_theta", "k_theta_s") if all_k else ("k_s",)
            q = p._replace(**{n: float(getattr(p, n)) * b for n in names})
            run = localize_mrclam(data, robot, calibration=cal._replace(parameters=q))
            row.append(f"× {b:g}: {fmt(run.score)} (α̂ {forward_backward(data, run)[0]:.2f})")
        print("  " + ", ".join(row), flush=True)


def backward(data, robot: int, run: Localization) -> tuple[ekf.Log, ekf.Trace]:
    """The filter's log and the same filter run backward over it (module docstring)."""
    log = recording(data, robot).log(*run.calibration.clock)
    T = len(log.t)
    reverse = ekf.Log(-log.t[::-1], -log.motion[::-1], (T - 1 - log.reading_index)[::-1],
                      log.z[::-1], log.signature[::-1])  # fmt: skip
    start = AT(run.estimate.mean[-1], 4.0 * run.estimate.cov[-1])
    trace = ekf.run(reverse, ekf.LandmarkMap(data.landmark_xy), run.calibration.parameters,
                    start=start, association="signatures")  # fmt: skip
    return log, trace


def predicted(x, P, steps: np.ndarray, noise: DistanceNoise) -> AT:
    """States (B,) each predicted through its own odometry steps (B, J, 2), zero-padded."""
    state = AT(x, P)
    for j in range(steps.shape[1]):
        state = ekf.predict(state, steps[:, j], noise)
    return state


def forward_backward(data, run: Localization, gap: float = 0.0, cache=None):
    """``(α̂, mean |d|², mean tr(P_f + P_b) of the position, mean heading d², its variance,
    correlation of the two errors)`` at one time per second (module docstring)."""
    robot = run.robot
    log, trace = cache if cache is not None else backward(data, robot, run)
    t, mf = log.t, log.motion
    xf, Pf = run.estimate.mean, run.estimate.cov
    xb, Pb = trace.mean[::-1], trace.cov[::-1]
    at = np.searchsorted(t, np.arange(t[0] + 45.0, t[-1] - 110.0, 1.0))
    a = np.searchsorted(t, t[at] - gap, side="right") - 1
    b = np.searchsorted(t, t[at] + gap, side="left")
    J = max(int((at - a).max()), int((b - at).max()), 1)
    fwd, bwd = np.zeros((len(at), J, 2)), np.zeros((len(at), J, 2))
    for i, (s, aa, bb) in enumerate(zip(at, a, b, strict=True)):
        fwd[i, : s - aa] = mf[aa:s]
        bwd[i, : bb - s] = -mf[s:bb][::-1]
    p = run.calibration.parameters
    noise = DistanceNoise(float(p.k_s), float(p.k_theta), float(p.k_theta_s))
    one = predicted(xf[a], Pf[a], fwd, noise) if gap else AT(xf[at], Pf[at])
    two = predicted(xb[b], Pb[b], bwd, noise) if gap else AT(xb[at], Pb[at])
    d = one.mean[:, :2] - two.mean[:, :2]
    C = (one.cov + two.cov)[:, :2, :2]
    alpha = float(np.mean(gaussian.mahalanobis2(d, 0.0, C)) / 2)
    heading = se2.wrap_angle(one.mean[:, 2] - two.mean[:, 2])
    ef, eb = (x[at, :2] - run.truth[at, :2] for x in (xf, xb))
    corr = float((ef * eb).sum(1).mean() / np.sqrt((ef**2).sum(1).mean() * (eb**2).sum(1).mean()))
    return (alpha, float((d**2).sum(1).mean()), float(np.trace(C, axis1=1, axis2=2).mean()),
            float((heading**2).mean()), float((one.cov + two.cov)[:, 2, 2].mean()), corr)  # fmt: skip


def forward_backward_table(data, robots: list[int], gaps: list[float]) -> None:
    for robot in robots:
        run = localize_mrclam(data, robot)
        cache = backward(data, robot, run)
        back = score(AT(cache[1].mean[::-1], cache[1].cov[::-1]), run.truth)
        print(f"robot {robot}: forward {fmt(run.score)}, backward {fmt(back)}", flush=True)
        for g in gaps:
            a, dd, tc, dh, ch, corr = forward_backward(data, run, g, cache)
            scaled = score(AT(run.estimate.mean, a * run.estimate.cov), run.truth)
            print(f"  gap {g:g} s: α̂ {a:.2f}; |d|² {dd:.4f} m² against tr {tc:.4f}; heading "
                  f"{dh:.5f} against {ch:.5f} rad²; error correlation {corr:.2f}; forward "
                  f"covariance × α̂: {scaled.coverage_90:.2f}/{scaled.anees:.2f}", flush=True)  # fmt: skip


def held_out(data, robots: list[int], scales: list[float], folds: int) -> None:
    sensor = RangeBearingSensor(1.0, 1.0)  # its predict: h and H (MRCLAM: no mount)
    for robot in robots:
        run = localize_mrclam(data, robot)
        cal, p = run.calibration, run.calibration.parameters
        log = recording(data, robot).log(*cal.clock)
        start = _start(data.robots[robot - 1].truth_at(log.t[:1])[0])
        batch = ekf.NoiseParameters(*(np.full(len(scales), float(v)) for v in p))
        batch = batch._replace(k_s=float(p.k_s) * np.asarray(scales))
        R = np.diag([float(p.sigma_r) ** 2, float(p.sigma_b) ** 2])
        total, n = np.zeros(len(scales)), 0
        for f in range(folds):
            out = log.signature % folds == f
            kept = log._replace(reading_index=log.reading_index[~out], z=log.z[~out],
                                signature=log.signature[~out])  # fmt: skip
            trace = ekf.run(kept, ekf.LandmarkMap(data.landmark_xy), batch, start=start)
            before = np.maximum(log.reading_index[out] - 1, 0)
            x, P = trace.mean[:, before], trace.cov[:, before]
            q = np.broadcast_to(data.landmark_xy[log.signature[out]], (*x.shape[:-1], 2))
            zh, H, _ = sensor.predict(x, q, jacobians=True)
            S = H @ P @ np.swapaxes(H, -1, -2) + R
            y = log.z[out] - zh
            y[..., 1] = se2.wrap_angle(y[..., 1])
            d2 = np.einsum("...i,...i->...", y, np.linalg.solve(S, y[..., None])[..., 0])
            logdet = np.linalg.slogdet(S)[1]
            total += autocalibration.logpdf(d2, logdet, 2, cal.nu).sum(axis=-1)
            n += int(out.sum())
        print(f"robot {robot}: held-out log-density per reading against × {scales[0]:g}: "
              + ", ".join(f"× {b:g} {(t - total[0]) / n:+.3f}" for b, t in zip(scales, total, strict=True))
              + f"; best × {scales[int(np.argmax(total))]:g}", flush=True)  # fmt: skip


def thinned(data, robots: list[int], spacings: list[float]) -> None:
    import relmap.app.localize as localize

    def thin(rec: autocalibration.Recording, spacing: float) -> autocalibration.Recording:
        keep, last = np.zeros(len(rec.reading_t), bool), {}
        for i, (t, s) in enumerate(zip(rec.reading_t, rec.signature, strict=True)):
            if t - last.get(int(s), -np.inf) >= spacing:
                keep[i], last[int(s)] = True, t
        return rec._replace(reading_t=rec.reading_t[keep], z=rec.z[keep],
                            signature=rec.signature[keep])  # fmt: skip

    full = localize._localization
    for spacing in spacings:

        def thinned_run(what, rec, *a, spacing=spacing, **k):
            return full(what, thin(rec, spacing), *a, **k)

        localize._localization = thinned_run
        try:
            runs = [localize_mrclam(data, robot) for robot in robots]
        finally:
            localize._localization = full
        print(f"one reading per landmark per {spacing:g} s: " + ", ".join(
            f"r{robot} {fmt(run.score)} (k_s {float(run.calibration.parameters.k_s):.3f})"
            for robot, run in zip(robots, runs, strict=True))
            + f"; mean RMSE {np.mean([r.score.rmse_position for r in runs]):.3f}",
            flush=True)  # fmt: skip


def window(data, robots: list[int], lags: int = 60, passes: int = 4) -> None:
    lag = np.arange(1, lags + 1)
    for robot in robots:
        run = localize_mrclam(data, robot)
        cal, p = run.calibration, run.calibration.parameters
        log = recording(data, robot).log(*cal.clock)
        t = log.t[log.reading_index]
        start = _start(data.robots[robot - 1].truth_at(log.t[:1])[0])
        landmarks = ekf.LandmarkMap(data.landmark_xy)
        sr2, c = float(p.sigma_r) ** 2, 1.0
        for _ in range(passes):
            trace = ekf.run(log, landmarks, p._replace(inflation=c), start=start, keep="summary")
            used = trace.status == ekf.Status.USED
            n = float(np.median(c**2 * sr2 / np.maximum(trace.S[used, 0, 0] - sr2, 1e-12)))
            rho = np.nan_to_num([autocalibration.innovation_correlation(trace, t, lag=k)[0]
                                 for k in lag])  # fmt: skip
            c = float(np.sqrt(max(1.0 + 2.0 * np.sum(np.clip(1 - lag / n, 0, None) * rho), 1.0)))
        q = p._replace(inflation=c)
        new = localize_mrclam(data, robot, calibration=cal._replace(parameters=q, inflation=c))
        print(
            f"robot {robot}: σ factor {cal.inflation:.2f} {fmt(run.score)} → window N {n:.1f}, "
            f"ρ1 {rho[0]:.2f}, factor {c:.2f}: {fmt(new.score)}",
            flush=True,
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "mode", choices=("odometry", "forward-backward", "held-out", "thinned", "window")
    )
    ap.add_argument("--robots", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--scales", type=float, nargs="+", default=[1.0, 0.5, 0.25, 0.1])
    ap.add_argument("--all-k", action="store_true", help="scale all three k, not only k_s")
    ap.add_argument("--gaps", type=float, nargs="+", default=[0.0, 5.0, 10.0, 20.0])
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--spacings", type=float, nargs="+", default=[2.0, 5.0, 10.0])
    args = ap.parse_args()
    data = read_mrclam(DATA / "landmarks" / "mrclam6")
    if args.mode == "odometry":
        odometry(data, args.robots, args.scales, args.all_k)
    elif args.mode == "held-out":
        held_out(data, args.robots, args.scales, args.folds)
    elif args.mode == "thinned":
        thinned(data, args.robots, args.spacings)
    elif args.mode == "window":
        window(data, args.robots)
    else:
        forward_backward_table(data, args.robots, args.gaps)


if __name__ == "__main__":
    main()
