"""relmap.models: the range-bearing model (lecture Eq. 20) and Appendix B's polar mappings."""

from __future__ import annotations

import numpy as np
import pytest

import relmap as rm
from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.models import (
    POLAR,
    BearingOnly,
    RangeBearingSensor,
    RangeOnly,
    cartesian_to_polar,
    merge_polar,
    polar_to_cartesian,
)
from relmap.sim import montecarlo
from relmap.uncertain import gaussian, propagate
from relmap.uncertain.propagate import SE2, numerical_jacobian

SENSOR = RangeBearingSensor(0.1, 0.02, mount=[0.2, -0.1, 0.3], fov=np.radians(120), max_range=8.0)


def lecture_eq20(x: np.ndarray, lm: np.ndarray, mount=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Lecture Eq. 20 written out: ``(r, φ)`` of landmark ``lm`` from a sensor at pose
    ``x ⊕ mount`` (its position ``x + R(θ) (mx, my)``, its axis ``θ + mθ``)."""
    mx, my, mt = mount
    c, s = np.cos(x[..., 2]), np.sin(x[..., 2])
    dx = lm[..., 0] - (x[..., 0] + c * mx - s * my)
    dy = lm[..., 1] - (x[..., 1] + s * mx + c * my)
    phi = se2.wrap_angle(np.arctan2(dy, dx) - x[..., 2] - mt)
    return np.stack(np.broadcast_arrays(np.hypot(dx, dy), phi), axis=-1)


def test_prediction_matches_lecture_eq20_without_mount():
    s = RangeBearingSensor(0.1, 0.02)
    pose, lm = np.array([1.0, 2.0, 0.4]), np.array([4.0, -1.0])
    r = np.hypot(3.0, -3.0)
    b = se2.wrap_angle(np.arctan2(-3.0, 3.0) - 0.4)
    np.testing.assert_allclose(s.h(pose, lm), [r, b], atol=1e-15)


def test_prediction_with_mount_is_the_sensor_frame_reading():
    pose = np.array([1.0, 2.0, -2.5])
    lm = np.array([0.5, 4.0])
    sensor_pose = se2.compose(pose, SENSOR.mount)
    local = se2.between(sensor_pose, np.r_[lm, 0.0])
    z = SENSOR.h(pose, lm)
    np.testing.assert_allclose(
        z, [np.hypot(*local[:2]), np.arctan2(local[1], local[0])], atol=1e-14
    )
    np.testing.assert_allclose(z, lecture_eq20(pose, lm, SENSOR.mount), atol=1e-14)


#: The three polar sensors on one mount, and the rows of Eq. 20 each reads.
POLAR_SENSORS = {
    "range-bearing": (SENSOR, slice(0, 2)),
    "range-only": (RangeOnly(0.1, mount=SENSOR.mount), slice(0, 1)),
    "bearing-only": (BearingOnly(0.02, mount=SENSOR.mount), slice(1, 2)),
}


@pytest.mark.parametrize("name", sorted(POLAR_SENSORS))
def test_jacobians_numeric_batched(name):
    """``linearize``: the reading and the analytic ``∂z/∂x`` (relmap's chart of the pose,
    through the mount) and ``∂z/∂l`` against central differences of Eq. 20 written out, bearings
    wrapped (reading chart); a batch of poses and landmarks."""
    sensor, rows = POLAR_SENSORS[name]
    rng = np.random.default_rng(1)
    poses = np.column_stack([rng.normal(size=(6, 2)), rng.uniform(-np.pi, np.pi, 6)])
    lms = rng.normal(size=(6, 2)) * 4
    z, Hp, Hl = sensor.linearize(poses, lms)
    assert z.shape == (6, sensor.dim) and Hp.shape == (6, sensor.dim, 3)
    assert Hl.shape == (6, sensor.dim, 2)

    def h(p, lm):
        return lecture_eq20(p, lm, SENSOR.mount)[..., rows]

    chart = propagate.Chart(lambda x, d: x + d, sensor.innovation)
    Hp_n = numerical_jacobian(lambda p: h(p, lms[:, None, :]), poses, chart_in=SE2,
                              chart_out=chart)  # fmt: skip
    Hl_n = numerical_jacobian(lambda lm: h(poses[:, None, :], lm), lms, chart_out=chart)
    np.testing.assert_allclose(z, h(poses, lms), atol=1e-14)
    np.testing.assert_allclose(Hp, Hp_n, atol=1e-8)
    np.testing.assert_allclose(Hl, Hl_n, atol=1e-8)
    H, H_l = sensor.jacobians(poses, lms)
    np.testing.assert_array_equal(H, Hp)
    np.testing.assert_array_equal(H_l, Hl)
    np.testing.assert_array_equal(sensor.h(poses, lms), z)


def test_the_components_of_a_reading_and_their_innovations():
    """Which components are angles (wrapped in innovations) and which ranges, per sensor."""
    rb, ro, bo = (POLAR_SENSORS[k][0] for k in ("range-bearing", "range-only", "bearing-only"))
    assert (rb.dim, rb.angles, rb.ranges, rb.landmark_dim) == (2, (1,), (0,), 2)
    assert (ro.dim, ro.angles, ro.ranges) == (1, (), (0,))
    assert (bo.dim, bo.angles, bo.ranges) == (1, (0,), ())
    np.testing.assert_allclose(rb.innovation([1.0, 3.1], np.array([0.5, -3.1])),
                               [0.5, 6.2 - 2 * np.pi], atol=1e-15)  # fmt: skip
    np.testing.assert_allclose(ro.innovation([7.0], np.array([0.5])), [6.5])  # not wrapped
    np.testing.assert_allclose(bo.innovation([3.1], np.array([-3.1])), [6.2 - 2 * np.pi],
                               atol=1e-15)  # fmt: skip


def test_noise_models_and_field_of_view():
    """``noise(z)`` at readings z: σ constant, ∝ r or ∝ r² of the reading's range."""
    r = np.array([1.0, 2.0, 4.0])
    z = np.column_stack([r, [0.3, -2.0, 3.0]])
    for model, scale in (("constant", np.ones(3)), ("proportional", r), ("quadratic", r * r)):
        s = RangeBearingSensor(0.1, 0.02, noise_model=model)
        R = s.noise(z)
        np.testing.assert_allclose(R[:, 0, 0], (0.1 * scale) ** 2)
        np.testing.assert_allclose(R[:, 1, 1], (0.02 * scale) ** 2)
        np.testing.assert_array_equal(R[:, 0, 1], 0.0)
        np.testing.assert_array_equal(R[:, 1, 0], 0.0)
        ranges = RangeOnly(0.1, noise_model=model).noise(r[:, None])
        np.testing.assert_allclose(ranges[:, 0, 0], (0.1 * scale) ** 2)
    # a bearing sensor knows no range: constant σ
    np.testing.assert_allclose(BearingOnly(0.02).noise(z[:, 1:])[:, 0, 0], 0.02**2)
    # array parameters: a batch of sensors
    batch = RangeBearingSensor(np.array([0.1, 0.2]), 0.02)
    assert batch.batch_shape == (2,)
    np.testing.assert_allclose(batch.noise(z[0])[:, 0, 0], [0.01, 0.04])
    z = np.array([[1.0, 0.0], [9.0, 0.0], [1.0, np.radians(61)], [1.0, np.radians(-59)]])
    np.testing.assert_array_equal(SENSOR.in_view(z), [True, False, False, True])


def test_usable_readings():
    """A reading the sensors can use is finite, with a positive range where it has one (a range
    of 0 has no bearing; the noise models need r > 0)."""
    z = np.array([[0.0, 1.0], [-1.0, 0.0], [np.nan, 0.0], [2.0, np.inf], [1.0, 0.3]])
    np.testing.assert_array_equal(SENSOR.usable(z), [False, False, False, False, True])
    ro = POLAR_SENSORS["range-only"][0]
    np.testing.assert_array_equal(ro.usable(z[:, :1]), [False, False, False, True, True])
    bo = POLAR_SENSORS["bearing-only"][0]
    np.testing.assert_array_equal(bo.usable(z[:, 1:]), [True, True, True, False, True])


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
    with pytest.raises(ParameterError, match="sigma_range"):
        RangeBearingSensor(-0.1, 0.02)
    with pytest.raises(ParameterError, match="sigma_bearing"):
        BearingOnly(np.array([0.1, np.nan]))
    with pytest.raises(ParameterError, match="sigma_range"):
        SENSOR.replace(sigma_range=-1.0)
    with pytest.raises(ShapeError):
        RangeBearingSensor(0.1, 0.02, mount=[0, 0])
    with pytest.raises(ShapeError, match="landmark"):
        SENSOR.h(np.zeros(3), np.zeros(3))


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
