"""EKF localization speed: relmap vs filterpy (and roboticstoolbox), on the same inputs.

Scenario: 50 point landmarks uniform in a 20 m × 20 m square; a robot drives circles of radius
6 m (Δs = 0.1 m per step) with odometry noise; a range-bearing sensor (σr = 0.1 m, σφ = 1°,
180° field of view, 8 m range, mounted 0.1 m ahead) sees about 10 landmarks per step, read in
random order. Each step is a prediction (Eq. 13) and a correction with all readings (Eqs. 20-28).

1. One filter, 5000 steps:
   - relmap, known association: ``predict`` + ``correct_landmarks(associate="signatures")``
     (the landmark ids as signatures);
   - relmap, Mahalanobis association: ``predict`` + ``correct_landmarks()`` — nearest landmark
     by Mahalanobis distance among all 50, one to one, χ² gate;
   - filterpy's ``ExtendedKalmanFilter``, as a filterpy user writes it: per step ``F = Gx`` and
     ``Q = Gu Σu Guᵀ`` in numpy by hand, ``predict_x`` returning ``g(x, u)``, ``predict()``, then
     one stacked ``update()`` of the step's readings with ``HJacobian``/``Hx`` vectorized in
     numpy over the readings, ``R`` block diagonal and a residual that wraps the bearing. It is
     told the true association (it has none of its own) and given exactly the readings relmap
     used (relmap gated out about 1%), so it does no association and no gating at all.
   Both filters' states are checked equal at every step before any timing is printed.
2. roboticstoolbox's EKF (map-based localization), if installed: its ``EKF.step()`` simulates
   its own vehicle and sensor and corrects with one reading per step; its simulation alone is
   timed too and subtracted, as an estimate of its filter's cost.
3. A batch of 1000 filters (1000 Monte Carlo runs of the scenario, each with its own noise and
   readings, padded to the step's largest count), one lap of the circle (380 steps, so that
   the landmarks in view vary as over the single filter's 5000 steps), both associations; the
   batch's first filter is checked equal to that filter run alone.

relmap runs its numba kernels when numba is installed (``RELMAP_NUMBA=0``: its numpy paths);
the first lines printed say which. Timings are the best of interleaved repeats (this machine is
noisy). Run:
``python benchmarks/bench_ekf.py [--steps 5000] [--batch 1000] [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small dense blocks: threads only cost

import numpy as np

import relmap as rm
from relmap import ekf
from relmap.lie import se2
from relmap.robot import DistanceNoise, increment
from relmap.sensors import RangeBearingSensor

L = 50
SENSOR = RangeBearingSensor(0.1, np.radians(1.0), mount=[0.1, 0.0, 0.0], fov=np.pi, max_range=8.0)
NOISE = DistanceNoise(0.002, 0.002, 0.0005)  # var Δs = 0.002|Δs|, var Δθ = 0.002|Δθ| + 0.0005|Δs|
STEP = np.array([0.1, 0.1 / 6.0])  # commanded (Δs, Δθ): circles of radius 6 m
START = rm.AT([6.0, 0.0, np.pi / 2], np.diag([0.01, 0.01, 0.001]))


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
    lsig = np.arange(L)
    for z, valid, ids in steps:
        t0 = time.perf_counter()
        state = ekf.predict(state, STEP, NOISE)
        t1 = time.perf_counter()
        if known:
            up = ekf.correct_landmarks(
                state, z, SENSOR, LANDMARKS, associate="signatures", signatures=ids,
                landmark_signatures=lsig, valid=valid,
            )  # fmt: skip
        else:
            up = ekf.correct_landmarks(state, z, SENSOR, LANDMARKS, valid=valid)
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


# ------------------------------------------------------------------ roboticstoolbox
def rtb_timing(n: int) -> tuple[float, float] | None:
    """(µs per EKF.step, µs per step of its own vehicle and sensor simulation), or None."""
    try:
        import warnings

        warnings.filterwarnings("ignore")
        from roboticstoolbox import EKF, Bicycle, LandmarkMap, RandomPath
        from roboticstoolbox import RangeBearingSensor as RTBSensor
    except ImportError:
        return None

    def build():
        V = np.diag([0.02, np.radians(0.5)]) ** 2
        W = np.diag([SENSOR.sigma_range, SENSOR.sigma_bearing]) ** 2
        robot = Bicycle(covar=V, animation=None)
        robot.control = RandomPath(workspace=10, seed=0)
        lmap = LandmarkMap(L, workspace=10, seed=0)
        sensor = RTBSensor(
            robot, lmap, covar=W, angle=[-np.pi / 2, np.pi / 2], range=8, animate=False, seed=0
        )
        f = EKF(robot=(robot, V), P0=np.diag([0.1, 0.1, 0.03]) ** 2, map=lmap,
                sensor=(sensor, W), animate=False, history=False)  # fmt: skip
        return f, robot, sensor

    f, _, _ = build()
    t0 = time.perf_counter()
    for _ in range(n):
        f.step()
    t_step = (time.perf_counter() - t0) / n
    _, robot, sensor = build()
    t0 = time.perf_counter()
    for _ in range(n):
        robot.step()
        sensor.reading()
    t_sim = (time.perf_counter() - t0) / n
    return t_step * 1e6, t_sim * 1e6


def main() -> None:
    global LANDMARKS
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000, help="steps of the single filter")
    parser.add_argument("--batch", type=int, default=1000, help="filters in the batch")
    parser.add_argument(
        "--batch-steps", type=int, default=380, help="steps of the batch (default: one lap)"
    )
    parser.add_argument("--repeat", type=int, default=3, help="interleaved repeats")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    LANDMARKS = rng.uniform(-10.0, 10.0, (L, 2))
    single = simulate(rng, LANDMARKS, 1, args.steps)
    n_read = np.mean([v.sum() for _, v, _ in single])
    # one filter: the readings of the step, unpadded
    single = [(z[:, v[0]], v[:, v[0]], i[:, v[0]]) for z, v, i in single]
    single1 = [(z[0], v[0], i[0]) for z, v, i in single]

    # --- 1. same numbers first
    known, _, _ = relmap_run(START, single1, known=True, record=True)
    maha, _, _ = relmap_run(START, single1, known=False, record=True)
    used = [up.status == ekf.USED for _, _, up in known]
    fp, _, _ = filterpy_run(single, used, record=True)
    d_mean = max(np.abs(se2.minus(k[0], f[0])).max() for k, f in zip(known, fp, strict=True))
    d_cov = max(
        np.abs(k[1] - f[1]).max() / np.abs(f[1]).max() for k, f in zip(known, fp, strict=True)
    )
    maha_used = [up.status == ekf.USED for _, _, up in maha]
    right = sum(
        (u & (up.landmark == ids)).sum()
        for u, (_, _, up), (_, _, ids) in zip(maha_used, maha, single1, strict=True)
    ) / sum(u.sum() for u in maha_used)
    same = np.mean([np.array_equal(u, v) for u, v in zip(used, maha_used, strict=True)])
    n_used = np.mean([u.sum() for u in used])
    from relmap import _numba

    print("relmap paths:", "numba kernels" if _numba.enabled() else "numpy (RELMAP_NUMBA=0)")
    print(
        f"scenario: {args.steps} steps, {L} landmarks, {n_read:.1f} readings per step "
        f"({n_used:.1f} used after the gate)"
    )
    print(
        f"  relmap (known association) vs filterpy, all steps: max |Δmean| {d_mean:.1e}, "
        f"max |ΔΣ|/|Σ| {d_cov:.1e}"
    )
    print(
        f"  Mahalanobis association: {right:.2%} of the readings it used paired with their true "
        f"landmark; same readings used as with known association in {same:.1%} of the steps"
    )
    assert d_mean < 1e-9 and d_cov < 1e-9, "relmap and filterpy disagree"

    # --- 3. batch (checked before timing)
    batch_steps = simulate(np.random.default_rng(1), LANDMARKS, args.batch, args.batch_steps)
    starts = rm.AT(
        np.broadcast_to(START.mean, (args.batch, 3)), np.broadcast_to(START.cov, (args.batch, 3, 3))
    )
    for is_known in (True, False):
        whole, _, _ = relmap_run(starts, batch_steps, known=is_known, record=True)
        alone, _, _ = relmap_run(
            START, [(z[0], v[0], i[0]) for z, v, i in batch_steps], known=is_known, record=True
        )
        dm = max(np.abs(se2.minus(w[0][0], a[0])).max() for w, a in zip(whole, alone, strict=True))
        dc = max(np.abs(w[1][0] - a[1]).max() for w, a in zip(whole, alone, strict=True))
        assert dm < 1e-12 and dc < 1e-12, "a filter of the batch differs from that filter alone"

    # --- timings, interleaved
    runs = {
        "relmap known": lambda: relmap_run(START, single1, known=True),
        "relmap Mahalanobis": lambda: relmap_run(START, single1, known=False),
        "filterpy": lambda: filterpy_run(single, used),
        "batch known": lambda: relmap_run(starts, batch_steps, known=True),
        "batch Mahalanobis": lambda: relmap_run(starts, batch_steps, known=False),
    }
    parts: dict[str, tuple[float, float]] = {}  # best (predict, correct) seconds of each run

    def timed(name: str) -> Callable[[], None]:
        def run() -> None:
            _, tp, tc = runs[name]()
            if name not in parts or tp + tc < sum(parts[name]):
                parts[name] = (tp, tc)

        return run

    best_of(*(timed(n) for n in runs), repeat=args.repeat)
    T, TB, B = args.steps, args.batch_steps, args.batch

    def us(name: str, n: int) -> tuple[float, float, float]:
        tp, tc = parts[name]
        return (tp + tc) / n * 1e6, tp / n * 1e6, tc / n * 1e6

    print("\nµs per step (predict + correct = whole step)")
    rows = [
        ("relmap, known association", us("relmap known", T)),
        ("relmap, Mahalanobis association", us("relmap Mahalanobis", T)),
        ("filterpy, stacked update (told the pairs)", us("filterpy", T)),
        (f"relmap batch of {B}, known, per filter", us("batch known", TB * B)),
        (f"relmap batch of {B}, Mahalanobis, per filter", us("batch Mahalanobis", TB * B)),
    ]
    for label, (total, tp, tc) in rows:
        print(f"  {label:<44}{total:9.2f}   ({tp:7.2f} + {tc:7.2f})")
    rtb = rtb_timing(min(T, 2000))
    if rtb is None:
        print("  roboticstoolbox: not installed")
    else:
        print(
            f"  {'roboticstoolbox EKF.step (1 reading/step)':<44}{rtb[0]:9.2f}   (of which its "
            f"own simulation {rtb[1]:.2f}: filter ≈ {rtb[0] - rtb[1]:.2f})"
        )
    fp_total, _, fp_corr = us("filterpy", T)
    print("\nratios")
    for name in ("relmap known", "relmap Mahalanobis"):
        total, _, corr = us(name, T)
        print(
            f"  filterpy / {name}: step {fp_total / total:5.2f}x, update alone "
            f"{fp_corr / corr:5.2f}x   (target >= 2x)"
        )
    for single_name, batch_name in (
        ("relmap known", "batch known"),
        ("relmap Mahalanobis", "batch Mahalanobis"),
    ):
        ratio = us(single_name, T)[0] / us(batch_name, TB * B)[0]
        print(f"  {single_name} / {batch_name} per filter-step: {ratio:6.1f}x   (target >= 20x)")


if __name__ == "__main__":
    main()
