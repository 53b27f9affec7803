"""relmap.sim.montecarlo: sample moments on the circle, agreement statistics, Gaussianity."""

from __future__ import annotations

import numpy as np
import pytest

import relmap as rm
from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.sim import montecarlo


def test_sample_moments_straddling_pi():
    rng = np.random.default_rng(1)
    n = 200_000
    theta = se2.wrap_angle(np.pi + rng.normal(0, 0.1, n))
    samples = np.column_stack([rng.normal(1, 0.2, n), rng.normal(-1, 0.3, n), theta])
    mean, cov = montecarlo.sample_moments(samples)
    assert abs(se2.angle_difference(mean[2], np.pi)) < 5 * 0.1 / np.sqrt(n)
    assert cov[2, 2] == pytest.approx(0.01, rel=0.02)  # a naive variance would be ≈ π²
    np.testing.assert_allclose(mean[:2], [1, -1], atol=5 * 0.3 / np.sqrt(n))


def test_sample_moments_errors():
    with pytest.raises(ShapeError):
        montecarlo.sample_moments(np.zeros((10, 2)))
    with pytest.raises(ParameterError):
        montecarlo.sample_moments(np.zeros((1, 3)))


def test_agreement_of_exact_linear_case():
    """No angular error: compounding is linear, so first order is exact (§3.1)."""
    a = rm.AT([1.0, 2.0, 0.4], np.diag([0.04, 0.01, 0.0]))
    b = rm.AT([2.0, -1.0, 0.2], np.array([[0.02, 0.005, 0], [0.005, 0.03, 0], [0, 0, 0]]))
    mc = montecarlo.simulate(se2.compose, a, b, n=200_000, seed=2).compare(a @ b)
    assert mc.cov_rel_error < 4 * mc.cov_rel_standard_error
    assert np.all(np.abs(mc.mean_error[:2]) < 5 * mc.mean_standard_error[:2])
    assert abs(mc.nees - 2.0) < 0.05  # the heading is exact: two degrees of freedom
    assert abs(mc.skewness) < 0.01 and abs(mc.excess_kurtosis) < 0.1
    assert abs(mc.coverage - 0.9) < 0.005


def test_gaussianity_statistics_detect_the_crescent():
    """Fig. 5: a large angular error followed by a long move bends the cloud into a crescent."""
    small = rm.AT.from_sigmas([0.0, 0.0, 0.0], [0.01, 0.01, np.deg2rad(1.0)])
    large = rm.AT.from_sigmas([0.0, 0.0, 0.0], [0.01, 0.01, np.deg2rad(30.0)])
    move = rm.AT.from_sigmas([5.0, 0.0, 0.0], [0.01, 0.01, 0.0])
    straight = montecarlo.simulate(se2.compose, small, move, n=100_000, seed=3).compare(
        small @ move
    )
    bent = montecarlo.simulate(se2.compose, large, move, n=100_000, seed=3).compare(large @ move)
    assert straight.skewness < 0.1  # Gaussian: ≈ p(p+1)(p+2)/n = 6e-4
    assert bent.skewness > 10
    assert bent.cov_rel_error > 0.05  # first order misses the crescent's moments too
    assert straight.cov_rel_error < 0.02


def test_batched_simulation_matches_single():
    a = rm.AT.from_sigmas([[1.0, 0, 0.3], [2.0, 1.0, -0.5]], [0.05, 0.05, 0.02])
    mc = montecarlo.simulate(se2.inverse, a, n=50_000, seed=4)
    assert mc.samples.shape == (50_000, 2, 3)
    report = mc.compare(a.reverse())
    assert report.cov_rel_error.shape == (2,)
    assert np.all(report.cov_rel_error < 0.03)
    assert mc.as_at().batch_shape == (2,)


def test_simulate_merge_truth_and_reproducibility():
    a = rm.AT.from_sigmas([1.0, 0.0, 0.1], [0.1, 0.1, 0.05])
    b = rm.AT.from_sigmas([1.1, 0.1, 0.12], [0.05, 0.2, 0.02])
    one = montecarlo.simulate_merge(a, b, truth=np.array([1.0, 0.0, 0.1]), n=20_000, seed=5)
    two = montecarlo.simulate_merge(a, b, truth=np.array([1.0, 0.0, 0.1]), n=20_000, seed=5)
    np.testing.assert_array_equal(one.samples, two.samples)
    report = one.compare(rm.AT([1.0, 0.0, 0.1], rm.merge(a, b).cov))
    assert np.all(np.abs(report.mean_error) < 5 * report.mean_standard_error)
