"""ROS ``PoseWithCovariance`` covariances ↔ relmap's chart: round trips, tf2's frame change, and
GTSAM's Pose3 (body, rotation-first) covariance where the two conventions meet."""

from __future__ import annotations

import numpy as np
import pytest

import relmap as rm
from relmap.lie import so3


def random_case(seed):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    t = rng.normal(size=3) * 3
    A = rng.normal(size=(6, 6)) * [0.3, 0.2, 0.1, 0.05, 0.04, 0.1]
    return t, q, A @ A.T + 1e-6 * np.eye(6)


@pytest.mark.parametrize("seed", range(5))
def test_round_trip_is_exact(seed):  # type: ignore[no-untyped-def]
    t, q, C = random_case(seed)
    at = rm.AT3.from_ros(t, q, C.reshape(36))
    np.testing.assert_array_equal(at.to_ros(), C)
    np.testing.assert_array_equal(at.to_ros().reshape(36), C.reshape(36))


@pytest.mark.parametrize("seed", range(5))
def test_frame_change_rotates_both_blocks_like_tf2(seed):  # type: ignore[no-untyped-def]
    """tf2's transformCovariance: a covariance moved into a frame rotated by R becomes
    blkdiag(R, R) Σ blkdiag(R, R)ᵀ — what compounding with an exact AT3 gives in relmap's
    chart, so the ROS numbers are relmap's chart (rotation about the fixed parent axes)."""
    t, q, C = random_case(seed)
    R = so3.exp(np.random.default_rng(seed + 10).normal(size=3))
    frame = rm.AT3(np.array([1.0, -2.0, 0.5]), R)  # exact
    moved = frame @ rm.AT3.from_ros(t, q, C)
    B = np.zeros((6, 6))
    B[:3, :3] = B[3:, 3:] = R
    np.testing.assert_allclose(moved.to_ros(), B @ C @ B.T, atol=1e-13)


@pytest.mark.parametrize("seed", range(5))
def test_ros_covariance_in_gtsam_convention(seed):  # type: ignore[no-untyped-def]
    """GTSAM's Pose3 covariance is on ξ = Logmap(T⁻¹ T') (body frame, rotation first). With T'
    perturbed as ROS says — t + δt, Exp(δφ) R about the fixed axes — the Jacobian dξ/dδ taken
    with GTSAM's own Rot3/Pose3 gives the covariance GTSAM means; relmap's to_body must equal it."""
    gtsam = pytest.importorskip("gtsam")
    t, q, C = random_case(seed)
    at = rm.AT3.from_ros(t, q, C)
    T = gtsam.Pose3(gtsam.Rot3(at.rotation), gtsam.Point3(*t))

    def xi(delta):  # type: ignore[no-untyped-def]
        R2 = gtsam.Rot3.Expmap(delta[3:]).compose(T.rotation())
        T2 = gtsam.Pose3(R2, gtsam.Point3(*(T.translation() + delta[:3])))
        return gtsam.Pose3.Logmap(T.between(T2))

    h = 1e-6
    J = np.column_stack([(xi(h * e) - xi(-h * e)) / (2 * h) for e in np.eye(6)])
    np.testing.assert_allclose(at.to_body(), J @ C @ J.T, rtol=1e-6, atol=1e-12)


def test_planar_ros_covariance_keeps_x_y_yaw():  # type: ignore[no-untyped-def]
    _, _, C = random_case(3)
    planar = rm.AT.from_ros([1.0, 2.0, 0.3], C)
    np.testing.assert_array_equal(planar.cov, C[np.ix_([0, 1, 5], [0, 1, 5])])
    back = planar.to_ros()
    np.testing.assert_array_equal(back[np.ix_([0, 1, 5], [0, 1, 5])], planar.cov)
