"""relmap.models.pose: readings of the pose itself — a full pose (the paper's sensing, §4) and a
position fix (GPS) — against their definitions and the textbook Kalman correction."""

from __future__ import annotations

import numpy as np
import pytest

import relmap as rm
from relmap.errors import NotPositiveSemidefiniteError, ParameterError
from relmap.filter import correct
from relmap.lie import se2
from relmap.models import FullPose, PositionFix
from relmap.uncertain.propagate import SE2, numerical_jacobian

PRIOR = rm.AT(
    [1.0, -2.0, 3.0], np.array([[0.04, 0.01, 0.002], [0.01, 0.05, -0.003], [0.002, -0.003, 0.01]])
)


def kalman(prior: rm.AT, y: np.ndarray, H: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, ...]:
    """Eqs. 26-28 written out: ``(x ⊞ K y, P - K S Kᵀ, yᵀ S⁻¹ y)``."""
    P = prior.cov
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    return se2.plus(prior.mean, K @ y), P - K @ S @ K.T, y @ np.linalg.solve(S, y)


def test_a_full_pose_reading_is_the_identity_and_its_correction_the_papers_merge():
    cov = np.diag([0.01, 0.02, 0.003])
    model = FullPose(cov)
    x = np.array([[0.5, 1.0, 3.1], [0.0, 0.0, -3.1]])
    np.testing.assert_array_equal(model.h(x), x)
    H, none = model.jacobians(x)
    assert none is None
    np.testing.assert_allclose(H, numerical_jacobian(model.h, x, chart_in=SE2, chart_out=SE2),
                               atol=1e-9)  # fmt: skip
    np.testing.assert_array_equal(model.noise(x), np.broadcast_to(cov, (2, 3, 3)))
    assert (model.dim, model.angles, model.landmark_dim) == (3, (2,), 0)
    # the correction: the merge of the prior with the reading (Eqs. 8-10), heading wrapped
    z = np.array([1.1, -1.9, -3.1])  # across ±π from the prior's 3.0
    c = correct(PRIOR, z, model)
    merged = rm.merge(PRIOR, rm.AT(z, cov))
    mean, P, nis = kalman(PRIOR, se2.minus(z, PRIOR.mean), np.eye(3), cov)
    np.testing.assert_allclose(se2.minus(c.state.mean, merged.mean), 0.0, atol=1e-12)
    np.testing.assert_allclose(c.state.cov, merged.cov, rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(se2.minus(c.state.mean, mean), 0.0, atol=1e-12)
    np.testing.assert_allclose(c.state.cov, P, rtol=1e-10, atol=1e-15)
    assert float(c.nis) == pytest.approx(nis, rel=1e-12)


def test_a_position_fix_against_the_textbook_correction():
    model = PositionFix(0.3)
    x = np.array([[0.5, 1.0, 3.1], [0.0, 0.0, -3.1]])
    np.testing.assert_array_equal(model.h(x), x[:, :2])
    H, _ = model.jacobians(x)
    np.testing.assert_allclose(H, numerical_jacobian(model.h, x, chart_in=SE2), atol=1e-9)
    np.testing.assert_allclose(model.noise(x[:, :2]), np.broadcast_to(0.09 * np.eye(2), (2, 2, 2)))
    z = np.array([1.4, -2.2])
    c = correct(PRIOR, z, model)
    mean, P, nis = kalman(PRIOR, z - PRIOR.mean[:2], np.eye(2, 3), 0.09 * np.eye(2))
    np.testing.assert_allclose(c.state.mean, mean, atol=1e-12)
    np.testing.assert_allclose(c.state.cov, P, rtol=1e-10, atol=1e-15)
    assert float(c.nis) == pytest.approx(nis, rel=1e-12)
    # the heading is corrected through its correlation with the position only
    assert c.state.mean[2] != PRIOR.mean[2]


def test_a_batch_of_position_fixes_is_a_batch_of_filters():
    sigma = np.array([0.1, 0.3, 1.0])
    c = correct(PRIOR, [1.4, -2.2], PositionFix(sigma))
    assert c.state.batch_shape == (3,)
    for k, s in enumerate(sigma):
        one = correct(PRIOR, [1.4, -2.2], PositionFix(s))
        np.testing.assert_allclose(c.state.mean[k], one.state.mean, rtol=1e-14)
        np.testing.assert_allclose(c.state.cov[k], one.state.cov, rtol=1e-13, atol=1e-18)
    # the tighter the fix, the tighter the position
    assert (np.diff(np.trace(c.state.cov[:, :2, :2], axis1=-2, axis2=-1)) > 0).all()


def test_bad_parameters():
    with pytest.raises(ParameterError, match="sigma"):
        PositionFix(-0.1)
    with pytest.raises(NotPositiveSemidefiniteError):
        FullPose([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
