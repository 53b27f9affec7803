"""EKF localization speed: relmap (its compiled core) vs filterpy, on the same inputs.

Scenario: 50 point landmarks uniform in a 20 m × 20 m square; a robot drives circles of radius
6 m (Δs = 0.1 m per step) with odometry noise; a range-bearing sensor (σr = 0.1 m, σφ = 1°,
180° field of view, 8 m range, mounted 0.1 m ahead) sees about 10 landmarks per step, read in
random order. Each step is a prediction (Eq. 13) and a correction with all readings (Eqs. 20-28).

1. One filter, 5000 steps:
   - relmap step by step from Python: ``ekf.predict`` + ``ekf.correct_landmarks`` per step
     (the map an ``ekf.LandmarkMap``, checked once per run),
     known association (``associate="signatures"``, the landmark ids as signatures) and
     Mahalanobis association (nearest of all 50 landmarks, one to one, χ² gate);
   - relmap ``ekf.run`` over the whole log (no Python per step), both associations;
   - filterpy's ``ExtendedKalmanFilter``, as a filterpy user writes it: per step ``F = Gx`` and
     ``Q = Gu Σu Guᵀ`` in numpy by hand, ``predict_x`` returning ``g(x, u)``, ``predict()``, then
     one stacked ``update()`` of the step's readings with ``HJacobian``/``Hx`` vectorized in
     numpy over the readings, ``R`` block diagonal and a residual that wraps the bearing. It is
     told the true association (it has none of its own) and given exactly the readings relmap
     used, so it does no association and no gating at all.
   Both filters' states are checked equal at every step before any timing is printed.
2. A batch of 1000 filters, one lap of the circle (380 steps):
   - Monte Carlo: 1000 runs each with its own noise and readings (padded to the step's largest
     count), stepped from Python with ``predict`` + ``correct_landmarks`` on the whole batch;
   - calibration: ``ekf.run`` of one log with 1000 noise parameter sets (``keep="summary"``).
   The batch's first filter is checked equal to that filter run alone.
3. ``ekf.run`` of MRCLAM robot 1 (50 201 filter times, 1 534 readings) with 64 and with 1000
   parameter sets, ``keep="summary"`` (what likelihood-based calibration calls), signature
   association, when the data is present.

Timings: min and median of interleaved repeats (the machine is shared and noisy). Run:
``python benchmarks/bench_ekf.py [--steps 5000] [--batch 1000] [--repeat 5]``.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small dense blocks: threads only cost

import numpy as np

import relmap as rm
from relmap.filter import ekf
from relmap.lie import se2
from relmap.models import DistanceNoise, RangeBearingSensor, increment

L = 50
SENSOR = RangeBearingSensor(0.1, np.radians(1.0), mount=[0.1, 0.0, 0.0], fov=np.pi, max_range=8.0)
NOISE = DistanceNoise(0.002, 0.002, 0.0005)  # var Δs = 0.002|Δs|, var Δθ = 0.002|Δθ| + 0.0005|Δs|
STEP = np.array([0.1, 0.1 / 6.0])  # commanded (Δs, Δθ): circles of radius 6 m
START = rm.AT([6.0, 0.0, np.pi / 2], np.diag([0.01, 0.01, 0.001]))
MRCLAM_SETS = (64, 1000)


def best_of(*fns: Callable[[], object], repeat: int) -> list[float]:
    """Smallest wall time (s) of each function over ``repeat`` rounds, calls interleaved so that
    a slow spell of this noisy machine hits all contenders alike."""
    times: list[list[float]] = [[] for _ in fns]
    for _ in range(repeat):
        for fn, record in zip(fns, times, strict=True):
            t0 = time.perf_counter()
            fn()
            record.append(time.perf_counter() - t0)
    return [min(t) for t in times]


def simulate(rng: np.random.Generator, landmarks: np.ndarray, B: int, T: int):
    """B Monte Carlo runs of T steps from START: per step, readings (B, m, 2) of the visible
    landmarks in random order, padded to the step's largest count, with validity and ids."""
    truth = np.broadcast_to(START.sample(B, seed=rng), (B, 3)).copy()
    Su = NOISE.covariance(STEP)
    steps = []
    for _ in range(T):
        moved = STEP + rng.multivariate_normal([0.0, 0.0], Su, size=B)
        truth = se2.compose(truth, increment(moved))
        z = SENSOR.predict(truth[:, None, :], landmarks)  # (B, L, 2)
        seen = SENSOR.in_view(z)
        z = z + rng.normal(size=z.shape) * [SENSOR.sigma_range, SENSOR.sigma_bearing]
        order = np.argsort(np.where(seen, rng.random(seen.shape), 2.0), axis=1)
        m = int(seen.sum(axis=1).max())
        ids = order[:, :m]
        rows = np.arange(B)[:, None]
        steps.append((z[rows, ids], seen[rows, ids], ids))
    return steps


# ------------------------------------------------------------------ relmap
def relmap_run(state: rm.AT, steps, *, known: bool, record: bool = False):
    """Predict + correct over the steps; per-step states if ``record``; time in each half."""
    out, t_pred, t_corr = [], 0.0, 0.0
    t0 = time.perf_counter()
    landmarks = ekf.LandmarkMap(LANDMARKS)  # checked once (signatures: the rows)
    t_corr += time.perf_counter() - t0
    for z, valid, ids in steps:
        t0 = time.perf_counter()
        state = ekf.predict(state, STEP, NOISE)
        t1 = time.perf_counter()
        if known:
            up = ekf.correct_landmarks(
                state, z, SENSOR, landmarks, associate="signatures", signatures=ids, valid=valid
            )
        else:
            up = ekf.correct_landmarks(state, z, SENSOR, landmarks, valid=valid)
        state = up.state
        t_corr += time.perf_counter() - t1
        t_pred += t1 - t0
        if record:
            out.append((state.mean, state.cov, up))
    return out, t_pred, t_corr


# ------------------------------------------------------------------ filterpy
def filterpy_run(single_steps, used, record: bool = False):
    """filterpy's EKF on the same steps, updating with the readings relmap used."""
    from filterpy.kalman import ExtendedKalmanFilter

    mx, my, mt = SENSOR.mount
    var = np.array([SENSOR.sigma_range**2, SENSOR.sigma_bearing**2])

    def hx(x, idx):
        c, s = np.cos(x[2]), np.sin(x[2])
        d = LANDMARKS[idx] - (x[0] + c * mx - s * my, x[1] + s * mx + c * my)
        h = np.empty(2 * len(idx))
        h[0::2] = np.hypot(d[:, 0], d[:, 1])
        h[1::2] = np.arctan2(d[:, 1], d[:, 0]) - (x[2] + mt)
        return h

    def jacobian(x, idx):
        c, s = np.cos(x[2]), np.sin(x[2])
        ax, ay = c * mx - s * my, s * mx + c * my
        d = LANDMARKS[idx] - (x[0] + ax, x[1] + ay)
        dx, dy = d[:, 0], d[:, 1]
        q = dx * dx + dy * dy
        r = np.sqrt(q)
        H = np.empty((len(idx), 2, 3))
        H[:, 0, 0], H[:, 0, 1], H[:, 0, 2] = -dx / r, -dy / r, (dx * ay - dy * ax) / r
        H[:, 1, 0], H[:, 1, 1], H[:, 1, 2] = dy / q, -dx / q, -(dy * ay + dx * ax) / q - 1.0
        return H.reshape(-1, 3)

    def residual(a, b):
        y = a - b
        y[1::2] = (y[1::2] + np.pi) % (2 * np.pi) - np.pi
        return y

    class Filter(ExtendedKalmanFilter):
        def predict_x(self, u=0):  # x = g(x, u), midpoint integration
            ds, dth = u
            a = self.x[2] + dth / 2
            self.x = self.x + np.array([ds * np.cos(a), ds * np.sin(a), dth])

    kf = Filter(dim_x=3, dim_z=2)
    kf.x, kf.P = START.mean.copy(), START.cov.copy()
    out, t_pred, t_corr = [], 0.0, 0.0
    ds, dth = STEP
    data = [
        (z[0][keep].reshape(-1), ids[0][keep])
        for (z, _, ids), keep in zip(single_steps, used, strict=True)
    ]
    for zk, idx in data:
        t0 = time.perf_counter()
        a = kf.x[2] + dth / 2
        c, s = np.cos(a), np.sin(a)
        kf.F = np.array([[1.0, 0.0, -ds * s], [0.0, 1.0, ds * c], [0.0, 0.0, 1.0]])
        Gu = np.array([[c, -ds * s / 2], [s, ds * c / 2], [0.0, 1.0]])
        Su = np.diag([NOISE.k_s * abs(ds), NOISE.k_theta * abs(dth) + NOISE.k_theta_s * abs(ds)])
        kf.Q = Gu @ Su @ Gu.T
        kf.predict(u=STEP)
        t1 = time.perf_counter()
        if len(idx):
            kf.update(
                zk, jacobian, hx, R=np.diag(np.tile(var, len(idx))),
                args=(idx,), hx_args=(idx,), residual=residual,
            )  # fmt: skip
        t_corr += time.perf_counter() - t1
        t_pred += t1 - t0
        if record:
            out.append((kf.x.copy(), kf.P.copy()))
    return out, t_pred, t_corr


# ------------------------------------------------------------------ runs
def as_log(steps) -> ekf.Log:
    """One filter's steps as an ekf.Log (readings of step k at time index k)."""
    z = np.concatenate([zk[0][v[0]] for zk, v, _ in steps])
    ids = np.concatenate([i[0][v[0]] for _, v, i in steps])
    index = np.concatenate([np.full(int(v[0].sum()), k + 1) for k, (_, v, _) in enumerate(steps)])
    return ekf.Log(np.arange(len(steps) + 1.0), np.tile(STEP, (len(steps), 1)), index, z, ids)


def params(n: int | None = None) -> ekf.NoiseParameters:
    p = ekf.NoiseParameters.of(NOISE, SENSOR)
    if n is None:
        return p
    scale = np.linspace(0.5, 2.0, n)  # n different parameter sets
    return p._replace(k_s=p.k_s * scale, sigma_r=p.sigma_r * scale)


def run_log(log, p, association, keep="all"):
    return ekf.run(log, LANDMARKS, p, start=START, association=association, keep=keep,
                   landmark_signatures=np.arange(L), readings=keep == "all")  # fmt: skip


def stats(times: list[float]) -> tuple[float, float]:
    return min(times), float(np.median(times))


def interleaved(fns: dict[str, Callable[[], object]], repeat: int) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            out[name].append(time.perf_counter() - t0)
    return out


def main() -> None:
    global LANDMARKS
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000, help="steps of the single filter")
    parser.add_argument("--batch", type=int, default=1000, help="filters in the batch")
    parser.add_argument(
        "--batch-steps", type=int, default=380, help="steps of the batch (default: one lap)"
    )
    parser.add_argument("--repeat", type=int, default=5, help="interleaved repeats")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    LANDMARKS = rng.uniform(-10.0, 10.0, (L, 2))
    single = simulate(rng, LANDMARKS, 1, args.steps)
    n_read = np.mean([v.sum() for _, v, _ in single])
    single = [(z[:, v[0]], v[:, v[0]], i[:, v[0]]) for z, v, i in single]
    single1 = [(z[0], v[0], i[0]) for z, v, i in single]
    log = as_log(single)

    # --- 1. same numbers first
    known, _, _ = relmap_run(START, single1, known=True, record=True)
    maha, _, _ = relmap_run(START, single1, known=False, record=True)
    used = [up.status == ekf.Status.USED for _, _, up in known]
    fp, _, _ = filterpy_run(single, used, record=True)
    d_mean = max(np.abs(se2.minus(k[0], f[0])).max() for k, f in zip(known, fp, strict=True))
    d_cov = max(
        np.abs(k[1] - f[1]).max() / np.abs(f[1]).max() for k, f in zip(known, fp, strict=True)
    )
    tr = run_log(log, params(), "signatures")
    d_run = max(np.abs(tr.mean[k + 1] - known[k][0]).max() for k in range(args.steps))
    maha_used = [up.status == ekf.Status.USED for _, _, up in maha]
    right = sum(
        (u & (up.landmark == ids)).sum()
        for u, (_, _, up), (_, _, ids) in zip(maha_used, maha, single1, strict=True)
    ) / sum(u.sum() for u in maha_used)
    n_used = np.mean([u.sum() for u in used])
    print(
        f"scenario: {args.steps} steps, {L} landmarks, {n_read:.1f} readings per step "
        f"({n_used:.1f} used after the gate)"
    )
    print(
        f"  relmap (known association) vs filterpy, all steps: max |Δmean| {d_mean:.1e}, "
        f"max |ΔΣ|/|Σ| {d_cov:.1e}; ekf.run vs step by step: max |Δmean| {d_run:.1e}"
    )
    print(f"  Mahalanobis association: {right:.2%} of the readings it used paired right")
    assert d_mean < 1e-9 and d_cov < 1e-9 and d_run < 1e-12, "relmap and filterpy disagree"

    # --- 2. batch (checked before timing)
    B, TB, T = args.batch, args.batch_steps, args.steps
    batch_steps = simulate(np.random.default_rng(1), LANDMARKS, B, TB)
    starts = rm.AT(np.broadcast_to(START.mean, (B, 3)), np.broadcast_to(START.cov, (B, 3, 3)))
    for is_known in (True, False):
        whole, _, _ = relmap_run(starts, batch_steps, known=is_known, record=True)
        alone, _, _ = relmap_run(
            START, [(z[0], v[0], i[0]) for z, v, i in batch_steps], known=is_known, record=True
        )
        dm = max(np.abs(se2.minus(w[0][0], a[0])).max() for w, a in zip(whole, alone, strict=True))
        dc = max(np.abs(w[1][0] - a[1]).max() for w, a in zip(whole, alone, strict=True))
        assert dm < 1e-12 and dc < 1e-12, "a filter of the batch differs from that filter alone"
    lap = as_log([(z[:1], v[:1], i[:1]) for z, v, i in batch_steps])
    pb = params(B)

    mrclam = None
    folder = os.environ.get(
        "RELMAP_DATA", str(Path(__file__).resolve().parents[2] / "shared" / "data")
    )
    if Path(folder, "landmarks", "mrclam6").is_dir():
        from relmap.app.localize import calibrate_mrclam
        from relmap.io import read_mrclam

        data = read_mrclam(Path(folder, "landmarks", "mrclam6"))
        r1 = data.robots[0]
        keep = data.landmark_index(r1.meas_subject) >= 0
        inside = (r1.odometry_t >= r1.truth_t[0]) & (r1.odometry_t <= r1.truth_t[-1])
        o = np.flatnonzero(inside)
        mlog = ekf.Log.from_velocities(
            r1.odometry_t[o[0]:], r1.odometry_v[o[0]:], r1.odometry_w[o[0]:], r1.meas_t[keep],
            np.column_stack([r1.meas_range[keep], r1.meas_bearing[keep]]),
            data.landmark_index(r1.meas_subject)[keep], end=float(r1.odometry_t[o[-1]]),
        )  # fmt: skip
        base = calibrate_mrclam(data, 2).parameters
        start = rm.AT(r1.truth_at(mlog.t[:1])[0], np.diag([4e-4, 4e-4, 4e-4]))

        def mrclam(n: int) -> Callable[[], object]:
            scale = np.linspace(0.5, 4.0, n)
            pn = base._replace(k_s=base.k_s * scale, sigma_r=base.sigma_r * scale)
            return lambda: ekf.run(
                mlog, data.landmark_xy, pn, start=start, keep="summary", readings=False,
                landmark_signatures=np.arange(len(data.landmark_xy)),
            )  # fmt: skip

    # --- timings, interleaved
    runs: dict[str, Callable[[], object]] = {
        "steps known": lambda: relmap_run(START, single1, known=True),
        "steps Mahalanobis": lambda: relmap_run(START, single1, known=False),
        "run known": lambda: run_log(log, params(), "signatures"),
        "run Mahalanobis": lambda: run_log(log, params(), "mahalanobis"),
        "filterpy": lambda: filterpy_run(single, used),
        "MC batch known": lambda: relmap_run(starts, batch_steps, known=True),
        "MC batch Mahalanobis": lambda: relmap_run(starts, batch_steps, known=False),
        "run batch known": lambda: run_log(lap, pb, "signatures", keep="summary"),
        "run batch Mahalanobis": lambda: run_log(lap, pb, "mahalanobis", keep="summary"),
    }
    if mrclam is not None:
        for n in MRCLAM_SETS:
            runs[f"MRCLAM robot 1, {n} parameter sets"] = mrclam(n)
    times = interleaved(runs, args.repeat)
    per = {
        "steps known": T, "steps Mahalanobis": T, "run known": T, "run Mahalanobis": T,
        "filterpy": T, "MC batch known": TB * B, "MC batch Mahalanobis": TB * B,
        "run batch known": TB * B, "run batch Mahalanobis": TB * B,
    }  # fmt: skip
    print(f"\nµs per filter-step, min / median of {args.repeat} interleaved repeats "
          "(machine shared with other jobs)")  # fmt: skip
    for name, n in per.items():
        lo, med = stats(times[name])
        print(f"  {name:<28}{lo / n * 1e6:10.3f} {med / n * 1e6:10.3f}")
    if mrclam is not None:
        for n in MRCLAM_SETS:
            lo, med = stats(times[f"MRCLAM robot 1, {n} parameter sets"])
            steps = len(mlog.t) * n
            print(f"  MRCLAM robot 1 ({len(mlog.t)} times, {len(mlog.z)} readings), {n} "
                  f"parameter sets: {lo:.3f} s min, {med:.3f} s median "
                  f"({lo / steps * 1e9:.0f} ns per filter-step)")  # fmt: skip
    fp_lo, fp_med = stats(times["filterpy"])
    print("\nratios filterpy / relmap per filter-step (from min; from median)")
    targets = {  # issue 17 (one compiled core) and issue 14 (the EKF rebuilt)
        "steps known": "issue 17: >= 5x; issue 14: >= 2x",
        "run known": "issue 17: >= 5x; issue 14: >= 2x",
        "MC batch known": "issue 17: >= 100x; issue 14: >= 50x",
        "run batch known": "issue 17: >= 100x; issue 14: >= 50x",
        "MC batch Mahalanobis": "issue 17: >= 100x; issue 14: >= 30x",
        "run batch Mahalanobis": "issue 17: >= 100x; issue 14: >= 30x",
    }
    for name, target in targets.items():
        lo, med = stats(times[name])
        r_lo = (fp_lo / T) / (lo / per[name])
        r_med = (fp_med / T) / (med / per[name])
        print(f"  {name:<28}{r_lo:9.1f}x {r_med:9.1f}x   ({target})")
    for name in ("steps Mahalanobis", "run Mahalanobis"):
        lo, med = stats(times[name])
        print(f"  {name:<28}{(fp_lo / T) / (lo / T):9.1f}x {(fp_med / T) / (med / T):9.1f}x   "
              "(filterpy told the pairs)")  # fmt: skip


if __name__ == "__main__":
    main()
