"""SO(3)/SE(3) geometry: Exp/Log, quaternions, Euler angles, Jacobians (numeric and GTSAM)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from relmap.errors import ParameterError, ShapeError
from relmap.lie import se3, so3
from relmap.uncertain.propagate import SE3, numerical_jacobian


def random_poses(seed: int, n: int, scale: float = 2.0) -> np.ndarray:
    """Random poses (n, 4, 4): uniform rotations, translations ~ N(0, scale²)."""
    R = Rotation.random(n, random_state=seed).as_matrix()
    return se3.from_parts(np.random.default_rng(seed).normal(scale=scale, size=(n, 3)), R)


def near_pi_poses(seed: int, n: int) -> np.ndarray:
    """Rotations within 1e-3 rad of angle π (where Log's closed form breaks down)."""
    g = np.random.default_rng(seed)
    axes = g.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    angles = np.pi - g.uniform(0, 1e-3, n)
    return se3.from_parts(g.normal(size=(n, 3)), so3.exp(axes * angles[:, None]))


def near_identity_poses(seed: int, n: int) -> np.ndarray:
    g = np.random.default_rng(seed)
    return se3.exp(g.normal(scale=1e-7, size=(n, 6)))


POSE_SETS = {
    "random": lambda: random_poses(1, 20),
    "near identity": lambda: near_identity_poses(2, 20),
    "near pi": lambda: near_pi_poses(3, 20),
}


# ------------------------------------------------------------------------- SO(3)
@pytest.mark.parametrize("scale", [1e-12, 1e-6, 1e-3, 0.5, 2.0])
def test_so3_exp_matches_scipy_at_every_scale(scale):
    phi = np.random.default_rng(4).normal(size=(50, 3))
    phi *= scale / np.linalg.norm(phi, axis=-1, keepdims=True)
    np.testing.assert_allclose(so3.exp(phi), Rotation.from_rotvec(phi).as_matrix(), atol=1e-15)


@pytest.mark.parametrize("angle", [0.0, 1e-10, 1e-5, 1e-4, 0.3, 3.0, np.pi - 1e-6, np.pi - 1e-9])
def test_so3_log_inverts_exp(angle):
    axes = np.random.default_rng(5).normal(size=(30, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    phi = axes * angle
    back = so3.log(so3.exp(phi))
    # near π the rotation determines φ only to ~ ε/(π - θ); the rotation itself is what matters
    np.testing.assert_allclose(so3.exp(back), so3.exp(phi), atol=1e-14)
    if angle < 3.0:
        np.testing.assert_allclose(back, phi, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(back, axis=-1), angle, atol=2e-8)


def test_so3_log_at_exactly_pi():
    for axis in np.eye(3):
        R = so3.exp(axis * np.pi)
        phi = so3.log(R)
        assert np.linalg.norm(phi) == pytest.approx(np.pi, abs=1e-12)
        np.testing.assert_allclose(so3.exp(phi), R, atol=1e-15)


def test_quaternions_match_scipy_and_round_trip():
    rot = Rotation.random(200, random_state=6)
    q = rot.as_quat()  # scalar-last
    np.testing.assert_allclose(so3.from_quaternion(q), rot.as_matrix(), atol=1e-15)
    back = so3.to_quaternion(rot.as_matrix())
    assert (back[:, 3] >= 0).all()
    np.testing.assert_allclose(np.abs(np.einsum("ni,ni->n", back, q)), 1.0, atol=1e-15)
    np.testing.assert_allclose(so3.from_quaternion(back), rot.as_matrix(), atol=1e-15)


def test_non_unit_quaternion_is_refused_with_its_index():
    q = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    q[2] = [0.1, 0.0, 0.0, 1.0]
    with pytest.raises(ParameterError, match=r"quaternion\[2\] has norm 1.00499"):
        so3.from_quaternion(q)
    with pytest.raises(ShapeError):
        so3.from_quaternion(np.ones(3))
    # within tolerance: normalized silently
    np.testing.assert_allclose(so3.from_quaternion([0, 0, 0, 1 + 1e-9]), np.eye(3), atol=1e-15)


def test_euler_matches_scipy_fixed_axes_xyz():
    rpy = np.random.default_rng(7).uniform(-1.5, 1.5, size=(100, 3))
    R = Rotation.from_euler("xyz", rpy).as_matrix()  # extrinsic x, y, z: Rz Ry Rx
    np.testing.assert_allclose(so3.from_euler(rpy), R, atol=1e-15)
    np.testing.assert_allclose(so3.to_euler(R), rpy, atol=1e-12)


def test_euler_pole_is_reported_not_guessed():
    R = so3.from_euler([[0.1, 0.2, 0.3], [0.3, np.pi / 2, 0.1]])
    with pytest.raises(ParameterError, match=r"rotation\[1\] is at the Euler pole"):
        so3.to_euler(R)
    so3.to_euler(so3.from_euler([0.3, np.pi / 2 - 1e-3, 0.1]))  # near, not at: fine


@pytest.mark.parametrize("angle", [1e-9, 1e-5, 0.7, 3.0])
def test_left_jacobian_against_numeric(angle):
    axes = np.random.default_rng(8).normal(size=(10, 3))
    phi = axes / np.linalg.norm(axes, axis=-1, keepdims=True) * angle
    R0 = so3.exp(phi)

    def f(p):
        return so3.log(so3.exp(p) @ np.swapaxes(R0, -1, -2)[:, None])

    Jn = numerical_jacobian(f, phi)
    np.testing.assert_allclose(so3.left_jacobian(phi), Jn, atol=1e-8)
    np.testing.assert_allclose(
        so3.left_jacobian_inverse(phi) @ so3.left_jacobian(phi),
        np.broadcast_to(np.eye(3), (10, 3, 3)),
        atol=1e-12,
    )


def test_rotation_shapes_are_checked():
    with pytest.raises(ShapeError):
        so3.exp(np.ones(4))
    with pytest.raises(ShapeError):
        se3.compose(np.eye(3), np.eye(4))


# ------------------------------------------------------------------------- SE(3)
@pytest.mark.parametrize("poses", POSE_SETS)
def test_compose_jacobians_against_numeric(poses):
    a, b = POSE_SETS[poses](), random_poses(9, 20)
    _, Ja, Jb = se3.compose(a, b, jacobians=True)
    np.testing.assert_allclose(
        numerical_jacobian(lambda x: se3.compose(x, b[:, None]), a, chart_in=SE3, chart_out=SE3),
        Ja,
        atol=1e-8,
    )
    np.testing.assert_allclose(
        numerical_jacobian(lambda x: se3.compose(a[:, None], x), b, chart_in=SE3, chart_out=SE3),
        Jb,
        atol=1e-8,
    )
    # and with the second argument near π / the identity
    _, Ja, Jb = se3.compose(b, a, jacobians=True)
    np.testing.assert_allclose(
        numerical_jacobian(lambda x: se3.compose(x, a[:, None]), b, chart_in=SE3, chart_out=SE3),
        Ja,
        atol=1e-8,
    )
    np.testing.assert_allclose(
        numerical_jacobian(lambda x: se3.compose(b[:, None], x), a, chart_in=SE3, chart_out=SE3),
        Jb,
        atol=1e-8,
    )


@pytest.mark.parametrize("poses", POSE_SETS)
def test_inverse_and_between_jacobians_against_numeric(poses):
    a, b = POSE_SETS[poses](), random_poses(10, 20)
    _, J = se3.inverse(a, jacobians=True)
    np.testing.assert_allclose(
        numerical_jacobian(se3.inverse, a, chart_in=SE3, chart_out=SE3), J, atol=1e-8
    )
    for x, y in ((a, b), (b, a)):
        d, Jx, Jy = se3.between(x, y, jacobians=True)
        np.testing.assert_allclose(d, se3.compose(se3.inverse(x), y), atol=1e-12)
        np.testing.assert_allclose(
            numerical_jacobian(
                lambda p, y=y: se3.between(p, y[:, None]), x, chart_in=SE3, chart_out=SE3
            ),
            Jx,
            atol=1e-8,
        )
        np.testing.assert_allclose(
            numerical_jacobian(
                lambda p, x=x: se3.between(x[:, None], p), y, chart_in=SE3, chart_out=SE3
            ),
            Jy,
            atol=1e-8,
        )


def test_compose_and_jacobians_match_gtsam():
    """GTSAM's Pose3 Jacobians are in its body chart (rotation first): J = M_c⁻¹ J_ours M_in."""
    a, b = random_poses(11, 25), random_poses(12, 25)
    c, Ja, Jb = se3.compose(a, b, jacobians=True)
    Ma, Mb, Mc = se3.body_to_chart(a), se3.body_to_chart(b), se3.body_to_chart(c)
    for i in range(25):
        Ha, Hb = np.zeros((6, 6), order="F"), np.zeros((6, 6), order="F")
        pc = gtsam.Pose3(a[i]).compose(gtsam.Pose3(b[i]), Ha, Hb)
        np.testing.assert_allclose(pc.matrix(), c[i], atol=1e-12)
        np.testing.assert_allclose(np.linalg.solve(Mc[i], Ja[i] @ Ma[i]), Ha, atol=1e-12)
        np.testing.assert_allclose(np.linalg.solve(Mc[i], Jb[i] @ Mb[i]), Hb, atol=1e-12)


def test_exp_log_match_gtsam_and_round_trip():
    xi = np.random.default_rng(13).normal(size=(30, 6))
    T = se3.exp(xi)
    for i in range(30):  # GTSAM's twist is (ω, v): rotation first
        np.testing.assert_allclose(
            gtsam.Pose3.Expmap(np.r_[xi[i, 3:], xi[i, :3]]).matrix(), T[i], atol=1e-12
        )
    principal = np.linalg.norm(xi[:, 3:], axis=-1) < np.pi  # Log returns |φ| ≤ π
    assert principal.sum() > 15
    np.testing.assert_allclose(se3.log(T)[principal], xi[principal], atol=1e-11)
    np.testing.assert_allclose(se3.exp(se3.log(T)), T, atol=1e-12)
    small = np.random.default_rng(14).normal(scale=1e-9, size=(5, 6))
    np.testing.assert_allclose(se3.log(se3.exp(small)), small, atol=1e-22, rtol=1e-12)


def test_adjoint_moves_a_twist_across_the_pose():
    T, xi = random_poses(15, 10), np.random.default_rng(15).normal(scale=0.3, size=(10, 6))
    np.testing.assert_allclose(
        se3.compose(T, se3.exp(xi)),
        se3.compose(se3.exp(np.einsum("nij,nj->ni", se3.adjoint(T), xi)), T),
        atol=1e-12,
    )


def test_plus_minus_round_trip():
    a, b = random_poses(16, 30), random_poses(17, 30)
    np.testing.assert_allclose(se3.plus(a, se3.minus(b, a)), b, atol=1e-12)
    d = np.random.default_rng(18).normal(scale=0.5, size=(30, 6))
    np.testing.assert_allclose(se3.minus(se3.plus(a, d), a), d, atol=1e-12)


def test_body_to_chart_is_first_order_body_perturbation():
    T = random_poses(19, 5)
    xi = 1e-7 * np.random.default_rng(19).normal(size=(5, 6))
    perturbed = np.stack([gtsam.Pose3(T[i]).retract(xi[i]).matrix() for i in range(5)])
    np.testing.assert_allclose(
        se3.minus(perturbed, T), np.einsum("nij,nj->ni", se3.body_to_chart(T), xi), atol=1e-13
    )


def test_batches_broadcast():
    a = random_poses(20, 4).reshape(2, 2, 4, 4)
    b = random_poses(21, 1)[0]
    c, Ja, Jb = se3.compose(a, b, jacobians=True)
    assert c.shape == (2, 2, 4, 4) and Ja.shape == Jb.shape == (2, 2, 6, 6)
    np.testing.assert_allclose(c[1, 0], a[1, 0] @ b, atol=1e-12)


# ----------------------------------------------------------------- group laws
twists = arrays(np.float64, (3, 6), elements=st.floats(-3, 3))


@given(twists)
def test_group_laws(xi):
    a, b, c = se3.exp(xi)
    np.testing.assert_allclose(
        se3.compose(se3.compose(a, b), c), se3.compose(a, se3.compose(b, c)), atol=1e-9
    )
    np.testing.assert_allclose(se3.compose(a, se3.inverse(a)), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(se3.inverse(se3.inverse(a)), a, atol=1e-12)
    np.testing.assert_allclose(se3.compose(a, se3.between(a, b)), b, atol=1e-9)
    R = a[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)


@pytest.mark.parametrize("angle", [0.0, 1e-8, 1e-3, 1e-2 - 1e-12, 1e-2 + 1e-12, 0.5, 3.0])
def test_se3_left_jacobian_inverse_against_numeric(angle):
    """∂Log(Exp(ε) T)/∂ε = 𝒥⁻¹(Log T), on both sides of the series threshold of Q."""
    xi = np.random.default_rng(23).normal(size=(10, 6))
    norms = np.linalg.norm(xi[:, 3:], axis=-1, keepdims=True)
    xi[:, 3:] *= angle / norms
    T = se3.exp(xi)
    Jn = numerical_jacobian(lambda eps: se3.log(se3.exp(eps) @ T[:, None]), np.zeros((10, 6)))
    np.testing.assert_allclose(se3.left_jacobian_inverse(xi), Jn, atol=3e-9)
    np.testing.assert_allclose(
        se3.left_jacobian(xi) @ se3.left_jacobian_inverse(xi),
        np.broadcast_to(np.eye(6), (10, 6, 6)),
        atol=1e-14,
    )


def test_q_series_and_closed_form_meet_at_the_threshold():
    xi = np.random.default_rng(24).normal(size=(5, 6))
    xi[:, 3:] /= np.linalg.norm(xi[:, 3:], axis=-1, keepdims=True)
    below, above = xi.copy(), xi.copy()
    below[:, 3:] *= 1e-2 * (1 - 1e-9)
    above[:, 3:] *= 1e-2 * (1 + 1e-9)
    np.testing.assert_allclose(se3.left_jacobian(below), se3.left_jacobian(above), atol=1e-13)
