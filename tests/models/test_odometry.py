"""relmap.models: differential-drive odometry (lecture Eqs. 9-12) and the planar arm (Eqs. 1-8)."""

from __future__ import annotations

import numpy as np
import pytest

import relmap as rm
from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.models import (
    AlphaNoise,
    DiffDrive,
    DistanceNoise,
    Odometry,
    PlanarArm,
    WheelNoise,
    dead_reckon,
    increment,
    increments_from_velocities,
    step,
)
from relmap.sim import montecarlo
from relmap.uncertain import gaussian
from relmap.uncertain.propagate import SE2, numerical_jacobian
from tests.helpers import assert_poses_close

DRIVE = DiffDrive(0.05, 0.3)


def lecture_g(x: np.ndarray, u: np.ndarray, drive: DiffDrive = DRIVE) -> np.ndarray:
    """Lecture Eqs. 9-10 written out: the pose after wheel increments u from pose x."""
    r, b = drive.wheel_radius, drive.baseline
    sl, sr = r * u[..., 0], r * u[..., 1]
    ds, dth = (sr + sl) / 2, (sr - sl) / b
    return np.stack(
        [
            x[..., 0] + ds * np.cos(x[..., 2] + dth / 2),
            x[..., 1] + ds * np.sin(x[..., 2] + dth / 2),
            se2.wrap_angle(x[..., 2] + dth),
        ],
        axis=-1,
    )


# ---------------------------------------------------------------- validation
@pytest.mark.parametrize(
    ("r", "b"), [(-0.05, 0.3), (0.0, 0.3), (0.05, -1.0), (0.05, 0.0), (np.nan, 0.3)]
)
def test_drive_rejects_non_positive_geometry(r, b):
    with pytest.raises(ParameterError, match="positive"):
        DiffDrive(r, b)


def test_noise_models_reject_negative_parameters():
    with pytest.raises(ParameterError):
        WheelNoise(sigma=-0.1)
    with pytest.raises(ParameterError):
        DistanceNoise(k_s=-1)
    with pytest.raises(ParameterError):
        AlphaNoise(0.1, 0.1, -0.1, 0.1)
    with pytest.raises(TypeError):
        WheelNoise(sigmaa=0.1)
    with pytest.raises(ParameterError, match="DiffDrive"):
        dead_reckon(np.ones((3, 2)), WheelNoise(0.1))


# ------------------------------------------------------------------ the step
def test_midpoint_step_matches_lecture_eq10():
    rng = np.random.default_rng(1)
    x = np.column_stack([rng.normal(size=(20, 2)), rng.uniform(-np.pi, np.pi, 20)])
    u = rng.normal(size=(20, 2)) * 3
    m = DRIVE.motion(u)
    assert_poses_close(se2.compose(x, increment(m, "midpoint")), lecture_g(x, u))


def test_arc_is_the_exponential_map_and_exact_near_zero():
    rng = np.random.default_rng(2)
    m = np.column_stack(
        [
            rng.normal(size=50),
            np.concatenate(
                [
                    rng.normal(size=40),
                    [1e-9, -1e-6, 9.9e-3, 1.01e-2, 0.0, 1e-4, 3e-3, -5e-3, 2.0, -3.0],
                ]
            ),
        ]
    )
    expected = se2.exp(np.column_stack([m[:, 0], np.zeros(50), m[:, 1]]))
    assert_poses_close(increment(m, "arc"), expected, atol=1e-14)


@pytest.mark.parametrize("integration", ["midpoint", "arc"])
def test_increment_jacobian_numeric(integration):
    m = np.array([[1.0, 0.3], [0.5, -2.0], [2.0, 1e-3], [0.7, 0.0099], [1.3, 0.0101], [0.2, -1e-7]])
    _, J = increment(m, integration, jacobians=True)
    Jn = numerical_jacobian(lambda v: increment(v, integration), m, step=1e-7, chart_out=SE2)
    np.testing.assert_allclose(J, Jn, atol=1e-8)


def test_step_jacobians_gx_gu_match_numeric_and_eq12():
    rng = np.random.default_rng(3)
    cov = np.array([[0.01, 0.002, 0.001], [0.002, 0.02, -0.001], [0.001, -0.001, 0.003]])
    pose = rm.AT(np.r_[rng.normal(size=2), 2.9], cov)
    u = np.array([2.5, 3.1])
    noise = WheelNoise(sigma=0.02, k=0.001)
    new, Gx, Gu = step(pose, u, noise, drive=DRIVE)
    Gx_n = numerical_jacobian(lambda x: lecture_g(x, u), pose.mean, chart_in=SE2, chart_out=SE2)
    Gu_n = numerical_jacobian(lambda v: lecture_g(pose.mean, v), u, chart_out=SE2)
    np.testing.assert_allclose(Gx, Gx_n, atol=1e-8)
    np.testing.assert_allclose(Gu, Gu_n, atol=1e-8)
    Su = np.diag(0.02**2 + 0.001 * np.abs(u))
    np.testing.assert_allclose(
        new.cov, Gx @ pose.cov @ Gx.T + Gu @ Su @ Gu.T, rtol=1e-12, atol=1e-17
    )
    assert_poses_close(new.mean, lecture_g(pose.mean, u))


def test_dead_reckoning_equals_the_step_by_step_recursion():
    rng = np.random.default_rng(4)
    u = np.abs(rng.normal(4, 1, (300, 2)))
    noise = WheelNoise(sigma=0.01, k=0.002)
    run = dead_reckon(u, noise, drive=DRIVE)
    assert run.batch_shape == (301,)
    np.testing.assert_array_equal(run.cov[0], 0.0)
    pose = rm.AT.identity()
    for k in range(300):
        pose, _, _ = step(pose, u[k], noise, drive=DRIVE)
        if k in (0, 17, 299):
            assert_poses_close(run.mean[k + 1], pose.mean, atol=1e-10)
            np.testing.assert_allclose(run.cov[k + 1], pose.cov, rtol=1e-9, atol=1e-15)


def test_dead_reckoning_from_an_uncertain_start():
    start = rm.AT.from_sigmas([1.0, 2.0, 0.5], [0.1, 0.1, 0.05])
    m = np.tile([0.1, 0.02], (50, 1))
    run = dead_reckon(m, DistanceNoise(0.001, 0.001, 0.0005), start=start)
    np.testing.assert_allclose(run.cov[0], start.cov)
    manual = start
    for _ in range(50):
        manual, _, _ = step(manual, [0.1, 0.02], DistanceNoise(0.001, 0.001, 0.0005))
    np.testing.assert_allclose(run.cov[-1], manual.cov, rtol=1e-10)


@pytest.mark.parametrize("noise", [WheelNoise(sigma=0.05), WheelNoise(k=0.002)])
def test_dead_reckoning_against_monte_carlo(noise):
    """Sample the wheel increments with the model's noise, integrate exactly (Eq. 10), compare."""
    rng = np.random.default_rng(5)
    n_steps, n = 40, 40_000
    u = np.tile([3.0, 3.4], (n_steps, 1))
    run = dead_reckon(u, noise, drive=DRIVE)
    Su = np.diag(noise.sigma**2 + noise.k * np.abs(u[0]))
    x = np.zeros((n, 3))
    for k in range(n_steps):
        x = lecture_g(x, u[k] + rng.multivariate_normal(np.zeros(2), Su, size=n))
    report = montecarlo.SampleSet.of(x).compare(run[-1])
    assert report.cov_rel_error < 0.03


def test_alpha_model_against_monte_carlo():
    a = AlphaNoise(0.01, 0.002, 0.01, 0.001)
    m = np.array([[0.5, 0.4]])
    at = dead_reckon(m, a)[-1]
    rng = np.random.default_rng(6)
    n = 200_000
    rot, trans = 0.2, 0.5
    v_rot, v_trans = a.a1 * rot**2 + a.a2 * trans**2, a.a3 * trans**2 + a.a4 * 2 * rot**2
    r1 = rot + rng.normal(0, np.sqrt(v_rot), n)
    tr = trans + rng.normal(0, np.sqrt(v_trans), n)
    r2 = rot + rng.normal(0, np.sqrt(v_rot), n)
    samples = np.column_stack([tr * np.cos(r1), tr * np.sin(r1), r1 + r2])
    report = montecarlo.SampleSet.of(samples).compare(at)
    assert report.cov_rel_error < 0.02
    with pytest.raises(ParameterError, match="midpoint"):
        dead_reckon(m, a, integration="arc")


def test_large_heading_noise_bends_the_cloud_into_a_crescent():
    """§6.3 / Fig. 5: first order stays near for small heading noise; large heading noise makes the
    sampled distribution measurably non-Gaussian (Mardia skewness) and the moments drift."""
    results = {}
    for k_theta in (1e-4, 0.05):
        noise = DistanceNoise(k_s=1e-4, k_theta_s=k_theta)
        m = np.tile([0.2, 0.0], (25, 1))
        run = dead_reckon(m, noise)
        rng = np.random.default_rng(7)
        n = 50_000
        x = np.zeros((n, 3))
        for _ in range(25):
            ds = 0.2 + rng.normal(0, np.sqrt(1e-4 * 0.2), n)
            dt = rng.normal(0, np.sqrt(k_theta * 0.2), n)
            x = se2.compose(x, np.column_stack([ds * np.cos(dt / 2), ds * np.sin(dt / 2), dt]))
        results[k_theta] = montecarlo.SampleSet.of(x).compare(run[-1])
    small, large = results[1e-4], results[0.05]
    assert small.skewness < 0.05 and small.cov_rel_error < 0.02
    assert large.skewness > 1.0
    assert large.cov_rel_error > 5 * small.cov_rel_error


def test_increments_from_velocities():
    t = np.array([0.0, 0.1, 0.3, 0.3, 0.6])
    v = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    w = np.array([0.1, 0.2, 0.3, 0.4, 0.5])
    m = increments_from_velocities(t, v, w)
    np.testing.assert_allclose(m, [[0.1, 0.01], [0.4, 0.04], [0.0, 0.0], [1.2, 0.12]])
    with pytest.raises(ParameterError, match="backwards"):
        increments_from_velocities([0.0, 1.0, 0.5], [1, 1, 1], [0, 0, 0])
    with pytest.raises(ShapeError):
        increments_from_velocities([0.0, 1.0], [1.0], [0.0, 0.0])


# ---------------------------------------------------------------------- the arm
ARM = PlanarArm(0.4, 0.3, shoulder=(0.1, 0.5), grip=(0.06, -0.04))


def test_arm_forward_kinematics_eq1():
    q = np.array([0.3, 0.7])
    x = 0.1 + 0.4 * np.cos(0.3) + 0.3 * np.cos(1.0) + 0.06
    z = 0.5 + 0.4 * np.sin(0.3) + 0.3 * np.sin(1.0) - 0.04
    np.testing.assert_allclose(ARM.forward(q), [x, z], atol=1e-15)


def test_arm_jacobian_numeric_batched():
    q = np.random.default_rng(8).uniform(-np.pi, np.pi, (5, 2, 2))
    np.testing.assert_allclose(ARM.jacobian(q), numerical_jacobian(ARM.forward, q), atol=1e-9)


def test_gripper_uncertainty_against_monte_carlo_and_ellipse():
    q = np.array([0.5, -0.8])
    cov_q = gaussian.rotated_covariance(np.radians(0.5), np.radians(0.2), np.radians(30))
    m = ARM.gripper(q, cov_q)
    J = ARM.jacobian(q)
    np.testing.assert_allclose(m.cov, J @ cov_q @ J.T, rtol=1e-12)
    samples = ARM.forward(gaussian.sample(q, cov_q, 200_000, seed=9))
    emp = np.cov(samples.T)
    assert np.linalg.norm(emp - m.cov) / np.linalg.norm(m.cov) < 0.02
    e = ARM.gripper_ellipse(q, cov_q, 0.9)
    inside = gaussian.mahalanobis2(samples, m.mean, m.cov) <= gaussian.confidence_k2(0.9, 2)
    assert abs(inside.mean() - 0.9) < 0.005
    assert e.semi_major > e.semi_minor > 0


def test_arm_errors():
    with pytest.raises(ParameterError):
        PlanarArm(-0.4, 0.3)
    with pytest.raises(ShapeError):
        ARM.forward([0.1, 0.2, 0.3])
    with pytest.raises(rm.errors.NotPositiveSemidefiniteError):
        ARM.gripper([0.1, 0.2], [[1.0, 2.0], [2.0, 1.0]])


# --------------------------------------------------------- the motion model (models.base)
@pytest.mark.parametrize("integration", ["midpoint", "arc"])
def test_distance_noise_step_covariance_is_j_sigma_jt(rng, integration):
    """The step's covariance (``Odometry(noise).increment(u).cov`` = J_w Q_w J_wᵀ) is
    J diag(var Δs, var Δθ) Jᵀ with J = ∂Δ/∂(Δs, Δθ) (Eqs. 10-13), J taken numerically here;
    batched and unbatched."""
    noise = DistanceNoise(0.01, 0.02, 0.003)
    model = Odometry(noise, integration)
    m = np.column_stack([rng.uniform(-1.0, 2.0, 5), rng.uniform(-0.8, 0.8, 5)])
    C = model.increment(m).cov
    for mi, Ci in zip(m, C, strict=True):
        J = numerical_jacobian(lambda v: increment(v, integration), mi)
        S = np.diag([0.01 * abs(mi[0]), 0.02 * abs(mi[1]) + 0.003 * abs(mi[0])])
        np.testing.assert_allclose(Ci, J @ S @ J.T, rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose(model.increment(mi).cov, Ci, rtol=1e-12)


def _alpha_step(w: np.ndarray) -> np.ndarray:
    """Probabilistic Robotics' rot-trans-rot step from ``w = (δrot1, δtrans, δrot2)``."""
    r1, tr, r2 = w[..., 0], w[..., 1], w[..., 2]
    return np.stack([tr * np.cos(r1), tr * np.sin(r1), r1 + r2], axis=-1)


def _wheel_cov(u: np.ndarray, noise: WheelNoise) -> np.ndarray:
    """Lecture Eq. 12's Σu on the wheels mapped to (Δs, Δθ) by Eq. 9's W: W Σu Wᵀ."""
    r, b = DRIVE.wheel_radius, DRIVE.baseline
    W = np.array([[r / 2, r / 2], [-r / b, r / b]])
    return W @ np.diag(noise.sigma**2 + noise.k * np.abs(u)) @ W.T


MODELS = {
    # name: (model, the noise sources w at input u, the step Δ(w), Q_w written out)
    "distance-midpoint": (
        Odometry(DistanceNoise(0.01, 0.02, 0.003)),
        lambda u: u,
        lambda w: increment(w, "midpoint"),
        lambda u: np.diag([0.01 * abs(u[0]), 0.02 * abs(u[1]) + 0.003 * abs(u[0])]),
    ),
    "distance-arc": (
        Odometry(DistanceNoise(0.01, 0.02, 0.003), integration="arc"),
        lambda u: u,
        lambda w: increment(w, "arc"),
        lambda u: np.diag([0.01 * abs(u[0]), 0.02 * abs(u[1]) + 0.003 * abs(u[0])]),
    ),
    "wheel": (
        Odometry(WheelNoise(sigma=0.02, k=0.001), drive=DRIVE),
        DRIVE.motion,
        lambda w: increment(w, "midpoint"),
        lambda u: _wheel_cov(u, WheelNoise(sigma=0.02, k=0.001)),
    ),
    "alpha": (
        Odometry(AlphaNoise(0.01, 0.002, 0.01, 0.001)),
        lambda u: np.array([u[1] / 2, u[0], u[1] / 2]),
        _alpha_step,
        lambda u: np.diag([0.01 * (u[1] / 2) ** 2 + 0.002 * u[0] ** 2,
                           0.01 * u[0] ** 2 + 0.001 * 2 * (u[1] / 2) ** 2,
                           0.01 * (u[1] / 2) ** 2 + 0.002 * u[0] ** 2]),
    ),
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(MODELS))
def test_odometry_model_jacobians_are_the_numeric_ones(rng, name):
    """The motion model ``x⁻ = x ⊕ Δ(u)``: F = ∂f/∂x and G = ∂f/∂w (w the noise sources) are
    the numeric Jacobians, in relmap's chart, of the pose compounded with the step written out
    here (lecture Eqs. 9-13; the α-model's rot-trans-rot); ``input_noise`` is Q_w written out,
    and ``step``'s J_w is ∂Δ/∂w."""
    model, sources, delta_of, Q_of = MODELS[name]
    for _ in range(10):
        x = np.r_[rng.normal(size=2) * 2, rng.uniform(-np.pi, np.pi)]
        u = rng.normal(size=2) * [0.6, 0.5] if name != "wheel" else rng.normal(3.0, 1.0, 2)
        w = sources(u)
        F, G = model.jacobians(x, u)
        F_n = numerical_jacobian(lambda xx, w=w: se2.compose(xx, delta_of(w)), x, chart_in=SE2,
                                 chart_out=SE2)  # fmt: skip
        G_n = numerical_jacobian(lambda ww, x=x: se2.compose(x, delta_of(ww)), w, chart_out=SE2)
        np.testing.assert_allclose(F, F_n, atol=1e-8)
        np.testing.assert_allclose(G, G_n, atol=1e-8)
        assert_poses_close(model.f(x, u), se2.compose(x, delta_of(w)), atol=1e-13)
        np.testing.assert_allclose(model.input_noise(u), Q_of(u), rtol=1e-12, atol=1e-18)
        delta, J_w, Q_w = model.step(u)
        assert_poses_close(delta, delta_of(w), atol=1e-14)
        np.testing.assert_allclose(J_w, numerical_jacobian(delta_of, w), atol=1e-8)
        np.testing.assert_allclose(model.increment(u).cov, J_w @ Q_w @ J_w.T, rtol=1e-12)


def test_odometry_model_is_the_lectures_step_for_wheel_increments():
    """With a DiffDrive the model's ``G Q_w Gᵀ`` is the lecture's ``Gu Σu Guᵀ`` on the wheel
    increments (Eq. 12; :func:`step`'s Gx and Gu)."""
    noise = WheelNoise(sigma=0.02, k=0.001)
    model = Odometry(noise, drive=DRIVE)
    pose = rm.AT([0.3, -1.0, 2.9], np.diag([0.01, 0.02, 0.003]))
    u = np.array([2.5, 3.1])
    _, Gx, Gu = step(pose, u, noise, drive=DRIVE)
    F, G = model.jacobians(pose.mean, u)
    np.testing.assert_allclose(F, Gx, atol=1e-15)
    Su = np.diag(0.02**2 + 0.001 * np.abs(u))
    np.testing.assert_allclose(G @ model.input_noise(u) @ G.T, Gu @ Su @ Gu.T, rtol=1e-12)


def test_a_batch_of_parameters_is_a_batch_of_models():
    """Array parameters: ``batch_shape``, each parameter set's step what that model alone
    gives; ``replace`` checks as the constructor does; ``batched`` adds axes for the inputs'."""
    k_s = np.array([0.001, 0.01, 0.1, 1.0])
    model = Odometry(DistanceNoise(k_s, 0.02, np.array([[0.0], [0.003]])))
    assert model.batch_shape == (2, 4) and model.noise_parameters == ("k_s", "k_theta", "k_theta_s")
    assert model.k_s is model.noise.k_s
    u = np.array([0.4, 0.3])
    C = model.increment(u).cov
    assert C.shape == (2, 4, 3, 3)
    for i, j in np.ndindex(2, 4):
        one = Odometry(DistanceNoise(k_s[j], 0.02, [0.0, 0.003][i]))
        np.testing.assert_allclose(C[i, j], one.increment(u).cov, rtol=1e-15)
    steps = np.array([[0.4, 0.3], [0.1, -0.2], [0.2, 0.0]])
    many = model.batched(1).increment(steps).cov  # (2, 4, 3 steps)
    assert many.shape == (2, 4, 3, 3, 3)
    np.testing.assert_allclose(many[1, 2, 1], Odometry(DistanceNoise(0.1, 0.02, 0.003))
                               .increment(steps[1]).cov, rtol=1e-15)  # fmt: skip
    assert model.replace(k_theta=0.5).k_theta == 0.5 and model.replace(k_theta=0.5).k_s is k_s
    with pytest.raises(ParameterError, match="k_s"):
        model.replace(k_s=-1.0)
    with pytest.raises(ParameterError, match="k_theta_s"):
        DistanceNoise(0.1, 0.1, np.array([0.1, np.nan]))
