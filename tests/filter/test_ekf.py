"""relmap.filter.ekf: predict and update in the textbook letters, against the equations written
out in numpy here — the odometry prediction (lecture Eqs. 10-13), a user's motion and
measurement models with analytic or numeric Jacobians (Eq. 13; Eqs. 26-28 in Joseph form), the
stacked update of m independent readings and each reading's innovation given the readings
before it, and the full-pose correction (the paper's merge, §4)."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np
import pytest
from scipy import stats

import relmap as rm
from relmap.errors import NonFiniteError, ParameterError, ShapeError
from relmap.filter import ekf
from relmap.lie import se2
from relmap.models import (
    DiffDrive,
    DistanceNoise,
    Measurement,
    Motion,
    Odometry,
    PositionFix,
    RangeBearingSensor,
    WheelNoise,
    increment,
    step,
)
from relmap.uncertain.propagate import EUCLIDEAN, SE2, numerical_jacobian

NOISE = DistanceNoise(0.01, 0.02, 0.005)
PRIOR = rm.AT(
    [0.2, -0.1, 0.1], np.array([[0.04, 0.01, 0.0], [0.01, 0.05, 0.002], [0.0, 0.002, 0.003]])
)


def _T(a):
    return np.swapaxes(a, -1, -2)


def block_diagonal(R: np.ndarray) -> np.ndarray:
    """``(..., m, d, d)`` → the block-diagonal ``(..., md, md)``."""
    *batch, m, d, _ = R.shape
    out = np.zeros((*batch, m * d, m * d))
    for i in range(m):
        out[..., i * d : (i + 1) * d, i * d : (i + 1) * d] = R[..., i, :, :]
    return out


def textbook(P, y, H, R):
    """Eqs. 26-28 on the stacked readings: ``S = H P Hᵀ + R``, ``K = P Hᵀ S⁻¹``, ``δ = K y``,
    Joseph ``(I - KH) P (I - KH)ᵀ + K R Kᵀ``, ``yᵀ S⁻¹ y`` and ``log det S``."""
    *batch, m, d, n = H.shape
    Hs = H.reshape(*batch, m * d, n)
    Rs = block_diagonal(R)
    ys = y.reshape(*batch, m * d)
    S = Hs @ P @ _T(Hs) + Rs
    K = P @ _T(Hs) @ np.linalg.inv(S)
    A = np.eye(n) - K @ Hs
    Pj = A @ P @ _T(A) + K @ Rs @ _T(K)
    nis = np.einsum("...i,...i->...", ys, np.linalg.solve(S, ys[..., None])[..., 0])
    return (K @ ys[..., None])[..., 0], Pj, nis, np.linalg.slogdet(S)[1], S


# ------------------------------------------------------------------------- prediction
def test_predict_is_the_odometry_step():
    new = ekf.predict(PRIOR, [0.5, 0.2], Odometry(NOISE))
    expected, _, _ = step(PRIOR, [0.5, 0.2], NOISE)
    np.testing.assert_allclose(new.mean, expected.mean)
    np.testing.assert_allclose(new.cov, expected.cov)
    drive = DiffDrive(0.05, 0.3)  # wheel increments, the lecture's Gx P Gxᵀ + Gu Σu Guᵀ
    wheels = WheelNoise(sigma=0.02, k=0.001)
    new = ekf.predict(PRIOR, [2.5, 3.1], Odometry(wheels, drive=drive))
    expected, _, _ = step(PRIOR, [2.5, 3.1], wheels, drive=drive)
    np.testing.assert_allclose(new.mean, expected.mean, atol=1e-15)
    np.testing.assert_allclose(new.cov, expected.cov, rtol=1e-12)


def test_odometry_prediction_uses_the_numeric_jacobians_of_the_midpoint_step():
    """P⁻ = F P Fᵀ + G Σu Gᵀ with F, G numeric Jacobians of f(x, u) = x ⊕ Δ(u) (Eqs. 10-13)."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        A = rng.normal(size=(3, 3)) * 0.1
        state = rm.AT(rng.normal(size=3) * [2, 2, 3], A @ A.T)
        u = rng.normal(size=2) * [0.5, 0.4]
        new = ekf.predict(state, u, Odometry(NOISE))

        def f(x, uu):
            return se2.compose(x, increment(uu))

        F = numerical_jacobian(lambda x, u=u: f(x, u), state.mean, chart_in=SE2, chart_out=SE2)
        G = numerical_jacobian(lambda uu, x=state.mean: f(x, uu), u, chart_out=SE2)
        P = F @ state.cov @ F.T + G @ NOISE.covariance(u) @ G.T
        np.testing.assert_allclose(new.mean, f(state.mean, u), atol=1e-13)
        np.testing.assert_allclose(new.cov, P, rtol=1e-6, atol=1e-10)


def test_predict_rejects_non_finite_steps():
    for u in ([np.nan, 0.1], [[0.5, 0.1], [0.5, np.inf]]):
        with pytest.raises(NonFiniteError, match="finite"):
            ekf.predict(PRIOR, u, Odometry(NOISE))
    batch = rm.AT.stack([PRIOR, PRIOR])
    with pytest.raises(NonFiniteError):
        ekf.predict(batch, [[0.5, 0.1], [np.nan, 0.1]], Odometry(NOISE))


# ------------------------------------------------------------------ a user's models
F_CV = np.array([[1, 0, 0.1, 0], [0, 1, 0, 0.1], [0, 0, 1, 0], [0, 0, 0, 1.0]])
G_CV = np.array([[0.005, 0], [0, 0.005], [0.1, 0], [0, 0.1]])
Q_CV = np.diag([0.3, 0.2])
BEACON = np.array([3.0, -1.0])


@dataclasses.dataclass(frozen=True)
class ConstantVelocity(Motion):
    """``x = (px, py, vx, vy)`` driven by an acceleration ``u`` over 0.1 s (a plain vector)."""

    analytic: bool = True
    chart: ClassVar = EUCLIDEAN

    def f(self, x, u):
        return x @ F_CV.T + u @ G_CV.T

    def input_noise(self, u):
        return np.broadcast_to(Q_CV, (*np.shape(u)[:-1], 2, 2))

    def jacobians(self, x, u):
        if not self.analytic:
            return super().jacobians(x, u)
        return np.broadcast_to(F_CV, (*x.shape[:-1], 4, 4)), np.broadcast_to(
            G_CV, (*x.shape[:-1], 4, 2)
        )


@dataclasses.dataclass(frozen=True)
class Range(Measurement):
    """The distance of the position to a beacon, σ² 0.04."""

    analytic: bool = True
    dim: ClassVar[int] = 1
    state_chart: ClassVar = EUCLIDEAN

    def h(self, x, landmark=None):
        return np.linalg.norm(BEACON - x[..., :2], axis=-1)[..., None]

    def noise(self, z):
        return np.full((*np.shape(z)[:-1], 1, 1), 0.04)

    def jacobians(self, x, landmark=None):
        if not self.analytic:
            return super().jacobians(x, landmark)
        return range_jacobian(x), None


def range_jacobian(x):
    d = x[..., :2] - BEACON
    r = np.linalg.norm(d, axis=-1)[..., None]
    return np.concatenate([d / r, np.zeros_like(d)], axis=-1)[..., None, :]


@pytest.mark.parametrize("analytic", [True, False], ids=["analytic", "numeric"])
def test_generic_steps_are_the_textbook_equations(analytic):
    """A constant-velocity model (n = 4) and a range sensor, as a user writes them (with or
    without their Jacobians): Eq. 13 and Eqs. 26-28 (Joseph form) in numpy, for a batch of
    beliefs."""
    rng = np.random.default_rng(1)
    A = rng.normal(size=(5, 4, 4))
    belief = ekf.Belief(rng.normal(size=(5, 4)), A @ _T(A) + np.eye(4))
    u = rng.normal(size=(5, 2))
    pred = ekf.predict(belief, u, ConstantVelocity(analytic))
    assert isinstance(pred, ekf.Belief) and pred.chart is EUCLIDEAN
    tol = dict(rtol=1e-12, atol=1e-12) if analytic else dict(rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(pred.x, belief.x @ F_CV.T + u @ G_CV.T, atol=1e-12)
    np.testing.assert_allclose(pred.P, F_CV @ belief.P @ F_CV.T + G_CV @ Q_CV @ G_CV.T, **tol)

    sensor = Range(analytic)
    h = sensor.h(pred.x)
    z = h + rng.normal(size=(5, 1)) * 0.2
    c = ekf.correct(pred, z, sensor)
    Hm = range_jacobian(pred.x)
    S = Hm @ pred.P @ _T(Hm) + 0.04
    K = pred.P @ _T(Hm) @ np.linalg.inv(S)
    y = z - h
    I_KH = np.eye(4) - K @ Hm
    P = I_KH @ pred.P @ _T(I_KH) + 0.04 * K @ _T(K)
    np.testing.assert_allclose(c.S, S, **tol)
    np.testing.assert_allclose(c.y, y, atol=1e-15)
    np.testing.assert_allclose(c.state.x, pred.x + (K @ y[..., None])[..., 0], **tol)
    np.testing.assert_allclose(c.state.P, P, **tol)
    np.testing.assert_allclose(c.nis, (y[..., 0] ** 2) / S[..., 0, 0], **tol)


@dataclasses.dataclass(frozen=True)
class First(Measurement):
    """The first component of a plain vector, noise ``r``."""

    r: float = 0.25
    dim: ClassVar[int] = 1
    state_chart: ClassVar = EUCLIDEAN

    def h(self, x, landmark=None):
        return x[..., :1]

    def noise(self, z):
        return np.full((*np.shape(z)[:-1], 1, 1), self.r)


def test_singular_priors_and_readings():
    """P = 0 (a state known exactly): the reading changes nothing and its NIS is y²/R — no
    0/0. R not positive definite (an exact reading: the update weighs each reading by R⁻¹):
    a clear error naming R, not a NaN."""
    belief = ekf.Belief(np.zeros((2, 2)), np.stack([np.zeros((2, 2)), np.eye(2)]))
    c = ekf.correct(belief, [[1.0], [1.0]], First())
    np.testing.assert_array_equal(c.state.x[0], [0.0, 0.0])
    np.testing.assert_array_equal(c.state.P[0], 0.0)
    np.testing.assert_allclose(c.state.x[1], [1.0 / 1.25, 0.0], rtol=1e-15)  # K = 1/(1 + R)
    np.testing.assert_allclose(c.nis, [1.0 / 0.25, 1.0 / 1.25], rtol=1e-15)
    assert np.isfinite(c.state.P).all()
    with pytest.raises(ParameterError, match=r"noise R.*not positive definite"):
        ekf.correct(ekf.Belief(np.zeros((1, 2)), np.eye(2)[None]), [[1.0]], First(0.0))
    with pytest.raises(ParameterError, match="not positive definite"):
        ekf.correct(PRIOR, [0.3, 0.0], PositionFix(0.0))  # GPS without error


def test_a_reading_of_a_known_landmark_is_the_textbook_correction():
    """``correct`` with a landmark: Eq. 20's reading through the mount, its bearing wrapped in
    the innovation (a reading across ±π), Eqs. 26-28; ``R`` given replaces the model's."""
    sensor = RangeBearingSensor(0.1, 0.02, mount=[0.1, 0.05, 0.0])
    lm = np.array([-4.0, -0.2])  # behind the robot: a bearing near ±π
    h, H, _ = sensor.linearize(PRIOR.mean, lm)
    assert abs(h[1]) > 3.0
    z = np.array([h[0] + 0.05, se2.wrap_angle(h[1] + 0.06)])
    y = np.array([0.05, 0.06])
    for R in (np.diag([0.01, 0.0004]), np.array([[0.04, 0.001], [0.001, 0.0009]])):
        given = None if R[0, 1] == 0 else R
        c = ekf.correct(PRIOR, z, sensor, lm, R=given)
        S = H @ PRIOR.cov @ H.T + R
        K = PRIOR.cov @ H.T @ np.linalg.inv(S)
        np.testing.assert_allclose(c.y, y, atol=1e-12)
        np.testing.assert_allclose(c.S, S, rtol=1e-12)
        np.testing.assert_allclose(se2.minus(c.state.mean, se2.plus(PRIOR.mean, K @ y)), 0.0,
                                   atol=1e-12)  # fmt: skip
        np.testing.assert_allclose(c.state.cov, PRIOR.cov - K @ S @ K.T, rtol=1e-10, atol=1e-15)
        assert float(c.nis) == pytest.approx(y @ np.linalg.solve(S, y), rel=1e-12)


def test_correct_bad_input():
    fix = PositionFix(0.1)
    with pytest.raises(ShapeError, match=r"\(\.\.\., 2\)"):
        ekf.correct(PRIOR, [0.3, 0.0, 0.1], fix)
    with pytest.raises(ParameterError, match="finite"):
        ekf.correct(PRIOR, [np.nan, 0.0], fix)
    with pytest.raises(ShapeError, match="belief"):
        ekf.correct(ekf.Belief(np.zeros(3), np.eye(2)), [0.3, 0.0], fix)


# -------------------------------------------------------------------- the stacked update
def random_problem(rng, batch, n, m, d, *, singular=False):
    A = rng.normal(size=(*batch, n, n))
    P = A @ _T(A) + (0.0 if singular else 0.1) * np.eye(n)
    if singular:  # rank n - 1: a direction known exactly
        v = rng.normal(size=(*batch, n, 1))
        Pr = np.eye(n) - v @ _T(v) / (_T(v) @ v)
        P = Pr @ P @ Pr
    H = rng.normal(size=(*batch, m, d, n))
    B = rng.normal(size=(*batch, m, d, d)) * 0.3
    R = B @ _T(B) + 0.05 * np.eye(d)
    y = rng.normal(size=(*batch, m, d))
    return P, y, H, R


@pytest.mark.parametrize("singular", [False, True], ids=["regular", "singular P"])
def test_update_is_the_stacked_textbook_update(singular):
    """``update`` against the (md)×(md) textbook update written out: the correction, the
    Joseph covariance, the NIS and log det S; batches and several reading sizes; a singular P
    too; ``used``: the readings left out carry no information (the update of the others)."""
    rng = np.random.default_rng(7)
    for batch, n, m, d in [((), 3, 1, 2), ((4,), 3, 5, 2), ((2, 3), 5, 3, 1), ((6,), 4, 2, 3)]:
        P, y, H, R = random_problem(rng, batch, n, m, d, singular=singular)
        delta, P_new, nis, logdet, _, _ = ekf.update(P, y, H, R)
        d_want, P_want, nis_want, logdet_want, _ = textbook(P, y, H, R)
        scale = np.abs(P).max()
        np.testing.assert_allclose(delta, d_want, rtol=1e-9, atol=1e-11 * scale)
        np.testing.assert_allclose(P_new, P_want, rtol=1e-8, atol=1e-11 * scale)
        np.testing.assert_allclose(nis, nis_want, rtol=1e-9)
        np.testing.assert_allclose(logdet, logdet_want, rtol=1e-10, atol=1e-10)
        np.testing.assert_array_equal(P_new, _T(P_new))
        assert (np.linalg.eigvalsh(P_new) > -1e-12 * scale).all()
        if m > 1:  # the first reading left out (its numbers NaN: never read)
            used = np.ones((*batch, m), bool)
            used[..., 0] = False
            part = ekf.update(P, np.where(used[..., None], y, np.nan), H, R, used)
            rest = (y[..., 1:, :], H[..., 1:, :, :], R[..., 1:, :, :])
            d_want, P_want, nis_want, logdet_want, _ = textbook(P, *rest)
            np.testing.assert_allclose(part.delta, d_want, rtol=1e-9, atol=1e-11 * scale)
            np.testing.assert_allclose(part.P, P_want, rtol=1e-8, atol=1e-11 * scale)
            np.testing.assert_allclose(part.nis, nis_want, rtol=1e-9)
            np.testing.assert_allclose(part.logdet, logdet_want, rtol=1e-10, atol=1e-10)


def test_joseph_form_keeps_the_covariance_positive_after_a_precise_reading():
    """A reading 10⁶ times more precise than the prior: Eq. 28's ``P - K S Kᵀ`` loses the
    remaining variance to cancellation; the Joseph form keeps it symmetric positive definite
    and near the exact ``(P⁻¹ + Hᵀ R⁻¹ H)⁻¹``."""
    P = np.diag([1e4, 1e4, 1.0])
    H = np.array([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    R = np.array([[[1e-4, 0.0], [0.0, 1e-4]]])
    P_new = ekf.update(P, np.array([[0.3, -0.2]]), H, R).P
    exact = np.linalg.inv(np.linalg.inv(P) + H[0].T @ np.linalg.inv(R[0]) @ H[0])
    np.testing.assert_allclose(P_new, exact, rtol=1e-9, atol=1e-18)
    assert (np.linalg.eigvalsh(P_new) > 0).all()


def test_innovations_given_the_readings_before_are_the_gaussian_conditionals():
    """Reading i given readings j < i: ``y_i - S_i< S_<<⁻¹ y_<`` and
    ``S_ii - S_i< S_<<⁻¹ S_<i`` of the stacked innovation (the Gaussian conditional), whose
    densities multiply to the stacked one (the prediction-error decomposition), from
    ``update(..., given=True)``."""
    rng = np.random.default_rng(8)
    for batch, n, m, d in [((), 3, 4, 2), ((3,), 4, 3, 1)]:
        P, y, H, R = random_problem(rng, batch, n, m, d)
        delta, P_all, _, _, y_g, S_g = ekf.update(P, y, H, R, given=True)
        d_want, P_want, _, _, S = textbook(P, y, H, R)
        np.testing.assert_allclose(delta, d_want, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(P_all, P_want, rtol=1e-8, atol=1e-12)
        ys = y.reshape(*batch, m * d)
        for b in np.ndindex(*batch):
            ll = 0.0
            for i in range(m):
                a, before = slice(i * d, (i + 1) * d), slice(0, i * d)
                Sb = S[b]
                gain = Sb[a, before] @ np.linalg.inv(Sb[before, before]) if i else np.zeros((d, 0))
                np.testing.assert_allclose(y_g[b][i], ys[b][a] - gain @ ys[b][before], rtol=1e-9,
                                           atol=1e-12)  # fmt: skip
                np.testing.assert_allclose(S_g[b][i], Sb[a, a] - gain @ Sb[before, a], rtol=1e-9)
                ll += stats.multivariate_normal(np.zeros(d), S_g[b][i]).logpdf(y_g[b][i])
            want = stats.multivariate_normal(np.zeros(m * d), S[b]).logpdf(ys[b])
            assert ll == pytest.approx(want, rel=1e-10)


# ------------------------------------------------------------------- full-pose readings
def test_full_pose_correction_is_the_paper_merge_with_a_gate():
    reading = rm.AT([0.3, -0.05, 0.12], np.diag([0.01, 0.01, 0.001]))
    up = ekf.correct_pose(PRIOR, reading)
    assert up.accepted
    merged = rm.merge(PRIOR, reading)
    np.testing.assert_allclose(up.state.cov, merged.cov)
    np.testing.assert_allclose(up.state.mean, merged.mean, atol=1e-15)
    # Eq. 17 in one dimension: x = (σz² x⁻ + σ⁻² z)/(σ⁻² + σz²)
    a, b = rm.AT([1.0, 0, 0], np.diag([4.0, 1, 1])), rm.AT([2.0, 0, 0], np.diag([1.0, 1, 1]))
    assert ekf.correct_pose(a, b).state.mean[0] == pytest.approx((1 * 1 + 4 * 2) / 5)
    wild = rm.AT([5.0, 5.0, 2.0], np.diag([0.01, 0.01, 0.001]))
    out = ekf.correct_pose(PRIOR, wild)
    assert not out.accepted and np.array_equal(out.state.mean, PRIOR.mean)
    y = se2.minus(wild.mean, PRIOR.mean)
    assert out.mahalanobis2 == pytest.approx(y @ np.linalg.solve(PRIOR.cov + wild.cov, y))
    assert ekf.correct_pose(PRIOR, wild, gate=None).accepted  # no gate


def test_pose_correction_is_the_paper_merge_for_a_batch():
    rng = np.random.default_rng(2)
    A = rng.normal(size=(4, 3, 3)) * 0.1
    prior = rm.AT(rng.normal(size=(4, 3)), A @ _T(A) + 1e-3 * np.eye(3))
    reading = rm.AT(
        se2.plus(prior.mean, rng.normal(size=(4, 3)) * 0.05), np.diag([0.01, 0.02, 0.003])
    )
    up = ekf.correct_pose(prior, reading, gate=None)
    merged = rm.merge(prior, reading)
    np.testing.assert_allclose(up.state.mean, merged.mean, atol=1e-12)
    np.testing.assert_allclose(up.state.cov, merged.cov, rtol=1e-10, atol=1e-14)
