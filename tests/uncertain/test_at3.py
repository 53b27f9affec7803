"""AT3: uncertain SE(3) poses, checked against GTSAM, Monte Carlo, the planar AT, Euler angles."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import relmap as rm
from relmap.errors import CovarianceError, ParameterError, ShapeError
from relmap.lie import se3, so3
from relmap.sim import montecarlo
from relmap.uncertain import gaussian, propagate
from tests.helpers import random_at3s, random_covs, valid_cross_cov


def small_angle_at3s(seed: int, n: int, sigma_rot: float = 0.02) -> rm.AT3:
    """Translation σ 0.03-0.1 m, rotation σ ``sigma_rot`` rad, random correlations up to 0.5."""
    g = np.random.default_rng(seed)
    sig = np.concatenate([g.uniform(0.03, 0.1, (n, 3)), np.full((n, 3), sigma_rot)], axis=-1)
    corr = random_covs(g, (n,), n=6, scale=1.0)
    d = np.sqrt(np.diagonal(corr, axis1=-2, axis2=-1))
    corr = 0.5 * np.eye(6) + 0.5 * corr / d[..., :, None] / d[..., None, :]  # well conditioned
    cov = corr * sig[..., :, None] * sig[..., None, :]
    q = Rotation.random(n, random_state=seed + 100).as_quat()
    return rm.AT3(g.uniform(-2, 2, (n, 3)), q, cov)


# ------------------------------------------------------------------ construction
def test_constructors_agree():
    rot = Rotation.random(3, random_state=1)
    t = np.random.default_rng(1).normal(size=(3, 3))
    a = rm.AT3(t, rot.as_quat())
    b = rm.AT3(t, rot.as_matrix())
    c = rm.AT3.from_vector(np.concatenate([t, rot.as_quat()], -1))
    d = rm.AT3.from_matrix(se3.from_parts(t, rot.as_matrix()))
    for x in (b, c, d):
        np.testing.assert_allclose(x.matrix, a.matrix, atol=1e-15)
    np.testing.assert_allclose(
        np.abs(np.einsum("ni,ni->n", a.quaternion, rot.as_quat())), 1, atol=1e-15
    )
    np.testing.assert_allclose(a.vector[:, :3], t)
    assert a.batch_shape == (3,) and len(a) == 3 and a[1].batch_shape == ()
    assert (a.cov == 0).all()
    s = rm.AT3.from_sigmas(t[0], rot.as_quat()[0], [1, 2, 3, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(s.sigmas, [1, 2, 3, 0.1, 0.2, 0.3])
    assert "AT3(t=[" in repr(s)


def test_bad_input_raises_specific_errors():
    q = [0.0, 0.0, 0.0, 1.0]
    with pytest.raises(ParameterError, match="norm"):
        rm.AT3([0, 0, 0], [0.0, 0.0, 0.1, 1.0])
    R = np.eye(3)
    R[0, 1] = 1e-2
    with pytest.raises(ParameterError, match="not a rotation matrix"):
        rm.AT3([0, 0, 0], R)
    with pytest.raises(ParameterError, match="det = -1"):
        rm.AT3([0, 0, 0], np.diag([1.0, 1.0, -1.0]))
    bad = np.eye(6)
    bad[0, 0] = -1
    with pytest.raises(CovarianceError):
        rm.AT3([0, 0, 0], q, bad)
    with pytest.raises(ShapeError):
        rm.AT3([0, 0], q)
    with pytest.raises(ShapeError):
        rm.AT3([0, 0, 0], [0, 0, 1])
    with pytest.raises(ShapeError):
        rm.AT3([0, 0, 0], q, np.eye(3))
    with pytest.raises(rm.errors.NonFiniteError):
        rm.AT3([0, np.nan, 0], q)
    a = rm.AT3([0, 0, 0], q)
    with pytest.raises(AttributeError):
        a._mean = None  # type: ignore[misc]
    with pytest.raises(TypeError):
        rm.compound(a, rm.AT([0, 0, 0]))  # type: ignore[arg-type]
    # nearly orthonormal input (rounding) is accepted and projected onto SO(3)
    noisy = Rotation.random(random_state=3).as_matrix() + 1e-9
    m = rm.AT3([0, 0, 0], noisy).rotation
    np.testing.assert_allclose(m.T @ m, np.eye(3), atol=1e-15)


# ------------------------------------------------------------------ vs GTSAM
def test_compound_matches_gtsam_via_body_conversion():
    a, b = random_at3s(4, 20), random_at3s(5, 20)
    c = a @ b
    assert isinstance(c, rm.AT3)
    for i in range(20):
        Ha, Hb = np.zeros((6, 6), order="F"), np.zeros((6, 6), order="F")
        pc = gtsam.Pose3(a.matrix[i]).compose(gtsam.Pose3(b.matrix[i]), Ha, Hb)
        body = Ha @ a[i].to_body() @ Ha.T + Hb @ b[i].to_body() @ Hb.T
        back = rm.AT3.from_body(pc.matrix(), body)
        np.testing.assert_allclose(c.matrix[i], back.matrix, atol=1e-12)
        np.testing.assert_allclose(c.cov[i], back.cov, atol=1e-12)


def test_reverse_matches_gtsam():
    a = random_at3s(6, 20)
    r = rm.reverse(a)
    for i in range(20):
        H = np.zeros((6, 6), order="F")
        p = gtsam.Pose3(a.matrix[i]).inverse(H)
        back = rm.AT3.from_body(p.matrix(), H @ a[i].to_body() @ H.T)
        np.testing.assert_allclose(r.matrix[i], back.matrix, atol=1e-12)
        np.testing.assert_allclose(r.cov[i], back.cov, atol=1e-12)


def test_body_convention_round_trips_and_matches_gtsam_sampling():
    a = random_at3s(7, 4)
    np.testing.assert_allclose(rm.AT3.from_body(a.matrix, a.to_body()).cov, a.cov, atol=1e-15)
    # a body covariance means T Exp(ξ) (GTSAM's retract); to first order our chart covariance
    one = rm.AT3.from_body(a.matrix[0], np.diag([4, 1, 2, 3, 1, 5]) * 1e-8)
    xi = np.random.default_rng(7).multivariate_normal(
        np.zeros(6), np.diag([4, 1, 2, 3, 1, 5]) * 1e-8, size=20_000
    )
    samples = se3.compose(a.matrix[0], se3.exp(np.concatenate([xi[:, 3:], xi[:, :3]], -1)))
    mc = montecarlo.SampleSet.of(samples, rm.AT3.group)
    agreement = mc.compare(one)
    assert agreement.cov_rel_error < 4 * agreement.cov_rel_standard_error


def test_ros_round_trip():
    a = random_at3s(8, 3)
    back = rm.AT3.from_ros(a.translation, a.quaternion, a.to_ros().reshape(3, 36))
    np.testing.assert_allclose(back.cov, a.cov, atol=0)
    np.testing.assert_allclose(back.matrix, a.matrix, atol=1e-15)


# ------------------------------------------------------------------ laws
def test_compound_with_own_reversal_cross_cov_is_zero():
    a = random_at3s(9, 50)
    r, J = rm.reverse(a, jacobians=True)
    c = rm.compound(a, r, cross_cov=a.cov @ np.swapaxes(J, -1, -2))
    np.testing.assert_allclose(c.matrix, np.broadcast_to(np.eye(4), (50, 4, 4)), atol=1e-14)
    assert np.abs(c.cov).max() <= 1e-15
    independent = a @ r  # Eq. 4's independence assumption: 2 J_a C J_aᵀ, not zero
    assert np.linalg.eigvalsh(independent.cov).max() > 1e-4


def test_compound_chain_dispatches_3d_chains():
    steps = random_at3s(11, 6)
    chain = rm.compound_chain(steps)
    assert isinstance(chain, rm.AT3)
    acc = steps[0]
    for k in range(1, 6):
        acc = rm.compound(acc, steps[k])
        np.testing.assert_allclose(chain[k].matrix, acc.matrix, atol=1e-13)
        np.testing.assert_allclose(chain[k].cov, acc.cov, rtol=1e-12, atol=1e-15)
    with pytest.raises(ParameterError, match="SE\\(2\\) ATs only"):
        rm.compound_chain(steps, moments="exact")


@pytest.mark.slow
@given(st.integers(0, 10_000))
def test_merge_is_order_independent_and_psd(seed):
    a, b, c = random_at3s(seed, 3, scale=0.1)
    # three estimates of one relation: perturb a's mean slightly
    b = rm.AT3.from_matrix(
        se3.plus(a.matrix, np.random.default_rng(seed).normal(scale=0.05, size=6)), b.cov
    )
    c = rm.AT3.from_matrix(
        se3.plus(a.matrix, np.random.default_rng(seed + 1).normal(scale=0.05, size=6)), c.cov
    )
    m1, m2 = rm.merge(a, b, c), rm.merge(c, a, b)
    np.testing.assert_allclose(m1.matrix, m2.matrix, atol=1e-12)
    np.testing.assert_allclose(m1.cov, m2.cov, atol=1e-12 * np.abs(m1.cov).max())
    for m in (m1, m2):
        assert np.linalg.eigvalsh(m.cov).min() >= -1e-15 * np.abs(m.cov).max()
        assert (np.diagonal(m.cov) <= np.diagonal(a.cov) + 1e-15).all()


def test_merge_with_exact_directions():
    """Zero-variance components are exact: the merge keeps them and refuses contradictions."""
    exact_z = np.diag([0.01, 0.01, 0.0, 1e-4, 1e-4, 1e-4])
    a = rm.AT3([1, 2, 0.5], [0, 0, 0, 1], exact_z)
    b = rm.AT3([1.1, 2, 0.5], [0, 0, 0, 1], exact_z)
    m = rm.merge(a, b)
    assert m.cov[2, 2] == 0 and m.translation[2] == 0.5
    np.testing.assert_allclose(m.translation[:2], [1.05, 2.0])
    with pytest.raises(rm.errors.InconsistentMergeError):
        rm.merge(a, rm.AT3([1, 2, 0.6], [0, 0, 0, 1], exact_z))


# ------------------------------------------------------------------ planar reduction
def test_planar_ats_reduce_exactly_to_at():
    g = np.random.default_rng(10)
    a = rm.AT(
        np.column_stack([g.normal(size=(30, 2)), g.uniform(-np.pi, np.pi, 30)]),
        random_covs(g, (30,)),
    )
    b = rm.AT(
        np.column_stack([g.normal(size=(30, 2)), g.uniform(-np.pi, np.pi, 30)]),
        random_covs(g, (30,)),
    )
    near = rm.AT(a.mean + g.normal(scale=0.1, size=(30, 3)), b.cov)  # another estimate of a
    A, B, N = rm.AT3.from_planar(a), rm.AT3.from_planar(b), rm.AT3.from_planar(near)
    keep = np.array([0, 1, 5])
    for planar, spatial in (
        (a @ b, A @ B),
        (a.reverse(), A.reverse()),
        (rm.merge(a, near), rm.merge(A, N)),
    ):
        np.testing.assert_allclose(spatial.cov[:, keep[:, None], keep], planar.cov, atol=1e-12)
        assert np.abs(np.delete(np.delete(spatial.cov, keep, 1), keep, 2)).max() == 0
        np.testing.assert_allclose(spatial.translation[:, :2], planar.mean[:, :2], atol=1e-12)
        np.testing.assert_allclose(spatial.translation[:, 2], 0, atol=0)
        yaw = so3.log(spatial.rotation)[:, 2]
        np.testing.assert_allclose(np.cos(yaw - planar.mean[:, 2]), 1, atol=1e-12)


# ------------------------------------------------------------------ Monte Carlo
def _agrees(mc: montecarlo.SampleSet, estimate: rm.AT3, linearization: float) -> None:
    """Covariance within 4 sampling standard errors plus a stated linearization allowance;
    mean within 4 standard errors plus the same allowance in σ units; NEES ≈ 6."""
    ag = mc.compare(estimate)
    assert (ag.cov_rel_error < 4 * ag.cov_rel_standard_error + linearization).all(), (
        ag.cov_rel_error.max()
    )
    assert (np.abs(ag.mean_error_sigmas) < 4 / np.sqrt(ag.n) + linearization).all()
    assert (np.abs(ag.nees - 6) < 6 * (4 * np.sqrt(2 / (6 * ag.n)) + linearization)).all()


@pytest.mark.slow
def test_compound_reverse_merge_agree_with_monte_carlo_at_small_angular_sigma():
    a, b = small_angle_at3s(11, 4), small_angle_at3s(12, 4)
    n = 20_000
    _agrees(montecarlo.simulate(se3.compose, a, b, n=n, seed=1), a @ b, linearization=0.01)
    _agrees(montecarlo.simulate(se3.inverse, a, n=n, seed=2), a.reverse(), linearization=0.01)
    merged = rm.merge(a, b.__class__._trusted(a.matrix, b.cov))
    _agrees(
        montecarlo.simulate_merge(a, rm.AT3._trusted(a.matrix, b.cov), n=n, seed=3),
        merged,
        linearization=0.01,
    )


def test_ellipsoid_probability_by_sampling():
    a = small_angle_at3s(13, 1)[0]
    axes, dirs = a.ellipsoid(0.9)
    k2 = gaussian.confidence_k2(0.9, 3)
    np.testing.assert_allclose(axes**2, k2 * np.linalg.eigvalsh(a.cov[:3, :3]), rtol=1e-12)
    d = se3.minus(a.sample(40_000, seed=4), a.matrix)[:, :3]
    inside = (((d @ dirs) / axes) ** 2).sum(-1) <= 1
    assert abs(inside.mean() - 0.9) < 4 * np.sqrt(0.9 * 0.1 / 40_000)


# ------------------------------------------------------------------ Euler angles and §7's poles
def test_euler_conversion_round_trips_with_covariance():
    g = np.random.default_rng(14)
    xyz_rpy = np.column_stack(
        [
            g.normal(size=(10, 3)),
            g.uniform(-3, 3, 10),
            g.uniform(-1.4, 1.4, 10),
            g.uniform(-3, 3, 10),
        ]
    )
    cov = random_covs(g, (10,), n=6, scale=0.05)
    a = rm.AT3.from_euler(xyz_rpy, cov)
    v, c = a.to_euler()
    np.testing.assert_allclose(v, xyz_rpy, atol=1e-12)
    np.testing.assert_allclose(c, cov, atol=1e-12, rtol=1e-9)


def test_euler_pole_is_detected():
    a = rm.AT3.from_euler([0, 0, 0, 0.2, np.pi / 2, 0.4], None)
    with pytest.raises(ParameterError, match="Euler pole"):
        a.to_euler()


def test_section7_poles_blow_up_euler_covariance_but_not_relmaps():
    """A fixed 0.01-rad rotation error: constant in relmap's chart at any attitude, but its
    Euler-angle form grows like 1/cos(pitch) (§7's singularity). Near the pole, compounding
    in Euler angles (first order) misses Monte Carlo badly; relmap's chart does not."""
    chart = np.diag([1e-4] * 6)
    sig_yaw = []
    for pitch in (0.0, 1.0, 1.5, 1.56, 1.5700):
        a = rm.AT3.from_matrix(se3.from_parts([1, 0, 0], so3.from_euler([0.1, pitch, 0.2])), chart)
        sig_yaw.append(np.sqrt(a.to_euler()[1][5, 5]))
    sig_yaw = np.array(sig_yaw)
    np.testing.assert_allclose(sig_yaw * np.cos([0.0, 1.0, 1.5, 1.56, 1.57]), 0.01, rtol=1e-6)
    assert sig_yaw[-1] > 10  # ~ 12.6 rad "standard deviation" of yaw

    # compound two ATs near the pole: relmap's chart vs first-order propagation in Euler angles
    a = rm.AT3.from_matrix(
        se3.from_parts([1, 0, 0], so3.from_euler([0.0, 1.52, 0.0])),
        np.diag([1e-4] * 3 + [4e-4] * 3),
    )
    b = rm.AT3.from_matrix(se3.from_parts([0, 1, 0], np.eye(3)), np.diag([1e-4] * 3 + [4e-4] * 3))
    mc = montecarlo.simulate(se3.compose, a, b, n=20_000, seed=5)
    ours = mc.compare(a @ b)
    assert ours.cov_rel_error < 4 * ours.cov_rel_standard_error  # measured 0.013

    va, ca = a.to_euler()
    vb, cb = b.to_euler()

    def compose_euler(v: np.ndarray) -> np.ndarray:
        Ta = se3.from_parts(v[..., :3], so3.from_euler(v[..., 3:6]))
        Tb = se3.from_parts(v[..., 6:9], so3.from_euler(v[..., 9:]))
        c = se3.compose(Ta, Tb)
        return np.concatenate([c[..., :3, 3], so3.to_euler(c[..., :3, :3])], -1)

    joint = np.zeros((12, 12))
    joint[:6, :6], joint[6:, 6:] = ca, cb
    euler_pred = propagate.propagate(compose_euler, np.concatenate([va, vb]), joint).cov
    euler_mc = np.cov(so3.to_euler(mc.samples[:, :3, :3]).T)
    rel = np.linalg.norm(euler_pred[3:, 3:] - euler_mc) / np.linalg.norm(euler_mc)
    assert rel > 0.25  # measured 0.36: Euler-form first-order propagation is far off near the pole


# ------------------------------------------------------- fast paths (single, batched, chunked)
def _reference_compound(a: rm.AT3, b: rm.AT3, X: np.ndarray | None = None):
    """The textbook form: full 6×6 Jacobians from se3.compose and batched matmul."""
    T, Ja, Jb = se3.compose(a.mean, b.mean, jacobians=True)
    C = Ja @ a.cov @ np.swapaxes(Ja, -1, -2) + Jb @ b.cov @ np.swapaxes(Jb, -1, -2)
    if X is not None:
        K = Ja @ X @ np.swapaxes(Jb, -1, -2)
        C = C + K + np.swapaxes(K, -1, -2)
    return T, C


def _reference_reverse(a: rm.AT3):
    T, J = se3.inverse(a.mean, jacobians=True)
    return T, J @ a.cov @ np.swapaxes(J, -1, -2)


def _close(at: rm.AT3, T: np.ndarray, C: np.ndarray) -> None:
    assert at.mean.shape == T.shape and at.cov.shape == C.shape
    np.testing.assert_allclose(at.mean, T, rtol=0, atol=1e-12 * max(1.0, np.abs(T).max()))
    np.testing.assert_allclose(at.cov, C, rtol=0, atol=1e-12 * np.abs(C).max())
    assert np.array_equal(at.cov, np.swapaxes(at.cov, -1, -2))  # exactly symmetric


def _shaped(at: rm.AT3, shape: tuple[int, ...]) -> rm.AT3:
    return rm.AT3(
        at.translation.reshape(*shape, 3),
        at.rotation.reshape(*shape, 3, 3),
        at.cov.reshape(*shape, 6, 6),
    )


@pytest.mark.parametrize(
    ("shape_a", "shape_b"),
    [((), ()), ((1,), ()), ((), (1,)), ((3, 1, 2), (1, 4, 2)), ((3, 1, 2), ()), ((5,), (5,))],
)
def test_compound_and_reverse_fast_paths_match_the_textbook_form(shape_a, shape_b):
    a = _shaped(random_at3s(11, int(np.prod(shape_a))), shape_a)
    b = _shaped(random_at3s(12, int(np.prod(shape_b))), shape_b)
    _close(a @ b, *_reference_compound(a, b))
    X = valid_cross_cov(a.cov, b.cov, 13, np.broadcast_shapes(shape_a, shape_b))
    _close(rm.compound(a, b, cross_cov=X), *_reference_compound(a, b, X))
    _close(a.reverse(), *_reference_reverse(a))


def test_single_pair_equals_its_batch_of_one():
    a, b = random_at3s(21, 1000), random_at3s(22, 1000)
    X = valid_cross_cov(a.cov, b.cov, 23)
    whole, crossed, rev = a @ b, rm.compound(a, b, cross_cov=X), a.reverse()
    for i in (0, 517, 999):  # one pair per call (the no-batch path) against the batch
        _close(a[i] @ b[i], whole.mean[i], whole.cov[i])
        _close(rm.compound(a[i], b[i], cross_cov=X[i]), crossed.mean[i], crossed.cov[i])
        _close(a[i].reverse(), rev.mean[i], rev.cov[i])


def test_fast_paths_accept_other_layouts_and_return_read_only_arrays():
    a = random_at3s(31, 7)
    # arrays in numpy's default layout, as other code may hand to _trusted
    plain = rm.AT3._trusted(np.ascontiguousarray(a.mean), np.ascontiguousarray(a.cov))
    _close(plain @ plain, *_reference_compound(a, a))
    _close(plain.reverse(), *_reference_reverse(a))
    for out in (a @ a, a[0] @ a[1], a.reverse(), a[0].reverse()):
        assert not out.mean.flags.writeable and not out.cov.flags.writeable
    empty = a[:0]
    assert (empty @ empty).batch_shape == (0,) and empty.reverse().batch_shape == (0,)
    with pytest.raises(ShapeError):
        a @ random_at3s(32, 3)
    with pytest.raises(ShapeError):
        rm.compound(a, a, cross_cov=np.zeros((3, 6, 6)))


@pytest.mark.parametrize("where", [0, 300, 999])
def test_compound_and_reverse_that_overflow_raise(where):
    """A result with inf or NaN (translations of 1e200 m: their squares in the covariance
    overflow) is refused with NumericalError, whichever batch element holds it (the core
    watches every output lane, chunks of 256 included)."""
    from relmap.errors import NumericalError

    rng = np.random.default_rng(where)
    T = se3.exp(rng.normal(size=(1000, 6)))
    T[where, :3, 3] = 1e200
    a = rm.AT3.from_matrix(T, np.broadcast_to(0.01 * np.eye(6), (1000, 6, 6)))
    with pytest.raises(NumericalError, match="compound overflowed"):
        a @ a
    with pytest.raises(NumericalError, match="reverse overflowed"):
        a.reverse()
    fine = rm.AT3.from_matrix(
        np.delete(T, where, 0), np.broadcast_to(0.01 * np.eye(6), (999, 6, 6))
    )
    assert np.isfinite((fine @ fine).cov).all()


def test_merging_at3s_that_share_their_covariances_computes_the_gains_once(rng):
    """AT3s of one covariance each (stored once): the gains are computed once (the result's
    covariance stays stride 0) and, for equal means, are the information form (I_a + I_b)⁻¹."""
    L1, L2 = rng.normal(scale=0.1, size=(6, 6)), rng.normal(scale=0.1, size=(6, 6))
    Ca, Cb = L1 @ L1.T + 1e-4 * np.eye(6), L2 @ L2.T + 1e-4 * np.eye(6)
    R = Rotation.random(8, random_state=3).as_matrix()
    t = rng.normal(size=(8, 3))
    m = rm.merge(rm.AT3(t, R, Ca), rm.AT3(t, R, Cb))
    assert m.batch_shape == (8,) and m.cov.strides[0] == 0
    np.testing.assert_allclose(
        m.cov[0], np.linalg.inv(np.linalg.inv(Ca) + np.linalg.inv(Cb)), rtol=1e-9, atol=1e-14
    )
    np.testing.assert_allclose(m.translation, t, atol=1e-12)
