"""Autocalibration from innovations: the statistics against their definitions, the whole
method against a simulated robot whose noise is known."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np
import pytest
from scipy import stats

import relmap as rm
import relmap.filter as rf
from relmap.errors import ParameterError, ShapeError
from relmap.filter import autocalibration as ac
from relmap.lie import se2
from relmap.models import DistanceNoise, Odometry, RangeBearingSensor

NOISE = DistanceNoise(0.01, 0.01, 0.002)
SIGMA_R, SIGMA_B = 0.02, 0.005  # a laser scanner's landmarks: 2 cm, 0.3°
#: The simulated robot's models, with its noise.
MOTION, SENSOR = Odometry(NOISE), RangeBearingSensor(SIGMA_R, SIGMA_B)
#: Where the calibration starts: cautious, large noise (relmap.app.localize's START_ODOMETRY
#: and START_SENSOR), so that the search comes down to the data.
CAUTIOUS = Odometry(DistanceNoise(0.05, 0.02, 0.005)), RangeBearingSensor(0.5, 0.05)
LANDMARKS = np.array([[x, y] for x in (-6.0, 0.0, 6.0) for y in (-6.0, 0.0, 6.0)])
#: The route: the corners of a 3 m square about the central landmark, driven counter-clockwise
#: (A B C D A) then clockwise (A D C B A), again and again.
CORNERS = np.array([[1.5, -1.5], [1.5, 1.5], [-1.5, 1.5], [-1.5, -1.5]])
ROUTE = np.concatenate([CORNERS, CORNERS[:1], CORNERS[:0:-1]])
START_POSE = np.array([1.5, -1.5, np.pi / 2])
#: Driving speed (m/s), turning rate in place (rad/s), the readings' range limits (m).
SPEED, TURN, RANGES = 0.3, 0.3, (1.0, 5.0)


def simulate(seed: int, steps: int = 3000, dt: float = 0.1, every: int = 2):
    """One run of :func:`simulate_runs`: its recording and true poses."""
    return simulate_runs(np.random.default_rng(seed), 1, steps, dt, every)[0]


def simulate_runs(rng: np.random.Generator, runs: int, steps: int, dt: float = 0.1,
                  every: int = 2) -> list[tuple[ac.Recording, np.ndarray]]:  # fmt: skip
    """Runs of a differential-drive robot patrolling :data:`ROUTE` as such a robot does: at
    each corner it turns in place to face the next one (at :data:`TURN`), then drives straight
    to it (at :data:`SPEED`), each plan made from its true pose. So the odometry noise of
    turning in place (``k_theta``) and of driving (``k_s``, ``k_theta_s``) come in separate
    steps, 40% of the time turning, and each is identifiable (a path that turns while driving,
    at one mean rate, leaves ``k_theta`` and ``k_theta_s`` on a ridge). Each run starts from a
    draw of :func:`start`'s prior. Odometry at 1/``dt`` Hz, the commanded step logged and the
    true one drawn with DistanceNoise NOISE (independent Δs, Δθ) and composed by the midpoint
    rule, written out here (``x += Δs cos(θ + Δθ/2)``, …); range-bearing readings of the
    landmarks within :data:`RANGES` every ``every`` steps with white noise (SIGMA_R, SIGMA_B).
    Returns each run's recording and its true poses at the odometry times (steps + 1, 3)."""
    t = np.arange(steps + 1) * dt
    at = np.arange(every, steps + 1, every)
    out = []
    for x0 in start(0.0).sample(runs, seed=rng):
        truth = np.empty((steps + 1, 3))
        truth[0] = x0
        cmd = np.zeros((steps + 1, 2))  # (v, ω), each held until the next record
        k, goal = 0, 1
        while k < steps:  # at a corner: turn in place to face the next one, then drive there
            x = truth[k]
            d = ROUTE[goal % len(ROUTE)] - x[:2]
            turn = float(se2.wrap_angle(np.arctan2(d[1], d[0]) - x[2]))
            n = int(np.ceil(abs(turn) / (TURN * dt)))
            m = int(np.ceil(np.hypot(*d) / (SPEED * dt)))
            plan = np.array([(0.0, turn / max(n, 1))] * n + [(np.hypot(*d) / m, 0.0)] * m)
            plan = plan[: steps - k]  # the steps (Δs, Δθ)
            j = len(plan)
            sd = np.sqrt(np.diagonal(NOISE.covariance(plan), axis1=-2, axis2=-1))
            ds, dth = (plan + sd * rng.normal(size=plan.shape)).T  # the true steps
            theta = x[2] + np.concatenate([[0.0], np.cumsum(dth)])
            mid = theta[:-1] + dth / 2
            truth[k + 1 : k + 1 + j, 0] = x[0] + np.cumsum(ds * np.cos(mid))
            truth[k + 1 : k + 1 + j, 1] = x[1] + np.cumsum(ds * np.sin(mid))
            truth[k + 1 : k + 1 + j, 2] = se2.wrap_angle(theta[1:])
            cmd[k : k + j] = plan / dt
            k, goal = k + j, goal + 1
        zz = RangeBearingSensor(0.0, 0.0).h(truth[at][:, None, :], LANDMARKS)
        i, landmark = np.nonzero((zz[..., 0] > RANGES[0]) & (zz[..., 0] < RANGES[1]))
        z = zz[i, landmark] + rng.normal(size=(len(i), 2)) * [SIGMA_R, SIGMA_B]
        rec = ac.Recording(t, cmd[:, 0], cmd[:, 1], t[at][i], z, landmark, float(t[-1]))
        out.append((rec, truth))
    return out


def padded(rec: ac.Recording) -> rf.Log:
    """``rec``'s log with a reading of every landmark at every scan (NaN when out of range):
    the runs of :func:`simulate_runs` then share their times and signatures, a batch of logs
    for :func:`relmap.filter.run`."""
    at = np.arange(2, len(rec.odometry_t), 2)  # simulate_runs' scans (every=2)
    t, L = rec.odometry_t[at], len(LANDMARKS)
    z = np.full((len(at), L, 2), np.nan)
    z[np.searchsorted(t, rec.reading_t), rec.signature] = rec.z
    return rec._replace(reading_t=np.repeat(t, L), z=z.reshape(-1, 2),
                        signature=np.tile(np.arange(L), len(at))).log()  # fmt: skip


def start(t0: float) -> rm.AT:
    return rm.AT(START_POSE, np.diag([1e-4, 1e-4, 1e-4]))


#: The gate of the simulated runs' filters: none to speak of (χ²₂ 27.6). The association is
#: known and no reading is wild, and a 0.99 gate drops the 1% largest true innovations, the
#: corrections the filter needed most: the likelihood of the gated filter then prefers more
#: odometry noise (on seeds 1-4 k_s +6% to +11%, k_theta up to +34%, k_theta_s up to +16%:
#: benchmarks/study_inflation.py sim --gate 0.99).
GATE = 1 - 1e-6


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1])  # (seed 2 passes too: 40 s)
def test_recovers_the_simulated_noise_and_the_turn_rate_bias(seed: int) -> None:
    """Every simulated noise parameter within 10% from one run of 15 minutes (9000 odometry
    steps, 4500 scans of about 2.3 landmarks), with a gyro-like bias of 0.01 rad/s added to
    every logged turn rate, found within 0.005 rad/s. The standard errors of the noise fit
    (observed information at the simulated noise, seed 1, over 12 000 steps: 3.0% k_s, 3.1%
    k_theta, 2.9% k_theta_s, 0.6% σ_r, 1.0% σ_b) are about 15% larger here; the bias's
    precision is the heading noise's: the odometry's heading variance grows by about
    0.0016 rad²/s, so a drift rate over T = 900 s is known to about √(0.0016/900) = 0.0013
    rad/s. Measured: seed 1 k_s -3.9%, k_theta -7.4%, k_theta_s -3.3%, σ_r -0.2%, σ_b -0.9%,
    bias 0.00937; seed 2 -2.4%, +3.1%, -5.7%, -0.1%, +0.5%, bias 0.01263 (over 12 000 steps
    -3.6%, -5.6%, -5.0%, +0.5%, +0.2%, 0.00838; without the bias the same noise and -0.0016).
    The calibrated filter is consistent against the truth of its run, and the innovations are
    white."""
    rec, truth = simulate(seed, steps=9000)
    rec = rec._replace(w=rec.w + 0.01)
    cal = ac.calibrate(rec, *CAUTIOUS, LANDMARKS, start=start, gate=GATE)
    assert cal.delay == 0.0
    assert abs(cal.correlation[0]) < 0.1  # white reading errors: white innovations
    assert cal.inflation < 1.1
    got = {k: float(getattr(m, k)) for m in (cal.motion, cal.sensor) for k in m.noise_parameters}
    want = {k: float(getattr(m, k)) for m in (MOTION, SENSOR) for k in m.noise_parameters}
    assert set(got) == {"k_s", "k_theta", "k_theta_s", "sigma_range", "sigma_bearing"}
    for k in got:
        assert got[k] == pytest.approx(want[k], rel=0.1), (k, got, want)
    assert cal.turn_bias == pytest.approx(0.01, abs=0.005)
    assert cal.clock == (cal.delay, cal.scale, cal.turn_bias)
    log = rec.log(*cal.clock)
    tr = rf.run(log, cal.motion, cal.sensor, LANDMARKS, start=start(0.0), gate=GATE,
                 **cal.options)  # fmt: skip
    e = se2.minus(truth, tr.mean)  # truth ⊟ estimate at every odometry time (no reading-only times)
    nees = np.einsum("ti,tij,tj->t", e, np.linalg.inv(tr.cov), e)
    assert 0.8 < nees.mean() / 3 < 1.25


@pytest.mark.slow
def test_anees_of_200_runs_within_its_chi2_interval() -> None:
    """The simulated robot with its known noise is consistent: 200 runs of 100 s (1000
    odometry steps, 500 scans), each its own log through relmap.filter.run. The average NEES over
    the runs at one time, divided by 3 (ANEES), is χ²(600)/600 if the filters are consistent: at
    the last time it lies in its 95% interval [0.890, 1.116], at ≥ 85% of all times too (95%
    expected; the times are correlated), and the ANEES over all times is 1 within 0.05. The
    runs are one batch of filters, each on its own log (every landmark read at every scan, NaN
    when out of range); the times are the start and the 500 reading times.
    Measured (seeds 1-5 and 14 of the runs): 88.5-95.2% of the times inside, the last inside
    on every seed (0.93-1.11), the mean 1.004-1.044 (the linearized filter slightly
    overconfident, most during the turns in place); this seed 90.6%, 1.051, 1.028."""
    runs, steps = 200, 1000
    simulated = simulate_runs(np.random.default_rng(14), runs, steps)
    tr = rf.run([padded(rec) for rec, _ in simulated], MOTION, SENSOR, LANDMARKS,
                start=start(0.0), gate=GATE, keep="events", readings=False)  # fmt: skip
    at = np.searchsorted(simulated[0][0].log().t, tr.t)  # the start and the reading times
    truth = np.stack([x[at] for _, x in simulated])
    e = se2.minus(truth, tr.mean)
    nees = np.einsum("rti,rtij,rtj->rt", e, np.linalg.inv(tr.cov), e)
    anees = nees.mean(axis=0) / 3.0
    lo, hi = (stats.chi2.ppf(q, 3 * runs) / (3 * runs) for q in (0.025, 0.975))
    inside = (anees >= lo) & (anees <= hi)
    print(f"\nANEES inside {inside.mean():.1%} of the times, last {anees[-1]:.3f}, "
          f"mean {anees.mean():.3f}")  # fmt: skip
    assert inside[-1], (anees[-1], lo, hi)
    assert inside.mean() >= 0.85, (inside.mean(), lo, hi)
    assert abs(anees.mean() - 1.0) < 0.05, anees.mean()


def test_finds_the_odometry_clock_offset() -> None:
    rec, _ = simulate(2, steps=1500)
    late = rec._replace(odometry_t=rec.odometry_t - 0.2)  # stamped 0.2 s before the motion
    cal = ac.calibrate(late, *CAUTIOUS, LANDMARKS, start=start, gate=GATE)
    assert cal.delay == pytest.approx(0.2)


def test_recording_log_subtracts_the_turn_bias() -> None:
    rec, _ = simulate(1, steps=50)
    plain, biased = rec.log(), rec.log(0.0, 1.0, 0.02)
    np.testing.assert_allclose(biased.motion[:, 0], plain.motion[:, 0])
    np.testing.assert_allclose(biased.motion[:, 1], plain.motion[:, 1] - 0.02 * np.diff(plain.t))


def test_innovation_correlation_of_an_ar1_sequence() -> None:
    """ρ of consecutive normalized innovations per landmark: 0 for white, ρ for AR(1)."""
    rng = np.random.default_rng(3)
    n, rho = 4000, 0.8
    for want in (0.0, rho):
        trace = _trace(_ar1(rng, want, n) * 0.3, np.full(n, 0.09))
        got, _ = ac.innovation_correlation(trace, np.arange(n) * 0.1)
        assert got == pytest.approx(want, abs=0.05)


def test_loglik_is_the_student_t_and_gaussian_density_of_every_paired_reading() -> None:
    rng = np.random.default_rng(4)
    y = rng.normal(size=(5, 2))
    A = rng.normal(size=(5, 2, 2))
    S = A @ np.swapaxes(A, -1, -2) + np.eye(2)
    status = np.array([0, 1, 0, 2, 5])  # used, gated, used, unknown, lost
    trace = _trace(y, S, status=status)
    paired = [0, 1, 2]
    want_g = sum(stats.multivariate_normal(np.zeros(2), S[i]).logpdf(y[i]) for i in paired)
    # the t of covariance S: scale S (ν - 2)/ν
    t4 = [stats.multivariate_t(np.zeros(2), S[i] * 2.0 / 4.0, df=4.0) for i in paired]
    want_t = sum(t.logpdf(y[i]) for t, i in zip(t4, paired, strict=True))
    assert float(ac.loglik(trace, np.inf)) == pytest.approx(want_g, rel=1e-12)
    assert float(ac.loglik(trace, 4.0)) == pytest.approx(want_t, rel=1e-12)


def _trace(y: np.ndarray, S: np.ndarray, *, status: np.ndarray | None = None) -> rf.Trace:
    """A one-filter trace holding only per-reading innovations (one landmark, one reading a
    time: given the readings before it is at the prior)."""
    n = len(y)
    st = np.zeros(n, np.int64) if status is None else status
    z = np.zeros(0)
    return rf.Trace(z, z, z, y, S, z, st, np.zeros(n, np.int64), np.float64(0), np.float64(0),
                     np.int64(0), np.int64(0), np.zeros(7, np.int64), np.int64(0),
                     y, S)  # fmt: skip


def test_bad_input_is_a_clear_error() -> None:
    rec, _ = simulate(5, steps=50)
    with pytest.raises(ShapeError, match="landmarks"):
        ac.calibrate(rec, *CAUTIOUS, np.zeros((0, 2)), start=start)
    with pytest.raises(ParameterError, match="no readings"):
        empty = rec._replace(reading_t=rec.reading_t[:0], z=rec.z[:0], signature=rec.signature[:0])
        ac.calibrate(empty, *CAUTIOUS, LANDMARKS, start=start)

    # the fitted parameters are named by the models, the readings' dof and the clutter: no clash
    @dataclasses.dataclass(frozen=True)
    class Robust(RangeBearingSensor):  # a sensor with its own "nu"
        nu: float = 4.0
        noise_parameters: ClassVar[tuple[str, ...]] = ("sigma_range", "sigma_bearing", "nu")

    with pytest.raises(ParameterError, match="distinct names"):
        ac.calibrate(rec, CAUTIOUS[0], Robust(0.5, 0.05), LANDMARKS, start=start)
    with pytest.raises(ParameterError, match="distinct names"):
        ac.calibrate(rec, CAUTIOUS[0], Odometry(DistanceNoise(0.1)), LANDMARKS, start=start)


def _ar1(rng: np.random.Generator, rho: float, n: int) -> np.ndarray:
    e = np.empty(n)
    e[0] = rng.normal()
    for k in range(1, n):
        e[k] = rho * e[k - 1] + np.sqrt(1 - rho**2) * rng.normal()
    return e


def test_variance_factor_is_the_sum_of_the_autocorrelations() -> None:
    """1 + 2 Σ ρ_k for ρ_k = ρ1 φ^(k-1), summed out to 10 000 lags; AR(1) and white cases."""
    for r1, r2 in ((0.5, 0.25), (0.8, 0.7), (0.3, 0.25)):
        phi = r2 / r1
        want = 1 + 2 * sum(r1 * phi ** (k - 1) for k in range(1, 10_000))
        assert ac.variance_factor(r1, r2, 1000) == pytest.approx(want, rel=1e-9)
    assert ac.variance_factor(0.5, 0.25, 1000) == pytest.approx(1.5 / 0.5)  # AR(1)
    assert ac.variance_factor(-0.2, 0.1, 1000) == 1.0 and ac.variance_factor(np.nan, 0, 0) == 1.0
    # a correlation within three standard errors of 0 is white: 0.05 of 1000 pairs (σ 0.032)
    assert ac.variance_factor(0.05, 0.049, 1000) == 1.0


def test_logpdf_is_scipys_student_t_of_unit_variance_and_normal() -> None:
    x = np.linspace(-5, 5, 11)
    for nu in (3.0, 8.5):
        t = stats.t(df=nu, scale=np.sqrt((nu - 2) / nu))
        assert t.var() == pytest.approx(1.0, rel=1e-12)
        assert np.allclose(ac.logpdf(x * x, 0.0, 1, nu), t.logpdf(x), rtol=1e-12, atol=0)
    assert np.allclose(ac.logpdf(x * x, 0.0, 1, np.inf), stats.norm.logpdf(x), rtol=1e-12)


def test_measurement_volume_is_the_readings_span():
    z = np.array([[1.0, -0.5], [3.0, 0.2], [np.nan, 9.0], [2.0, 0.5]])
    assert ac.measurement_volume(z) == pytest.approx(2.0 * 1.0)
    assert ac.measurement_volume(np.array([4.0, 1.5, 2.0])) == pytest.approx(2.5)
    assert ac.measurement_volume(np.array([[1.0, 0.0]])) == 1.0
