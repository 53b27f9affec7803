"""Dead reckoning of the five MRCLAM robots with covariance, and how well calibrated it is.

The noise model (relmap.models.DistanceNoise: random-walk errors per metre and per radian) is
fitted on robot 1 only, by the method of moments on windows of the run
(relmap.models.calibration.fit_distance_noise), then every robot is dead-reckoned from its true
start over its whole run. Printed: the fitted parameters for several window lengths, and for
each robot the fraction of time the ground truth lies inside the predicted 90% position
ellipse, overall and per tenth of the run.

Run: python examples/mrclam_odometry.py [DATA_DIR]   (default ../shared/data)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import relmap as rm
from relmap.io import read_mrclam
from relmap.models import dead_reckon, increments_from_velocities
from relmap.models.calibration import fit_distance_noise
from relmap.uncertain import gaussian


def clipped(robot):
    """The odometry log within the ground truth's span (ground truth is needed to score)."""
    t = robot.odometry_t
    inside = (t >= robot.truth_t[0]) & (t <= robot.truth_t[-1])
    return t[inside], robot.odometry_v[inside], robot.odometry_w[inside]


def coverage(robot, noise, probability=0.9):
    t, v, w = clipped(robot)
    run = dead_reckon(increments_from_velocities(t, v, w), noise, start=rm.AT(robot.truth_at(t[0])))
    d2 = gaussian.mahalanobis2(robot.truth_at(t)[:, :2], run.mean[:, :2], run.cov[:, :2, :2])
    inside = d2[1:] <= gaussian.confidence_k2(probability, 2)
    return inside.mean(), [b.mean() for b in np.array_split(inside, 10)], run


def main() -> None:
    root = (
        Path(sys.argv[1])
        if len(sys.argv) > 1
        else Path(__file__).resolve().parents[2] / "shared" / "data"
    )
    data = read_mrclam(root / "landmarks" / "mrclam6")
    train = data.robots[0]
    print("noise fitted on robot 1 (method of moments on windows); 90% coverage per robot")
    for window in (2.0, 10.0, 30.0, 60.0):
        fit = fit_distance_noise(*clipped(train), train.truth_at, window=window)
        n = fit.noise
        rates = [coverage(r, n)[0] for r in data.robots]
        print(
            f"  window {window:4.0f} s: k_s={n.k_s:.4f} m²/m, k_θ={n.k_theta:.4f} rad²/rad, "
            f"k_θs={n.k_theta_s:.4f} rad²/m -> coverage " + " ".join(f"{c:.2f}" for c in rates)
        )
    fit = fit_distance_noise(*clipped(train), train.truth_at, window=30.0)
    print("\nwith the 30 s fit, coverage over time (tenths of each run):")
    for r in data.robots:
        total, tenths, run = coverage(r, fit.noise)
        t, _, _ = clipped(r)
        err = np.hypot(*(r.truth_at(t[-1])[:2] - run.mean[-1, :2]))
        print(
            f"  robot {r.robot}: {total:.2f}  ["
            + " ".join(f"{c:.2f}" for c in tenths)
            + f"]  final error {err:.2f} m"
        )


if __name__ == "__main__":
    main()
