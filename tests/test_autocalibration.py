"""Autocalibration from innovations: the statistics against their definitions, the whole
method against a simulated robot whose noise is known."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import relmap as rm
from relmap import autocalibration as ac
from relmap import ekf
from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.robot import DistanceNoise, increment
from relmap.sensors import RangeBearingSensor

NOISE = DistanceNoise(0.01, 0.01, 0.002)
SIGMA_R, SIGMA_B = 0.02, 0.005  # a laser scanner's landmarks: 2 cm, 0.3°
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
        zz = RangeBearingSensor(0.0, 0.0).predict(truth[at][:, None, :], LANDMARKS)
        i, landmark = np.nonzero((zz[..., 0] > RANGES[0]) & (zz[..., 0] < RANGES[1]))
        z = zz[i, landmark] + rng.normal(size=(len(i), 2)) * [SIGMA_R, SIGMA_B]
        rec = ac.Recording(t, cmd[:, 0], cmd[:, 1], t[at][i], z, landmark, float(t[-1]))
        out.append((rec, truth))
    return out


def start(t0: float) -> rm.AT:
    return rm.AT(START_POSE, np.diag([1e-4, 1e-4, 1e-4]))


@pytest.mark.slow
def test_recovers_the_simulated_noise() -> None:
    """σ_r and σ_b within 10%, the odometry's k_s and k_theta within 20%. Measured on this seed
    (8000 steps, 1600 scans): σ_r -2.1%, σ_b -2.8%, k_s -7.9%, k_theta +13.4%; seeds 2-4 gave
    k_s +12%, +7%, -2% and k_theta +18%, -2%, 0% (σ within 0.5% to 11%). The search is not at
    fault (the likelihood is higher at the fitted noise than at the simulated on seeds 1 and 2:
    benchmarks/study_inflation.py sim). k_theta is off because this path does not separate
    turning noise per radian from turning noise per metre: the mean |Δθ| and |Δs| per step are
    both 0.03, so k_theta_s fell to 0.0001 (seed 1) and 0.0007 (seed 2) against 0.002, and
    k_theta grew to make up the heading variance. What the data does fix is the heading
    variance per step at the mean motion, k_theta·mean|Δθ| + k_theta_s·mean|Δs|: -4.8%,
    +3.6%, -6.3% on seeds 1-3, checked here within 10% (seed 4: +12%, with σ_b -10.7%: bearing
    error taken for heading noise; there 2Δ log-likelihood fitted - simulated is 52, beyond
    the χ²₅ spread of an unbiased fit, so the EKF's linearized S, not chance, moves it)."""
    rec, truth = simulate(1, steps=8000)
    cal = ac.calibrate(rec, LANDMARKS, start=start, landmark_signatures=np.arange(len(LANDMARKS)))
    p = cal.parameters
    assert cal.delay == 0.0
    assert abs(cal.correlation[0]) < 0.1  # white reading errors: white innovations
    assert cal.inflation < 1.1
    for got, want, rel in ((p.k_s, NOISE.k_s, 0.2), (p.sigma_r, SIGMA_R, 0.1),
                           (p.k_theta, NOISE.k_theta, 0.2), (p.sigma_b, SIGMA_B, 0.1)):  # fmt: skip
        assert got == pytest.approx(want, rel=rel)
    dtheta, ds = np.abs(rec.w).mean() * 0.1, np.abs(rec.v).mean() * 0.1  # per 0.1 s step
    heading = p.k_theta * dtheta + p.k_theta_s * ds
    assert heading == pytest.approx(NOISE.k_theta * dtheta + NOISE.k_theta_s * ds, rel=0.1)
    # and the calibrated filter is consistent against the truth
    log = rec.log(cal.delay)
    tr = ekf.run(log, LANDMARKS, p, start=start(0.0), landmark_signatures=np.arange(9))
    e = se2.minus(truth, tr.mean)  # truth ⊟ estimate at every odometry time (no reading-only times)
    nees = np.einsum("ti,tij,tj->t", e, np.linalg.inv(tr.cov), e)
    assert 0.7 < nees.mean() / 3 < 1.5


def test_finds_the_odometry_clock_offset() -> None:
    rec, _ = simulate(2, steps=1500)
    late = rec._replace(odometry_t=rec.odometry_t - 0.2)  # stamped 0.2 s before the motion
    cal = ac.calibrate(late, LANDMARKS, start=start, landmark_signatures=np.arange(9))
    assert cal.delay == pytest.approx(0.2)


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


def _trace(y: np.ndarray, S: np.ndarray, *, status: np.ndarray | None = None) -> ekf.Trace:
    """A one-filter trace holding only per-reading innovations (one landmark)."""
    n = len(y)
    st = np.zeros(n, np.int64) if status is None else status
    z = np.zeros(0)
    return ekf.Trace(z, z, z, y, S, z, st, np.zeros(n, np.int64), np.float64(0), np.float64(0),
                     np.int64(0), np.int64(0), np.zeros(7, np.int64), np.int64(0), y, S)  # fmt: skip


def test_bad_input_is_a_clear_error() -> None:
    rec, _ = simulate(5, steps=50)
    with pytest.raises(ShapeError, match="landmarks"):
        ac.calibrate(rec, np.zeros((0, 2)), start=start)
    with pytest.raises(ParameterError, match="no readings"):
        empty = rec._replace(reading_t=rec.reading_t[:0], z=rec.z[:0], signature=rec.signature[:0])
        ac.calibrate(empty, LANDMARKS, start=start)


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
