"""relmap.models: the range-bearing model (lecture Eq. 20) and Appendix B's polar mappings."""

from __future__ import annotations

import numpy as np
import pytest

import relmap as rm
from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.models import (
    POLAR,
    RangeBearingSensor,
    cartesian_to_polar,
    merge_polar,
    polar_to_cartesian,
)
from relmap.sim import montecarlo
from relmap.uncertain import gaussian, propagate
from relmap.uncertain.propagate import SE2, numerical_jacobian

SENSOR = RangeBearingSensor(0.1, 0.02, mount=[0.2, -0.1, 0.3], fov=np.radians(120), max_range=8.0)


def test_prediction_matches_lecture_eq20_without_mount():
    s = RangeBearingSensor(0.1, 0.02)
    pose, lm = np.array([1.0, 2.0, 0.4]), np.array([4.0, -1.0])
    r = np.hypot(3.0, -3.0)
    b = se2.wrap_angle(np.arctan2(-3.0, 3.0) - 0.4)
    np.testing.assert_allclose(s.predict(pose, lm), [r, b], atol=1e-15)


def test_prediction_with_mount_is_the_sensor_frame_reading():
    pose = np.array([1.0, 2.0, -2.5])
    lm = np.array([0.5, 4.0])
    sensor_pose = se2.compose(pose, SENSOR.mount)
    local = se2.between(sensor_pose, np.r_[lm, 0.0])
    z = SENSOR.predict(pose, lm)
    np.testing.assert_allclose(
        z, [np.hypot(*local[:2]), np.arctan2(local[1], local[0])], atol=1e-14
    )


def test_jacobians_numeric_batched():
    rng = np.random.default_rng(1)
    poses = np.column_stack([rng.normal(size=(6, 2)), rng.uniform(-np.pi, np.pi, 6)])
    lms = rng.normal(size=(6, 2)) * 4
    _, Hp, Hl = SENSOR.predict(poses, lms, jacobians=True)

    def bearing_chart_minus(a, b):
        out = a - b
        out[..., 1] = se2.wrap_angle(out[..., 1])
        return out

    chart = propagate.Chart(lambda x, d: x + d, bearing_chart_minus)
    Hp_n = numerical_jacobian(
        lambda p: SENSOR.predict(p, lms[:, None, :]), poses, chart_in=SE2, chart_out=chart
    )
    Hl_n = numerical_jacobian(
        lambda lm: SENSOR.predict(poses[:, None, :], lm), lms, chart_out=chart
    )
    np.testing.assert_allclose(Hp, Hp_n, atol=1e-8)
    np.testing.assert_allclose(Hl, Hl_n, atol=1e-8)


def test_noise_models_and_field_of_view():
    r = np.array([1.0, 2.0, 4.0])
    for model, scale in (("constant", np.ones(3)), ("proportional", r), ("quadratic", r * r)):
        s = RangeBearingSensor(0.1, 0.02, noise_model=model)
        R = s.noise(r)
        np.testing.assert_allclose(R[:, 0, 0], (0.1 * scale) ** 2)
        np.testing.assert_allclose(R[:, 1, 1], (0.02 * scale) ** 2)
    z = np.array([[1.0, 0.0], [9.0, 0.0], [1.0, np.radians(61)], [1.0, np.radians(-59)]])
    np.testing.assert_array_equal(SENSOR.in_view(z), [True, False, False, True])


@pytest.mark.parametrize(
    "kwargs",
    [
        {"fov": 7.0},
        {"fov": 0.0},
        {"max_range": 0.0},
        {"max_range": -1.0},
        {"min_range": 5.0, "max_range": 4.0},
        {"noise_model": "cubic"},
    ],
)
def test_sensor_rejects_bad_parameters(kwargs):
    with pytest.raises(ParameterError):
        RangeBearingSensor(0.1, 0.02, **kwargs)


def test_sensor_bad_inputs():
    with pytest.raises(ParameterError):
        RangeBearingSensor(-0.1, 0.02)
    with pytest.raises(ParameterError, match="range must be positive"):
        SENSOR.noise(np.array([0.0, 1.0]))
    with pytest.raises(ShapeError):
        RangeBearingSensor(0.1, 0.02, mount=[0, 0])


# ----------------------------------------------------------------- Appendix B
def test_polar_to_cartesian_is_appendix_b():
    mean = np.array([5.0, 0.4, -0.2])
    cov = np.array([[0.04, 0.001, 0.0], [0.001, 0.0025, 0.0002], [0.0, 0.0002, 0.001]])
    at = polar_to_cartesian(mean, cov)
    x, y = 5 * np.cos(0.4), 5 * np.sin(0.4)
    R = np.array([[x / 5, -y, 0], [y / 5, x, 0], [0, 0, 1]])
    np.testing.assert_allclose(at.mean, [x, y, -0.2], atol=1e-14)
    np.testing.assert_allclose(at.cov, R @ cov @ R.T, rtol=1e-12)
    back_mean, back_cov = cartesian_to_polar(at)
    np.testing.assert_allclose(back_mean, mean, atol=1e-12)
    np.testing.assert_allclose(back_cov, cov, rtol=1e-6, atol=1e-12)


@pytest.mark.slow
def test_unscented_mapping_tracks_monte_carlo_where_first_order_does_not():
    """Large bearing error: the true mean is pulled towards the sensor (E[cos φ] = cos φ̂ e^{-σ²/2});
    the unscented mapping follows it, the first-order mapping does not."""
    mean = np.array([10.0, 0.0, 0.0])
    cov = np.diag([0.01, 0.3**2, 1e-4])
    samples = gaussian.sample(mean, cov, 400_000, seed=2)
    cart = np.column_stack(
        [
            samples[:, 0] * np.cos(samples[:, 1]),
            samples[:, 0] * np.sin(samples[:, 1]),
            samples[:, 2],
        ]
    )
    mc = montecarlo.SampleSet.of(cart)
    lin, ut = polar_to_cartesian(mean, cov), polar_to_cartesian(mean, cov, "unscented")
    err_lin = mc.compare(lin)
    err_ut = mc.compare(ut)
    assert abs(err_ut.mean_error[0]) < 0.2 * abs(err_lin.mean_error[0])
    assert err_ut.cov_rel_error < err_lin.cov_rel_error


@pytest.mark.slow
def test_merging_in_polar_coordinates_beats_merging_after_mapping():
    """§6.2 step 3: k sensings of one object with a large bearing error. Merged in polar and
    mapped once, the estimate is unbiased to first order and its covariance matches its spread;
    mapped one by one and merged in Cartesian, each reading's mapping bias survives the merge."""
    truth = np.array([8.0, 0.5, 0.1])
    cov = np.diag([0.02**2, 0.15**2, 0.01**2])
    k, n = 6, 20_000
    rng = np.random.default_rng(3)
    readings = truth + rng.multivariate_normal(np.zeros(3), cov, size=(k, n))
    covs = np.broadcast_to(cov, (k, n, 3, 3))
    polar_first, _ = merge_polar(readings, covs)
    cart = [polar_to_cartesian(readings[i], covs[i]) for i in range(k)]
    cart_first = rm.merge(*cart)
    true_at = polar_to_cartesian(truth, cov / k, "unscented")  # the target: the exact merged polar
    for est in (polar_first, cart_first):
        assert est.batch_shape == (n,)
    err_polar = se2.minus(polar_first.mean, np.r_[8 * np.cos(0.5), 8 * np.sin(0.5), 0.1])
    err_cart = se2.minus(cart_first.mean, np.r_[8 * np.cos(0.5), 8 * np.sin(0.5), 0.1])
    bias_polar = np.linalg.norm(err_polar[:, :2].mean(0))
    bias_cart = np.linalg.norm(err_cart[:, :2].mean(0))
    assert bias_cart > 2 * bias_polar
    spread = montecarlo.SampleSet.of(polar_first.mean).compare(
        rm.AT(true_at.mean, polar_first.cov[0])
    )
    assert spread.cov_rel_error < 0.05


def test_polar_chart_wraps_both_angles():
    d = POLAR.minus(np.array([1.0, 3.1, -3.1]), np.array([1.0, -3.1, 3.1]))
    np.testing.assert_allclose(d, [0.0, 6.2 - 2 * np.pi, 2 * np.pi - 6.2], atol=1e-12)


def test_appendix_b_errors():
    with pytest.raises(ParameterError):
        polar_to_cartesian([-1.0, 0.0, 0.0], np.eye(3))
    with pytest.raises(ParameterError):
        polar_to_cartesian([1.0, 0.0, 0.0], np.eye(3), method="exact")
    with pytest.raises(ParameterError, match="origin"):
        cartesian_to_polar(rm.AT([0.0, 0.0, 0.3], np.eye(3)))
    with pytest.raises(ShapeError):
        merge_polar(np.zeros((2, 3)), np.zeros((2, 2, 3)))
