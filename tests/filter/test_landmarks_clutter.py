"""Readings of nothing in the map (clutter, a moving object): the clutter hypothesis of
relmap.filter.landmarks (a used reading weighed by w = g/(g + λ)) against its mathematics, and
the filter on a simulated robot whose clutter is known."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import relmap as rm
import relmap.filter as rf
from relmap import models
from relmap.filter import autocalibration as ac
from relmap.lie import se2
from tests.filter.test_autocalibration import (
    LANDMARKS,
    MOTION,
    SENSOR,
    SIGMA_B,
    SIGMA_R,
    simulate,
    start,
)

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
            zz = models.RangeBearingSensor(0.0, 0.0).h(truth[kk], obj)
            if FOV[0][0] < zz[0, 0] < FOV[0][1]:
                rt.append([t])
                z.append(zz + rng.normal(size=(1, 2)) * [SIGMA_R, SIGMA_B])
    sig = [rec.signature] + [np.full(len(a), -1) for a in rt[1:]]
    t_all = np.concatenate(rt)
    order = np.argsort(t_all, kind="stable")
    return rec._replace(reading_t=t_all[order], z=np.concatenate(z)[order],
                        signature=np.concatenate(sig)[order])  # fmt: skip


def _one_reading(clutter: float | None, z: np.ndarray, nu: float = np.inf):
    """One filter from pose (0.5, -0.2, 0.1) with covariance P0, no motion, one range-bearing
    reading z of the single landmark (3, 1) at t = 1 (``clutter`` None: the argument left
    out)."""
    log = rf.Log(np.array([0.0, 1.0]), np.zeros((1, 2)), np.array([1]), z[None])
    s0 = rm.AT(np.array([0.5, -0.2, 0.1]), P0)
    kw = {} if clutter is None else {"clutter": clutter}
    return rf.run(log, models.Odometry(models.DistanceNoise(0.0, 0.0, 0.0)),
                   models.RangeBearingSensor(0.2, 0.05), np.array([[3.0, 1.0]]), start=s0,
                   associate="mahalanobis", nu=nu, **kw)  # fmt: skip


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
    assert tr.status[-1] == rf.Status.USED
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
    plain = _one_reading(None, z)
    for name in ("mean", "cov", "y", "S", "loglik", "nis"):
        np.testing.assert_array_equal(getattr(a, name), getattr(plain, name))


def _nees(tr: rf.Trace, log: rf.Log, rec: ac.Recording, truth: np.ndarray) -> np.ndarray:
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
    tr = rf.run(log, MOTION, SENSOR, LANDMARKS, start=start(0.0), associate=association,
                 clutter=lam)  # fmt: skip
    nees, e = _nees(tr, log, rec, truth)
    assert 0.7 < nees.mean() / 3 < 1.5
    assert np.sqrt((e[:, :2] ** 2).sum(axis=1).mean()) < 0.06
    used = tr.status == rf.Status.USED
    assert (used & out).sum() < 0.1 * out.sum()  # the gate rejects nearly all of them
