"""relmap.lie.se2: geometry, analytic Jacobians against numeric ones and against GTSAM."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from relmap.errors import ShapeError
from relmap.lie import se2
from relmap.uncertain.propagate import SE2, numerical_jacobian
from tests.helpers import assert_poses_close, random_poses

RNG = np.random.default_rng(20261122)
SHAPES = [(), (1,), (3, 1, 2, 1), (7,)]


def _jac(f, x):
    return numerical_jacobian(f, x, chart_in=SE2, chart_out=SE2)


# ---------------------------------------------------------------------- wrap_angle
def test_wrap_angle_range_and_edges():
    th = np.array([np.pi, -np.pi, 3 * np.pi, -3 * np.pi, 0.0, -1e-17, 2 * np.pi - 1e-17, 7.0])
    w = se2.wrap_angle(th)
    assert np.all(w >= -np.pi) and np.all(w < np.pi)
    np.testing.assert_allclose(w[:4], -np.pi)
    np.testing.assert_allclose(np.sin(w), np.sin(th), atol=1e-15)
    np.testing.assert_allclose(np.cos(w), np.cos(th), atol=1e-15)


def test_angle_difference_across_pi():
    assert se2.angle_difference(3.1, -3.1) == pytest.approx(6.2 - 2 * np.pi)
    assert se2.angle_difference(-3.1, 3.1) == pytest.approx(2 * np.pi - 6.2)


# -------------------------------------------------------------- group properties
@pytest.mark.parametrize("shape", SHAPES)
def test_compose_inverse_between_consistent(shape):
    a, b = random_poses(RNG, shape), random_poses(RNG, shape)
    assert_poses_close(se2.compose(a, se2.inverse(a)), se2.identity(shape))
    assert_poses_close(se2.compose(a, se2.between(a, b)), b)
    assert_poses_close(se2.between(a, b), se2.compose(se2.inverse(a), b))
    assert_poses_close(se2.inverse(se2.inverse(a)), a)
    c = se2.compose(a, b)
    assert c.shape == (*shape, 3)
    assert np.all(c[..., 2] >= -np.pi) and np.all(c[..., 2] < np.pi)


def test_compose_matches_paper_eq1():
    a = np.array([1.0, 2.0, 0.3])
    b = np.array([0.5, -0.2, 1.0])
    c = se2.compose(a, b)
    x3 = b[0] * np.cos(a[2]) - b[1] * np.sin(a[2]) + a[0]
    y3 = b[0] * np.sin(a[2]) + b[1] * np.cos(a[2]) + a[1]
    np.testing.assert_allclose(c, [x3, y3, 1.3], rtol=0, atol=1e-15)


def test_broadcasting_batches():
    a = random_poses(RNG, (4, 1))
    b = random_poses(RNG, (5,))
    c, Ja, Jb = se2.compose(a, b, jacobians=True)
    assert c.shape == (4, 5, 3) and Ja.shape == (4, 5, 3, 3) and Jb.shape == (4, 5, 3, 3)
    assert_poses_close(c[2, 3], se2.compose(a[2, 0], b[3]))


def test_shape_errors_are_specific():
    with pytest.raises(ShapeError, match=r"\(\.\.\., 3\)"):
        se2.compose(np.zeros(2), np.zeros(3))
    with pytest.raises(ShapeError):
        se2.inverse(np.zeros((4, 4)))
    with pytest.raises(ShapeError):
        se2.exp(1.0)


# ---------------------------------------------------------- Jacobians vs numeric
@pytest.mark.parametrize("shape", SHAPES)
def test_compose_jacobians_numeric(shape):
    a, b = random_poses(RNG, shape), random_poses(RNG, shape)
    _, Ja, Jb = se2.compose(a, b, jacobians=True)
    np.testing.assert_allclose(Ja, _jac(lambda x: se2.compose(x, b[..., None, :]), a), atol=1e-8)
    np.testing.assert_allclose(Jb, _jac(lambda x: se2.compose(a[..., None, :], x), b), atol=1e-8)


@pytest.mark.parametrize("shape", SHAPES)
def test_inverse_jacobian_numeric(shape):
    a = random_poses(RNG, shape)
    _, J = se2.inverse(a, jacobians=True)
    np.testing.assert_allclose(J, _jac(se2.inverse, a), atol=1e-8)


@pytest.mark.parametrize("shape", SHAPES)
def test_between_jacobians_numeric(shape):
    a, b = random_poses(RNG, shape), random_poses(RNG, shape)
    _, Ja, Jb = se2.between(a, b, jacobians=True)
    np.testing.assert_allclose(Ja, _jac(lambda x: se2.between(x, b[..., None, :]), a), atol=1e-8)
    np.testing.assert_allclose(Jb, _jac(lambda x: se2.between(a[..., None, :], x), b), atol=1e-8)


def test_jacobians_near_pi():
    """Headings just either side of ±π: the wrap must not leak into the Jacobians."""
    a = np.array([[1.0, -2.0, np.pi - 1e-9], [0.3, 0.4, -np.pi + 1e-9]])
    b = np.array([[0.5, 0.1, 1e-9], [2.0, -1.0, -1e-9]])
    _, Ja, Jb = se2.compose(a, b, jacobians=True)
    np.testing.assert_allclose(Ja, _jac(lambda x: se2.compose(x, b[..., None, :]), a), atol=1e-7)
    np.testing.assert_allclose(Jb, _jac(lambda x: se2.compose(a[..., None, :], x), b), atol=1e-7)
    _, J = se2.inverse(a, jacobians=True)
    np.testing.assert_allclose(J, _jac(se2.inverse, a), atol=1e-7)


def test_jacobians_match_paper_eq3_and_eq7():
    a = np.array([1.0, 2.0, 0.3])
    b = np.array([0.5, -0.2, 1.0])
    c, H, K = se2.compose(a, b, jacobians=True)
    H_paper = np.array([[1, 0, -(c[1] - a[1])], [0, 1, c[0] - a[0]], [0, 0, 1]])
    K_paper = np.array([[np.cos(0.3), -np.sin(0.3), 0], [np.sin(0.3), np.cos(0.3), 0], [0, 0, 1]])
    np.testing.assert_allclose(H, H_paper, atol=1e-15)
    np.testing.assert_allclose(K, K_paper, atol=1e-15)
    inv, R = se2.inverse(b, jacobians=True)
    cb, sb = np.cos(1.0), np.sin(1.0)
    np.testing.assert_allclose(R, [[-cb, -sb, inv[1]], [sb, -cb, -inv[0]], [0, 0, -1]], atol=1e-15)


# ------------------------------------------------------------------- vs GTSAM
def _gt(p):
    return gtsam.Pose2(*map(float, p))


def _vec(p):
    return np.array([p.x(), p.y(), p.theta()])


def _M(p):
    return se2.body_to_chart(p)


def test_compose_between_match_gtsam_with_jacobians():
    """GTSAM's body-frame Jacobians, converted by M, equal ours to 1e-12."""
    for a, b in zip(random_poses(RNG, (50,)), random_poses(RNG, (50,)), strict=True):
        Ha, Hb = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        c_gt = _gt(a).compose(_gt(b), Ha, Hb)
        c, Ja, Jb = se2.compose(a, b, jacobians=True)
        assert_poses_close(c, _vec(c_gt))
        np.testing.assert_allclose(Ja, _M(c) @ Ha @ _M(a).T, atol=1e-12)
        np.testing.assert_allclose(Jb, _M(c) @ Hb @ _M(b).T, atol=1e-12)

        Ha, Hb = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        d_gt = _gt(a).between(_gt(b), Ha, Hb)
        d, Ja, Jb = se2.between(a, b, jacobians=True)
        assert_poses_close(d, _vec(d_gt))
        np.testing.assert_allclose(Ja, _M(d) @ Ha @ _M(a).T, atol=1e-12)
        np.testing.assert_allclose(Jb, _M(d) @ Hb @ _M(b).T, atol=1e-12)


def test_inverse_matches_gtsam_with_jacobian():
    for a in random_poses(RNG, (30,)):
        H, H_unused = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        inv_gt = _gt(a).between(gtsam.Pose2(), H, H_unused)  # a⁻¹ ∘ identity, with ∂/∂a
        inv, J = se2.inverse(a, jacobians=True)
        assert_poses_close(inv, _vec(inv_gt))
        np.testing.assert_allclose(J, _M(inv) @ H @ _M(a).T, atol=1e-12)


def test_exp_log_adjoint_match_gtsam():
    xis = np.concatenate(
        [RNG.normal(size=(30, 3)), [[1.0, 2.0, 0.0], [0.5, 0.5, 3.1], [0.2, 0.1, 0.01]]]
    )
    for xi in xis:
        p = gtsam.Pose2.Expmap(xi)
        assert_poses_close(se2.exp(xi), _vec(p), atol=1e-12)
        np.testing.assert_allclose(se2.log(_vec(p)), gtsam.Pose2.Logmap(p), atol=1e-10)
        np.testing.assert_allclose(se2.adjoint(_vec(p)), p.AdjointMap(), atol=1e-12)


@pytest.mark.parametrize("w", [0.0, 1e-200, 1e-12, 1e-9, 3e-5, 1e-4, 1e-3, -0.5])
def test_exp_log_small_angles_exact(w):
    """Near ω = 0 the textbook closed forms cancel (GTSAM's Expmap is off by ~1e-8 at
    ω = 1e-9); relmap must match the cancellation-free form evaluated in extended precision."""
    v = np.array([0.3, -0.2])
    wl = np.longdouble(w)
    so = np.sin(wl) / wl if w else np.longdouble(1)
    co = 2 * np.sin(wl / 2) ** 2 / wl if w else np.longdouble(0)
    expected = np.array([so * v[0] - co * v[1], co * v[0] + so * v[1]], dtype=np.float64)
    got = se2.exp([v[0], v[1], w])
    np.testing.assert_allclose(got[:2], expected, rtol=0, atol=2e-16)
    np.testing.assert_allclose(se2.log(got), [v[0], v[1], w], rtol=0, atol=2e-16)


def test_exp_log_roundtrip_batched():
    xi = RNG.normal(size=(3, 1, 2, 1, 3))
    xi[..., 2] = se2.wrap_angle(xi[..., 2])
    np.testing.assert_allclose(se2.log(se2.exp(xi)), xi, atol=1e-12)


def test_adjoint_identity():
    a, xi = random_poses(RNG, ()), RNG.normal(size=3) * 0.3
    lhs = se2.compose(a, se2.exp(xi))
    rhs = se2.compose(se2.exp(se2.adjoint(a) @ xi), a)
    assert_poses_close(lhs, rhs)


def test_body_to_chart_is_first_order_right_perturbation():
    a = random_poses(RNG, (5,))
    M = se2.body_to_chart(a)
    J = numerical_jacobian(
        lambda xi: se2.compose(a[:, None, :], se2.exp(xi)), np.zeros((5, 3)), chart_out=SE2
    )
    np.testing.assert_allclose(J, M, atol=1e-8)
