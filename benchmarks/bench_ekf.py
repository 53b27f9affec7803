"""EKF localization speed: relmap (:mod:`relmap.filter`) vs filterpy, side by side in one run.

Scenario: 50 point landmarks uniform in a 20 m × 20 m square; a robot drives circles of radius
6 m (Δs = 0.1 m per step) with odometry noise (``Odometry(DistanceNoise(...))``, midpoint
integration); a range-bearing sensor (σr = 0.1 m, σφ = 1°, 180° field of view, 8 m range,
mounted 0.1 m ahead) sees about 10 landmarks per step, read in random order. Each step is a
prediction (Eq. 13) and a correction with all readings (Eqs. 20-28) in one stacked update.

The contenders (the issue's speed floors in brackets):

- filterpy's ``ExtendedKalmanFilter``, as a filterpy user writes it: per step ``F = Gx`` and
  ``Q = Gu Σu Guᵀ`` in numpy by hand, ``predict_x`` returning ``g(x, u)``, ``predict()``, then one
  stacked ``update()`` of the step's readings with ``HJacobian``/``Hx`` vectorized in numpy over
  the readings, ``R`` block diagonal and a residual that wraps the bearing. It has no
  association: it is told the pairs (the true landmarks of the readings relmap used), so it does
  no association and no gating at all.
- (c) one filter stepped from Python: ``relmap.filter.predict`` + ``correct_landmarks`` per step,
  the map a ``LandmarkMap`` built once; signature association (the landmark ids as signatures)
  [>= 2x filterpy], and Mahalanobis association (informative: filterpy is told the pairs);
- one filter over the whole log: ``relmap.filter.run`` (keep="all", readings kept);
- (a) a batch of 1000 filters, signature association [>= 20x filterpy per filter-step]: Monte Carlo (1000 runs each with its own noise and readings, padded to the
  step's largest count, stepped from Python with ``predict`` + ``correct_landmarks`` on the
  whole batch) and calibration (``run`` of one log with 1000 noise parameter sets,
  ``keep="summary"``);
- (b) the same with Mahalanobis association (nearest of all 50 landmarks, one to one, χ² gate)
  [>= 10x filterpy per filter-step];
- ``run`` of MRCLAM robot 1 (50 201 filter times, 1 534 readings) with 64 and with 1000
  parameter sets about robot 2's noise against its ground truth (``calibrate_mrclam``),
  ``keep="summary"`` (what likelihood-based calibration calls), signature association, when the
  data is present (``$RELMAP_DATA`` or ``../shared/data``).

Before any timing, every relmap contender's states are checked against filterpy's (given the
pairs relmap used), to 1e-9: with signatures over the whole run, the single filter and the first
filter of the Monte Carlo batch; with Mahalanobis association step by step (filterpy from
relmap's state before each step), leaving out the steps where relmap took a reading as a mixture
of the landmarks inside its gate (module ``relmap.filter.landmarks``; no filterpy update says
that); ``run`` against the filter stepped; the first and last filters of each parameter batch
against the same filter run alone, to 1e-12.

Timings: wall min and median, and CPU (process time) min, of interleaved repeats (the machine is
shared and noisy; the load averages are printed; the CPU time is the least disturbed). Run: ``python benchmarks/bench_ekf.py [--steps 1000] [--batch 1000]
[--batch-steps 100] [--repeat 3] [--no-mrclam]`` (about 4 minutes with these defaults on the
shared 2-core machine, most of it relmap's Mahalanobis batches). The batches run the first 100
steps of a lap by default (--batch-steps 380: the whole lap); they see a few more landmarks per
step than the single filter (both counts are printed), which if anything understates relmap's
ratio.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small dense blocks: threads only cost

import numpy as np

import relmap as rm
from relmap.filter import LandmarkMap, Log, Status, correct_landmarks, predict, run
from relmap.lie import se2
from relmap.models import DistanceNoise, Odometry, RangeBearingSensor, increment

L = 50
SENSOR = RangeBearingSensor(0.1, np.radians(1.0), mount=[0.1, 0.0, 0.0], fov=np.pi, max_range=8.0)
NOISE = DistanceNoise(0.002, 0.002, 0.0005)  # var Δs = 0.002|Δs|, var Δθ = 0.002|Δθ| + 0.0005|Δs|
MOTION = Odometry(NOISE)
STEP = np.array([0.1, 0.1 / 6.0])  # commanded (Δs, Δθ): circles of radius 6 m
START = rm.AT([6.0, 0.0, np.pi / 2], np.diag([0.01, 0.01, 0.001]))
MRCLAM_SETS = (64, 1000)
TOL = 1e-9
FLOORS = {"a": 20.0, "b": 10.0, "c": 2.0}  # issue 31, item 4

Steps = list[tuple[np.ndarray, np.ndarray, np.ndarray]]  # per step: z (B, m, 2), valid, ids


def simulate(rng: np.random.Generator, landmarks: np.ndarray, B: int, T: int) -> Steps:
    """B Monte Carlo runs of T steps from START: per step, readings (B, m, 2) of the visible
    landmarks in random order, padded to the step's largest count, with validity and ids."""
    truth = np.broadcast_to(START.sample(B, seed=rng), (B, 3)).copy()
    Su = NOISE.covariance(STEP)
    steps = []
    for _ in range(T):
        moved = STEP + rng.multivariate_normal([0.0, 0.0], Su, size=B)
        truth = se2.compose(truth, increment(moved))
        z = SENSOR.h(truth[:, None, :], landmarks)  # (B, L, 2)
        seen = SENSOR.in_view(z)
        z = z + rng.normal(size=z.shape) * [SENSOR.sigma_range, SENSOR.sigma_bearing]
        order = np.argsort(np.where(seen, rng.random(seen.shape), 2.0), axis=1)
        m = int(seen.sum(axis=1).max())
        ids = order[:, :m]
        rows = np.arange(B)[:, None]
        steps.append((z[rows, ids], seen[rows, ids], ids))
    return steps


def first(steps: Steps) -> Steps:
    """The first filter's steps, its padding dropped: z (m, 2), valid (m,), ids (m,)."""
    return [(z[0][v[0]], v[0][v[0]], i[0][v[0]]) for z, v, i in steps]


# ------------------------------------------------------------------ relmap
def relmap_steps(state: rm.AT, steps: Steps, lmap: LandmarkMap, *, known: bool,
                 record: bool = False) -> list:  # fmt: skip
    """``predict`` + ``correct_landmarks`` per step (signatures, else Mahalanobis association);
    each step's correction if ``record``."""
    out = []
    for z, valid, ids in steps:
        state = predict(state, STEP, MOTION)
        if known:
            up = correct_landmarks(state, z, SENSOR, lmap, associate="signatures",
                                   signatures=ids, valid=valid)  # fmt: skip
        else:
            up = correct_landmarks(state, z, SENSOR, lmap, associate="mahalanobis", valid=valid)
        state = up.state
        if record:
            out.append(up)
    return out


def as_log(steps: Steps) -> Log:
    """One filter's steps (:func:`first`) as a Log (the readings of step k at time index k)."""
    index = np.concatenate([np.full(len(z), k + 1) for k, (z, _, _) in enumerate(steps)])
    return Log(np.arange(len(steps) + 1.0), np.tile(STEP, (len(steps), 1)), index,
               np.concatenate([z for z, _, _ in steps]),
               np.concatenate([i for _, _, i in steps]))  # fmt: skip


def models(n: int) -> tuple[Odometry, RangeBearingSensor]:
    """n noise parameter sets: k_s and σr scaled by 0.5 ... 2."""
    scale = np.linspace(0.5, 2.0, n)
    return (MOTION.replace(k_s=NOISE.k_s * scale),
            SENSOR.replace(sigma_range=SENSOR.sigma_range * scale))  # fmt: skip


# ------------------------------------------------------------------ filterpy
def filterpy_steps(steps: Steps, landmarks: np.ndarray, record: bool = False,
                   priors: list | None = None) -> list:  # fmt: skip
    """filterpy's EKF over ``steps`` (z (m, 2), ids (m,): the readings to update with and their
    landmarks); each step's ``(x, P)`` if ``record``; ``priors``: the state to start each step
    from (else the previous step's)."""
    from filterpy.kalman import ExtendedKalmanFilter

    mx, my, mt = SENSOR.mount
    var = np.array([SENSOR.sigma_range**2, SENSOR.sigma_bearing**2])

    def hx(x, idx):
        c, s = np.cos(x[2]), np.sin(x[2])
        d = landmarks[idx] - (x[0] + c * mx - s * my, x[1] + s * mx + c * my)
        h = np.empty(2 * len(idx))
        h[0::2] = np.hypot(d[:, 0], d[:, 1])
        h[1::2] = np.arctan2(d[:, 1], d[:, 0]) - (x[2] + mt)
        return h

    def jacobian(x, idx):
        c, s = np.cos(x[2]), np.sin(x[2])
        ax, ay = c * mx - s * my, s * mx + c * my
        d = landmarks[idx] - (x[0] + ax, x[1] + ay)
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
    out = []
    ds, dth = STEP
    Su = np.diag([NOISE.k_s * abs(ds), NOISE.k_theta * abs(dth) + NOISE.k_theta_s * abs(ds)])
    for k, (z, idx) in enumerate(steps):
        if priors is not None:
            kf.x, kf.P = priors[k][0].copy(), priors[k][1].copy()
        a = kf.x[2] + dth / 2
        c, s = np.cos(a), np.sin(a)
        kf.F = np.array([[1.0, 0.0, -ds * s], [0.0, 1.0, ds * c], [0.0, 0.0, 1.0]])
        Gu = np.array([[c, -ds * s / 2], [s, ds * c / 2], [0.0, 1.0]])
        kf.Q = Gu @ Su @ Gu.T
        kf.predict(u=STEP)
        if len(idx):
            kf.update(
                z.reshape(-1), jacobian, hx, R=np.diag(np.tile(var, len(idx))),
                args=(idx,), hx_args=(idx,), residual=residual,
            )  # fmt: skip
        if record:
            out.append((kf.x.copy(), kf.P.copy()))
    return out


def told(steps: Steps, ups: list, b: int | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """What filterpy is given: per step the readings relmap used (of filter ``b`` of a batch)
    and the landmarks relmap paired them with."""
    out = []
    for (z, _, _), up in zip(steps, ups, strict=True):
        zz, st, lm = (z, up.status, up.landmark) if b is None else (
            z[b], up.status[b], up.landmark[b])  # fmt: skip
        used = st == Status.USED
        out.append((zz[used], lm[used]))
    return out


def worst(a: list[tuple[np.ndarray, np.ndarray]], b: list[tuple[np.ndarray, np.ndarray]]):
    """max |Δmean| (heading wrapped) and max |ΔP|/|P| over the steps."""
    dm = max(float(np.abs(se2.minus(x, y)).max()) for (x, _), (y, _) in zip(a, b, strict=True))
    dc = max(
        float(np.abs(P - Q).max() / np.abs(Q).max()) for (_, P), (_, Q) in zip(a, b, strict=True)
    )
    return dm, dc


def check(what: str, a, b, tol: float = TOL, note: str = "") -> None:
    dm, dc = worst(a, b)
    print(f"  {what:<60} |Δmean| {dm:7.1e}  |ΔP|/|P| {dc:7.1e}{note}")
    if not (dm <= tol and dc <= tol):
        raise SystemExit(f"{what}: the states differ (tolerance {tol:g}); no timings")


def check_steps(what: str, steps: Steps, ups: list, landmarks: np.ndarray,
                b: int | None = None) -> int:  # fmt: skip
    """Mahalanobis association: each step of filterpy from relmap's state before it, given the
    pairs relmap used, compared with relmap's step — except where relmap took a reading as a
    mixture of landmarks (its gate held several: no filterpy update can say that). Returns the
    steps left out."""
    post = states(ups, b)
    fp = filterpy_steps(told(steps, ups, b), landmarks, True,
                        [(START.mean, START.cov), *post[:-1]])  # fmt: skip
    mixed = [bool((u.ambiguous if b is None else u.ambiguous[b]) > 0) for u in ups]
    keep = [k for k, m in enumerate(mixed) if not m]
    check(f"{what}, step by step", [post[k] for k in keep], [fp[k] for k in keep],
          note=f"  ({sum(mixed)} of {len(ups)} steps with a mixture left out)")  # fmt: skip
    return sum(mixed)


def states(ups: list, b: int | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(u.state.mean, u.state.cov) if b is None else (u.state.mean[b], u.state.cov[b])
            for u in ups]  # fmt: skip


# ------------------------------------------------------------------ timing
class Timed(NamedTuple):
    fn: Callable[[], object]
    steps: int  #: filter-steps per call
    floor: float | None = None  #: the issue's floor, filterpy / relmap per filter-step


def interleaved(runs: dict[str, Timed], repeat: int) -> dict[str, tuple[list[float], ...]]:
    """Wall and CPU (process) times of each run over ``repeat`` rounds, the calls interleaved so
    that a slow spell of this shared machine hits all contenders alike."""
    out: dict[str, tuple[list[float], list[float]]] = {k: ([], []) for k in runs}
    for _ in range(repeat):
        for name, r in runs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            r.fn()
            out[name][0].append(time.perf_counter() - t0)
            out[name][1].append(time.process_time() - c0)
    return out


def load() -> str:
    return "load averages " + " ".join(f"{v:.2f}" for v in os.getloadavg())


def mrclam_setup(folder: Path):
    """MRCLAM robot 1's log, map and start, and the models of robot 2's noise against its ground
    truth; or None without the data."""
    if not Path(folder, "landmarks", "mrclam6").is_dir():
        return None
    from relmap.app.localize import calibrate_mrclam
    from relmap.io import read_mrclam

    data = read_mrclam(Path(folder, "landmarks", "mrclam6"))
    r1 = data.robots[0]
    lm = data.landmark_index(r1.meas_subject)
    keep = lm >= 0
    inside = (r1.odometry_t >= r1.truth_t[0]) & (r1.odometry_t <= r1.truth_t[-1])
    o = np.flatnonzero(inside)
    log = Log.from_velocities(
        r1.odometry_t[o[0]:], r1.odometry_v[o[0]:], r1.odometry_w[o[0]:], r1.meas_t[keep],
        np.column_stack([r1.meas_range[keep], r1.meas_bearing[keep]]), lm[keep],
        end=float(r1.odometry_t[o[-1]]),
    )  # fmt: skip
    start = rm.AT(r1.truth_at(log.t[:1])[0], np.diag([4e-4, 4e-4, 4e-4]))
    cal = calibrate_mrclam(data, 2)
    return log, LandmarkMap(data.landmark_xy), start, cal.motion, cal.sensor


def mrclam_models(motion: Odometry, sensor: RangeBearingSensor, n: int):
    """n parameter sets about the given noise (k_s and σr scaled by 0.5 ... 4)."""
    scale = np.linspace(0.5, 4.0, n)
    return (motion.replace(k_s=motion.noise.k_s * scale),
            sensor.replace(sigma_range=sensor.sigma_range * scale))  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000, help="steps of the single filter")
    parser.add_argument("--batch", type=int, default=1000, help="filters in a batch")
    parser.add_argument("--batch-steps", type=int, default=100,
                        help="steps of a batch (380: one lap)")  # fmt: skip
    parser.add_argument("--repeat", type=int, default=3, help="interleaved repeats")
    parser.add_argument("--no-mrclam", action="store_true", help="skip the MRCLAM runs")
    args = parser.parse_args()
    T, B, TB = args.steps, args.batch, args.batch_steps
    print(f"{load()} (before)")
    rng = np.random.default_rng(0)
    landmarks = rng.uniform(-10.0, 10.0, (L, 2))
    lmap = LandmarkMap(landmarks)  # the landmark ids (rows) are their signatures
    single = first(simulate(rng, landmarks, 1, T))
    log = as_log(single)
    mc = simulate(np.random.default_rng(1), landmarks, B, TB)
    lap = as_log(first(mc))
    starts = rm.AT(np.broadcast_to(START.mean, (B, 3)), np.broadcast_to(START.cov, (B, 3, 3)))
    motion_b, sensor_b = models(B)

    # --- the same numbers first
    print(f"checks (every step; tolerance {TOL:g}):")
    known = relmap_steps(START, single, lmap, known=True, record=True)
    maha = relmap_steps(START, single, lmap, known=False, record=True)
    check("(c) stepped, signatures, vs filterpy",
          states(known), filterpy_steps(told(single, known), landmarks, True))  # fmt: skip
    check_steps("    stepped, Mahalanobis, vs filterpy", single, maha, landmarks)
    tr = run(log, MOTION, SENSOR, lmap, start=START, associate="signatures")
    check("    run, signatures, vs stepped", [(tr.mean[k + 1], tr.cov[k + 1]) for k in range(T)],
          states(known))  # fmt: skip
    mixed_mc = 0.0
    for is_known, name in ((True, "(a)"), (False, "(b)")):
        ups = relmap_steps(starts, mc, lmap, known=is_known, record=True)
        if is_known:
            check(f"{name} Monte Carlo batch, its filter 0, vs filterpy", states(ups, 0),
                  filterpy_steps(told(mc, ups, 0), landmarks, True))  # fmt: skip
        else:
            check_steps(f"{name} Monte Carlo batch, filter 0, vs filterpy", mc, ups, landmarks, 0)
            mixed_mc = float(np.mean([u.ambiguous for u in ups]))
        a = "signatures" if is_known else "mahalanobis"
        whole = run(lap, motion_b, sensor_b, lmap, start=START, associate=a, keep="summary",
                    readings=False)  # fmt: skip
        for j in (0, B - 1):
            alone = run(lap, MOTION.replace(k_s=motion_b.noise.k_s[j]),
                        SENSOR.replace(sigma_range=sensor_b.sigma_range[j]), lmap, start=START,
                        associate=a, keep="summary", readings=False)  # fmt: skip
            check(f"{name} parameter batch, its filter {j}, vs that filter alone",
                  [(whole.mean[j, -1], whole.cov[j, -1])],
                  [(alone.mean[-1], alone.cov[-1])], 1e-12)  # fmt: skip

    folder = Path(os.environ.get("RELMAP_DATA",
                                 Path(__file__).resolve().parents[2] / "shared" / "data"))  # fmt: skip
    mr = None if args.no_mrclam else mrclam_setup(folder)
    if mr is not None:
        mlog, mmap, mstart, mmotion, msensor = mr
        m64, s64 = mrclam_models(mmotion, msensor, MRCLAM_SETS[0])
        whole = run(mlog, m64, s64, mmap, start=mstart, keep="summary", readings=False)
        alone = run(mlog, m64.replace(k_s=m64.noise.k_s[0]),
                    s64.replace(sigma_range=s64.sigma_range[0]), mmap, start=mstart,
                    keep="summary", readings=False)  # fmt: skip
        check("MRCLAM robot 1, 64 sets, its filter 0, vs that filter alone",
              [(whole.mean[0, -1], whole.cov[0, -1])], [(alone.mean[-1], alone.cov[-1])],
              1e-12)  # fmt: skip

    used = [int((u.status == Status.USED).sum()) for u in known]
    right = sum(int(((u.status == Status.USED) & (u.landmark == ids)).sum())
                for u, (_, _, ids) in zip(maha, single, strict=True))  # fmt: skip
    right /= sum(int((u.status == Status.USED).sum()) for u in maha)
    print(f"scenario: one filter {T} steps, {np.mean([len(z) for z, _, _ in single]):.1f} "
          f"readings per step ({np.mean(used):.1f} used); batches {B} filters x {TB} steps, "
          f"{np.mean([v.sum(axis=1).mean() for _, v, _ in mc]):.1f} readings per step (padded to "
          f"{np.mean([z.shape[1] for z, _, _ in mc]):.1f}); {L} landmarks")  # fmt: skip
    print(f"Mahalanobis: {right:.2%} of the used readings paired right; readings per step taken "
          f"as a mixture of landmarks: {np.mean([u.ambiguous for u in maha]):.2f} (one filter), "
          f"{mixed_mc:.2f} (batch)")  # fmt: skip

    # --- timings, interleaved
    fp_told = told(single, known)
    runs: dict[str, Timed] = {
        "filterpy, stepped (told the pairs)": Timed(lambda: filterpy_steps(fp_told, landmarks), T),
        "(c) stepped, signatures": Timed(
            lambda: relmap_steps(START, single, lmap, known=True), T, FLOORS["c"]),
        "    stepped, Mahalanobis": Timed(
            lambda: relmap_steps(START, single, lmap, known=False), T),
        "    run, signatures": Timed(lambda: run(log, MOTION, SENSOR, lmap, start=START), T),
        "(a) Monte Carlo batch, signatures": Timed(
            lambda: relmap_steps(starts, mc, lmap, known=True), B * TB, FLOORS["a"]),
        "(a) parameter batch (run), signatures": Timed(
            lambda: run(lap, motion_b, sensor_b, lmap, start=START, keep="summary",
                        readings=False), B * TB, FLOORS["a"]),
        "(b) Monte Carlo batch, Mahalanobis": Timed(
            lambda: relmap_steps(starts, mc, lmap, known=False), B * TB, FLOORS["b"]),
        "(b) parameter batch (run), Mahalanobis": Timed(
            lambda: run(lap, motion_b, sensor_b, lmap, start=START, associate="mahalanobis",
                        keep="summary", readings=False), B * TB, FLOORS["b"]),
    }  # fmt: skip
    if mr is not None:
        for n in MRCLAM_SETS:
            mm, ss = mrclam_models(mmotion, msensor, n)
            runs[f"MRCLAM robot 1, {n} parameter sets"] = Timed(
                lambda mm=mm, ss=ss: run(mlog, mm, ss, mmap, start=mstart, keep="summary",
                                         readings=False), len(mlog.t) * n)  # fmt: skip
    t0 = time.perf_counter()
    times = interleaved(runs, args.repeat)
    print(f"\ntimed in {time.perf_counter() - t0:.0f} s; {load()} (after; 2 cores, shared)")
    print(f"µs per filter-step over {args.repeat} interleaved repeats: wall min, wall median, "
          "CPU min; the ratios filterpy / relmap per filter-step from each")  # fmt: skip
    fp = [f(t) / T for f, t in ((min, times[next(iter(runs))][0]),
                                (np.median, times[next(iter(runs))][0]),
                                (min, times[next(iter(runs))][1]))]  # fmt: skip
    for name, r in runs.items():
        wall, cpu = times[name]
        mine = [min(wall) / r.steps, float(np.median(wall)) / r.steps, min(cpu) / r.steps]
        line = f"  {name:<40}" + "".join(f"{v * 1e6:9.3f}" for v in mine)
        if name.startswith("MRCLAM"):
            line += f"   ({min(wall):.3f} s min, {np.median(wall):.3f} s median a run)"
        elif not name.startswith("filterpy"):
            line += "  " + "".join(f"{a / b:7.1f}x" for a, b in zip(fp, mine, strict=True))
        if r.floor is not None:
            ok = min(a / b for a, b in zip(fp, mine, strict=True)) >= r.floor
            line += f"  floor {r.floor:g}x: {'meets' if ok else 'MISSES'}"
        print(line)
    if mr is not None:
        print(f"MRCLAM robot 1: {len(mlog.t)} filter times, {len(mlog.z)} readings, signatures")


if __name__ == "__main__":
    main()
