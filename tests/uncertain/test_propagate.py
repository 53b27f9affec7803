"""relmap.uncertain.propagate: numeric Jacobians, first-order propagation, the unscented
transform."""

from __future__ import annotations

import numpy as np
import pytest

from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.uncertain import gaussian
from relmap.uncertain.propagate import SE2, Chart, numerical_jacobian, propagate, unscented
from tests.helpers import random_covs, random_poses

RNG = np.random.default_rng(99)


def polar_to_cartesian(x):
    r, phi = x[..., 0], x[..., 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)


def polar_jacobian(x):
    r, phi = x[..., 0], x[..., 1]
    c, s = np.cos(phi), np.sin(phi)
    return np.stack([np.stack([c, -r * s], -1), np.stack([s, r * c], -1)], -2)


def test_numerical_jacobian_of_known_function():
    x = np.array([[2.0, 0.3], [1.0, -2.0]])
    np.testing.assert_allclose(
        numerical_jacobian(polar_to_cartesian, x), polar_jacobian(x), atol=1e-9
    )


def test_numerical_jacobian_in_chart_across_pi():
    """Output heading near ±π: without the chart's minus the difference would jump by 2π."""
    a = np.array([0.0, 0.0, np.pi - 1e-8])
    J = numerical_jacobian(
        lambda x: se2.compose(x, [1.0, 0.0, 0.0]), a, chart_in=SE2, chart_out=SE2
    )
    _, Ja, _ = se2.compose(a, [1.0, 0.0, 0.0], jacobians=True)
    np.testing.assert_allclose(J, Ja, atol=1e-7)


def test_numerical_jacobian_rejects_bad_step():
    with pytest.raises(ParameterError):
        numerical_jacobian(polar_to_cartesian, [1.0, 0.0], step=0.0)


def test_propagate_linear_is_exact():
    A = RNG.normal(size=(4, 3))
    b = RNG.normal(size=4)
    cov = random_covs(RNG, ())
    m = propagate(lambda x: x @ A.T + b, [1.0, 2.0, 3.0], cov)
    np.testing.assert_allclose(m.mean, A @ [1, 2, 3] + b, atol=1e-14)
    np.testing.assert_allclose(m.cov, A @ cov @ A.T, atol=1e-9)


def test_propagate_analytic_and_numeric_jacobians_agree():
    x = np.array([[3.0, 0.4], [2.0, 2.5]])
    cov = random_covs(RNG, (2,), n=2, scale=0.05)
    a = propagate(polar_to_cartesian, x, cov, jacobian=polar_jacobian)
    n = propagate(polar_to_cartesian, x, cov)
    J = polar_jacobian(x)
    given = propagate(polar_to_cartesian, x, cov, jacobian=J)
    np.testing.assert_allclose(a.cov, n.cov, rtol=1e-7, atol=1e-14)
    np.testing.assert_allclose(given.cov, a.cov)
    np.testing.assert_allclose(a.mean, polar_to_cartesian(x))


def test_propagate_shape_errors():
    with pytest.raises(ShapeError):
        propagate(polar_to_cartesian, [1.0, 0.0], np.eye(3))
    with pytest.raises(ShapeError):
        propagate(polar_to_cartesian, [1.0, 0.0], np.eye(2), jacobian=np.eye(3))


def test_unscented_exact_for_linear_and_quadratic_mean():
    A = RNG.normal(size=(2, 3))
    cov = random_covs(RNG, ())
    m = unscented(lambda x: x @ A.T, [1.0, -1.0, 0.5], cov)
    np.testing.assert_allclose(m.mean, A @ [1, -1, 0.5], atol=1e-13)
    np.testing.assert_allclose(m.cov, A @ cov @ A.T, atol=1e-13)
    # E[x²] = μ² + σ² exactly: sigma points match moments up to the third
    q = unscented(lambda x: x**2, [2.0], [[0.25]])
    assert q.mean[0] == pytest.approx(4.25, rel=1e-14)
    assert q.cov[0, 0] == pytest.approx(4 * 4 * 0.25 + 2 * 0.25**2, rel=1e-12)


def test_unscented_beats_first_order_on_polar_mean():
    """Polar → Cartesian with large bearing error: E[r cos φ] = r cos φ̂ e^{-σ²/2} exactly."""
    sigma = 0.5
    x, cov = np.array([10.0, 0.0]), np.diag([0.01, sigma**2])
    first = propagate(polar_to_cartesian, x, cov)
    ut = unscented(polar_to_cartesian, x, cov)
    exact = 10.0 * np.exp(-(sigma**2) / 2)
    assert abs(ut.mean[0] - exact) < 0.2 * abs(first.mean[0] - exact)


def test_unscented_singular_covariance_and_angles():
    """Singular input covariance is fine; an output heading near ±π averages correctly."""
    a = np.array([1.0, 2.0, np.pi - 0.01])
    cov = np.diag([0.0, 0.0, 0.02**2])
    ut = unscented(lambda x: se2.compose(x, [1.0, 0.0, 0.05]), a, cov, chart_in=SE2, chart_out=SE2)
    expected = se2.compose(a, [1.0, 0.0, 0.05])
    assert abs(se2.angle_difference(ut.mean[2], expected[2])) < 1e-12
    assert ut.cov[2, 2] == pytest.approx(0.02**2, rel=1e-10)


def test_unscented_se2_compound_matches_first_order_for_small_noise():
    a, b = random_poses(RNG, (5,)), random_poses(RNG, (5,))
    covs = random_covs(RNG, (5,), n=6, scale=1e-3)

    def f(x):
        return se2.compose(x[..., :3], x[..., 3:])

    def plus6(x, d):
        return np.concatenate(
            [se2.plus(x[..., :3], d[..., :3]), se2.plus(x[..., 3:], d[..., 3:])], -1
        )

    x = np.concatenate([a, b], -1)
    pair = Chart(plus6, None)
    ut = unscented(f, x, covs, chart_in=pair, chart_out=SE2)
    lin = propagate(f, x, covs, chart_in=pair, chart_out=SE2)
    rel = np.linalg.norm(ut.cov - lin.cov, axis=(-2, -1)) / np.linalg.norm(lin.cov, axis=(-2, -1))
    assert rel.max() < 1e-3


def test_unscented_rejects_bad_parameters():
    with pytest.raises(ParameterError):
        unscented(polar_to_cartesian, [1.0, 0.0], np.eye(2), alpha=1.0, kappa=-2.0)


def test_propagate_agrees_with_monte_carlo_for_small_noise():
    x, cov = np.array([5.0, 0.7]), np.diag([0.02**2, 0.01**2])
    lin = propagate(polar_to_cartesian, x, cov, jacobian=polar_jacobian)
    s = polar_to_cartesian(gaussian.sample(x, cov, 200_000, seed=5))
    emp = np.cov(s.T)
    assert np.linalg.norm(emp - lin.cov) / np.linalg.norm(emp) < 0.02
