"""relmap.AT: construction, compound / reverse / merge, conversions; against the paper, GTSAM
and Monte Carlo."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

import relmap as rm
from relmap.errors import (
    InconsistentMergeError,
    NonFiniteError,
    NotPositiveSemidefiniteError,
    NotSymmetricError,
    ParameterError,
    ShapeError,
)
from relmap.lie import se2
from relmap.sim import montecarlo
from relmap.uncertain import at
from relmap.uncertain.gaussian import congruence
from relmap.uncertain.propagate import SE2, Chart, propagate
from tests.helpers import assert_poses_close, random_ats, random_covs, random_poses


def rel_fro(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a - b, axis=(-2, -1)) / np.linalg.norm(b, axis=(-2, -1))


# ------------------------------------------------------------------ construction
def test_construct_wraps_copies_and_freezes():
    mean = np.array([1.0, 2.0, 3 * np.pi / 2])
    cov = np.diag([0.01, 0.02, 0.003])
    a = rm.AT(mean, cov)
    assert a.mean[2] == pytest.approx(-np.pi / 2)
    mean[0] = 99.0
    cov[0, 0] = 99.0
    assert a.mean[0] == 1.0 and a.cov[0, 0] == 0.01
    with pytest.raises(ValueError):
        a.mean[0] = 5.0
    with pytest.raises(ValueError):
        a.cov[0, 0] = 5.0
    with pytest.raises(AttributeError):
        a.foo = 1  # type: ignore[attr-defined]
    assert a.batch_shape == () and a.ndim == 0
    np.testing.assert_allclose(a.sigmas, np.sqrt([0.01, 0.02, 0.003]))
    assert "AT(mean=[1, 2, -1.5708]" in repr(a)


def test_exact_and_identity():
    a = rm.AT([1.0, 2.0, 0.5])
    np.testing.assert_array_equal(a.cov, np.zeros((3, 3)))
    i = rm.AT.identity((2, 3))
    assert i.batch_shape == (2, 3)
    assert_poses_close((a @ rm.AT.identity()).mean, a.mean)


@pytest.mark.parametrize(
    ("mean", "cov", "error"),
    [
        (np.zeros(2), None, ShapeError),
        (np.zeros((4, 3)), np.zeros((5, 3, 3)), ShapeError),
        ([0.0, np.nan, 0.0], None, NonFiniteError),
        ([0.0, 0.0, 0.0], np.eye(2), ShapeError),
        ([0.0, 0.0, 0.0], [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]], NotSymmetricError),
        ([0.0, 0.0, 0.0], np.diag([1.0, -1.0, 1.0]), NotPositiveSemidefiniteError),
        ([0.0, 0.0, 0.0], [[1, 2, 0], [2, 1, 0], [0, 0, 1]], NotPositiveSemidefiniteError),
        ([0.0, 0.0, 0.0], np.full((3, 3), np.inf), NonFiniteError),
    ],
)
def test_construct_rejects_bad_input(mean, cov, error):
    with pytest.raises(error):
        rm.AT(mean, cov)


def test_batch_broadcast_indexing_and_stack():
    means = random_poses(np.random.default_rng(1), (4, 5))
    a = rm.AT(means, np.diag([0.1, 0.1, 0.01]))  # one covariance shared by the batch
    assert a.batch_shape == (4, 5) and a.cov.shape == (4, 5, 3, 3)
    b = a[2, 3]
    np.testing.assert_array_equal(b.mean, se2.plus(means[2, 3], np.zeros(3)))
    assert a[1].batch_shape == (5,)
    assert a[:, 1:3].batch_shape == (4, 2)
    with pytest.raises(IndexError):
        b[0]
    with pytest.raises(IndexError):
        a[0, 0, 0]
    s = rm.AT.stack([a[0], a[1], a[2]], axis=1)
    assert s.batch_shape == (5, 3)
    np.testing.assert_array_equal(s.mean[:, 1], a[1].mean)
    with pytest.raises(TypeError):
        rm.AT.stack([a[0], "no"])  # type: ignore[list-item]
    assert len(a) == 4 and [r.batch_shape for r in a] == [(5,)] * 4
    with pytest.raises(TypeError):
        len(b)
    with pytest.raises(TypeError):
        list(b)


def test_from_sigmas_and_errors():
    a = rm.AT.from_sigmas([1.0, 2.0, 0.1], [0.1, 0.2, 0.03])
    np.testing.assert_allclose(a.cov, np.diag([0.01, 0.04, 0.0009]))
    with pytest.raises(ParameterError):
        rm.AT.from_sigmas([0, 0, 0], [0.1, -0.2, 0.1])
    with pytest.raises(ShapeError):
        rm.AT.from_sigmas([0, 0, 0], [0.1, 0.2])


def test_from_ellipse_lecture_eq6():
    """Σ = R(α) diag(σa², σb²) R(α)ᵀ; the ellipse of the result has those axes and direction."""
    alpha = np.deg2rad(30.0)
    a = rm.AT.from_ellipse([0, 0, 0], 0.3, 0.1, alpha, sigma_theta=0.02)
    R = np.array([[np.cos(alpha), -np.sin(alpha)], [np.sin(alpha), np.cos(alpha)]])
    np.testing.assert_allclose(a.cov[:2, :2], R @ np.diag([0.09, 0.01]) @ R.T, atol=1e-15)
    assert a.cov[2, 2] == pytest.approx(0.0004)
    e = a.ellipse(0.9)
    k = np.sqrt(-2 * np.log(0.1))
    assert e.semi_major == pytest.approx(0.3 * k) and e.semi_minor == pytest.approx(0.1 * k)
    assert e.angle == pytest.approx(alpha)
    with pytest.raises(ParameterError):
        rm.AT.from_ellipse([0, 0, 0], -0.3, 0.1, 0.0)


# ---------------------------------------------------------------------- compound
@pytest.mark.parametrize("shape", [(), (1,), (3, 1, 2, 1), (40,)])
def test_compound_equals_paper_eq4(shape):
    a, b = random_ats(2, shape), random_ats(3, shape)
    c = rm.compound(a, b)
    mean, H, K = se2.compose(a.mean, b.mean, jacobians=True)
    Ht, Kt = np.swapaxes(H, -1, -2), np.swapaxes(K, -1, -2)
    expected = H @ a.cov @ Ht + K @ b.cov @ Kt
    assert_poses_close(c.mean, mean)
    np.testing.assert_allclose(c.cov, expected, rtol=1e-13, atol=1e-16)
    assert_poses_close((a @ b).mean, c.mean)


def test_compound_broadcasts_batches():
    a, b = random_ats(4, (3, 1)), random_ats(5, (4,))
    c = a @ b
    assert c.batch_shape == (3, 4)
    np.testing.assert_allclose(c[1, 2].cov, (a[1, 0] @ b[2]).cov, rtol=1e-14)


def test_compound_rejects_non_at():
    a = random_ats(6, ())
    with pytest.raises(TypeError):
        rm.compound(a, np.zeros(3))  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        a @ np.zeros(3)


def test_compound_matches_gtsam_via_body_conversion():
    """GTSAM composes in the body chart: convert, compose with Jacobians, propagate, convert."""
    a, b = random_ats(7, (30,)), random_ats(8, (30,))
    c = a @ b
    for i in range(30):
        Ha, Hb = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        pc = gtsam.Pose2(*a.mean[i]).compose(gtsam.Pose2(*b.mean[i]), Ha, Hb)
        cov_body = Ha @ a[i].to_body() @ Ha.T + Hb @ b[i].to_body() @ Hb.T
        back = rm.AT.from_body([pc.x(), pc.y(), pc.theta()], cov_body)
        assert_poses_close(c.mean[i], back.mean)
        np.testing.assert_allclose(c.cov[i], back.cov, atol=1e-12)


def test_compound_with_own_reversal_cross_cov_is_exactly_zero():
    """A ⊕ Aᴿ with A's true correlation with Aᴿ: zero covariance; Eq. 4's independence: 2HCHᵀ."""
    unit = rm.AT([1.0, 0.5, 0.3], np.diag([0.01, 0.01, 0.001]))
    r, R = rm.reverse(unit, jacobians=True)
    assert np.abs(rm.compound(unit, r, cross_cov=unit.cov @ R.T).cov).max() <= 1e-15

    a = random_ats(9, (200,))  # translations of metres, so terms reach ~1: zero to rounding
    r, R = rm.reverse(a, jacobians=True)
    cross = a.cov @ np.swapaxes(R, -1, -2)  # Cov(A, Aᴿ) = C_A Rᵀ
    z = rm.compound(a, r, cross_cov=cross)
    indep = rm.compound(a, r)
    scale = np.abs(indep.cov).max(axis=(-2, -1))
    assert np.all(np.abs(z.cov).max(axis=(-2, -1)) <= 1e-15 * scale)
    assert_poses_close(z.mean, np.zeros((200, 3)), atol=1e-12)
    _, H, _ = se2.compose(a.mean, r.mean, jacobians=True)
    np.testing.assert_allclose(
        indep.cov, 2 * H @ a.cov @ np.swapaxes(H, -1, -2), rtol=1e-12, atol=1e-15
    )


def test_compound_cross_cov_matches_joint_propagation():
    """A dependent pair given by its 6×6 joint covariance (§3.2), against numeric propagation."""
    g = np.random.default_rng(10)
    a_mean, b_mean = random_poses(g, (6,)), random_poses(g, (6,))
    joint = random_covs(g, (6,), n=6)
    a = rm.AT(a_mean, joint[:, :3, :3])
    b = rm.AT(b_mean, joint[:, 3:, 3:])
    c = rm.compound(a, b, cross_cov=joint[:, :3, 3:])

    def plus6(x, d):
        return np.concatenate(
            [se2.plus(x[..., :3], d[..., :3]), se2.plus(x[..., 3:], d[..., 3:])], -1
        )

    ref = propagate(
        lambda x: se2.compose(x[..., :3], x[..., 3:]),
        np.concatenate([a_mean, b_mean], -1),
        joint,
        chart_in=Chart(plus6, None),  # type: ignore[arg-type]
        chart_out=SE2,
    )
    np.testing.assert_allclose(c.cov, ref.cov, rtol=1e-6, atol=1e-12)


def test_compound_cross_cov_shape_error():
    a = random_ats(11, ())
    with pytest.raises(ShapeError):
        rm.compound(a, a, cross_cov=np.zeros((3, 2)))


# ----------------------------------------------------------------------- reverse
@pytest.mark.parametrize("shape", [(), (3, 1, 2, 1), (40,)])
def test_reverse_equals_paper_eqs5_to_7(shape):
    a = random_ats(12, shape)
    r = a.reverse()
    inv, R = se2.inverse(a.mean, jacobians=True)
    assert_poses_close(r.mean, inv)
    np.testing.assert_allclose(r.cov, R @ a.cov @ np.swapaxes(R, -1, -2), rtol=1e-13, atol=1e-16)
    rr = r.reverse()
    assert_poses_close(rr.mean, a.mean)
    np.testing.assert_allclose(rr.cov, a.cov, rtol=1e-12, atol=1e-15)


def test_reverse_matches_gtsam():
    a = random_ats(13, (20,))
    r = a.reverse()
    for i in range(20):
        H, H2 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        p = gtsam.Pose2(*a.mean[i]).between(gtsam.Pose2(), H, H2)  # a⁻¹ and ∂/∂a (body chart)
        back = rm.AT.from_body([p.x(), p.y(), p.theta()], H @ a[i].to_body() @ H.T)
        np.testing.assert_allclose(r.cov[i], back.cov, atol=1e-12)


# ------------------------------------------------------------------------- merge
def test_merge_reduces_to_eq11_in_one_dimension():
    v1, v2 = np.array([0.04, 0.09, 0.01]), np.array([0.01, 0.01, 0.04])
    x1, x2 = np.array([1.0, 2.0, 0.1]), np.array([1.1, 1.9, 0.3])
    m = rm.merge(rm.AT(x1, np.diag(v1)), rm.AT(x2, np.diag(v2)))
    np.testing.assert_allclose(np.diag(m.cov), v1 * v2 / (v1 + v2), rtol=1e-14)
    np.testing.assert_allclose(m.mean, v2 / (v1 + v2) * x1 + v1 / (v1 + v2) * x2, rtol=1e-14)


def test_merge_equals_information_form():
    a, b = random_ats(14, (10,)), random_ats(15, (10,))
    b = rm.AT(se2.plus(a.mean, np.random.default_rng(16).normal(scale=0.05, size=(10, 3))), b.cov)
    m = rm.merge(a, b)
    Ia, Ib = np.linalg.inv(a.cov), np.linalg.inv(b.cov)
    C = np.linalg.inv(Ia + Ib)
    np.testing.assert_allclose(m.cov, C, rtol=1e-9, atol=1e-15)
    d = se2.minus(b.mean, a.mean)
    expected = se2.plus(a.mean, np.einsum("...ij,...jk,...k->...i", C, Ib, d))
    assert_poses_close(m.mean, expected, atol=1e-12)


def test_merge_wraps_heading_innovation():
    """θ = 3.1 merged with θ = -3.1 (equal weights) is ≈ ±π, not 0."""
    cov = np.diag([0.01, 0.01, 0.01])
    m = rm.merge(rm.AT([0, 0, 3.1], cov), rm.AT([0, 0, -3.1], cov))
    assert abs(se2.angle_difference(m.mean[2], np.pi)) < 1e-12
    assert -np.pi <= m.mean[2] < np.pi


def test_merge_is_stable_with_huge_covariance():
    """Eq. 9 as printed (C₁ - K C₁) loses accuracy by cancellation; the symmetric form does not."""
    C1, C2 = 1e12 * np.eye(3), np.eye(3)
    m = rm.merge(rm.AT([0, 0, 0], C1), rm.AT([1, 1, 0.1], C2))
    exact = 1e12 / (1e12 + 1)
    np.testing.assert_allclose(np.diag(m.cov), exact, rtol=1e-14)
    K = C1 @ np.linalg.inv(C1 + C2)
    printed = C1 - K @ C1
    assert abs(printed[0, 0] - exact) / exact > 1e-5  # the printed form really does lose digits


def test_merge_with_exactly_known_component():
    m = rm.merge(
        rm.AT([1.0, 2.0, 0.1], np.diag([0.0, 1.0, 1.0])), rm.AT([1.5, 3.0, 0.2], np.eye(3))
    )
    assert m.mean[0] == 1.0 and m.cov[0, 0] == 0.0
    np.testing.assert_allclose(np.diag(m.cov)[1:], 0.5)
    np.testing.assert_allclose(m.mean[1:], [2.5, 0.15])


def test_merge_no_angular_error_case():
    """Both θ variances zero (the paper's 'no angular error'), 3×3 covariances, consistent θ."""
    a = rm.AT([1.0, 2.0, 0.3], np.diag([0.04, 0.09, 0.0]))
    b = rm.AT([1.2, 1.8, 0.1 + 0.2], np.diag([0.04, 0.01, 0.0]))  # 0.1 + 0.2 != 0.3 by one ulp
    m = rm.merge(a, b)
    assert m.cov[2, 2] == 0.0 and m.mean[2] == pytest.approx(0.3, abs=1e-15)
    np.testing.assert_allclose(np.diag(m.cov)[:2], [0.02, 0.009])
    np.testing.assert_allclose(m.mean[:2], [1.1, 1.82])


def test_merge_contradicting_exact_components_raises():
    a = rm.AT([1.0, 2.0, 0.3], np.diag([0.04, 0.09, 0.0]))
    b = rm.AT([1.0, 2.0, 0.31], np.diag([0.04, 0.09, 0.0]))
    with pytest.raises(InconsistentMergeError, match="both know exactly"):
        rm.merge(a, b)
    batch = rm.AT.stack([a, a, b])
    with pytest.raises(InconsistentMergeError, match=r"batch index \[2\]"):
        rm.merge(rm.AT.stack([a, a, a]), batch)


def test_merge_of_two_exact_equal_ats():
    a = rm.AT([1.0, 2.0, 0.3])
    m = rm.merge(a, a, a)
    np.testing.assert_array_equal(m.cov, 0.0)
    np.testing.assert_allclose(m.mean, a.mean)


def test_merge_arguments():
    a = random_ats(17, ())
    assert rm.merge(a) is a
    with pytest.raises(ShapeError):
        rm.merge()
    with pytest.raises(TypeError):
        rm.merge(a, 3.0)  # type: ignore[arg-type]


# ------------------------------------------------------------------ compound_chain
def _chain_by_loop(steps: rm.AT) -> list[rm.AT]:
    out = [steps[0]]
    for i in range(1, steps.batch_shape[0]):
        out.append(out[-1] @ steps[i])
    return out


def test_compound_chain_equals_sequential_compounding():
    g = np.random.default_rng(18)
    n = 400
    means = np.column_stack([g.uniform(0.5, 1.5, n), g.normal(0, 0.1, n), g.normal(0.05, 0.3, n)])
    steps = rm.AT(means, random_covs(g, (n,), scale=0.03))
    chain = rm.compound_chain(steps)
    loop = _chain_by_loop(steps)
    for k in (0, 1, 57, n - 1):
        assert_poses_close(chain.mean[k], loop[k].mean, atol=1e-10)
        assert rel_fro(chain.cov[k], loop[k].cov) < 1e-10


def test_compound_chain_batched_and_axis():
    g = np.random.default_rng(19)
    steps = random_ats(g, (3, 20), scale=0.05, pose_scale=1.0)
    chain = rm.compound_chain(steps)
    along0 = rm.compound_chain(
        rm.AT(np.swapaxes(steps.mean, 0, 1), np.swapaxes(steps.cov, 0, 1)), axis=0
    )
    for b in range(3):
        last = _chain_by_loop(steps[b])[-1]
        assert_poses_close(chain.mean[b, -1], last.mean, atol=1e-12)
        assert rel_fro(chain.cov[b, -1], last.cov) < 1e-12
        np.testing.assert_allclose(along0.cov[:, b], chain.cov[b], rtol=1e-14)
    with pytest.raises(ShapeError):
        rm.compound_chain(steps[0, 0])
    with pytest.raises(ShapeError):
        rm.compound_chain(steps, axis=2)


def test_compound_chain_far_from_origin_keeps_precision():
    """A chain starting 10 km away (UTM-like coordinates) still matches the loop."""
    g = np.random.default_rng(20)
    means = np.column_stack([np.full(200, 1.0), np.zeros(200), g.normal(0, 0.05, 200)])
    means[0] = [1e4, -2e4, 0.3]
    steps = rm.AT(means, np.diag([1e-4, 1e-4, 1e-6]))
    chain = rm.compound_chain(steps)
    loop = _chain_by_loop(steps)
    assert rel_fro(chain.cov[-1], loop[-1].cov) < 1e-8


# --------------------------------------------------------------------- conversions
def test_body_roundtrip_and_definition():
    a = random_ats(21, (8,))
    body = a.to_body()
    M = se2.body_to_chart(a.mean)
    np.testing.assert_allclose(M @ body @ np.swapaxes(M, -1, -2), a.cov, atol=1e-15)
    np.testing.assert_allclose(rm.AT.from_body(a.mean, body).cov, a.cov, atol=1e-15)


def test_body_convention_matches_gtsam_sampling_semantics():
    """A body covariance means T ∘ Exp(ξ); first-order, that is our chart covariance M Σ Mᵀ."""
    a = rm.AT([2.0, -1.0, 2.5], np.zeros((3, 3)))
    body = np.diag([0.01, 0.04, 0.0025]) * 1e-4
    xi = np.random.default_rng(22).multivariate_normal(np.zeros(3), body, size=100_000)
    samples = se2.compose(a.mean, se2.exp(xi))
    d = se2.minus(samples, a.mean)
    expected = rm.AT.from_body(a.mean, body).cov
    assert rel_fro(np.cov(d.T), expected) < 0.02


def test_ros_covariance_layout_and_roundtrip():
    a = random_ats(23, (2,))
    ros = a.to_ros()
    assert ros.shape == (2, 6, 6)
    np.testing.assert_array_equal(ros[..., [0, 1, 5], :][..., :, [0, 1, 5]], a.cov)
    np.testing.assert_array_equal(ros[..., 2, 2], 0.0)
    assert a.to_ros(unused_variance=1e6)[0, 3, 3] == 1e6
    back = rm.AT.from_ros(a.mean, ros.reshape(2, 36))
    np.testing.assert_array_equal(back.cov, a.cov)
    with pytest.raises(ShapeError):
        rm.AT.from_ros(a.mean, np.zeros((2, 5, 5)))


# --------------------------------------------------------------------- Monte Carlo
def _small_angle_ats(seed: int, n: int, sigma_theta_deg: float) -> rm.AT:
    g = np.random.default_rng(seed)
    sig = np.column_stack(
        [g.uniform(0.02, 0.1, n), g.uniform(0.02, 0.1, n), np.full(n, np.deg2rad(sigma_theta_deg))]
    )
    means = np.column_stack(
        [g.uniform(0.5, 3, n), g.uniform(-1, 1, n), g.uniform(-np.pi, np.pi, n)]
    )
    return rm.AT.from_sigmas(means, sig)


@pytest.mark.slow
@pytest.mark.parametrize("sigma_theta_deg", [0.5, 2.0])
def test_compound_monte_carlo_within_two_percent(sigma_theta_deg):
    a, b = _small_angle_ats(30, 8, sigma_theta_deg), _small_angle_ats(31, 8, sigma_theta_deg)
    mc = montecarlo.simulate(se2.compose, a, b, n=150_000, seed=32).compare(a @ b)
    assert np.all(mc.cov_rel_error < 0.02)
    assert np.all(np.abs(mc.nees - 3.0) < 0.05)
    assert np.all(np.abs(mc.coverage - 0.9) < 0.01)


@pytest.mark.slow
def test_reverse_monte_carlo_within_two_percent():
    a = _small_angle_ats(33, 8, 2.0)
    mc = montecarlo.simulate(se2.inverse, a, n=150_000, seed=34).compare(a.reverse())
    assert np.all(mc.cov_rel_error < 0.02)


@pytest.mark.slow
def test_merge_monte_carlo_error_distribution():
    """Merged estimator's error around the truth has the merged covariance and no bias."""
    a = _small_angle_ats(35, 6, 2.0)
    b = rm.AT(a.mean, random_covs(np.random.default_rng(36), (6,), scale=0.05))
    c = rm.AT(a.mean, np.diag([0.02, 0.01, 1e-4]))
    merged = rm.merge(a, b, c)
    mc = montecarlo.simulate_merge(a, b, c, n=100_000, seed=37).compare(merged)
    assert np.all(mc.cov_rel_error < 5 * mc.cov_rel_standard_error)
    assert np.all(np.abs(mc.mean_error) < 5 * mc.mean_standard_error)


@pytest.mark.parametrize("how", ["independent", "cross_cov", "joint_cov"])
def test_merge_of_a_batch_sharing_its_covariances_computes_the_gain_once(rng, how):
    """ATs built from one covariance each (stored once, broadcast): the merge's gain is
    computed once (the result's covariance is still one, stride 0) and every element is the
    information-form merge (Eq. 8-10) of its means."""
    Ca, Cb = random_covs(rng, (), scale=0.05), random_covs(rng, (), scale=0.05)
    X = 0.3 * np.linalg.cholesky(Ca) @ np.linalg.cholesky(Cb).T if how != "independent" else 0 * Ca
    ma = rng.normal(scale=0.5, size=(50, 3))
    a = rm.AT(ma, Ca)
    b = rm.AT(se2.plus(ma, rng.normal(scale=0.05, size=(50, 3))), Cb)
    kwargs = {
        "independent": {},
        "cross_cov": {"cross_cov": X},
        "joint_cov": {"joint_cov": np.block([[Ca, X], [X.T, Cb]])},
    }[how]
    m = rm.merge(a, b, **kwargs)
    assert m.batch_shape == (50,) and m.cov.strides[0] == 0
    # GLS with A = [I; I] on the joint covariance, the second mean written as first ⊞ d
    Si = np.linalg.inv(np.block([[Ca, X], [X.T, Cb]]))
    A = np.vstack([np.eye(3), np.eye(3)])
    C = np.linalg.inv(A.T @ Si @ A)
    np.testing.assert_allclose(m.cov[0], C, rtol=1e-9, atol=1e-14)
    d = se2.minus(b.mean, a.mean)
    step = np.einsum("ij,...j->...i", C @ A.T @ Si[:, 3:], d)
    assert_poses_close(m.mean, se2.plus(a.mean, step), atol=1e-12)


# ------------------------------------- SE(2)'s fused 3×3 congruences, against the matrix products
def test_fused_congruences_are_the_matrix_products(rng):
    C = random_covs(rng, (50,))
    t, dx, dy = rng.uniform(-3, 3, 50), rng.normal(size=50), rng.normal(size=50)
    c, s = np.cos(t), np.sin(t)
    K = np.zeros((50, 3, 3))
    K[:, 0, 0], K[:, 0, 1], K[:, 1, 0], K[:, 1, 1], K[:, 2, 2] = c, -s, s, c, 1.0
    H = np.broadcast_to(np.eye(3), (50, 3, 3)).copy()
    H[:, 0, 2], H[:, 1, 2] = -dy, dx
    e = at.entries(C)
    np.testing.assert_allclose(at.to_matrix(e), C, rtol=0, atol=0)
    np.testing.assert_allclose(at.to_matrix(at.rotate(e, c, s)), K @ C @ K.transpose(0, 2, 1),
                               rtol=1e-13, atol=1e-15)  # fmt: skip
    np.testing.assert_allclose(at.to_matrix(at.shear(e, dx, dy)), H @ C @ H.transpose(0, 2, 1),
                               rtol=1e-13, atol=1e-15)  # fmt: skip
    S = random_covs(rng, (50,), n=2)
    a, b, ee, f = rng.normal(size=(4, 50))
    J = np.zeros((50, 3, 2))
    J[:, 0], J[:, 1], J[:, 2, 1] = np.stack([a, ee], -1), np.stack([b, f], -1), 1.0
    out = at.congruence_3x2(a, ee, b, f, S[:, 0, 0], S[:, 0, 1], S[:, 1, 1])
    np.testing.assert_allclose(at.to_matrix(out), J @ S @ J.transpose(0, 2, 1),
                               rtol=1e-13, atol=1e-15)  # fmt: skip
    np.testing.assert_allclose(congruence(J, S), J @ S @ J.transpose(0, 2, 1), rtol=1e-13)
    assert (congruence(J, S) == congruence(J, S).transpose(0, 2, 1)).all()


def test_one_matrix_gives_python_floats():
    e = at.entries(np.diag([1.0, 2.0, 3.0]))
    assert all(type(v) is float for v in e)
    assert at.to_matrix(at.rotate(e, 0.0, 1.0)).shape == (3, 3)
