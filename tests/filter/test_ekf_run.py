"""relmap.filter.ekf's generic steps, built-in models and runner against the mathematics.

- generic predict/correct (a user's motion and sensor models, analytic or numeric Jacobians)
  against the textbook equations written in numpy here;
- the built-in models' Jacobians against numeric ones of the lecture's functions (odometry
  midpoint step, range-bearing with a mount offset);
- the runner against the textbook procedure step by step (tests/test_ekf_reference.py's
  reference correction and relmap.compound for the prediction);
- a batch of filters against each filter alone (bitwise);
- robust (Student-t) readings and the innovation log-likelihood against scipy.stats; each
  reading's innovation given the ones before it against the Gaussian conditional;
- biases and mount; JCBB against a brute-force search of the jointly compatible sets;
- bad input: 0/0 statuses, overflow, bad logs.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import relmap as rm
from relmap.errors import NonFiniteError, NumericalError, ParameterError, ShapeError
from relmap.filter import ekf
from relmap.lie import se2
from relmap.models import DistanceNoise, RangeBearingSensor, increment
from relmap.uncertain import gaussian
from relmap.uncertain.propagate import SE2, numerical_jacobian
from tests.filter.test_ekf_reference import reference

NOISE = DistanceNoise(0.004, 0.003, 0.001)
SENSOR = RangeBearingSensor(0.08, 0.015, mount=[0.12, 0.04, 0.1])
LANDMARKS = np.array([[4.0, 1.0], [6.0, -2.5], [2.5, 4.0], [-1.0, 5.0], [-4.5, 1.5], [1.0, -5.0]])


def params_of(noise=NOISE, sensor=SENSOR, **kw):
    return ekf.NoiseParameters.of(noise, sensor, **kw)


# ------------------------------------------------------------------------- generic steps
def constant_velocity(dt):
    F = np.array([[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    G = np.array([[dt * dt / 2, 0], [0, dt * dt / 2], [dt, 0], [0, dt]])
    return F, G


@pytest.mark.parametrize("analytic", [True, False], ids=["analytic", "numeric"])
def test_generic_steps_are_the_textbook_equations(analytic):
    """A constant-velocity model (n = 4) and a range sensor: Eq. 13 and Eqs. 26-28 (Joseph
    form) in numpy, for a batch of beliefs."""
    rng = np.random.default_rng(1)
    F, G = constant_velocity(0.1)
    Qu = np.diag([0.3, 0.2])
    motion = ekf.Motion(
        lambda x, u: x @ F.T + u @ G.T,
        lambda u: np.broadcast_to(Qu, (*np.shape(u)[:-1], 2, 2)),
        (lambda x, u: (np.broadcast_to(F, (*x.shape[:-1], 4, 4)),
                       np.broadcast_to(G, (*x.shape[:-1], 4, 2)))) if analytic else None,
    )  # fmt: skip
    A = rng.normal(size=(5, 4, 4))
    belief = ekf.Belief(rng.normal(size=(5, 4)), A @ np.swapaxes(A, -1, -2) + np.eye(4))
    u = rng.normal(size=(5, 2))
    pred = ekf.predict(belief, u, motion)
    np.testing.assert_allclose(pred.x, belief.x @ F.T + u @ G.T, atol=1e-12)
    np.testing.assert_allclose(pred.P, F @ belief.P @ F.T + G @ Qu @ G.T, rtol=1e-7)

    beacon = np.array([3.0, -1.0])

    def h(x):
        return np.hypot(*(beacon - x[..., :2]).T)[..., None] if x.ndim == 2 else np.hypot(
            *np.moveaxis(beacon - x[..., :2], -1, 0))[..., None]  # fmt: skip

    def H(x):
        d = x[..., :2] - beacon
        r = np.hypot(d[..., 0], d[..., 1])[..., None]
        return np.concatenate([d / r, np.zeros_like(d)], axis=-1)[..., None, :]

    sensor = ekf.Sensor(h, [[0.04]], H if analytic else None)
    z = h(pred.x) + rng.normal(size=(5, 1)) * 0.2
    c = ekf.correct(pred, z, sensor)
    Hm = H(pred.x)
    S = Hm @ pred.P @ np.swapaxes(Hm, -1, -2) + 0.04
    K = pred.P @ np.swapaxes(Hm, -1, -2) @ np.linalg.inv(S)
    y = z - h(pred.x)
    I_KH = np.eye(4) - K @ Hm
    P = I_KH @ pred.P @ np.swapaxes(I_KH, -1, -2) + 0.04 * K @ np.swapaxes(K, -1, -2)
    tol = dict(rtol=1e-12, atol=1e-12) if analytic else dict(rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(c.S, S, **tol)
    np.testing.assert_allclose(c.state.x, pred.x + (K @ y[..., None])[..., 0], **tol)
    np.testing.assert_allclose(c.state.P, P, **tol)
    np.testing.assert_allclose(c.nis, (y[..., 0] ** 2) / S[..., 0, 0], **tol)
    assert c.ok.all()


def test_a_singular_innovation_covariance_is_a_0_over_0_not_nan():
    """No noise and no uncertainty: S = 0 is not positive definite; the state is unchanged."""
    belief = ekf.Belief(np.zeros((2, 2)), np.stack([np.zeros((2, 2)), np.eye(2)]))

    def H(x):
        return np.broadcast_to([[1.0, 0.0]], (*x.shape[:-1], 1, 2))

    sensor = ekf.Sensor(lambda x: x[..., :1], [[0.0]], H)
    c = ekf.correct(belief, [[1.0], [1.0]], sensor)
    assert list(c.ok) == [False, True] and np.isnan(c.nis[0])
    np.testing.assert_array_equal(c.state.x[0], [0.0, 0.0])
    np.testing.assert_allclose(c.state.x[1], [1.0, 0.0])
    assert np.isfinite(c.state.P).all()


def test_pose_correction_is_the_paper_merge_for_a_batch():
    rng = np.random.default_rng(2)
    A = rng.normal(size=(4, 3, 3)) * 0.1
    prior = rm.AT(rng.normal(size=(4, 3)), A @ np.swapaxes(A, -1, -2) + 1e-3 * np.eye(3))
    reading = rm.AT(
        se2.plus(prior.mean, rng.normal(size=(4, 3)) * 0.05), np.diag([0.01, 0.02, 0.003])
    )
    up = ekf.correct_pose(prior, reading, gate=None)
    merged = rm.merge(prior, reading)
    np.testing.assert_allclose(up.state.mean, merged.mean, atol=1e-12)
    np.testing.assert_allclose(up.state.cov, merged.cov, rtol=1e-10, atol=1e-14)


# ------------------------------------------------------------------------ built-in models
def test_odometry_prediction_uses_the_numeric_jacobians_of_the_midpoint_step():
    """P⁻ = F P Fᵀ + G Σu Gᵀ with F, G numeric Jacobians of f(x, u) = x ⊕ Δ(u) (Eqs. 10-13)."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        A = rng.normal(size=(3, 3)) * 0.1
        state = rm.AT(rng.normal(size=3) * [2, 2, 3], A @ A.T)
        u = rng.normal(size=2) * [0.5, 0.4]
        new = ekf.predict(state, u, NOISE)

        def f(x, uu):
            return se2.compose(x, increment(uu))

        F = numerical_jacobian(lambda x, u=u: f(x, u), state.mean, chart_in=SE2, chart_out=SE2)
        G = numerical_jacobian(lambda uu, x=state.mean: f(x, uu), u, chart_out=SE2)
        P = F @ state.cov @ F.T + G @ NOISE.covariance(u) @ G.T
        np.testing.assert_allclose(new.mean, f(state.mean, u), atol=1e-13)
        np.testing.assert_allclose(new.cov, P, rtol=1e-6, atol=1e-10)


def test_range_bearing_innovation_covariance_uses_the_numeric_jacobian():
    """S = H P Hᵀ + R with H the numeric Jacobian of Eq. 20 through the mount offset."""
    rng = np.random.default_rng(4)
    state = rm.AT([0.3, -0.2, 0.7], np.diag([0.04, 0.03, 0.01]) + 0.005)
    z = SENSOR.predict(state.mean, LANDMARKS)
    up = ekf.correct_landmarks(state, z + rng.normal(size=z.shape) * 0.01, SENSOR, LANDMARKS,
                               associate="signatures", signatures=np.arange(6))  # fmt: skip
    for k, lm in enumerate(LANDMARKS):
        H = numerical_jacobian(lambda x, lm=lm: SENSOR.predict(x, lm), state.mean, chart_in=SE2)
        S = H @ state.cov @ H.T + np.diag([SENSOR.sigma_range**2, SENSOR.sigma_bearing**2])
        np.testing.assert_allclose(up.S[k], S, rtol=1e-7, atol=1e-12)


def test_biases_are_subtracted_and_the_mount_is_used():
    """Noise-free readings with a known bias, from a sensor mounted off-centre: with those
    parameters every innovation is zero and the state does not move."""
    mounted = RangeBearingSensor(0.1, 0.02, mount=[0.3, -0.1, 0.2])
    state = rm.AT([1.0, 2.0, 0.4], np.diag([0.01, 0.01, 0.001]))
    z = mounted.predict(state.mean, LANDMARKS) + np.array([0.25, -0.03])
    log = ekf.Log(np.array([0.0]), np.zeros((0, 2)), np.zeros(6, np.int64), z, np.arange(6))
    p = params_of(sensor=mounted, b_r=0.25, b_b=-0.03)
    tr = ekf.run(log, LANDMARKS, p, start=state)
    np.testing.assert_allclose(tr.y, 0.0, atol=1e-12)
    np.testing.assert_allclose(tr.mean[0], state.mean, atol=1e-12)
    unbiased = ekf.run(log, LANDMARKS, params_of(sensor=mounted), start=state)
    np.testing.assert_allclose(unbiased.y[:, 0], 0.25, atol=1e-12)


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
        z = SENSOR.predict(truth, LANDMARKS[idx]) + rng.normal(size=(per_step, 2)) * [0.08, 0.015]
        fake = rng.random(per_step) < clutter
        z[fake] = np.column_stack([rng.uniform(1, 8, fake.sum()), rng.uniform(-3, 3, fake.sum())])
        index += [k] * per_step
        zs.append(z)
        sigs.append(np.where(fake, -7, idx))
    return ekf.Log(np.arange(steps + 1.0), motion, np.array(index), np.concatenate(zs),
                   np.concatenate(sigs))  # fmt: skip


@pytest.mark.parametrize("associate", ["signatures", "mahalanobis", "euclidean"])
def test_run_is_the_textbook_procedure_step_by_step(associate):
    """ekf.run over a log against a Python loop: relmap.compound with the odometry step's AT
    (relmap.models) for each prediction, the reference correction of test_ekf_reference."""
    rng = np.random.default_rng(5)
    log = simulated_log(rng)
    start = rm.AT([0.0, -1.0, 0.2], np.diag([0.01, 0.01, 0.002]))
    tr = ekf.run(log, LANDMARKS, params_of(), start=start, association=associate,
                 landmark_signatures=np.arange(6))  # fmt: skip
    state = start
    means = [state.mean]
    covs = [state.cov]
    from relmap.models.odometry import _step_ats

    kw = dict(signatures=None, landmark_signatures=None)
    for k in range(1, len(log.t)):
        state = rm.compound(state, _step_ats(log.motion[k - 1], NOISE, "midpoint", None))
        rows = np.flatnonzero(log.reading_index == k)
        if len(rows):
            if associate == "signatures":
                kw = dict(signatures=log.signature[rows], landmark_signatures=np.arange(6))
            new, landmark, d2, status = reference(state, log.z[rows], SENSOR, LANDMARKS,
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
    assert tr.count(ekf.Status.USED) == (tr.status == ekf.Status.USED).sum() > 0


def test_a_batch_of_filters_is_each_filter_alone_bitwise():
    rng = np.random.default_rng(6)
    log = simulated_log(rng, clutter=0.3)
    start = rm.AT([0.0, -1.0, 0.2], np.diag([0.01, 0.01, 0.002]))
    scale = rng.uniform(0.3, 3.0, (2, 3))
    p = ekf.NoiseParameters(0.004 * scale, 0.003 * scale, 0.001, 0.08 * scale, 0.015,
                            nu=np.where(scale > 1.5, 4.0, np.inf))  # fmt: skip
    for association in ("mahalanobis", "jcbb"):
        batch = ekf.run(log, LANDMARKS, p, start=start, association=association)
        assert batch.mean.shape == (2, 3, len(log.t), 3) and batch.loglik.shape == (2, 3)
        for i, j in itertools.product(range(2), range(3)):
            one = ekf.NoiseParameters(*(np.broadcast_to(v, (2, 3))[i, j] for v in p))
            alone = ekf.run(log, LANDMARKS, one, start=start, association=association)
            for name in ("mean", "cov", "y", "S", "mahalanobis2", "status", "landmark",
                         "loglik", "nis", "dof", "counts", "y_given", "S_given"):  # fmt: skip
                np.testing.assert_array_equal(getattr(batch, name)[i, j], getattr(alone, name))


def test_keep_modes_and_summary_do_not_hold_every_state():
    rng = np.random.default_rng(7)
    log = simulated_log(rng)
    start = rm.AT([0.0, -1.0, 0.2], np.diag([0.01, 0.01, 0.002]))
    p = ekf.NoiseParameters(np.full(50, 0.004), 0.003, 0.001, 0.08, 0.015)
    full = ekf.run(log, LANDMARKS, p, start=start, association="mahalanobis")
    events = ekf.run(log, LANDMARKS, p, start=start, association="mahalanobis", keep="events")
    summary = ekf.run(log, LANDMARKS, p, start=start, association="mahalanobis",
                      keep="summary", readings=False)  # fmt: skip
    assert summary.mean.shape == (50, 1, 3) and summary.y.shape == (50, 0, 2)
    np.testing.assert_array_equal(summary.mean[:, 0], full.mean[:, -1])
    np.testing.assert_array_equal(summary.loglik, full.loglik)
    at = np.unique(log.reading_index)
    np.testing.assert_array_equal(events.t, np.concatenate([[0.0], log.t[at]]))
    np.testing.assert_array_equal(events.mean[:, 1:], full.mean[:, at])
    with pytest.raises(ParameterError):
        ekf.run(log, LANDMARKS, p, start=start, keep="everything")


# ----------------------------------------------------------------- likelihood and robustness
def three_readings(rng):
    """One time stamp with readings of landmarks 0-2 about a prior ``state``: its log, the
    stacked innovation ``y``, Jacobian ``Hs``, noise ``R`` and ``S = Hs P Hsᵀ + R`` (Eqs. 20-26
    written out)."""
    state = rm.AT([0.2, 0.1, 0.3], np.diag([0.05, 0.04, 0.01]))
    z = SENSOR.predict(state.mean, LANDMARKS[:3]) + rng.normal(size=(3, 2)) * [0.3, 0.05]
    log = ekf.Log(np.array([0.0]), np.zeros((0, 2)), np.zeros(3, np.int64), z, np.arange(3))
    h, H, _ = SENSOR.predict(state.mean, LANDMARKS[:3], jacobians=True)
    y = (z - h).reshape(-1)
    y[1::2] = se2.wrap_angle(y[1::2])
    Hs = H.reshape(-1, 3)
    R = np.diag(np.tile([SENSOR.sigma_range**2, SENSOR.sigma_bearing**2], 3))
    S = Hs @ state.cov @ Hs.T + R
    return state, log, y, Hs, R, S


def test_loglik_is_the_gaussian_or_student_t_density_of_the_stacked_innovation():
    from scipy import stats

    state, log, y, Hs, R, S = three_readings(np.random.default_rng(8))
    gauss = ekf.run(log, LANDMARKS, params_of(), start=state, gate=0.999999)
    assert (gauss.status == ekf.Status.USED).all()
    assert gauss.loglik == pytest.approx(
        stats.multivariate_normal(np.zeros(6), S).logpdf(y), rel=1e-10
    )
    assert gauss.nis == pytest.approx(y @ np.linalg.solve(S, y), rel=1e-10) and gauss.dof == 6
    nu = 3.5
    robust = ekf.run(log, LANDMARKS, params_of(nu=nu), start=state, gate=0.999999)
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
    from scipy import stats

    state, log, y, Hs, R, S = three_readings(np.random.default_rng(9))
    c = 2.5
    tr = ekf.run(log, LANDMARKS, params_of()._replace(inflation=c), start=state, gate=0.999999)
    assert (tr.status == ekf.Status.USED).all()
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
    plain = ekf.run(log, LANDMARKS, params_of(), start=state, gate=0.999999)
    one = ekf.run(log, LANDMARKS, params_of()._replace(inflation=1.0), start=state,
                  gate=0.999999)  # fmt: skip
    np.testing.assert_array_equal(plain.cov, one.cov)
    with pytest.raises(ParameterError, match="inflation"):
        ekf.run(log, LANDMARKS, params_of()._replace(inflation=0.0), start=state)


def test_innovations_given_the_readings_before_are_the_stacked_one_decomposed():
    """``y_given``, ``S_given``: reading k's innovation and covariance conditioned on the
    readings before it, ``y_k - S_k< S_<<⁻¹ y_<`` and ``S_kk - S_k< S_<<⁻¹ S_<k`` of the stacked
    innovation (the Gaussian conditional), whose densities multiply to the stacked likelihood;
    with R itself also for a robust or inflated filter. A gated reading is conditioned on all
    the used ones: the posterior's ``z - h - H δ`` and ``H P⁺ Hᵀ + R``."""
    from scipy import stats

    state, log, y, Hs, R, S = three_readings(np.random.default_rng(8))
    for kw in ({}, {"nu": 4.0}, {"inflation": 2.5}):
        tr = ekf.run(log, LANDMARKS, params_of()._replace(**kw), start=state, gate=0.999999)
        assert (tr.status == ekf.Status.USED).all()
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
    tr = ekf.run(far, LANDMARKS, params_of(), start=state)
    np.testing.assert_array_equal(tr.status, [ekf.Status.USED, ekf.Status.USED, ekf.Status.GATED])
    u = slice(0, 4)
    K = state.cov @ Hs[u].T @ np.linalg.inv(S[u, u])
    post = (np.eye(3) - K @ Hs[u]) @ state.cov
    H2 = Hs[4:]
    np.testing.assert_allclose(tr.y_given[2], y[4:] + shift - H2 @ K @ y[u], rtol=1e-10)
    np.testing.assert_allclose(tr.S_given[2], H2 @ post @ H2.T + R[4:, 4:], rtol=1e-9)
    np.testing.assert_allclose(tr.y[2], y[4:] + shift, rtol=1e-12)  # y, S: at the prior
    np.testing.assert_allclose(tr.S[2], S[4:, 4:], rtol=1e-12)


# ------------------------------------------------------------------------------------ JCBB
def brute_force_jcbb(state, z, sensor, lm, gate):
    """All one-to-one sets of individually compatible pairs: the largest jointly compatible
    one, of least joint d² (Neira & Tardós 2001's objective), searched exhaustively. As in
    JCBB's tree, a set counts as jointly compatible when each of its prefixes (readings in
    order) passes its joint χ² gate."""
    h, H, _ = sensor.predict(state.mean[None], lm, jacobians=True)
    R = np.diag([sensor.sigma_range**2, sensor.sigma_bearing**2])
    S = H @ state.cov @ np.swapaxes(H, -1, -2) + R
    m, L = len(z), len(lm)
    v = z[:, None] - h[None]
    v[..., 1] = se2.wrap_angle(v[..., 1])
    d2 = np.einsum("mla,lab,mlb->ml", v, np.linalg.inv(S), v)
    g2 = float(gaussian.confidence_k2(gate, 2))
    best, best_j = [], np.inf
    options = [[None] + [j for j in range(L) if d2[i, j] <= g2] for i in range(m)]
    for choice in itertools.product(*options):
        pairs = [(i, j) for i, j in enumerate(choice) if j is not None]
        ls = [j for _, j in pairs]
        if len(set(ls)) < len(ls) or len(pairs) < len(best):
            continue
        j2, compatible = 0.0, True
        for k in range(1, len(pairs) + 1):  # every prefix jointly compatible, as JCBB's nodes
            y = np.concatenate([v[i, j] for i, j in pairs[:k]])
            Hs = np.concatenate([H[j] for _, j in pairs[:k]])
            Sj = Hs @ state.cov @ Hs.T + np.kron(np.eye(k), R)
            j2 = float(y @ np.linalg.solve(Sj, y))
            compatible = compatible and j2 <= gaussian.confidence_k2(gate, 2 * k)
        if not compatible:
            continue
        if len(pairs) > len(best) or j2 < best_j:
            best, best_j = pairs, j2
    return dict(best)


def test_jcbb_finds_the_largest_jointly_compatible_set():
    rng = np.random.default_rng(9)
    sensor = RangeBearingSensor(0.1, 0.03)
    found_ambiguous = 0
    for _ in range(60):
        lm = rng.uniform(-3, 3, (5, 2))
        state = rm.AT(rng.normal(size=3) * 0.3, np.diag([0.3, 0.3, 0.05]))
        truth = se2.plus(state.mean, rng.normal(size=3) * [0.4, 0.4, 0.15])
        z = sensor.predict(truth, lm[rng.choice(5, 4, replace=False)])
        z += rng.normal(size=z.shape) * [0.1, 0.03]
        up = ekf.correct_landmarks(state, z, sensor, lm, associate="jcbb", gate=0.95)
        want = brute_force_jcbb(state, z, sensor, lm, 0.95)
        got = {i: int(j) for i, j in enumerate(up.landmark) if up.status[i] == ekf.Status.USED}
        assert got == want
        nn = ekf.correct_landmarks(state, z, sensor, lm, gate=0.95)
        found_ambiguous += int(list(nn.landmark) != list(up.landmark))
    assert found_ambiguous > 0  # JCBB differs from nearest neighbour on some scans


# ------------------------------------------------------------------------------- bad input
def test_a_0_over_0_reading_in_a_run_is_counted_alike_alone_and_in_a_batch():
    """A landmark exactly at the sensor (no bearing): DEGENERATE, the same in a batch."""
    start = rm.AT([0.0, 0.0, 0.0], np.diag([0.01, 0.01, 0.001]))
    lm = np.array([[SENSOR.mount[0], SENSOR.mount[1]], [3.0, 1.0]])
    z = np.array([[1.0, 0.0], SENSOR.predict(start.mean, lm[1])])
    log = ekf.Log(np.arange(2.0), np.zeros((1, 2)), np.array([1, 1]), z, np.array([0, 1]))
    one = ekf.run(log, lm, params_of(), start=start)
    assert list(one.status) == [ekf.Status.DEGENERATE, ekf.Status.USED]
    p = ekf.NoiseParameters(*(np.stack([v, v]) for v in params_of()))
    both = ekf.run(log, lm, p, start=start)
    np.testing.assert_array_equal(both.status[1], one.status)
    np.testing.assert_array_equal(both.mean[1], one.mean)
    assert np.isfinite(both.mean).all() and np.isfinite(both.cov).all()


def test_bad_logs_and_parameters():
    start = rm.AT([0.0, 0.0, 0.0], np.diag([0.01, 0.01, 0.001]))
    p = params_of()
    good = ekf.Log(
        np.arange(3.0), np.zeros((2, 2)), np.array([1]), np.array([[1.0, 0.1]]), np.array([0])
    )
    with pytest.raises(ParameterError, match="empty"):
        ekf.run(good._replace(t=np.zeros(0)), LANDMARKS, p, start=start)
    with pytest.raises(ParameterError, match="strictly increasing"):
        ekf.run(good._replace(t=np.array([0.0, 2.0, 1.0])), LANDMARKS, p, start=start)
    with pytest.raises(ShapeError, match="motion"):
        ekf.run(good._replace(motion=np.zeros((1, 2))), LANDMARKS, p, start=start)  # truncated
    with pytest.raises(ParameterError, match="reading_index"):
        ekf.run(good._replace(reading_index=np.array([5])), LANDMARKS, p, start=start)
    with pytest.raises(NonFiniteError):
        ekf.run(good, LANDMARKS, p._replace(sigma_r=np.nan), start=start)
    with pytest.raises(ParameterError):
        ekf.run(good, LANDMARKS, p._replace(nu=0.0), start=start)
    with pytest.raises(ParameterError, match="signature"):
        ekf.run(good._replace(signature=None), LANDMARKS, p, start=start)
    with pytest.raises(ParameterError, match="must not decrease"):
        ekf.Log.from_velocities([0.0, 2.0, 1.0], [0, 0, 0], [0, 0, 0], [], np.zeros((0, 2)))
    with pytest.raises(ParameterError, match="no odometry"):
        ekf.Log.from_velocities([], [], [], [], np.zeros((0, 2)))
    # NaN readings are counted, the filter stays finite
    nan = good._replace(z=np.array([[np.nan, 0.1]]))
    tr = ekf.run(nan, LANDMARKS, p, start=start)
    assert tr.status[0] == ekf.Status.INVALID and tr.count(ekf.Status.INVALID) == 1
    assert np.isfinite(tr.mean).all()
    # overflow: a clear error naming the time, never a NaN state
    huge = good._replace(motion=np.array([[1e300, 0.0], [1e300, 0.0]]))
    with pytest.raises(NumericalError, match="overflowed"):
        ekf.run(huge, LANDMARKS, p, start=start)
