"""examples/panorama_camera.py: a measurement model relmap does not ship, written by a user in a
few lines, goes through the filter (Mahalanobis association) and the autocalibration exactly as
the built-ins do — on robots simulated by relmap.sim with known noise, the calibration finds
that noise and the filter is consistent."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

import relmap as rm
import relmap.filter as rf
from relmap.filter import autocalibration, run
from relmap.models import DistanceNoise, Odometry
from relmap.sim import Patrol, random_landmarks, simulate
from tests.conftest import PROJECT_ROOT

EXAMPLE = PROJECT_ROOT / "examples" / "panorama_camera.py"


def _definitions(path: Path) -> dict[str, object]:
    """The example's imports and classes, without its script (which calibrates)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    tree.body = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom, ast.ClassDef))]
    namespace: dict[str, object] = {}
    exec(compile(tree, str(path), "exec"), namespace)
    return namespace


Panorama = _definitions(EXAMPLE)["Panorama"]
#: The example's world: 8 landmarks with heights, the robot patrolling 4 m back and forth.
LANDMARKS = random_landmarks(5, 8, (-6, -6, 1.5), (6, 6, 3))
ROUTE = [[2, 0], [-2, 0]]
ODOMETRY, CAMERA = Odometry(DistanceNoise(0.01, 0.01, 0.002)), Panorama(0.02)
TRUTH = {"k_s": 0.01, "k_theta": 0.01, "k_theta_s": 0.002, "sigma": 0.02}
#: Where the calibration starts: five times the truth (cautious).
GUESS = Odometry(DistanceNoise(0.05, 0.05, 0.01)), Panorama(0.1)
#: The length of the calibrated run (odometry steps of 0.1 s, a reading time each).
STEPS = 2000
#: The calibration's gate: open (χ²₂ 27.6). The landmarks stand far apart in the camera's
#: angles, so the association needs none; a 0.99 gate drops the largest true innovations and
#: the likelihood then asks for more odometry noise (k_theta +21% to +25% on seeds 1-3).
GATE = 1 - 1e-6


def _fitted(cal: autocalibration.Calibrated) -> dict[str, float]:
    return {k: float(getattr(cal.motion if k != "sigma" else cal.sensor, k)) for k in TRUTH}


@pytest.mark.slow
def test_the_example_runs_in_30_lines():
    """Its own short run (300 steps, 30 s of driving): every reading paired with its landmark
    and the camera's σ found within 5% (measured +0.2%). So short a run does not pin the
    odometry's noise (measured: k_s +7.2%, k_theta -10%, k_theta_s -32%); the long run of the
    tests below does."""
    assert len(EXAMPLE.read_text(encoding="utf-8").splitlines()) <= 30
    done = subprocess.run([sys.executable, str(EXAMPLE)], capture_output=True, text=True,
                          cwd=PROJECT_ROOT, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert float(re.search(r"paired right ([\d.]+)%", done.stdout)[1]) >= 99.0
    got = {name: float(re.search(rf"\b{name}=([\d.e-]+)", done.stdout)[1]) for name in TRUTH}
    assert got["sigma"] == pytest.approx(TRUTH["sigma"], rel=0.05), done.stdout
    assert all(v > 0 for v in got.values())


@pytest.fixture(scope="module")
def calibrated() -> autocalibration.Calibrated:
    """The noise of one simulated run of STEPS steps, calibrated from its innovations with
    Mahalanobis association (no ground truth, no signatures), from GUESS."""
    x0 = rm.AT([-2.0, 0.0, 0.0])
    sim = simulate(Patrol(ROUTE), ODOMETRY, CAMERA, LANDMARKS, start=x0, steps=STEPS, seed=1)
    wall, cpu = time.perf_counter(), time.process_time()
    cal = autocalibration.calibrate(sim.recording(), *GUESS, LANDMARKS, start=lambda t: x0,
                                    associate="mahalanobis", gate=GATE)  # fmt: skip
    print(f"\ncalibrate, {STEPS} reading times: {time.perf_counter() - wall:.0f} s "
          f"({time.process_time() - cpu:.0f} s CPU)")  # fmt: skip
    return cal


@pytest.mark.slow
def test_autocalibration_recovers_the_simulated_noise(calibrated):
    """Every simulated noise parameter within 10%: the odometry's k_s, k_theta, k_theta_s and
    the camera's σ, from GUESS (five times the truth), with no signatures (the association
    Mahalanobis, the clutter fitted too: it comes out at none). Measured on this run (seed 1):
    k_s -0.5%, k_theta -7.7%, k_theta_s -2.0%, σ -0.2%; seed 2 -5.0%, +5.8%, -0.3%, -0.2%;
    seed 3 0.0%, +3.8%, -12%, -0.3% (k_theta_s outside). Odometry noise is learnt once per
    interval between readings, and the camera (σ 0.02 rad over 8 landmarks) sees the heading
    less sharply than a step's noise moves it (0.0017 rad a turn step), so 200 s of patrol
    pin the odometry's noise to about 10%, not better. With a sharper camera (0.005 rad) the
    first-order odometry noise's rank (docs/simulation.md) biases k_theta instead."""
    got = _fitted(calibrated)
    for name, want in TRUTH.items():
        assert got[name] == pytest.approx(want, rel=0.10), (name, got)
    assert calibrated.clutter_fraction < 0.01
    assert calibrated.delay == 0.0 and calibrated.inflation == 1.0


def _anees(motion, sensor, options, runs=100, steps=150, seed=2):
    """The ANEES at four well-separated times of ``runs`` simulated runs, one batch of filters
    each on its own log (Mahalanobis association; the scans padded with NaN readings to the
    most any run read, so that the logs share their reading times), NEES taken of each run
    once per time: ``(times, ANEES (4,))``."""
    prior = rm.AT([-2.0, 0.0, 0.0], np.diag([0.01, 0.01, 0.001]))
    sim = simulate(Patrol(ROUTE), ODOMETRY, CAMERA, LANDMARKS, start=prior, steps=steps,
                   runs=runs, seed=seed)  # fmt: skip
    scans = sim.scans()
    index = np.repeat(scans.reading_index, scans.z.shape[-2])
    logs = [rf.Log(sim.t, sim.inputs[r], index, scans.z[r].reshape(-1, 2)) for r in range(runs)]
    tr = run(logs, motion, sensor, LANDMARKS, start=prior, associate="mahalanobis",
             keep="events", readings=False, **options)  # fmt: skip
    steps_kept = np.searchsorted(sim.t, tr.t)
    times = np.linspace(steps // 4, steps, 4).astype(int)
    assert np.isin(times, steps_kept).all()  # (a reading at every step)
    k = np.searchsorted(steps_kept, times)
    e = rm.lie.se2.minus(sim.truth[:, times], tr.mean[:, k])
    nees = np.einsum("rti,rti->rt", e, np.linalg.solve(tr.cov[:, k], e[..., None])[..., 0])
    return times, nees.mean(axis=0) / 3


#: The ANEES of 100 runs at one time, if the filters are consistent: χ²(300)/300. Its 95%
#: interval. (One NEES per run at a time: the runs are independent, a run's times are not.)
ANEES_95 = tuple(stats.chi2.ppf(q, 300) / 300 for q in (0.025, 0.975))


@pytest.mark.slow
def test_anees_of_100_runs_with_the_true_noise_is_in_its_chi2_interval():
    """The filter with the simulated noise: its ANEES over 100 runs of 15 s (150 reading
    times), at the last time, lies in [0.846, 1.166]; at the other three times (4, 8 and 11 s;
    correlated with it) it is reported. Measured: see the report."""
    times, anees = _anees(ODOMETRY, CAMERA, {})
    print(f"\nANEES at steps {times}: {anees.round(3)} (95% interval {np.round(ANEES_95, 3)})")
    assert ANEES_95[0] <= anees[-1] <= ANEES_95[1], anees


@pytest.mark.slow
def test_anees_of_100_runs_with_the_calibrated_noise_is_in_its_chi2_interval(calibrated):
    """The same with the noise autocalibration found (and its weights: Student-t dof, clutter,
    inflation) instead of the truth."""
    times, anees = _anees(calibrated.motion, calibrated.sensor, calibrated.options)
    print(f"\nANEES at steps {times}: {anees.round(3)} (95% interval {np.round(ANEES_95, 3)})")
    assert ANEES_95[0] <= anees[-1] <= ANEES_95[1], anees
