"""relmap.sim.robots against the mathematics: the simulated errors have the models' covariances
(Monte Carlo within its sampling error), a noise-free robot is dead reckoning and ``h`` exactly,
the random draws have their distributions, seeds reproduce, bad input is named."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy import stats

import relmap as rm
from relmap.errors import ParameterError, RelmapError, ShapeError
from relmap.filter import Status, run
from relmap.lie import se2, so3
from relmap.models import (
    AlphaNoise,
    DiffDrive,
    DistanceNoise,
    Odometry,
    PositionFix,
    RangeBearingSensor,
    WheelNoise,
    dead_reckon,
)
from relmap.sim import (
    Patrol,
    random_at3s,
    random_ats,
    random_covariances,
    random_landmarks,
    random_poses,
    simulate,
)
from tests.conftest import PROJECT_ROOT

MOTIONS = {
    "distance": Odometry(DistanceNoise(0.01, 0.02, 0.004)),
    "distance-arc": Odometry(DistanceNoise(0.01, 0.02, 0.004), integration="arc"),
    "wheels": Odometry(WheelNoise(0.01, 0.02), drive=DiffDrive(0.1, 0.5)),
    "alpha": Odometry(AlphaNoise(0.05, 0.01, 0.05, 0.01)),
}
SENSOR = RangeBearingSensor(0.05, 0.01, fov=np.pi, max_range=8.0, min_range=0.5)
LANDMARKS = random_landmarks(0, 30)
START = rm.AT([0.0, 0.0, 0.3], np.diag([0.01, 0.01, 0.001]))
#: A wavy open-loop drive of 60 steps (v, ω).
COMMANDS = np.column_stack([0.5 + 0.2 * np.sin(np.arange(60) / 9), 0.4 * np.cos(np.arange(60) / 7)])


def _within_sampling_error(e: np.ndarray, cov: np.ndarray, k: float = 5.0) -> None:
    """Samples ``e`` (n, d) of N(0, cov): the sample mean and covariance within ``k`` standard
    errors of 0 and ``cov`` (a sample covariance entry's variance is (Σii Σjj + Σij²)/n)."""
    n = len(e)
    var = np.diagonal(cov)
    assert np.all(np.abs(e.mean(axis=0)) <= k * np.sqrt(var / n) + 1e-15), (e.mean(0), var)
    se = np.sqrt((np.outer(var, var) + cov**2) / n)
    S = np.cov(e, rowvar=False)
    assert np.all(np.abs(S - cov) <= k * se + 1e-15), (S, cov, se)


# ------------------------------------------------------------------ random poses and maps
def test_random_draws_reproduce_and_have_their_shapes():
    for f, kw in ((random_poses, {}), (random_covariances, {"n": 4}), (random_landmarks, {})):
        args = (7, 5) if f is random_landmarks else (7, (2, 5))
        np.testing.assert_array_equal(f(*args, **kw), f(*args, **kw))
    assert random_poses(1, (2, 5)).shape == (2, 5, 3)
    assert random_covariances(1, 4, n=6).shape == (4, 6, 6)
    a, b = random_ats(3, (4, 2)), random_ats(3, (4, 2))
    assert a.batch_shape == (4, 2)
    np.testing.assert_array_equal(a.mean, b.mean) and np.testing.assert_array_equal(a.cov, b.cov)
    g = np.random.default_rng(1)
    assert not np.array_equal(random_ats(g, 3).mean, random_ats(g, 3).mean)  # a generator moves
    assert random_at3s(5, (3, 2)).batch_shape == (3, 2)
    assert np.linalg.eigvalsh(random_covariances(2, 1000, n=6)).min() > 0


def test_random_headings_rotations_and_landmarks_are_uniform():
    """Headings uniform on [-π, π); rotations uniform on SO(3) — the angle θ of a uniform
    rotation has the CDF (θ - sin θ)/π, and E[R] = 0 —; landmarks uniform in their box."""
    th = random_poses(1, 20_000)[:, 2]
    assert stats.kstest(th, stats.uniform(-np.pi, 2 * np.pi).cdf).pvalue > 1e-3
    R = random_at3s(2, 20_000).rotation
    angle = np.linalg.norm(so3.log(R), axis=-1)
    assert stats.kstest(angle, lambda x: (x - np.sin(x)) / np.pi).pvalue > 1e-3
    assert np.abs(R.mean(axis=0)).max() < 5 * np.sqrt(1 / 3 / 20_000)
    lm = random_landmarks(3, 20_000, (-2.0, 1.0), (4.0, 2.0))
    assert lm.min(0) @ [1, 0] >= -2 and lm.max(0) @ [0, 1] <= 2
    for j, (lo, hi) in enumerate(((-2.0, 4.0), (1.0, 2.0))):
        assert stats.kstest(lm[:, j], stats.uniform(lo, hi - lo).cdf).pvalue > 1e-3


# ------------------------------------------------------------------ the robot
@pytest.mark.parametrize("name", MOTIONS)
def test_one_step_errors_have_the_motion_models_covariance(name):
    """20 000 robots make one commanded step: the true step ⊟ the commanded one has mean 0 and
    the model's covariance J Q Jᵀ (its step's AT) within the sampling error."""
    motion = MOTIONS[name]
    sim = simulate([[0.8, 0.6]], motion, SENSOR, LANDMARKS, start=[1.0, 2.0, 0.5], dt=0.5,
                   runs=20_000, every=2, seed=1)  # fmt: skip
    assert len(sim.z) == 0  # (no reading time in one step of every 2)
    step = motion.increment(sim.inputs[0, 0])
    e = se2.minus(se2.between(sim.truth[:, 0], sim.truth[:, 1]), step.mean)
    _within_sampling_error(e, step.cov)


def test_a_runs_errors_accumulate_as_dead_reckoning_says():
    """5000 robots drive the wavy path: their final poses spread as dead reckoning's
    covariance (the steps compounded to first order) says, about its mean — for a noise small
    enough for first order (final heading σ 0.02 rad: a bias of order σ², 0.1 SE here)."""
    motion = Odometry(DistanceNoise(1e-4, 2e-4, 4e-5))
    sim = simulate(COMMANDS, motion, SENSOR, LANDMARKS, start=[0.0, 0.0, 0.3], runs=5000,
                   every=1000, seed=2)  # fmt: skip
    dr = dead_reckon(sim.inputs[0], motion.noise, start=rm.AT([0.0, 0.0, 0.3]))
    _within_sampling_error(se2.minus(sim.truth[:, -1], dr.mean[-1]), dr.cov[-1])


@pytest.mark.parametrize("name", MOTIONS)
def test_a_noise_free_robot_is_dead_reckoning_and_reads_h_exactly(name):
    motion = MOTIONS[name]
    quiet = motion.replace(**{k: 0.0 for k in motion.noise_parameters})
    sensor = SENSOR.replace(sigma_range=0.0, sigma_bearing=0.0)
    sim = simulate(COMMANDS, quiet, sensor, LANDMARKS, start=[1.0, 2.0, 0.3], seed=3)
    dr = dead_reckon(sim.inputs, quiet.noise, start=rm.AT([1.0, 2.0, 0.3]),
                     integration=quiet.integration, drive=quiet.drive)  # fmt: skip
    assert np.abs(se2.minus(sim.truth, dr.mean)).max() < 1e-12
    h = sensor.h(sim.truth[sim.reading_index], LANDMARKS[sim.landmark])
    np.testing.assert_array_equal(sim.z, h)
    assert len(sim.z) > 100


def test_readings_errors_have_the_sensors_covariance():
    """Range-proportional noise: each reading's error, whitened by R(ẑ)^(-1/2), is N(0, I);
    its d² is χ²₂ (Kolmogorov-Smirnov)."""
    sensor = RangeBearingSensor(0.02, 0.01, noise_model="proportional", max_range=6.0)
    sim = simulate(COMMANDS, MOTIONS["distance"], sensor, LANDMARKS, start=START, runs=40, seed=4)
    h = sensor.h(sim.truth[sim.run, sim.reading_index], LANDMARKS[sim.landmark])
    e = sensor.innovation(sim.z, h)
    L = np.linalg.cholesky(sensor.noise(h))
    w = np.linalg.solve(L, e[..., None])[..., 0]
    assert len(w) > 10_000
    _within_sampling_error(w, np.eye(2))
    assert stats.kstest((w * w).sum(-1), stats.chi2(2).cdf).pvalue > 1e-3


def test_readings_of_the_state_by_a_model_without_landmarks():
    """A position fix (landmark_dim 0): one reading a time, z - (x, y) ~ N(0, σ² I)."""
    sensor = PositionFix(0.3)
    sim = simulate(COMMANDS, MOTIONS["distance"], sensor, np.zeros((0, 1)), start=START,
                   runs=300, every=3, seed=5)  # fmt: skip
    assert len(sim.z) == 300 * 20 and (sim.landmark == 0).all()
    e = sim.z - sim.truth[sim.run, sim.reading_index, :2]
    _within_sampling_error(e, 0.09 * np.eye(2))


def test_the_sensor_reads_what_is_in_view_detected_or_not():
    sim = simulate(COMMANDS, MOTIONS["distance"], SENSOR, LANDMARKS, start=START, runs=20, seed=6)
    h = SENSOR.h(sim.truth[:, 1:, None, :], LANDMARKS)  # every landmark at every reading time
    seen = SENSOR.in_view(h)
    counts = np.zeros(seen.shape[:2], int)
    np.add.at(counts, (sim.run, sim.reading_index - 1), 1)
    np.testing.assert_array_equal(counts, seen.sum(-1))  # all in view, nothing else
    assert SENSOR.in_view(SENSOR.h(sim.truth[sim.run, sim.reading_index],
                                   LANDMARKS[sim.landmark])).all()  # fmt: skip
    half = simulate(COMMANDS, MOTIONS["distance"], SENSOR, LANDMARKS, start=START, runs=20,
                    seed=6, detection=0.5)  # fmt: skip
    n = seen.sum()
    assert abs(len(half.z) / n - 0.5) < 5 * np.sqrt(0.25 / n)
    near = simulate(COMMANDS, MOTIONS["distance"], SENSOR, LANDMARKS, start=START, runs=20,
                    seed=6, visible=lambda z: z[..., 0] < 3.0)  # fmt: skip
    assert len(near.z) and (near.z[:, 0] < 3.5).all()  # (3 m and the noise)


def test_clutter_is_poisson_per_scan_and_uniform_in_its_box():
    box = (np.array([0.5, -1.0]), np.array([8.0, 1.0]))
    sim = simulate(COMMANDS, MOTIONS["distance"], SENSOR, LANDMARKS, start=START, runs=100,
                   clutter=1.5, clutter_box=box, seed=7)  # fmt: skip
    fake = sim.landmark == -1
    scans = 100 * 60
    assert abs(fake.sum() / scans - 1.5) < 5 * np.sqrt(1.5 / scans)
    for j in range(2):
        lo, hi = box[0][j], box[1][j]
        assert stats.kstest(sim.z[fake, j], stats.uniform(lo, hi - lo).cdf).pvalue > 1e-3
    default = simulate(COMMANDS, MOTIONS["distance"], SENSOR, LANDMARKS, start=START, runs=5,
                       clutter=1.0, seed=7)  # fmt: skip
    true, spurious = default.z[default.landmark >= 0], default.z[default.landmark < 0]
    assert (spurious >= true.min(0)).all() and (spurious <= true.max(0)).all()


def test_seeds_reproduce_and_start_draws_from_the_prior():
    a = simulate(COMMANDS, MOTIONS["alpha"], SENSOR, LANDMARKS, start=START, runs=3, seed=8,
                 clutter=0.5)  # fmt: skip
    b = simulate(COMMANDS, MOTIONS["alpha"], SENSOR, LANDMARKS, start=START, runs=3, seed=8,
                 clutter=0.5)  # fmt: skip
    for name in ("truth", "commands", "inputs", "run", "reading_index", "z", "landmark"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    c = simulate(COMMANDS, MOTIONS["alpha"], SENSOR, LANDMARKS, start=START, runs=3, seed=9)
    assert not np.array_equal(a.truth, c.truth)
    many = simulate(COMMANDS[:1], MOTIONS["distance"], SENSOR, LANDMARKS, start=START,
                    runs=20_000, every=2, seed=10)  # fmt: skip
    _within_sampling_error(se2.minus(many.truth[:, 0], START.mean), START.cov)


def test_log_recording_and_scans_are_one_run_three_ways():
    """The Log, the Recording's log and the padded scans hold the same readings; the filter
    runs on them (signatures: the true landmarks)."""
    sim = simulate(COMMANDS, MOTIONS["distance"], SENSOR, LANDMARKS, start=START, runs=4,
                   clutter=0.3, every=2, seed=11)  # fmt: skip
    for r in range(4):
        log, again = sim.log(r), sim.recording(r).log()
        for name in log._fields:
            np.testing.assert_array_equal(getattr(log, name), getattr(again, name))
    scans = sim.scans()
    np.testing.assert_array_equal(scans.reading_index, np.arange(2, 61, 2))
    assert scans.valid.sum() == len(sim.z)
    r, j, s = np.nonzero(scans.valid)
    np.testing.assert_array_equal(scans.z[r, j, s], sim.z)  # (ordered by run, time, as listed)
    np.testing.assert_array_equal(scans.landmark[r, j, s], sim.landmark)
    tr = run(sim.log(1), MOTIONS["distance"], SENSOR, LANDMARKS, start=START)
    status = tr.status[sim.log(1).signature >= 0]
    assert (status == Status.USED).mean() > 0.95  # (the 1% gate, and a few near the fov's edge)


def test_patrol_drives_its_route_turning_in_place_then_straight():
    route = np.array([[2.0, 0.0], [0.0, 2.0], [-2.0, 0.0]])
    quiet = MOTIONS["distance"].replace(k_s=0.0, k_theta=0.0, k_theta_s=0.0)
    sim = simulate(Patrol(route), quiet, SENSOR, LANDMARKS, start=[0.0, 0.0, 0.0], steps=400,
                   runs=2, seed=12)  # fmt: skip
    v, w = sim.commands[..., 0], sim.commands[..., 1]
    assert ((v == 0) | (w == 0)).all() and (np.abs(v) <= 0.3).all() and (np.abs(w) <= 0.3).all()
    for p in route:  # noise-free: it reaches every waypoint
        assert np.hypot(*(sim.truth[0, :, :2] - p).T).min() < 1e-9
    # it replans from its true pose: each leg's error is its own (a turn's heading σ 0.05 rad,
    # 0.14 m off at the leg's end), never the sum of the legs' (the same commands open loop: 1.7 m)
    small = Odometry(DistanceNoise(1e-3, 1e-3, 2e-4))
    noisy = simulate(Patrol(route), small, SENSOR, LANDMARKS, start=START, steps=2000, runs=5,
                     every=5000, seed=13)  # fmt: skip
    edges = np.stack([route, np.roll(route, -1, axis=0)], 1)
    p = noisy.truth[..., None, :2]
    a, b = edges[:, 0], edges[:, 1]
    f = np.clip(((p - a) * (b - a)).sum(-1) / ((b - a) ** 2).sum(-1), 0, 1)
    gap = np.hypot(*np.moveaxis(p - a - f[..., None] * (b - a), -1, 0)).min(-1)
    assert gap.max() < 0.6, gap.max()


def test_docs_simulation_examples_run():
    text = (PROJECT_ROOT / "docs" / "simulation.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert blocks
    namespace: dict[str, object] = {}
    for block in blocks:
        exec(compile(block, "docs/simulation.md", "exec"), namespace)


BAD = [
    (dict(commands=np.zeros((5, 3))), ShapeError, "commands must be velocities"),
    (dict(commands=np.zeros((2, 5, 2)), runs=3), ShapeError, "runs"),
    (dict(commands=[[np.nan, 0.0]]), RelmapError, "commands"),
    (dict(commands=lambda k, pose, dt: pose[..., :2]), ParameterError, "number of steps"),
    (dict(motion=SENSOR), ParameterError, "Odometry"),
    (dict(sensor=MOTIONS["distance"]), ParameterError, "Measurement"),
    (dict(sensor=SENSOR.replace(sigma_range=np.ones(3))), ParameterError, "one true noise"),
    (dict(landmarks=np.zeros((4, 3))), ShapeError, r"landmarks must have shape \(L, 2\)"),
    (dict(landmarks=[[np.inf, 0.0]]), RelmapError, "landmarks"),
    (dict(start=[0.0, 1.0]), ShapeError, "start"),
    (dict(start=random_ats(1, 2)), ShapeError, "start must be one AT"),
    (dict(dt=0.0), ParameterError, "dt"),
    (dict(every=0), ParameterError, "every"),
    (dict(runs=0), ParameterError, "runs"),
    (dict(detection=0.0), ParameterError, "detection"),
    (dict(clutter=-1.0), ParameterError, "clutter"),
    (dict(clutter=1.0, clutter_box=([0.0], [1.0])), ShapeError, "clutter_box"),
]


@pytest.mark.parametrize(("change", "error", "match"), BAD)
def test_bad_input_is_a_clear_error(change, error, match):
    kw = dict(commands=COMMANDS, motion=MOTIONS["distance"], sensor=SENSOR, landmarks=LANDMARKS,
              start=START, seed=1)  # fmt: skip
    kw.update(change)
    with pytest.raises(error, match=match):
        simulate(**kw)


def test_bad_runs_routes_and_recordings_are_clear_errors():
    sim = simulate(COMMANDS, MOTIONS["wheels"], SENSOR, LANDMARKS, start=START, runs=2, seed=1)
    with pytest.raises(ParameterError, match="run must be in"):
        sim.log(2)
    with pytest.raises(ParameterError, match="without a DiffDrive"):
        sim.recording(0)
    with pytest.raises(ShapeError, match="two or more waypoints"):
        Patrol([[0.0, 0.0]])
    with pytest.raises(ParameterError, match="must differ"):
        Patrol([[0.0, 0.0], [1.0, 1.0], [1.0, 1.0]])
    with pytest.raises(ParameterError, match="positive"):
        Patrol([[0.0, 0.0], [1.0, 1.0]], speed=0.0)
    with pytest.raises(ShapeError, match="low and high"):
        random_landmarks(1, 3, (0.0, 0.0), (1.0, -1.0))
