"""Dead reckoning with covariance over a long run: relmap vs a GTSAM loop vs a per-step numpy loop.

N wheel-odometry steps of a differential-drive robot (midpoint integration, proportional wheel
noise), every intermediate pose and covariance kept:

- relmap: ``relmap.models.dead_reckon`` (each step an AT in the robot frame, the run one parallel
  scan);
- GTSAM: a Python loop of ``Pose2.compose`` with Jacobians and the covariance update in GTSAM's
  body chart (each step's covariance converted once, before timing);
- numpy loop: the lecture's recursion ``Σ' = Gx Σ Gxᵀ + Gu Σu Guᵀ`` one step at a time.

All three are checked to agree before the timings are printed.
Run: ``python benchmarks/bench_odometry.py [--n 1000000] [--repeat 3]`` (min and median of
interleaved repeats).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import gtsam
import numpy as np

import relmap as rm
from relmap.lie import se2
from relmap.models import DiffDrive, WheelNoise, dead_reckon, increment


def numpy_loop(u: np.ndarray, drive: DiffDrive, noise: WheelNoise) -> tuple[np.ndarray, np.ndarray]:
    r, b = drive.wheel_radius, drive.baseline
    n = len(u)
    poses, covs = np.zeros((n + 1, 3)), np.zeros((n + 1, 3, 3))
    x, P = np.zeros(3), np.zeros((3, 3))
    for k in range(n):
        ul, ur = u[k]
        ds, dth = r * (ul + ur) / 2, r * (ur - ul) / b
        a = x[2] + dth / 2
        c, s = np.cos(a), np.sin(a)
        Gx = np.array([[1.0, 0.0, -ds * s], [0.0, 1.0, ds * c], [0.0, 0.0, 1.0]])
        dds = np.array([r / 2, r / 2])
        ddt = np.array([-r / b, r / b])
        Gu = np.array(
            [
                dds * c - ds * s * ddt / 2,
                dds * s + ds * c * ddt / 2,
                ddt,
            ]
        )
        Su = np.diag(noise.sigma**2 + noise.k * np.abs(u[k]))
        x = np.array([x[0] + ds * c, x[1] + ds * s, x[2] + dth])
        P = Gx @ P @ Gx.T + Gu @ Su @ Gu.T
        poses[k + 1], covs[k + 1] = x, P
    poses[:, 2] = se2.wrap_angle(poses[:, 2])
    return poses, covs


def gtsam_loop(steps: rm.AT) -> tuple[np.ndarray, np.ndarray]:
    n = steps.batch_shape[0]
    body = steps.to_body()
    means = steps.mean
    poses, covs = np.zeros((n + 1, 3)), np.zeros((n + 1, 3, 3))
    pose, cov = gtsam.Pose2(), np.zeros((3, 3))
    for k in range(n):
        H1, H2 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        pose = pose.compose(gtsam.Pose2(*means[k]), H1, H2)
        cov = H1 @ cov @ H1.T + H2 @ body[k] @ H2.T
        poses[k + 1] = (pose.x(), pose.y(), pose.theta())
        covs[k + 1] = cov
    return poses, covs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=3)
    n = parser.parse_args().n
    repeat = parser.parse_args().repeat
    rng = np.random.default_rng(0)
    drive = DiffDrive(0.05, 0.3)
    noise = WheelNoise(sigma=0.002, k=0.0005)
    u = np.abs(rng.normal([1.0, 1.05], 0.2, (n, 2)))

    # GTSAM gets each step as a Pose2 and its body-frame covariance, prepared before timing
    motion = drive.motion(u)
    steps_at = rm.AT(increment(motion), _step_covs(motion, noise, drive))
    run = dead_reckon(u, noise, drive=drive)
    g_poses, g_covs = gtsam_loop(steps_at)
    np_poses, np_covs = numpy_loop(u, drive, noise)
    back = rm.AT.from_body(g_poses[1:], g_covs[1:])
    for name, poses, covs in (
        ("GTSAM", back.mean, back.cov),
        ("numpy loop", np_poses[1:], np_covs[1:]),
    ):
        dm = np.abs(se2.minus(run.mean[1:], poses)).max()
        dc = (
            np.linalg.norm(run.cov[1:] - covs, axis=(1, 2)) / np.linalg.norm(covs, axis=(1, 2))
        ).max()
        assert dm < 1e-6 and dc < 1e-8, (name, dm, dc)

    runs = {
        "relmap dead_reckon": lambda: dead_reckon(u, noise, drive=drive),
        "GTSAM compose loop": lambda: gtsam_loop(steps_at),
        "numpy per-step loop": lambda: numpy_loop(u, drive, noise),
    }
    times: dict[str, list[float]] = {k: [] for k in runs}
    for _ in range(repeat):  # interleaved: a slow spell of the shared machine hits all alike
        for name, fn in runs.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    print(f"dead reckoning, {n:,} steps, every pose and covariance kept (results checked equal); "
          f"min / median of {repeat} interleaved repeats; load averages "
          + " ".join(f"{v:.2f}" for v in os.getloadavg()))  # fmt: skip
    for name, t in times.items():
        lo, med = min(t), float(np.median(t))
        print(f"  {name:<22} {lo * 1e3:10.1f} {med * 1e3:10.1f} ms  {lo / n * 1e9:8.1f} "
              f"{med / n * 1e9:8.1f} ns/step")  # fmt: skip
    rel = times["relmap dead_reckon"]
    for name in ("GTSAM compose loop", "numpy per-step loop"):
        t = times[name]
        print(f"  relmap vs {name}: {min(t) / min(rel):.0f}x (min), "
              f"{np.median(t) / np.median(rel):.0f}x (median)")  # fmt: skip


def _step_covs(motion: np.ndarray, noise: WheelNoise, drive: DiffDrive) -> np.ndarray:
    _, J = increment(motion, jacobians=True)
    S = noise.covariance(motion, drive)
    return J @ S @ np.swapaxes(J, -1, -2)


if __name__ == "__main__":
    main()
