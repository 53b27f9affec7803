"""relmap.filter (predict, correct_landmarks, correct_pose, run) against filterpy's
ExtendedKalmanFilter, step by step, to 1e-12.

filterpy (MIT licence) is given the same model by hand: its ``predict`` with ``F = Gx``,
``Q = Gu Σu Guᵀ`` and ``predict_x`` overridden to ``x = g(x, u)`` (its default is linear), and
its ``update`` with the readings stacked: ``HJacobian`` and ``Hx`` of all readings at once,
``R`` block diagonal, a residual that wraps bearings (and headings). filterpy has no
association: it is given the landmarks relmap paired the readings with.
"""

from __future__ import annotations

import numpy as np
import pytest

import relmap as rm
import relmap.filter as rf
from relmap.lie import se2
from relmap.models import DistanceNoise, Odometry, RangeBearingSensor, increment

filterpy_ekf = pytest.importorskip("filterpy.kalman.EKF")

SENSOR = RangeBearingSensor(
    0.08, 0.015, mount=[0.12, 0.04, 0.1], fov=np.radians(200), max_range=9.0
)
NOISE = DistanceNoise(0.004, 0.003, 0.001)
MOTION = Odometry(NOISE)
LANDMARKS = np.array(
    [[4.0, 1.0], [6.0, -2.5], [2.5, 4.0], [-1.0, 5.0], [-4.5, 1.5], [-3.0, -4.0], [1.0, -5.0],
     [7.0, 3.0]]
)  # fmt: skip
TOL = 1e-12


class _Filter(filterpy_ekf.ExtendedKalmanFilter):
    """filterpy's EKF with the nonlinear motion: ``x = g(x, u)``, midpoint integration."""

    def predict_x(self, u=0):
        ds, dth = u
        a = self.x[2] + dth / 2
        self.x = self.x + np.array([ds * np.cos(a), ds * np.sin(a), dth])


def jacobians(x, u):
    """``Gx`` (3×3) and ``Gu Σu Guᵀ`` of the midpoint step, by hand as a filterpy user would."""
    ds, dth = u
    a = x[2] + dth / 2
    c, s = np.cos(a), np.sin(a)
    Gx = np.array([[1.0, 0.0, -ds * s], [0.0, 1.0, ds * c], [0.0, 0.0, 1.0]])
    Gu = np.array([[c, -ds * s / 2], [s, ds * c / 2], [0.0, 1.0]])
    return Gx, Gu @ NOISE.covariance(np.asarray(u)) @ Gu.T


def hx(x, idx):
    """Stacked readings ``(r₁, φ₁, r₂, φ₂, …)`` of landmarks ``idx`` from pose x."""
    mx, my, mt = SENSOR.mount
    c, s = np.cos(x[2]), np.sin(x[2])
    d = LANDMARKS[idx] - (x[0] + c * mx - s * my, x[1] + s * mx + c * my)
    out = np.empty(2 * len(idx))
    out[0::2] = np.hypot(d[:, 0], d[:, 1])
    out[1::2] = np.arctan2(d[:, 1], d[:, 0]) - (x[2] + mt)
    return out


def h_jacobian(x, idx):
    """Stacked ``∂h/∂x`` (2k×3), the sensor offset included."""
    mx, my, _ = SENSOR.mount
    c, s = np.cos(x[2]), np.sin(x[2])
    ax, ay = c * mx - s * my, s * mx + c * my
    d = LANDMARKS[idx] - (x[0] + ax, x[1] + ay)
    dx, dy = d[:, 0], d[:, 1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    H = np.empty((len(idx), 2, 3))
    H[:, 0] = np.stack([-dx / r, -dy / r, (dx * ay - dy * ax) / r], axis=-1)
    H[:, 1] = np.stack([dy / q, -dx / q, -(dy * ay + dx * ax) / q - 1.0], axis=-1)
    return H.reshape(-1, 3)


def wrapped_every_second(a, b):
    y = a - b
    y[1::2] = se2.wrap_angle(y[1::2])
    return y


def assert_same(state: rm.AT, kf, what: str) -> None:
    dm = np.abs(se2.minus(state.mean, kf.x)).max()
    dc = np.abs(state.cov - kf.P).max() / np.abs(kf.P).max()
    assert dm <= TOL and dc <= TOL, f"{what}: |Δmean| {dm:.1e}, |ΔΣ|/|Σ| {dc:.1e}"


def simulate(rng, steps):
    truth = np.array([0.0, -3.0, 0.2])
    out = []
    for t in range(steps):
        u = np.array([0.25, 0.12 if t % 20 < 12 else -0.05])
        truth = se2.compose(truth, increment(u + rng.normal(0.0, [0.01, 0.005])))
        z = SENSOR.h(truth, LANDMARKS)
        seen = np.flatnonzero(SENSOR.in_view(z))
        order = rng.permutation(seen)  # readings come in no particular order
        z = z[order] + rng.normal(size=(len(order), 2)) * [SENSOR.sigma_range, SENSOR.sigma_bearing]
        gps = rm.AT(
            se2.plus(truth, rng.normal(0.0, [0.3, 0.3, 0.05])), np.diag([0.09, 0.09, 0.0025])
        )
        out.append((u, z, order, gps))
    return out


@pytest.mark.parametrize("associate", ["signatures", "mahalanobis"])
def test_step_by_step_equal_to_filterpy(associate):
    rng = np.random.default_rng(11)
    state = rm.AT([0.1, -2.9, 0.15], np.diag([0.05, 0.04, 0.01]))
    kf = _Filter(dim_x=3, dim_z=2)
    kf.x, kf.P = state.mean.copy(), state.cov.copy()
    for t, (u, z, ids, gps) in enumerate(simulate(rng, 40)):
        state = rf.predict(state, u, MOTION)
        kf.F, kf.Q = jacobians(kf.x, u)
        kf.predict(u=u)
        assert_same(state, kf, f"prediction {t}")

        kw = dict(signatures=ids) if associate == "signatures" else {}
        up = rf.correct_landmarks(
            state, z, SENSOR, LANDMARKS, associate=associate, gate=0.9999, **kw
        )
        np.testing.assert_array_equal(up.landmark, ids)  # the true landmarks, every reading
        assert (up.status == rf.Status.USED).all()
        state = up.state
        if len(ids):
            R = np.diag(np.tile([SENSOR.sigma_range**2, SENSOR.sigma_bearing**2], len(ids)))
            kf.update(
                z.reshape(-1), h_jacobian, hx, R=R, args=(ids,), hx_args=(ids,),
                residual=wrapped_every_second,
            )  # fmt: skip
        assert_same(state, kf, f"landmark update {t} ({len(ids)} readings)")

        if t % 10 == 9:  # a GPS + compass fix: the full-pose correction (the paper's merge)
            pose = rf.correct_pose(state, gps, gate=None)
            state = pose.state
            kf.update(
                gps.mean, lambda x: np.eye(3), lambda x: x, R=gps.cov,
                residual=lambda a, b: se2.minus(a, b),
            )  # fmt: skip
            assert_same(state, kf, f"pose update {t}")


@pytest.mark.parametrize("associate", ["signatures", "mahalanobis", "jcbb"])
def test_a_whole_log_through_ekf_run_equals_filterpy(associate):
    """The same simulated log replayed by relmap.filter.run (the odometry between readings
    compounded first) and stepped through filterpy with the pairs run chose: the same state at
    every time, to 1e-12."""
    rng = np.random.default_rng(12)
    start = rm.AT([0.1, -2.9, 0.15], np.diag([0.05, 0.04, 0.01]))
    steps = simulate(rng, 60)
    index = np.concatenate([np.full(len(ids), k + 1) for k, (_, _, ids, _) in enumerate(steps)])
    log = rf.Log(
        np.arange(len(steps) + 1.0),
        np.array([u for u, _, _, _ in steps]),
        index.astype(np.int64),
        np.concatenate([z for _, z, _, _ in steps]),
        np.concatenate([ids for _, _, ids, _ in steps]),
    )
    tr = rf.run(log, MOTION, SENSOR, LANDMARKS, start=start, associate=associate, gate=0.9999)
    assert (tr.status == rf.Status.USED).all()
    np.testing.assert_array_equal(tr.landmark, log.signature)
    kf = _Filter(dim_x=3, dim_z=2)
    kf.x, kf.P = start.mean.copy(), start.cov.copy()
    for k, (u, z, _, _) in enumerate(steps):
        kf.F, kf.Q = jacobians(kf.x, u)
        kf.predict(u=u)
        rows = np.flatnonzero(index == k + 1)
        if len(rows):
            ids = tr.landmark[rows]
            R = np.diag(np.tile([SENSOR.sigma_range**2, SENSOR.sigma_bearing**2], len(ids)))
            kf.update(z.reshape(-1), h_jacobian, hx, R=R, args=(ids,), hx_args=(ids,),
                      residual=wrapped_every_second)  # fmt: skip
        assert_same(rm.AT._trusted(tr.mean[k + 1], tr.cov[k + 1]), kf, f"time {k + 1}")


def test_filterpy_updates_in_joseph_form(monkeypatch):
    """filterpy's update is ``P = (I-KH)P(I-KH)ᵀ + KRKᵀ`` (as relmap's): with its gain made
    suboptimal (S⁻¹ scaled by 1.3) it still equals that, not ``(I-KH)P``."""

    class Off:
        @staticmethod
        def inv(S):
            return 1.3 * np.linalg.inv(S)

    monkeypatch.setattr(filterpy_ekf, "linalg", Off)
    kf = _Filter(dim_x=3, dim_z=2)
    kf.x = np.array([0.5, -0.2, 0.3])
    P = np.array([[0.05, 0.01, 0.002], [0.01, 0.04, -0.003], [0.002, -0.003, 0.01]])
    kf.P = P.copy()
    ids = np.array([0, 2, 5])
    R = np.diag(np.tile([0.0064, 0.000225], 3))
    z = hx(kf.x, ids) + 0.05
    kf.update(z, h_jacobian, hx, R=R, args=(ids,), hx_args=(ids,), residual=wrapped_every_second)
    H, K = h_jacobian(np.array([0.5, -0.2, 0.3]), ids), kf.K
    I_KH = np.eye(3) - K @ H
    joseph = I_KH @ P @ I_KH.T + K @ R @ K.T
    np.testing.assert_allclose(kf.P, joseph, rtol=1e-13, atol=1e-16)
    assert np.abs(kf.P - I_KH @ P).max() > 1e-4
