"""Exact SE(2) moments (relmap.uncertain.moments): against Monte Carlo, against brute-force
quadrature,
against first order when the uncertainty is tiny, and the laws (PSD, pair = chain of 2, batches).

The exact moments are those of the heading on the real line, so Monte Carlo here sums sampled
headings without wrapping before it takes moments.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import relmap as rm
from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.sim import montecarlo
from relmap.uncertain import moments as mo
from relmap.uncertain.propagate import EUCLIDEAN, SE2, unscented
from tests.helpers import (
    assert_poses_close,
    random_ats,
    random_covs,
    random_poses,
    valid_cross_cov,
    wrapped,
)


# ----------------------------------------------------------------------------- helpers
def _chain_end_samples(steps: rm.AT, n: int, seed: int) -> np.ndarray:
    """End poses ``(n, 3)`` of a chain along axis 0 of ``steps``, heading summed unwrapped."""
    links = steps.sample(n, np.random.default_rng(seed))  # (n, links, 3)
    theta = np.cumsum(links[..., 2], axis=-1)
    before = theta - links[..., 2]
    c = (np.exp(1j * before) * (links[..., 0] + 1j * links[..., 1])).sum(axis=-1)
    return np.stack([c.real, c.imag, theta[:, -1]], axis=-1)


def _unwrapped(mean: np.ndarray, heading_sum: float) -> np.ndarray:
    out = np.array(mean, dtype=float)
    out[2] = heading_sum + wrapped(out[2] - heading_sum)
    return out


def _quadrature_pair(mu: np.ndarray, S: np.ndarray, nodes: int = 40):
    """Moments of ``a ⊕ b`` for ``(a, b) ~ N(μ, Σ)`` (6-D, heading unwrapped) by brute force:
    given both headings, the translations are jointly Gaussian and c is linear in them;
    integrate over the two headings with a tensor Gauss–Hermite rule."""
    th, tr = [2, 5], [0, 1, 3, 4]
    S_tt, S_tq, S_qq = S[np.ix_(tr, tr)], S[np.ix_(tr, th)], S[np.ix_(th, th)]
    gain = S_tq @ np.linalg.inv(S_qq)
    C_t = S_tt - gain @ S_tq.T
    u, w = np.polynomial.hermite_e.hermegauss(nodes)
    U = np.stack(np.meshgrid(u, u, indexing="ij"), axis=-1).reshape(-1, 2)
    W = np.outer(w, w).ravel()
    W = W / W.sum()
    q = mu[th] + U @ np.linalg.cholesky(S_qq).T  # (K, 2) heading nodes
    m_t = mu[tr] + (q - mu[th]) @ gain.T  # (K, 4)
    c, s = np.cos(q[:, 0]), np.sin(q[:, 0])
    G = np.zeros((len(W), 2, 4))
    G[:, 0, 0] = G[:, 1, 1] = 1.0
    G[:, 0, 2], G[:, 0, 3], G[:, 1, 2], G[:, 1, 3] = c, -s, s, c
    m_y = np.concatenate([np.einsum("kij,kj->ki", G, m_t), q.sum(axis=1)[:, None]], axis=1)
    C_y = np.zeros((len(W), 3, 3))
    C_y[:, :2, :2] = G @ C_t @ np.swapaxes(G, -1, -2)
    mean = W @ m_y
    d = m_y - mean
    cov = np.einsum("k,kij->ij", W, C_y) + np.einsum("k,ki,kj->ij", W, d, d)
    return mean, cov


def _joint(Ca, Cb, X):
    S = np.zeros((6, 6))
    S[:3, :3], S[3:, 3:], S[:3, 3:], S[3:, :3] = Ca, Cb, X, X.T
    return S


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# ---------------------------------------------------------------------- Monte Carlo
@pytest.mark.slow
def test_chain_matches_monte_carlo_within_sampling_error():
    # 8 curved links, correlated within each link, 8.6° heading error per link: first order is
    # visibly wrong here, the exact moments must agree with 2·10⁵ samples to their own error.
    rng = np.random.default_rng(3)
    n_links, n = 8, 200_000
    mean = np.column_stack([np.full(n_links, 1.0), rng.uniform(-0.2, 0.2, n_links),
                            rng.uniform(-0.3, 0.3, n_links)])  # fmt: skip
    cov = random_covs(rng, (n_links,), scale=0.04)
    cov[:, 2, 2] += 0.15**2
    steps = rm.AT(mean, cov)
    exact = rm.compound_chain(steps, axis=0, moments="exact")[-1]
    first = rm.compound_chain(steps, axis=0)[-1]
    y = _chain_end_samples(steps, n, seed=11)
    ref = _unwrapped(exact.mean, mean[:, 2].sum())
    d = y - ref
    mc_mean = ref + d.mean(axis=0)
    dc = y - mc_mean
    prod = dc[:, :, None] * dc[:, None, :]
    mc_cov = prod.sum(axis=0) / (n - 1)
    se_cov = prod.std(axis=0) / np.sqrt(n)  # sampling error of every covariance entry
    se_mean = dc.std(axis=0) / np.sqrt(n)

    z_cov = np.abs(exact.cov - mc_cov) / se_cov
    z_mean = np.abs(_unwrapped(exact.mean, mc_mean[2]) - mc_mean) / se_mean
    assert z_cov.max() < 4.5, z_cov
    assert z_mean.max() < 4.5, z_mean
    # The same test rejects first order decisively (the check has power).
    assert (np.abs(first.cov - mc_cov) / se_cov).max() > 20
    assert (np.abs(_unwrapped(first.mean, mc_mean[2]) - mc_mean) / se_mean).max() > 20
    # The sample is far from Gaussian (the crescent), which exact moments do not change.
    report = montecarlo.SampleSet.of(y[:50_000]).compare(exact)
    assert report.skewness > 0.1


# ---------------------------------------------------------------- brute-force quadrature
@pytest.mark.parametrize("dependent", [False, True])
def test_pair_matches_quadrature(dependent):
    rng = np.random.default_rng(5 + dependent)
    for _ in range(4):
        mu = np.concatenate([random_poses(rng, (), 2.0), random_poses(rng, (), 2.0)])
        L = rng.normal(scale=0.4, size=(6, 6))
        S = L @ L.T + 0.01 * np.eye(6)
        if not dependent:
            S[:3, 3:] = S[3:, :3] = 0.0
        mean, cov = _quadrature_pair(mu, S)
        # both paths: the 6-D tilt formulas (cross_cov given) and, when independent, the chain
        for X in [S[:3, 3:]] + ([] if dependent else [None]):
            got = mo.compound_moments(mu[:3], S[:3, :3], mu[3:], S[3:, 3:], cross_cov=X)
            assert_poses_close(got.mean, mean, atol=1e-10)
            np.testing.assert_allclose(got.cov, cov, atol=1e-10 * np.abs(cov).max())


def test_heading_variance_is_exact_on_the_real_line():
    # Huge heading errors: variance is Σσ², the mean heading Σμ wrapped, nothing overflows.
    n = 2000
    steps = rm.AT.from_sigmas(np.tile([1.0, 0.5, 3.0], (n, 1)), np.tile([0.1, 0.1, 1.5], (n, 1)))
    out = rm.compound_chain(steps, axis=0, moments="exact")
    np.testing.assert_allclose(out.cov[:, 2, 2], 2.25 * np.arange(1, n + 1), rtol=1e-12)
    np.testing.assert_allclose(wrapped(out.mean[:, 2] - 3.0 * np.arange(1, n + 1)), 0, atol=1e-9)
    assert np.isfinite(out.cov).all()
    assert np.linalg.eigvalsh(out.cov).min() > 0
    # Fully randomized heading: the position mean tends to the last few links' contribution.
    assert np.abs(out.mean[-1, :2]).max() < 2.0


# ------------------------------------------------------------------------------ limits
def test_tiny_uncertainty_reduces_to_first_order():
    rng = np.random.default_rng(7)
    mean = random_poses(rng, (30,), 1.0)
    cov = random_covs(rng, (30,), scale=1e-5)
    steps = rm.AT(mean, cov)
    exact = rm.compound_chain(steps, axis=0, moments="exact")
    first = rm.compound_chain(steps, axis=0)
    assert_poses_close(exact.mean, first.mean, atol=1e-8)
    for k in range(30):
        assert _rel(exact.cov[k], first.cov[k]) < 1e-6
    diag = mo.linearization_error(steps, axis=0)
    assert diag.cov_rel_error.max() < 1e-6
    assert np.abs(diag.mean_error_sigmas).max() < 1e-3


def test_single_link_is_unchanged():
    a = rm.AT([1.0, 2.0, 3.1], np.diag([0.1, 0.2, 0.3]))
    out = mo.chain_moments(a.mean[None], a.cov[None], axis=0)
    np.testing.assert_allclose(out.mean[0], a.mean, atol=1e-15)
    np.testing.assert_allclose(out.cov[0], a.cov, atol=1e-15)


# -------------------------------------------------------------------------------- laws
FACTOR = st.one_of(st.just(0.0), st.floats(1e-3, 0.8), st.floats(-0.8, -1e-3))


@given(
    hnp.arrays(np.float64, (5, 3), elements=st.floats(-3.0, 3.0)),
    hnp.arrays(np.float64, (5, 3, 3), elements=FACTOR),
)
def test_exact_covariance_is_psd(mean, L):
    cov = L @ np.swapaxes(L, -1, -2)
    out = mo.chain_moments(mean, cov, axis=0)
    scale = np.abs(out.cov).max(axis=(-2, -1), keepdims=True)[..., 0] + 1e-300
    assert (np.linalg.eigvalsh(out.cov) >= -1e-10 * scale).all()
    np.testing.assert_allclose(out.cov, np.swapaxes(out.cov, -1, -2), atol=0)
    pair = mo.compound_moments(mean[0], cov[0], mean[1], cov[1])
    assert np.linalg.eigvalsh(pair.cov).min() >= -1e-10 * np.abs(pair.cov).max()


def test_pair_equals_chain_of_two():
    # Two independent implementations: the 6-D tilt formulas and the chain recursions.
    rng = np.random.default_rng(9)
    ma, mb = random_poses(rng, (50,)), random_poses(rng, (50,))
    Ca, Cb = random_covs(rng, (50,), scale=0.5), random_covs(rng, (50,), scale=0.5)
    # (a zero cross-covariance takes the 6-D path; None the chain path)
    pair = mo.compound_moments(ma, Ca, mb, Cb, cross_cov=np.zeros((3, 3)))
    chain = mo.chain_moments(np.stack([ma, mb]), np.stack([Ca, Cb]), axis=0)
    assert_poses_close(pair.mean, chain.mean[1], atol=1e-12)
    np.testing.assert_allclose(pair.cov, chain.cov[1], atol=1e-12)
    independent = mo.compound_moments(ma, Ca, mb, Cb)
    np.testing.assert_array_equal(independent.cov, chain.cov[1])


def test_chain_is_sequential_exact_compounding_of_prefix_and_link_moments_batched():
    # Batched over other axes, any chain axis: equal to one chain at a time.
    rng = np.random.default_rng(13)
    mean = random_poses(rng, (3, 7, 2), 1.5)
    cov = random_covs(rng, (3, 7, 2), scale=0.3)
    out = mo.chain_moments(mean, cov, axis=1)
    assert out.mean.shape == (3, 7, 2, 3) and out.cov.shape == (3, 7, 2, 3, 3)
    for i in range(3):
        for j in range(2):
            one = mo.chain_moments(mean[i, :, j], cov[i, :, j], axis=0)
            assert_poses_close(out.mean[i, :, j], one.mean, atol=1e-12)
            np.testing.assert_allclose(out.cov[i, :, j], one.cov, atol=1e-12)
    neg = mo.chain_moments(mean, cov, axis=-2)
    np.testing.assert_array_equal(neg.cov, out.cov)
    # the pair function broadcasts like numpy
    pair = mo.compound_moments(mean[:, 0, :1], cov[:, 0, :1], mean[0, 1, 0], cov[0, 1, 0])
    assert pair.mean.shape == (3, 1, 3)
    ref = mo.compound_moments(mean[2, 0, 0], cov[2, 0, 0], mean[0, 1, 0], cov[0, 1, 0])
    np.testing.assert_allclose(pair.cov[2, 0], ref.cov, atol=1e-14)


# ------------------------------------------------------------------------- AT surface
def test_compound_dispatches_on_moments():
    rng = np.random.default_rng(17)
    a = random_ats(rng, (4,), scale=0.3)
    b = random_ats(rng, (4,), scale=0.3)
    X = valid_cross_cov(a.cov, b.cov, 18)
    exact = rm.compound(a, b, cross_cov=X, moments="exact")
    ref = mo.compound_moments(a.mean, a.cov, b.mean, b.cov, cross_cov=X)
    np.testing.assert_array_equal(exact.mean, ref.mean)
    np.testing.assert_array_equal(exact.cov, ref.cov)
    first = rm.compound(a, b, moments="first_order")
    np.testing.assert_array_equal(first.cov, (a @ b).cov)
    # unscented: propagate.unscented of se2.compose on the 6-D joint input
    uns = rm.compound(a, b, moments="unscented")
    mu = np.concatenate([a.mean, b.mean], axis=-1)
    S = np.zeros((4, 6, 6))
    S[:, :3, :3], S[:, 3:, 3:] = a.cov, b.cov
    direct = unscented(
        lambda x: se2.compose(x[..., :3], x[..., 3:]), mu, S, chart_in=EUCLIDEAN, chart_out=SE2
    )
    np.testing.assert_allclose(uns.cov, direct.cov, atol=1e-14)
    assert_poses_close(uns.mean, direct.mean)
    with pytest.raises(ParameterError, match="moments"):
        rm.compound(a, b, moments="second_order")  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="SE\\(2\\)"):
        rm.compound(rm.AT3.identity(), rm.AT3.identity(), moments="exact")
    with pytest.raises(ShapeError):
        rm.compound(a, b, cross_cov=np.zeros((4, 2, 2)), moments="exact")


def test_compound_chain_dispatches_on_moments():
    rng = np.random.default_rng(19)
    steps = random_ats(rng, (2, 6), scale=0.2, pose_scale=1.0)
    exact = rm.compound_chain(steps, moments="exact")  # default axis -1
    ref = mo.chain_moments(steps.mean, steps.cov, axis=-1)
    np.testing.assert_array_equal(exact.cov, ref.cov)
    # sequential unscented == compounding one step at a time with moments="unscented"
    uns = rm.compound_chain(steps, moments="unscented")
    acc = steps[:, 0]
    for k in range(1, 6):
        acc = rm.compound(acc, steps[:, k], moments="unscented")
        np.testing.assert_allclose(uns.cov[:, k], acc.cov, atol=1e-13)
        assert_poses_close(uns.mean[:, k], acc.mean, atol=1e-13)
    with pytest.raises(ParameterError):
        rm.compound_chain(steps, moments="exactly")  # type: ignore[arg-type]


def test_unscented_schemes_reduce_to_first_order_for_tiny_uncertainty():
    rng = np.random.default_rng(23)
    steps = random_ats(rng, (6,), scale=1e-5, pose_scale=1.0)
    first = rm.compound_chain(steps, axis=0)
    for scheme in ("sequential", "joint"):
        m, C = mo.unscented_chain(steps.mean, steps.cov, axis=0, scheme=scheme)
        assert_poses_close(m, first.mean, atol=1e-8)
        for k in range(6):
            assert _rel(C[k], first.cov[k]) < 1e-5
    with pytest.raises(ParameterError):
        mo.unscented_chain(steps.mean, steps.cov, axis=0, scheme="parallel")  # type: ignore[arg-type]


def test_linearization_error_predicts_the_first_order_error():
    # The straight chain: 20 links of 1 m, σxy 0.05 m; first order measured against
    # 10⁶ samples is off by ≈4% at 3° and ≈44% at 10° per link (docs/studies/moments.py).
    def chain(sd):
        return rm.AT.from_sigmas(
            np.tile([1.0, 0.0, 0.0], (20, 1)), np.tile([0.05, 0.05, np.radians(sd)], (20, 1))
        )

    small, large = mo.linearization_error(chain(3.0)), mo.linearization_error(chain(10.0))
    assert small.cov_rel_error.shape == (20,) and large.mean_error.shape == (20, 3)
    assert 0.03 < small.cov_rel_error[-1] < 0.05
    assert 0.40 < large.cov_rel_error[-1] < 0.48
    assert np.all(np.diff(large.cov_rel_error) > 0)  # grows along the chain
    assert large.cov_rel_error[0] == 0.0  # one link: nothing to linearize
    # The first-order mean is too far along the chain: it ignores E[cos θ] < 1.
    assert large.mean_error[-1, 0] > 0


@pytest.mark.parametrize("chain", [mo.chain_moments, mo.unscented_chain])
def test_a_chains_axis_is_checked_once_for_both_chains(chain):
    """chain_moments and unscented_chain check the axis as compound_chain does
    (relmap.uncertain.pose.chain_batch_axis): a batch axis, an integer in range, one step."""
    m, C = np.zeros((4, 3)), np.broadcast_to(0.01 * np.eye(3), (4, 3, 3))
    with pytest.raises(ShapeError, match="at least one batch axis"):
        chain(m[0], C[0])
    with pytest.raises(ParameterError, match="integer"):
        chain(m, C, axis=0.5)
    with pytest.raises(ParameterError, match="integer"):
        chain(m, C, axis=True)
    with pytest.raises(ShapeError, match="out of range"):
        chain(m, C, axis=1)
    with pytest.raises(ShapeError, match="at least one step"):
        chain(m[:0], C[:0])
    assert chain(m, C, axis=-1).mean.shape == (4, 3)
