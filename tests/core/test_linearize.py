"""The pose-graph normal equations (relmap._core.normal_equations2 and normal_equations3 through
relmap.network.optimal) against the mathematics: cost, gradient and Gauss-Newton matrix from
residuals written with relmap.lie and Jacobians by central differences, under least squares and
under a robust loss (the information of each AT weighted by ρ'(s²))."""

from __future__ import annotations

import numpy as np
import pytest

from relmap.lie import SE2, SE3, se3, so3
from relmap.network import optimal
from relmap.network.losses import Huber
from relmap.network.problem import Problem, parameterize
from tests.helpers import random_covs


def _problem(group, seed: int, n: int = 7, m: int = 14) -> Problem:
    rng = np.random.default_rng(seed)
    b = group.dof
    i = np.concatenate([np.arange(n - 1), rng.integers(0, n, m - n + 1)])
    j = np.concatenate([np.arange(1, n), rng.integers(0, n, m - n + 1)])
    j = np.where(i == j, (j + 1) % n, j)
    truth = group.plus(group.identity((n,)), rng.normal(scale=1.5, size=(n, b)))
    z = group.plus(group.between(truth[i], truth[j]), rng.normal(scale=0.1, size=(m, b)))
    cov = random_covs(rng, (m,), n=b, scale=0.05) + 1e-3 * np.eye(b)
    guess = group.plus(truth, rng.normal(scale=0.3, size=(n, b)))
    return Problem(n, i, j, z, cov, [], guess, 0, [f"e{k}" for k in range(m)], group)


def _numeric(residual, x0: np.ndarray, h: float = 1e-6) -> np.ndarray:
    cols = []
    for k in range(len(x0)):
        e = np.zeros_like(x0)
        e[k] = h
        cols.append((residual(e) - residual(-e)) / (2 * h))
    return np.stack(cols, axis=1)


def _check(p: Problem, linearize, moved, pattern, loss=None) -> None:
    """The linearization against the mathematics: cost Σ ρ(s²) (s² = rᵀ Σ⁻¹ r, ρ(s²) = s² without
    a loss), gradient ½ ∇ Σ ρ(s²) by central differences of that cost, normal matrix
    Σ ρ'(s²) Jᵀ Σ⁻¹ J with J by central differences, and the weights ρ'(s²)."""
    group = p.group
    W = np.linalg.inv(p.cov)

    def residual(delta):
        poses = moved(delta)
        return group.minus(group.between(poses[p.i], poses[p.j]), p.z)

    def cost_at(delta):
        r = residual(delta)
        s2 = np.einsum("ka,kab,kb->k", r, W, r)
        return float(np.sum(s2 if loss is None else loss.value(s2)))

    size = pattern.size
    r = residual(np.zeros(size))
    s2 = np.einsum("ka,kab,kb->k", r, W, r)
    w = np.ones(len(s2)) if loss is None else loss.weight(s2)
    J = _numeric(lambda d: residual(d).reshape(-1), np.zeros(size))
    Wbig = np.zeros((J.shape[0], J.shape[0]))
    b = group.dof
    for k in range(len(p.i)):
        Wbig[b * k : b * k + b, b * k : b * k + b] = w[k] * W[k]
    cost, _, data, grad, weights = linearize()
    assert cost == pytest.approx(cost_at(np.zeros(size)), rel=1e-12)
    if loss is None:
        assert weights is None
    else:
        np.testing.assert_allclose(weights, w, rtol=1e-12)
    grad_ref = 0.5 * np.array([(cost_at(h) - cost_at(-h)) / 2e-6 for h in 1e-6 * np.eye(size)])
    np.testing.assert_allclose(grad, grad_ref, rtol=1e-6, atol=1e-6 * abs(grad).max())
    H = pattern.matrix(data).toarray()
    H_ref = J.T @ Wbig @ J
    np.testing.assert_allclose(H, H_ref, rtol=1e-6, atol=1e-6 * abs(H_ref).max())


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("loss", [None, Huber(15.0)], ids=["l2", "huber"])
def test_planar_normal_equations_equal_numeric_jacobians(seed, loss):
    p = _problem(SE2, seed)
    param = parameterize(p)
    w = optimal._weights(p, param)
    system = optimal._System(p, param, w, optimal._losses(p, w, loss))
    state = param.initial_state(p.guess, p.anchor)
    move = param.stepper()
    _check(
        p,
        lambda: system.linearize(*state),
        lambda d: param.poses(*move(*state, d)),
        system.pattern,
        loss,
    )


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("loss", [None, Huber(15.0)], ids=["l2", "huber"])
def test_3d_normal_equations_equal_numeric_jacobians(seed, loss):
    p = _problem(SE3, seed)
    param = parameterize(p)
    w = optimal._weights(p, param)
    system = optimal._LieSystem(p, param, w, optimal._losses(p, w, loss))
    poses = np.array(p.guess)
    _check(
        p, lambda: system.linearize(poses), lambda d: system.step(poses, d), system.pattern, loss
    )


def test_the_robust_tests_down_weight_some_ats_and_not_others():
    """What the two tests above rely on: at their guesses Huber(15.0) weights some ATs below 1
    (s > k) and leaves others at 1 (s ≤ k), so both branches of the loss are exercised."""
    for group in (SE2, SE3):
        for seed in range(3):
            p = _problem(group, seed)
            r = group.minus(group.between(p.guess[p.i], p.guess[p.j]), p.z)
            s = np.sqrt(np.einsum("ka,kab,kb->k", r, np.linalg.inv(p.cov), r))
            assert (s > 15.0).any() and (s <= 15.0).any()


def _rotation_near(angle: float, rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=3)
    return so3.exp(angle * axis / np.linalg.norm(axis))


@pytest.mark.parametrize("angle", [0.0, 1e-9, 3e-5, 0.7, 2.5, np.pi - 5e-4, np.pi - 1e-4])
def test_3d_residuals_are_the_chart_difference_with_numeric_jacobians(angle):
    """relmap._core.residuals3 against the definition r = (T_i⁻¹ T_j) ⊟ z and central
    differences in the chart, on both sides of the small-angle and near-π branches."""
    rng = np.random.default_rng(int(1e3 * angle) % 997)
    Ti, Tj = se3.exp(rng.normal(size=6)), se3.exp(rng.normal(size=6))
    d = se3.between(Ti, Tj)
    # the measurement leaves a residual rotation of the given angle
    z = se3.from_parts(d[:3, 3] + rng.normal(size=3), _rotation_near(angle, rng).T @ d[:3, :3])
    poses = np.stack([Ti, Tj])
    i, j = np.array([0]), np.array([1])
    r, Ji, Jj = optimal.residuals3(poses, i, j, z[None])
    expected = se3.minus(d, z)
    np.testing.assert_allclose(r[0], expected, rtol=1e-12, atol=1e-12)
    assert np.linalg.norm(r[0, 3:]) == pytest.approx(angle, abs=1e-12)

    def residual(frame: int, delta: np.ndarray) -> np.ndarray:
        moved = poses.copy()
        moved[frame] = se3.plus(poses[frame], delta)
        return se3.minus(se3.between(moved[0], moved[1]), z)

    h = 1e-6
    for frame, J in ((0, Ji[0]), (1, Jj[0])):
        numeric = np.stack(
            [(residual(frame, h * e) - residual(frame, -h * e)) / (2 * h) for e in np.eye(6)], 1
        )
        np.testing.assert_allclose(J, numeric, atol=1e-6)


def test_bad_arguments_are_refused_by_the_3d_core():
    from relmap import _core

    poses, z = np.broadcast_to(np.eye(4), (2, 4, 4)).copy(), np.eye(4)[None].copy()
    i, j = np.array([0]), np.array([1])
    W, slots, g = np.eye(6)[None].copy(), np.zeros((1, 144), np.int64), np.zeros(12, np.int64)
    cost, _, _ = _core.normal_equations3(poses, i, j, z, W, slots, g, 1, 1)
    assert cost == 0.0
    with pytest.raises(ValueError, match="frame index"):
        _core.residuals3(poses, i, j + 1, z)
    with pytest.raises(ValueError, match="slot"):
        _core.normal_equations3(poses, i, j, z, W, slots + 5, g, 1, 1)
    with pytest.raises(ValueError):
        _core.normal_equations3(poses, i, j, z, W[:, :3, :3].copy(), slots, g, 1, 1)


def test_planar_residuals_equal_the_mathematics_across_the_wrap():
    """relmap._core.residuals2 against d = p_i⁻¹ ∘ p_j ⊟ z written with relmap.lie.se2, and
    its Jacobians (times each frame's ∂pose/∂parameters F) against central differences; the
    headings straddle ±π and lie far outside [-π, π)."""
    from relmap.lie import se2

    rng = np.random.default_rng(5)
    n, m = 6, 40
    poses = rng.normal(scale=2.0, size=(n, 3))
    poses[:, 2] = rng.choice([-np.pi + 1e-9, np.pi - 1e-9, 7.0, -9.5, 0.3, 3.1], size=n)
    i, j = rng.integers(0, n, m), rng.integers(0, n, m)
    z = rng.normal(scale=2.0, size=(m, 3))
    z[:, 2] = rng.choice([np.pi - 1e-12, -np.pi, 4.0, -0.2], size=m)
    F = np.eye(3) + rng.normal(scale=0.3, size=(n, 3, 3))
    r, Ji, Jj = optimal._residuals2(poses, i, j, z, F)
    np.testing.assert_allclose(r, se2.minus(se2.between(poses[i], poses[j]), z), atol=1e-12)
    assert np.all((r[:, 2] >= -np.pi) & (r[:, 2] < np.pi))
    for k in range(m):  # pose f moved by F[f] δ in the chart: the Jacobian is J F[f]
        for f, J in ((i[k], Ji[k]), (j[k], Jj[k])):
            if i[k] == j[k]:
                continue

            def res(d, f=f, k=k):
                moved = poses.copy()
                moved[f] = poses[f] + F[f] @ d
                return se2.minus(se2.between(moved[i[k]], moved[j[k]]), z[k])

            h = 1e-6  # central differences, the heading's difference wrapped
            num = np.stack([se2.minus(res(h * e), res(-h * e)) / (2 * h) for e in np.eye(3)], 1)
            np.testing.assert_allclose(J, num, atol=1e-6)
    r0, Ji0, Jj0 = optimal._residuals2(poses, i, j, z, None)  # no F: the chart Jacobians
    np.testing.assert_array_equal(r0, r)
    np.testing.assert_allclose(Ji0 @ F[i], Ji, atol=1e-13)
    np.testing.assert_allclose(Jj0 @ F[j], Jj, atol=1e-13)


def test_bad_planar_arguments_are_refused_by_the_core():
    from relmap import _core

    poses, z, F0 = np.zeros((3, 3)), np.zeros((2, 3)), np.zeros((0, 3, 3))
    i, j = np.array([0, 1]), np.array([1, 2])
    W, slots, g = np.zeros((2, 3, 3)), np.zeros((2, 36), np.int64), np.zeros(12, np.int64)
    cost, _, _ = _core.normal_equations2(poses, i, j, z, F0, W, slots, g, 1, 1)
    assert cost == 0.0
    with pytest.raises(ValueError, match="W"):
        _core.normal_equations2(poses, i, j, z, F0, np.zeros((2, 4, 4)), slots, g, 1, 1)
    with pytest.raises(ValueError, match="slots"):
        _core.normal_equations2(poses, i, j, z, F0, W, slots[:, :30].copy(), g, 1, 1)
    with pytest.raises(ValueError, match="frame index"):
        _core.residuals2(poses, i, j + 1, z, F0)
    with pytest.raises(ValueError, match="F must be"):
        _core.residuals2(poses, i, j, z, np.zeros((2, 3, 3)))
    with pytest.raises(ValueError, match="slot"):
        _core.normal_equations2(poses, i, j, z, F0, W, slots + 5, g, 1, 1)
    with pytest.raises(ValueError, match="gradient"):
        _core.normal_equations2(poses, i, j, z, F0, W, slots, g + 5, 1, 1)


def test_negative_targets_are_refused_by_the_core():
    """The range check of the scatter targets (one vectorized pass) catches a negative slot or
    gradient index anywhere, not only a too large one."""
    from relmap import _core

    poses, z, F0 = np.zeros((3, 3)), np.zeros((2, 3)), np.zeros((0, 3, 3))
    i, j = np.array([0, 1]), np.array([1, 2])
    W, slots, g = np.zeros((2, 3, 3)), np.zeros((2, 36), np.int64), np.zeros(12, np.int64)
    bad_slots, bad_g = slots.copy(), g.copy()
    bad_slots[1, 35], bad_g[11] = -1, -1
    with pytest.raises(ValueError, match="slot"):
        _core.normal_equations2(poses, i, j, z, F0, W, bad_slots, g, 1, 1)
    with pytest.raises(ValueError, match="gradient"):
        _core.normal_equations2(poses, i, j, z, F0, W, slots, bad_g, 1, 1)
    poses3, z3 = np.broadcast_to(np.eye(4), (3, 4, 4)).copy(), np.broadcast_to(np.eye(4), (2, 4, 4))
    W3, slots3, g3 = np.zeros((2, 6, 6)), np.zeros((2, 144), np.int64), np.zeros(24, np.int64)
    bad_slots3, bad_g3 = slots3.copy(), g3.copy()
    bad_slots3[1, 143], bad_g3[23] = -1, -1
    z3 = np.ascontiguousarray(z3)
    with pytest.raises(ValueError, match="slot"):
        _core.normal_equations3(poses3, i, j, z3, W3, bad_slots3, g3, 1, 1)
    with pytest.raises(ValueError, match="gradient"):
        _core.normal_equations3(poses3, i, j, z3, W3, slots3, bad_g3, 1, 1)
