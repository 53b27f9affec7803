"""Readings of nothing in the map (clutter, a moving object): the clutter hypothesis of
relmap.filter.ekf (a used reading weighed by w = g/(g + λ)) against its mathematics, and the filter
and its autocalibration on a simulated robot whose clutter is known."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import relmap as rm
from relmap import models
from relmap.filter import autocalibration as ac
from relmap.filter import ekf
from relmap.lie import se2
from tests.filter.test_autocalibration import LANDMARKS, NOISE, SIGMA_B, SIGMA_R, simulate, start

#: the simulated sensor's field of view: ranges 1-8 m, every bearing
FOV = ((1.0, 8.0), (-np.pi, np.pi))
CLUTTER = 0.2  # fraction of the readings that are clutter


def with_clutter(rec: ac.Recording, truth: np.ndarray, seed: int, fraction: float = CLUTTER,
                 mover: bool = True, radius: float = 0.6) -> ac.Recording:  # fmt: skip
    """``rec`` with clutter readings uniform over FOV (``fraction`` of all readings, on average)
    and, with ``mover``, the readings of an object driving a circle of radius ``radius`` around
    the landmark in the middle of the map at 0.2 m/s, read at every scan while in range:
    signature -1 (no landmark)."""
    rng = np.random.default_rng(seed)
    times = np.unique(rec.reading_t)
    per_scan = fraction / (1 - fraction) * len(rec.reading_t) / len(times)
    k = np.searchsorted(rec.odometry_t, times)
    rt, z = [rec.reading_t], [rec.z]
    for t, kk in zip(times, k, strict=True):
        n = rng.poisson(per_scan)
        rt.append(np.full(n, t))
        z.append(np.column_stack([rng.uniform(*FOV[0], n), rng.uniform(*FOV[1], n)]))
        if mover:
            a = 0.2 * t / radius
            obj = np.array([[radius * np.cos(a), radius * np.sin(a)]])
            zz = models.RangeBearingSensor(0.0, 0.0).predict(truth[kk], obj)
            if FOV[0][0] < zz[0, 0] < FOV[0][1]:
                rt.append([t])
                z.append(zz + rng.normal(size=(1, 2)) * [SIGMA_R, SIGMA_B])
    sig = [rec.signature] + [np.full(len(a), -1) for a in rt[1:]]
    t_all = np.concatenate(rt)
    order = np.argsort(t_all, kind="stable")
    return rec._replace(reading_t=t_all[order], z=np.concatenate(z)[order],
                        signature=np.concatenate(sig)[order])  # fmt: skip


def _one_reading(clutter: float, z: np.ndarray, nu: float = np.inf):
    """One filter from pose (0.5, -0.2, 0.1) with covariance P0, no motion, one range-bearing
    reading z of the single landmark (3, 1) at t = 1."""
    log = ekf.Log(np.array([0.0, 1.0]), np.zeros((1, 2)), np.array([1]), z[None])
    p = ekf.NoiseParameters(0.0, 0.0, 0.0, 0.2, 0.05, nu=nu, clutter=clutter)
    s0 = rm.AT(np.array([0.5, -0.2, 0.1]), P0)
    return ekf.run(log, np.array([[3.0, 1.0]]), p, start=s0, association="mahalanobis")


P0 = np.array([[0.04, 0.01, 0.0], [0.01, 0.09, 0.005], [0.0, 0.005, 0.01]])


@pytest.mark.parametrize("clutter", [0.05, 2.0, 40.0])
def test_a_used_reading_is_weighed_by_the_probability_that_it_is_of_its_landmark(clutter):
    """PDA with clutter (Bar-Shalom & Tse 1975): w = g/(g + λ), g = N(y; 0, S); the update is
    the Kalman update (Joseph form) with R / w."""
    x0 = np.array([0.5, -0.2, 0.1])
    dx, dy = 3.0 - x0[0], 1.0 - x0[1]
    q = dx * dx + dy * dy
    h = np.array([np.sqrt(q), np.arctan2(dy, dx) - x0[2]])
    H = np.array([[-dx / np.sqrt(q), -dy / np.sqrt(q), 0.0], [dy / q, -dx / q, -1.0]])
    R = np.diag([0.2**2, 0.05**2])
    z = h + np.array([0.25, -0.04])
    tr = _one_reading(clutter, z)
    assert tr.status[-1] == ekf.Status.USED
    y = z - h
    S = H @ P0 @ H.T + R
    g = stats.multivariate_normal(np.zeros(2), S).pdf(y)
    w = g / (g + clutter)
    Rw = R / w
    K = P0 @ H.T @ np.linalg.inv(H @ P0 @ H.T + Rw)
    A = np.eye(3) - K @ H
    np.testing.assert_allclose(tr.mean[-1], x0 + K @ y, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(tr.cov[-1], A @ P0 @ A.T + K @ Rw @ K.T, rtol=1e-11, atol=1e-15)
    # association, S and the likelihood stay the landmark hypothesis's (R itself)
    np.testing.assert_allclose(tr.S[-1], S, rtol=1e-12)
    assert float(tr.loglik) == pytest.approx(stats.multivariate_normal(np.zeros(2), S).logpdf(y),
                                             rel=1e-12)  # fmt: skip


def test_no_clutter_is_the_filter_without_it_bit_for_bit():
    z = np.array([2.9, 0.25])
    a, b = _one_reading(0.0, z), _one_reading(1e-300, z)
    assert np.array_equal(a.mean, _one_reading(0.0, z).mean)
    np.testing.assert_allclose(b.mean, a.mean, rtol=1e-15)  # λ → 0: w → 1
    rec, _truth = simulate(3, steps=300)
    tr = ekf.run(rec.log(), LANDMARKS, ekf.NoiseParameters.of(
        NOISE, models.RangeBearingSensor(SIGMA_R, SIGMA_B)), start=start(0.0),
        association="mahalanobis")  # fmt: skip
    for nu in (np.inf, 4.0):
        assert np.array_equal(ac.loglik(tr, nu, 0.0, 5.0), ac.loglik(tr, nu))


def test_the_mixture_likelihood_is_landmark_or_uniform_clutter():
    """Per paired reading log(g + λ) - log(1 + λV) (the mixture (1 - π) g + π/V over
    1 - π, λ = π/((1 - π) V)), g scipy's Student-t of covariance S (each reading's innovation
    given the readings before it at its time); a LOST reading is clutter."""
    rec, truth = simulate(3, steps=300)
    rec = with_clutter(rec, truth, 7, mover=False)
    p = ekf.NoiseParameters.of(NOISE, models.RangeBearingSensor(SIGMA_R, SIGMA_B))
    tr = ekf.run(rec.log(), LANDMARKS, p, start=start(0.0), association="mahalanobis")
    nu, V, lam = 5.0, 2.5, 0.3
    paired = np.flatnonzero((tr.status == ekf.Status.USED) | (tr.status == ekf.Status.GATED))
    assert (tr.status == ekf.Status.GATED).sum() > 10
    want = 0.0
    for i in paired:
        t = stats.multivariate_t(np.zeros(2), tr.S_given[i] * (nu - 2) / nu, df=nu)
        want += np.log(t.pdf(tr.y_given[i]) + lam) - np.log1p(lam * V)
    want += (tr.status == ekf.Status.LOST).sum() * (np.log(lam) - np.log1p(lam * V))
    assert float(ac.loglik(tr, nu, lam, V)) == pytest.approx(want, rel=1e-10)


def test_measurement_volume_is_the_readings_span():
    z = np.array([[1.0, -0.5], [3.0, 0.2], [np.nan, 9.0], [2.0, 0.5]])
    assert ac.measurement_volume(z) == pytest.approx(2.0 * 1.0)
    assert ac.measurement_volume(np.array([4.0, 1.5, 2.0])) == pytest.approx(2.5)
    assert ac.measurement_volume(np.array([[1.0, 0.0]])) == 1.0


def _nees(tr: ekf.Trace, log: ekf.Log, rec: ac.Recording, truth: np.ndarray) -> np.ndarray:
    at = np.searchsorted(log.t, rec.odometry_t)  # the odometry times, where truth is known
    e = se2.minus(truth, tr.mean[at])
    return np.einsum("ti,tij,tj->t", e, np.linalg.inv(tr.cov[at]), e), e


@pytest.mark.parametrize("association", ["mahalanobis", "jcbb"])
def test_the_filter_with_clutter_and_a_mover_stays_consistent(association):
    """30% of the readings clutter uniform over the field of view, plus an object circling the
    middle landmark 0.3 m from it (inside its gate at times): with the true noise and the λ of
    the true clutter fraction the filter stays consistent. Measured (seed 1): ANEES 1.20
    (Mahalanobis; 84 of the mover's readings used), 0.97 (JCBB, 34 used); position RMSE 4.4 cm
    and 4.2 cm."""
    rec, truth = simulate(1, steps=3000)
    rec = with_clutter(rec, truth, 5, radius=0.3)
    log = rec.log()
    out = log.signature < 0
    V = ac.measurement_volume(rec.z) / len(LANDMARKS)
    lam = out.mean() / ((1 - out.mean()) * V)
    p = ekf.NoiseParameters.of(NOISE, models.RangeBearingSensor(SIGMA_R, SIGMA_B))
    tr = ekf.run(log, LANDMARKS, p._replace(clutter=lam), start=start(0.0),
                 association=association)  # fmt: skip
    nees, e = _nees(tr, log, rec, truth)
    assert 0.7 < nees.mean() / 3 < 1.5
    assert np.sqrt((e[:, :2] ** 2).sum(axis=1).mean()) < 0.06
    used = tr.status == ekf.Status.USED
    assert (used & out).sum() < 0.1 * out.sum()  # the gate rejects nearly all of them


def test_calibration_recovers_the_clutter_fraction():
    """Without signatures the autocalibration fits λ with the rest: the fraction λV/(1 + λV)
    within 0.05 of the simulated one (measured: 0.314 against 0.303), σ within 10%."""
    rec, truth = simulate(1, steps=3000)
    rec = with_clutter(rec, truth, 5, radius=0.3)
    cal = ac.calibrate(rec, LANDMARKS, start=start, association="mahalanobis")
    frac = float((rec.signature < 0).mean())
    assert cal.clutter_fraction == pytest.approx(frac, abs=0.05)
    assert float(cal.parameters.sigma_r) == pytest.approx(SIGMA_R, rel=0.1)
    assert float(cal.parameters.sigma_b) == pytest.approx(SIGMA_B, rel=0.1)
    assert cal.as_dict()["clutter_fraction"] == cal.clutter_fraction
    # with signatures the signature names the landmark: no clutter fitted
    sig = ac.calibrate(rec, LANDMARKS, start=start, landmark_signatures=np.arange(9))
    assert float(sig.parameters.clutter) == 0.0 and sig.clutter_fraction == 0.0
