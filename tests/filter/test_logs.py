"""relmap.filter.logs: filters over whole logs against the mathematics.

- the runner against the textbook procedure step by step (the prediction by
  :func:`relmap.compound` with each odometry step's AT, the correction by the reference
  procedure of tests/filter/test_landmarks.py), for range-bearing and range-only sensors; a
  motion model that is not a relative one (stepped) against the composed steps;
- a batch of filters against each filter alone;
- robust (Student-t) readings, the update's inflation and the innovation log-likelihood against
  scipy.stats; each reading's innovation given the ones before it against the Gaussian
  conditional;
- the sensor's mount; logs from velocities; no readings = dead reckoning;
- bad input: 0/0 statuses, overflow, bad logs, an empty map.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
from scipy import stats

import relmap as rm
import relmap.filter as rf
from relmap import models
from relmap.errors import NonFiniteError, NumericalError, ParameterError, ShapeError
from relmap.lie import se2
from relmap.models import (
    DistanceNoise,
    Motion,
    Odometry,
    RangeBearingSensor,
    RangeOnly,
    increment,
    increments_from_velocities,
)
from tests.filter.test_landmarks import reference

NOISE = DistanceNoise(0.004, 0.003, 0.001)
MOTION = Odometry(NOISE)
SENSOR = RangeBearingSensor(0.08, 0.015, mount=[0.12, 0.04, 0.1])
LANDMARKS = np.array([[4.0, 1.0], [6.0, -2.5], [2.5, 4.0], [-1.0, 5.0], [-4.5, 1.5], [1.0, -5.0]])
START = rm.AT([0.0, -1.0, 0.2], np.diag([0.01, 0.01, 0.002]))


# ------------------------------------------------------------------------------- runner
def simulated_log(rng, steps=60, per_step=3, clutter=0.1):
    truth = np.array([0.0, -1.0, 0.2])
    index, zs, sigs = [], [], []
    motion = np.tile([0.2, 0.05], (steps, 1)) + rng.normal(size=(steps, 2)) * [0.02, 0.02]
    for k in range(1, steps + 1):
        truth = se2.compose(truth, increment(motion[k - 1] + rng.normal(0, [0.01, 0.005])))
        if k % 2:
            continue  # readings every second step
        idx = rng.choice(len(LANDMARKS), per_step, replace=False)
        z = SENSOR.h(truth, LANDMARKS[idx]) + rng.normal(size=(per_step, 2)) * [0.08, 0.015]
        fake = rng.random(per_step) < clutter
        z[fake] = np.column_stack([rng.uniform(1, 8, fake.sum()), rng.uniform(-3, 3, fake.sum())])
        index += [k] * per_step
        zs.append(z)
        sigs.append(np.where(fake, -7, idx))
    return rf.Log(np.arange(steps + 1.0), motion, np.array(index), np.concatenate(zs),
                   np.concatenate(sigs))  # fmt: skip


@pytest.mark.parametrize("associate", ["signatures", "mahalanobis", "euclidean"])
def test_run_is_the_textbook_procedure_step_by_step(associate):
    """run over a log against a Python loop: relmap.compound with the odometry step's AT
    (relmap.models) for each prediction, the reference correction of test_landmarks."""
    rng = np.random.default_rng(5)
    log = simulated_log(rng)
    lmap = rf.LandmarkMap(LANDMARKS)
    tr = rf.run(log, MOTION, SENSOR, lmap, start=START, associate=associate)
    state = START
    means, covs = [state.mean], [state.cov]
    for k in range(1, len(log.t)):
        state = rm.compound(state, MOTION.increment(log.motion[k - 1]))
        rows = np.flatnonzero(log.reading_index == k)
        if len(rows):
            kw = dict(signatures=log.signature[rows]) if associate == "signatures" else {}
            new, landmark, d2, status = reference(state, log.z[rows], SENSOR, lmap,
                                                  associate=associate, **kw)  # fmt: skip
            np.testing.assert_array_equal(tr.status[rows], status)
            np.testing.assert_array_equal(tr.landmark[rows], landmark)
            fin = np.isfinite(d2)
            np.testing.assert_allclose(tr.mahalanobis2[rows][fin], d2[fin], rtol=1e-8)
            state = new
        means.append(state.mean)
        covs.append(state.cov)
    assert np.abs(se2.minus(tr.mean, np.array(means))).max() < 1e-9
    np.testing.assert_allclose(tr.cov, np.array(covs), rtol=1e-8, atol=1e-14)
    assert tr.count(rf.Status.USED) == (tr.status == rf.Status.USED).sum() > 0


def test_range_only_run_is_the_textbook_procedure_step_by_step():
    """Range-only readings (d = 1: the trace's reading axes dropped) of known beacons against
    the textbook update written out (H = -(l - p)ᵀ/r, Eqs. 26-28) after relmap.compound."""
    rng = np.random.default_rng(6)
    sensor = RangeOnly(0.1)
    truth = START.mean
    steps = np.tile([0.2, 0.05], (40, 1))
    index, zs, sigs = [], [], []
    for k in range(1, 41):
        truth = se2.compose(truth, increment(steps[k - 1] + rng.normal(0, [0.01, 0.005])))
        idx = rng.choice(len(LANDMARKS), 2, replace=False)
        zs.append(np.hypot(*(LANDMARKS[idx] - truth[:2]).T) + rng.normal(0, 0.1, 2))
        index += [k, k]
        sigs.append(idx)
    log = rf.Log(np.arange(41.0), steps, np.array(index), np.concatenate(zs),
                  np.concatenate(sigs))  # fmt: skip
    tr = rf.run(log, MOTION, sensor, LANDMARKS, start=START, gate=0.999999)
    assert tr.y.shape == tr.S.shape == (80,) and (tr.status == rf.Status.USED).all()
    state = START
    for k in range(1, 41):
        state = rm.compound(state, MOTION.increment(steps[k - 1]))
        rows = np.flatnonzero(log.reading_index == k)
        d = LANDMARKS[log.signature[rows]] - state.mean[:2]
        r = np.hypot(*d.T)
        H = np.column_stack([-d / r[:, None], np.zeros(2)])
        S = H @ state.cov @ H.T + 0.01 * np.eye(2)
        K = state.cov @ H.T @ np.linalg.inv(S)
        y = log.z[rows] - r
        np.testing.assert_allclose(tr.y[rows], y, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(tr.S[rows], np.diag(S), rtol=1e-9)
        state = rm.AT._trusted(se2.plus(state.mean, K @ y), state.cov - K @ S @ K.T)
        assert np.abs(se2.minus(tr.mean[k], state.mean)).max() < 1e-10
        np.testing.assert_allclose(tr.cov[k], state.cov, rtol=1e-8, atol=1e-14)


@dataclasses.dataclass(frozen=True)
class Stepped(Motion):
    """The odometry model as a plain motion model (not a relative one): the runner steps it."""

    inner: Odometry = MOTION

    def f(self, x, u):
        return self.inner.f(x, u)

    def jacobians(self, x, u):
        return self.inner.jacobians(x, u)

    def input_noise(self, u):
        return self.inner.input_noise(u)


@pytest.mark.parametrize("keep", ["all", "events", "summary"])
def test_a_motion_model_that_is_not_relative_is_stepped(keep):
    """Any motion model runs: predicted step by step (Eq. 13) where a relative one has its
    steps between readings compounded first — the same states to rounding."""
    log = simulated_log(np.random.default_rng(7))
    kw = dict(start=START, associate="mahalanobis", keep=keep)
    composed = rf.run(log, MOTION, SENSOR, LANDMARKS, **kw)
    stepped = rf.run(log, Stepped(), SENSOR, LANDMARKS, **kw)
    np.testing.assert_array_equal(stepped.t, composed.t)
    np.testing.assert_array_equal(stepped.status, composed.status)
    assert np.abs(se2.minus(stepped.mean, composed.mean)).max() < 1e-12
    np.testing.assert_allclose(stepped.cov, composed.cov, rtol=1e-10, atol=1e-16)
    np.testing.assert_allclose(stepped.loglik, composed.loglik, rtol=1e-10)


def test_a_batch_of_filters_is_each_filter_alone_bitwise():
    """A batch of noise parameters (the models' and the Student-t dof) is a batch of filters:
    each filter's trace is what it gives alone, bitwise."""
    rng = np.random.default_rng(6)
    log = simulated_log(rng, clutter=0.3)
    scale = rng.uniform(0.3, 3.0, (2, 3))
    motion = Odometry(DistanceNoise(0.004 * scale, 0.003 * scale, 0.001))
    sensor = SENSOR.replace(sigma_range=0.08 * scale)
    nu = np.where(scale > 1.5, 4.0, np.inf)
    for associate in ("mahalanobis", "jcbb"):
        batch = rf.run(log, motion, sensor, LANDMARKS, start=START, associate=associate, nu=nu)
        assert batch.mean.shape == (2, 3, len(log.t), 3) and batch.loglik.shape == (2, 3)
        for i, j in itertools.product(range(2), range(3)):
            alone = rf.run(log, Odometry(DistanceNoise(0.004 * scale[i, j], 0.003 * scale[i, j],
                                                        0.001)),
                            SENSOR.replace(sigma_range=0.08 * scale[i, j]), LANDMARKS, start=START,
                            associate=associate, nu=nu[i, j])  # fmt: skip
            for name in ("mean", "cov", "y", "S", "mahalanobis2", "status", "landmark",
                         "loglik", "nis", "dof", "counts", "updates", "ambiguous", "y_given",
                         "S_given"):  # fmt: skip
                np.testing.assert_array_equal(getattr(batch, name)[i, j], getattr(alone, name),
                                              err_msg=f"{associate}: {name}")  # fmt: skip


def test_keep_modes_and_summary_do_not_hold_every_state():
    rng = np.random.default_rng(7)
    log = simulated_log(rng)
    motion = Odometry(DistanceNoise(np.full(50, 0.004), 0.003, 0.001))
    kw = dict(start=START, associate="mahalanobis")
    full = rf.run(log, motion, SENSOR, LANDMARKS, **kw)
    events = rf.run(log, motion, SENSOR, LANDMARKS, keep="events", **kw)
    summary = rf.run(log, motion, SENSOR, LANDMARKS, keep="summary", readings=False, **kw)
    assert summary.mean.shape == (50, 1, 3) and summary.y.shape == (50, 0, 2)
    np.testing.assert_array_equal(summary.mean[:, 0], full.mean[:, -1])
    np.testing.assert_array_equal(summary.loglik, full.loglik)
    at = np.unique(log.reading_index)
    np.testing.assert_array_equal(events.t, np.concatenate([[0.0], log.t[at]]))
    np.testing.assert_array_equal(events.mean[:, 1:], full.mean[:, at])
    with pytest.raises(ParameterError, match="keep"):
        rf.run(log, motion, SENSOR, LANDMARKS, start=START, keep="everything")


@pytest.mark.parametrize("associate", ["signatures", "mahalanobis"])
def test_a_batch_of_logs_is_each_log_alone(associate):
    """Logs with the same times and signatures, their own inputs and readings (some NaN: a
    landmark not seen), as a batch axis of their own: each filter gives, bit for bit, what it
    gives alone (its final state, the states after each reading time, its totals); logs of
    other times keep the final state only."""
    rng = np.random.default_rng(11)
    base = simulated_log(rng)
    logs = [base]
    for _ in range(2):
        z = base.z + rng.normal(size=base.z.shape) * [0.05, 0.01]
        z[rng.random(len(z)) < 0.2] = np.nan
        logs.append(base._replace(motion=base.motion + rng.normal(size=base.motion.shape) * 0.01,
                                  z=z))  # fmt: skip
    motion = Odometry(DistanceNoise([[0.004], [0.008]], 0.003, 0.001))  # batch (2, 3)
    kw = dict(start=START, associate=associate)
    events = rf.run(logs, motion, SENSOR, LANDMARKS, keep="events", **kw)
    summary = rf.run(logs, motion, SENSOR, LANDMARKS, keep="summary", **kw)
    assert events.mean.shape[:2] == (2, 3) and summary.t.shape == (2, 3, 1)
    for i, j in itertools.product(range(2), range(3)):
        one = Odometry(DistanceNoise(0.004 * (i + 1), 0.003, 0.001))
        alone = rf.run(logs[j], one, SENSOR, LANDMARKS, keep="events", **kw)
        np.testing.assert_array_equal(events.mean[i, j], alone.mean)
        np.testing.assert_array_equal(events.cov[i, j], alone.cov)
        np.testing.assert_array_equal(events.t, alone.t)
        np.testing.assert_array_equal(summary.mean[i, j, 0], alone.mean[-1])
        for k in ("loglik", "nis", "dof", "counts"):
            np.testing.assert_array_equal(getattr(summary, k)[i, j], getattr(alone, k))
    later = logs[1]._replace(t=logs[1].t + 0.5)
    with pytest.raises(ParameterError, match="keep"):
        rf.run([logs[0], later], MOTION, SENSOR, LANDMARKS, keep="events", **kw)
    with pytest.raises(ParameterError, match="keep"):
        rf.run(logs, MOTION, SENSOR, LANDMARKS, **kw)


# ----------------------------------------------------------------- likelihood and robustness
def three_readings(rng):
    """One time stamp with readings of landmarks 0-2 about a prior ``state``: its log, the
    stacked innovation ``y``, Jacobian ``Hs``, noise ``R`` and ``S = Hs P Hsᵀ + R`` (Eqs. 20-26
    written out)."""
    state = rm.AT([0.2, 0.1, 0.3], np.diag([0.05, 0.04, 0.01]))
    z = SENSOR.h(state.mean, LANDMARKS[:3]) + rng.normal(size=(3, 2)) * [0.3, 0.05]
    log = rf.Log(np.array([0.0]), np.zeros((0, 2)), np.zeros(3, np.int64), z, np.arange(3))
    h, H, _ = SENSOR.linearize(state.mean, LANDMARKS[:3])
    y = (z - h).reshape(-1)
    y[1::2] = se2.wrap_angle(y[1::2])
    Hs = H.reshape(-1, 3)
    R = np.diag(np.tile([SENSOR.sigma_range**2, SENSOR.sigma_bearing**2], 3))
    S = Hs @ state.cov @ Hs.T + R
    return state, log, y, Hs, R, S


def run_one(log, state, **kw):
    return rf.run(log, MOTION, SENSOR, LANDMARKS, start=state, **kw)


def test_loglik_is_the_gaussian_or_student_t_density_of_the_stacked_innovation():
    state, log, y, Hs, R, S = three_readings(np.random.default_rng(8))
    gauss = run_one(log, state, gate=0.999999)
    assert (gauss.status == rf.Status.USED).all()
    assert gauss.loglik == pytest.approx(
        stats.multivariate_normal(np.zeros(6), S).logpdf(y), rel=1e-10
    )
    assert gauss.nis == pytest.approx(y @ np.linalg.solve(S, y), rel=1e-10) and gauss.dof == 6
    nu = 3.5
    robust = run_one(log, state, gate=0.999999, nu=nu)
    assert robust.loglik == pytest.approx(
        stats.multivariate_t(np.zeros(6), S, df=nu).logpdf(y), rel=1e-10
    )
    # the update: each reading's R divided by its weight (ν + 2)/(ν + d²)
    d2 = gauss.mahalanobis2
    w = np.repeat((nu + 2) / (nu + d2), 2)
    Rw = R / w
    Sw = Hs @ state.cov @ Hs.T + Rw
    K = state.cov @ Hs.T @ np.linalg.inv(Sw)
    I_KH = np.eye(3) - K @ Hs
    np.testing.assert_allclose(robust.mean[0], se2.plus(state.mean, K @ y), atol=1e-12)
    np.testing.assert_allclose(robust.cov[0], I_KH @ state.cov @ I_KH.T + K @ Rw @ K.T, atol=1e-13)


def test_inflation_scales_the_update_but_not_the_gate_nor_the_likelihood():
    """``inflation`` c: the gain and the Joseph covariance with c²R, S, d², NIS and the
    likelihood with R (the textbook update, Eqs. 26-28, written out)."""
    state, log, y, Hs, R, S = three_readings(np.random.default_rng(9))
    c = 2.5
    tr = run_one(log, state, gate=0.999999, inflation=c)
    assert (tr.status == rf.Status.USED).all()
    assert tr.loglik == pytest.approx(stats.multivariate_normal(np.zeros(6), S).logpdf(y),
                                      rel=1e-10)  # fmt: skip
    assert tr.nis == pytest.approx(y @ np.linalg.solve(S, y), rel=1e-10)
    for k in range(3):
        Sk = S[2 * k : 2 * k + 2, 2 * k : 2 * k + 2]
        np.testing.assert_allclose(tr.S[k], Sk, rtol=1e-12)
        yk = y[2 * k : 2 * k + 2]
        assert tr.mahalanobis2[k] == pytest.approx(yk @ np.linalg.solve(Sk, yk), rel=1e-10)
    K = state.cov @ Hs.T @ np.linalg.inv(Hs @ state.cov @ Hs.T + c * c * R)
    I_KH = np.eye(3) - K @ Hs
    np.testing.assert_allclose(tr.mean[0], se2.plus(state.mean, K @ y), atol=1e-12)
    want = I_KH @ state.cov @ I_KH.T + K @ (c * c * R) @ K.T
    np.testing.assert_allclose(tr.cov[0], want, atol=1e-13)
    # c = 1 is the plain filter, and c must be positive
    plain = run_one(log, state, gate=0.999999)
    one = run_one(log, state, gate=0.999999, inflation=1.0)
    np.testing.assert_array_equal(plain.cov, one.cov)
    with pytest.raises(ParameterError, match="inflation"):
        run_one(log, state, inflation=0.0)


def test_innovations_given_the_readings_before_are_the_stacked_one_decomposed():
    """``y_given``, ``S_given``: reading k's innovation and covariance conditioned on the
    readings before it, ``y_k - S_k< S_<<⁻¹ y_<`` and ``S_kk - S_k< S_<<⁻¹ S_<k`` of the stacked
    innovation (the Gaussian conditional), whose densities multiply to the stacked likelihood;
    with R itself also for a robust or inflated filter. A gated reading is conditioned on all
    the used ones: the posterior's ``z - h - H δ`` and ``H P⁺ Hᵀ + R``."""
    state, log, y, Hs, R, S = three_readings(np.random.default_rng(8))
    for kw in ({}, {"nu": 4.0}, {"inflation": 2.5}):
        tr = run_one(log, state, gate=0.999999, **kw)
        assert (tr.status == rf.Status.USED).all()
        ll = 0.0
        for k in range(3):
            a, b = slice(2 * k, 2 * k + 2), slice(0, 2 * k)
            gain = S[a, b] @ np.linalg.inv(S[b, b]) if k else np.zeros((2, 0))
            np.testing.assert_allclose(tr.y_given[k], y[a] - gain @ y[b], rtol=1e-10, atol=1e-13)
            np.testing.assert_allclose(tr.S_given[k], S[a, a] - gain @ S[b, a], rtol=1e-10)
            ll += stats.multivariate_normal(np.zeros(2), tr.S_given[k]).logpdf(tr.y_given[k])
        assert ll == pytest.approx(stats.multivariate_normal(np.zeros(6), S).logpdf(y), rel=1e-10)
    shift = np.array([3.0, 0.0])  # the third reading moved 3 m in range: gated
    far = log._replace(z=log.z + np.array([[0.0, 0.0], [0.0, 0.0], shift]))
    tr = run_one(far, state)
    np.testing.assert_array_equal(tr.status, [rf.Status.USED, rf.Status.USED, rf.Status.GATED])
    u = slice(0, 4)
    K = state.cov @ Hs[u].T @ np.linalg.inv(S[u, u])
    post = (np.eye(3) - K @ Hs[u]) @ state.cov
    H2 = Hs[4:]
    np.testing.assert_allclose(tr.y_given[2], y[4:] + shift - H2 @ K @ y[u], rtol=1e-10)
    np.testing.assert_allclose(tr.S_given[2], H2 @ post @ H2.T + R[4:, 4:], rtol=1e-9)
    np.testing.assert_allclose(tr.y[2], y[4:] + shift, rtol=1e-12)  # y, S: at the prior
    np.testing.assert_allclose(tr.S[2], S[4:, 4:], rtol=1e-12)


# --------------------------------------------------------------- the sensor and the log
def test_the_mount_is_the_sensors():
    """Noise-free readings from a sensor mounted off-centre: with that sensor every innovation
    is zero and the state does not move; the same readings taken as from the robot's centre
    give the innovations of the mount's offset (Eq. 20 with and without it)."""
    mounted = RangeBearingSensor(0.1, 0.02, mount=[0.3, -0.1, 0.2])
    state = rm.AT([1.0, 2.0, 0.4], np.diag([0.01, 0.01, 0.001]))
    z = mounted.h(state.mean, LANDMARKS)
    log = rf.Log(np.array([0.0]), np.zeros((0, 2)), np.zeros(6, np.int64), z, np.arange(6))
    tr = rf.run(log, MOTION, mounted, LANDMARKS, start=state)
    np.testing.assert_allclose(tr.y, 0.0, atol=1e-12)
    np.testing.assert_allclose(tr.mean[0], state.mean, atol=1e-12)
    centred = rf.run(log, MOTION, RangeBearingSensor(0.1, 0.02), LANDMARKS, start=state,
                      gate=0.999999)  # fmt: skip
    want = z - RangeBearingSensor(0.1, 0.02).h(state.mean, LANDMARKS)
    want[:, 1] = se2.wrap_angle(want[:, 1])
    np.testing.assert_allclose(centred.y, want, atol=1e-12)
    assert np.abs(want).max() > 0.1


def test_log_from_velocities_merges_odometry_and_reading_times():
    """The filter's times are the odometry times merged with the reading times; each step is
    the velocity of the last record before it times the step's duration."""
    ot = np.array([0.0, 1.0, 2.0, 3.0])
    v, w = np.array([1.0, 2.0, 3.0, 4.0]), np.array([0.1, 0.2, 0.3, 0.4])
    rt = np.array([-1.0, 0.5, 1.0, 1.0, 2.25, 9.0])  # before, between, on, twice, after
    z = np.column_stack([np.arange(6.0) + 1, np.zeros(6)])
    log = rf.Log.from_velocities(ot, v, w, rt, z, np.arange(6), end=2.5)
    np.testing.assert_array_equal(log.t, [0.0, 0.5, 1.0, 2.0, 2.25])
    np.testing.assert_allclose(log.motion, [[0.5, 0.05], [0.5, 0.05], [2.0, 0.2], [0.75, 0.075]])
    np.testing.assert_array_equal(log.reading_index, [1, 2, 2, 4])
    np.testing.assert_array_equal(log.signature, [1, 2, 3, 4])
    np.testing.assert_array_equal(log.z[:, 0], [2, 3, 4, 5])
    held = [0, 0, 1, 2, 2]  # the record in force at each time
    np.testing.assert_allclose(increments_from_velocities(log.t, v[held], w[held]), log.motion)


def test_filter_without_readings_is_dead_reckoning():
    """run with no readings against relmap.models.dead_reckon (compounding in numpy)."""
    rng = np.random.default_rng(4)
    motion = np.column_stack([rng.uniform(0, 0.01, 2000), rng.normal(0, 0.01, 2000)])
    noise = DistanceNoise(0.004, 0.02, 0.001)
    start = rm.AT.from_sigmas([0.5, 0.2, -3.0], [0.02, 0.02, 0.02])
    log = rf.Log(np.arange(2001.0), motion, np.zeros(0, np.int64), np.zeros((0, 2)))
    est = rf.run(log, Odometry(noise), SENSOR, np.zeros((0, 2)), start=start,
                  associate="mahalanobis")  # fmt: skip
    dr = models.dead_reckon(motion, noise, start=start)
    np.testing.assert_allclose(est.mean, dr.mean, atol=1e-10)
    np.testing.assert_allclose(est.cov, dr.cov, rtol=1e-8, atol=1e-14)


# ------------------------------------------------------------------------------- bad input
def test_a_0_over_0_reading_in_a_run_is_counted_alike_alone_and_in_a_batch():
    """A landmark exactly at the sensor (no bearing): DEGENERATE, the same in a batch."""
    start = rm.AT([0.0, 0.0, 0.0], np.diag([0.01, 0.01, 0.001]))
    lm = np.array([[SENSOR.mount[0], SENSOR.mount[1]], [3.0, 1.0]])
    z = np.array([[1.0, 0.0], SENSOR.h(start.mean, lm[1])])
    log = rf.Log(np.arange(2.0), np.zeros((1, 2)), np.array([1, 1]), z, np.array([0, 1]))
    one = rf.run(log, MOTION, SENSOR, lm, start=start)
    assert list(one.status) == [rf.Status.DEGENERATE, rf.Status.USED]
    pair = SENSOR.replace(sigma_range=np.full(2, SENSOR.sigma_range))
    both = rf.run(log, MOTION, pair, lm, start=start)
    np.testing.assert_array_equal(both.status[1], one.status)
    np.testing.assert_array_equal(both.mean[1], one.mean)
    assert np.isfinite(both.mean).all() and np.isfinite(both.cov).all()


def test_an_unknown_landmark_and_an_empty_map_are_counted_never_nan():
    flog = rf.Log(np.arange(3.0), np.zeros((2, 2)), np.array([1, 2]), np.array([[1.0, 0.0]] * 2),
                   np.array([99, 0]))  # fmt: skip
    start = rm.AT([0.0, 0.0, 0.0], np.eye(3) * 0.01)
    sensor = RangeBearingSensor(0.1, 0.01)
    tr = rf.run(flog, MOTION, sensor, [[1.0, 0.0]], start=start)
    assert list(tr.status) == [rf.Status.UNKNOWN, rf.Status.USED]
    for associate in ("signatures", "mahalanobis", "jcbb"):
        tr = rf.run(flog, MOTION, sensor, np.zeros((0, 2)), start=start, associate=associate)
        assert list(tr.status) == [rf.Status.UNKNOWN, rf.Status.UNKNOWN]
        assert tr.count(rf.Status.UNKNOWN) == 2 and tr.dof == 0 and tr.loglik == 0.0
        assert np.isfinite(tr.mean).all()
    with pytest.raises(NonFiniteError):
        rf.run(flog._replace(motion=np.full((2, 2), np.nan)), MOTION, sensor, [[1.0, 0.0]],
                start=start)  # fmt: skip


def test_bad_logs_and_parameters():
    start = rm.AT([0.0, 0.0, 0.0], np.diag([0.01, 0.01, 0.001]))
    good = rf.Log(
        np.arange(3.0), np.zeros((2, 2)), np.array([1]), np.array([[1.0, 0.1]]), np.array([0])
    )

    def run(log, sensor=SENSOR, **kw):
        return rf.run(log, MOTION, sensor, LANDMARKS, start=start, **kw)

    with pytest.raises(ParameterError, match="empty"):
        run(good._replace(t=np.zeros(0)))
    with pytest.raises(ParameterError, match="strictly increasing"):
        run(good._replace(t=np.array([0.0, 2.0, 1.0])))
    with pytest.raises(ShapeError, match="motion"):
        run(good._replace(motion=np.zeros((1, 2))))  # truncated
    with pytest.raises(ParameterError, match="reading_index"):
        run(good._replace(reading_index=np.array([5])))
    with pytest.raises(ShapeError, match=r"\(M, 1\)"):
        run(good, sensor=RangeOnly(0.1))  # range-bearing readings for a range sensor
    with pytest.raises(ParameterError, match="sigma_range"):
        run(good, sensor=SENSOR.replace(sigma_range=np.nan))
    with pytest.raises(ParameterError, match="sigma_range"):
        run(good, sensor=SENSOR.replace(sigma_range=0.0))  # R must be positive definite
    with pytest.raises(ParameterError):
        run(good, nu=0.0)
    with pytest.raises(ParameterError, match="clutter"):
        run(good, clutter=-1.0)
    with pytest.raises(ParameterError, match="signature"):
        run(good._replace(signature=None))
    with pytest.raises(ParameterError, match="associate"):
        run(good, associate="psychic")
    with pytest.raises(ParameterError, match="must not decrease"):
        rf.Log.from_velocities([0.0, 2.0, 1.0], [0, 0, 0], [0, 0, 0], [], np.zeros((0, 2)))
    with pytest.raises(ParameterError, match="no odometry"):
        rf.Log.from_velocities([], [], [], [], np.zeros((0, 2)))
    # NaN readings are counted, the filter stays finite
    nan = good._replace(z=np.array([[np.nan, 0.1]]))
    tr = run(nan)
    assert tr.status[0] == rf.Status.INVALID and tr.count(rf.Status.INVALID) == 1
    assert np.isfinite(tr.mean).all()
    # overflow: a clear error naming the time, never a NaN state
    huge = good._replace(motion=np.array([[1e300, 0.0], [1e300, 0.0]]))
    with pytest.raises(NumericalError, match="overflowed"):
        run(huge)
