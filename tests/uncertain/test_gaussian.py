"""relmap.uncertain.gaussian: validation, confidence regions (Appendix A corrected), ellipses,
sampling."""

from __future__ import annotations

import math

import numpy as np
import pytest

from relmap.errors import (
    NonFiniteError,
    NotPositiveSemidefiniteError,
    NotSymmetricError,
    ParameterError,
    ShapeError,
)
from relmap.uncertain import gaussian
from tests.helpers import random_covs

RNG = np.random.default_rng(7)


def Phi(x: float) -> float:
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))


# ----------------------------------------------------------------- confidence k
@pytest.mark.parametrize("k", [0.1, 0.5, 1.0, 1.5, 2.0, 3.0, 4.5])
def test_probability_inside_closed_forms(k):
    """Appendix A as it should read.

    N=1: erf(k/√2); N=2: 1 - e^{-k²/2}; N=3: erf(k/√2) - √(2/π)·k·e^{-k²/2}.
    """
    assert gaussian.probability_inside(k, 1) == pytest.approx(math.erf(k / math.sqrt(2)), abs=1e-14)
    assert gaussian.probability_inside(k, 1) == pytest.approx(2 * Phi(k) - 1, abs=1e-14)
    assert gaussian.probability_inside(k, 2) == pytest.approx(1 - math.exp(-k * k / 2), abs=1e-14)
    p3 = math.erf(k / math.sqrt(2)) - math.sqrt(2 / math.pi) * k * math.exp(-k * k / 2)
    assert gaussian.probability_inside(k, 3) == pytest.approx(p3, abs=1e-14)


def test_confidence_k2_matches_paper_values():
    assert gaussian.confidence_k2(0.5, 2) == pytest.approx(1.386, abs=5e-4)
    assert gaussian.confidence_k2(0.9, 2) == pytest.approx(4.605, abs=5e-4)
    assert gaussian.confidence_k2(0.9, 2) == pytest.approx(-2 * math.log(0.1), rel=1e-13)


def test_planar_k2_closed_form_equals_chi2_quantile():
    from scipy.special import gammaincinv

    p = np.array([1e-12, 0.01, 0.5, 0.9, 0.99, 1 - 1e-12])
    np.testing.assert_allclose(gaussian.confidence_k2(p, 2), 2 * gammaincinv(1.0, p), rtol=1e-12)


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 6, 9])
def test_k2_and_probability_are_inverse(dof):
    p = np.array([0.01, 0.5, 0.9, 0.99, 0.999999])
    k = np.sqrt(gaussian.confidence_k2(p, dof))
    np.testing.assert_allclose(gaussian.probability_inside(k, dof), p, rtol=1e-12)


@pytest.mark.parametrize("dof", [1, 2, 3, 5])
def test_probability_inside_monte_carlo(dof):
    n = 400_000
    z = RNG.standard_normal((n, dof))
    d2 = (z * z).sum(axis=1)
    for p in (0.5, 0.9, 0.99):
        frac = (d2 <= gaussian.confidence_k2(p, dof)).mean()
        assert abs(frac - p) < 5 * math.sqrt(p * (1 - p) / n)


@pytest.mark.parametrize("bad", [0.0, 1.0, -0.1, 1.5, float("nan")])
def test_probability_outside_open_interval_raises(bad):
    with pytest.raises(ParameterError, match="between 0 and 1"):
        gaussian.confidence_k2(bad, 2)


def test_bad_dof_and_k():
    with pytest.raises(ParameterError):
        gaussian.confidence_k2(0.9, 0)
    with pytest.raises(ParameterError):
        gaussian.probability_inside(-1.0, 2)


# ---------------------------------------------------------------------- ellipse
def test_ellipse_axes_and_angle_against_eigendecomposition():
    covs = random_covs(RNG, (200,), n=2)
    e = gaussian.ellipse(np.zeros((200, 2)), covs, 0.9)
    lam, U = np.linalg.eigh(covs)
    k = math.sqrt(-2 * math.log(0.1))
    np.testing.assert_allclose(e.semi_major, k * np.sqrt(lam[:, 1]), rtol=1e-10)
    np.testing.assert_allclose(e.semi_minor, k * np.sqrt(lam[:, 0]), rtol=1e-7)
    major = U[:, :, 1]
    direction = np.stack([np.cos(e.angle), np.sin(e.angle)], axis=-1)
    np.testing.assert_allclose(np.abs((major * direction).sum(-1)), 1.0, atol=1e-10)
    assert np.all(e.angle > -np.pi / 2) and np.all(e.angle <= np.pi / 2)


def test_ellipse_angle_when_sigma_y_exceeds_sigma_x():
    """The printed ½·arctan(2B/(A-C)) would give the minor axis here; relmap gives the major."""
    cov = np.array([[1.0, 0.3], [0.3, 4.0]])
    e = gaussian.ellipse([0, 0], cov)
    _, U = np.linalg.eigh(cov)
    assert abs(np.cos(e.angle) * U[0, 1] + np.sin(e.angle) * U[1, 1]) == pytest.approx(1.0)
    printed = 0.5 * math.atan(2 * 0.3 / (1.0 - 4.0))
    assert abs(math.cos(printed) * U[0, 1] + math.sin(printed) * U[1, 1]) < 0.2


def test_ellipse_boundary_lies_on_k_contour():
    cov = np.array([[0.04, 0.01], [0.01, 0.02]])
    mean = np.array([1.0, -2.0])
    e = gaussian.ellipse(mean, cov, 0.5)
    pts = e.boundary(64)
    d2 = gaussian.mahalanobis2(pts, mean, cov)
    np.testing.assert_allclose(d2, gaussian.confidence_k2(0.5, 2), rtol=1e-10)
    np.testing.assert_allclose(pts[0], pts[-1])


def test_ellipse_of_degenerate_covariance():
    e = gaussian.ellipse([0, 0], np.zeros((2, 2)))
    assert e.semi_major == 0 and e.semi_minor == 0


# -------------------------------------------------------------------- validation
def test_validate_accepts_and_symmetrizes():
    c = random_covs(RNG, (4, 2))
    c[..., 0, 1] += 1e-13 * np.abs(c).max()
    out = gaussian.validate_covariance(c, dim=3)
    np.testing.assert_array_equal(out, np.swapaxes(out, -1, -2))
    assert out is not c


def test_validate_zero_and_exact_components():
    gaussian.validate_covariance(np.zeros((3, 3)))
    gaussian.validate_covariance(np.diag([0.1, 0.2, 0.0]))
    gaussian.validate_covariance(np.diag([1e12, 1e-12, 1.0]))  # units do not decide


def test_validate_is_scale_free_for_near_singular():
    """A perfectly correlated pair is PSD at any scale; a slightly over-correlated one is not."""
    for s in (1e-6, 1.0, 1e6):
        ok = np.array([[s * s, s], [s, 1.0]])
        gaussian.validate_covariance(ok)
        bad = np.array([[s * s, 1.001 * s], [1.001 * s, 1.0]])
        with pytest.raises(NotPositiveSemidefiniteError):
            gaussian.validate_covariance(bad)


@pytest.mark.parametrize(
    ("cov", "error", "match"),
    [
        (np.zeros((3, 2)), ShapeError, "shape"),
        (np.zeros(3), ShapeError, "shape"),
        (np.array([[1.0, np.nan], [np.nan, 1.0]]), NonFiniteError, r"\[0, 1\]"),
        (np.array([[1.0, 0.5], [0.4, 1.0]]), NotSymmetricError, "not symmetric"),
        (np.array([[1.0, 0.0], [0.0, -1e-3]]), NotPositiveSemidefiniteError, "negative variance"),
        (np.array([[1.0, 2.0], [2.0, 1.0]]), NotPositiveSemidefiniteError, "smallest eigenvalue"),
        (
            np.array([[0.0, 0.1], [0.1, 1.0]]),
            NotPositiveSemidefiniteError,
            "positive semi-definite",
        ),
    ],
)
def test_validate_rejects(cov, error, match):
    with pytest.raises(error, match=match):
        gaussian.validate_covariance(cov)


def test_validate_names_the_batch_element():
    c = random_covs(RNG, (3, 4), n=2)
    c[2, 1] = [[1.0, 3.0], [3.0, 1.0]]
    with pytest.raises(NotPositiveSemidefiniteError, match=r"cov\[2, 1\]"):
        gaussian.validate_covariance(c)


def test_validate_wrong_dim():
    with pytest.raises(ShapeError, match=r"3, 3"):
        gaussian.validate_covariance(np.eye(2), dim=3)


# ------------------------------------------------------- generalized inverse, Mahalanobis
def test_generalized_inverse_invertible_and_singular():
    c = random_covs(RNG, (10,))
    G, null = gaussian.generalized_inverse(c)
    np.testing.assert_allclose(G @ c, np.broadcast_to(np.eye(3), c.shape), atol=1e-8)
    np.testing.assert_array_equal(null, 0.0)
    s = np.diag([2.0, 0.0, 1e-20])  # an exact direction and a tiny-but-real variance
    G, null = gaussian.generalized_inverse(s)
    np.testing.assert_allclose(s @ G @ s, s, atol=1e-30)
    assert G[2, 2] == pytest.approx(1e20)
    np.testing.assert_allclose(
        np.abs(null[:, 0]) + np.abs(null[:, 1]) + np.abs(null[:, 2]), [0, 1, 0]
    )


def test_generalized_inverse_null_space_of_correlated_matrix():
    """Perfectly correlated x and y: the null direction is (1, -1)/√2 in x, y (scale 1)."""
    s = np.array([[4.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]])  # x = 2y exactly
    G, null = gaussian.generalized_inverse(s)
    np.testing.assert_allclose(s @ G @ s, s, atol=1e-14)
    direction = null[:, np.abs(null).sum(0) > 0][:, 0]
    np.testing.assert_allclose(
        np.abs(direction), np.array([1.0, 2.0, 0.0]) / np.sqrt(5), atol=1e-12
    )


def test_mahalanobis_regular_and_singular():
    cov = np.array([[4.0, 0.0], [0.0, 1.0]])
    assert gaussian.mahalanobis2([2.0, 1.0], [0.0, 0.0], cov) == pytest.approx(2.0)
    sing = np.diag([1.0, 0.0])
    assert gaussian.mahalanobis2([3.0, 0.0], [0.0, 0.0], sing) == pytest.approx(9.0)
    assert gaussian.mahalanobis2([3.0, 0.1], [0.0, 0.0], sing) == np.inf
    with pytest.raises(NonFiniteError):
        gaussian.mahalanobis2([np.nan, 0.0], [0.0, 0.0], cov)


# ----------------------------------------------------------------------- sampling
def test_sample_moments_and_singular():
    cov = np.array([[1.0, 0.5, 0.0], [0.5, 2.0, 0.0], [0.0, 0.0, 0.0]])
    n = 200_000
    x = gaussian.sample([1.0, 2.0, 3.0], cov, n, seed=3)
    assert x.shape == (n, 3)
    np.testing.assert_array_equal(x[:, 2], 3.0)
    np.testing.assert_allclose(x.mean(0), [1, 2, 3], atol=5 * math.sqrt(2 / n))
    np.testing.assert_allclose(np.cov(x.T), cov, atol=5 * math.sqrt(2 * 4 / n))


def test_sample_is_reproducible_and_batched():
    covs = random_covs(RNG, (2, 3))
    a = gaussian.sample(np.zeros(3), covs, 5, seed=11)
    b = gaussian.sample(np.zeros(3), covs, 5, seed=11)
    assert a.shape == (5, 2, 3, 3)
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ParameterError):
        gaussian.sample(np.zeros(3), covs, 0)


def test_sqrt_psd():
    c = random_covs(RNG, (6,))
    L = gaussian.sqrt_psd(c)
    np.testing.assert_allclose(L @ np.swapaxes(L, -1, -2), c, atol=1e-14)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 6])
def test_inverse_pd_equals_lapack_on_badly_scaled_matrices(n):
    rng = np.random.default_rng(n)
    A = rng.normal(size=(500, n, n))
    C = A @ np.swapaxes(A, -1, -2) + 1e-3 * np.eye(n)
    scale = 10.0 ** rng.uniform(-6, 6, size=(500, n))
    C = C * scale[:, :, None] * scale[:, None, :]  # units from µm² to km²
    inv = gaussian.inverse_pd(C)
    np.testing.assert_array_equal(inv, np.swapaxes(inv, -1, -2))
    # the inverse of the correlation matrix, unscaled: compare in that frame
    s = scale
    unit = inv * s[:, :, None] * s[:, None, :]
    ref = np.linalg.inv(C / (s[:, :, None] * s[:, None, :]))
    cond = np.linalg.cond(C / (s[:, :, None] * s[:, None, :]))
    err = np.abs(unit - ref).max(axis=(1, 2)) / np.abs(ref).max(axis=(1, 2))
    assert (err <= 50 * cond * np.finfo(float).eps).all()
    assert gaussian.inverse_pd(C[0]).shape == (n, n)


@pytest.mark.parametrize("n", [2, 3, 6])
def test_not_positive_definite_against_the_eigenvalues(n):
    """The verdict is the plain statement: a positive diagonal and every eigenvalue of the
    correlation matrix above the margin; the offender is the first in batch order, whatever
    the units."""
    rng = np.random.default_rng(10 + n)
    U = np.linalg.qr(rng.normal(size=(4, 5, n, n)))[0]
    lam = rng.uniform(0.5, 2.0, size=(4, 5, n))
    assert gaussian.not_positive_definite(U * lam[..., None, :] @ np.swapaxes(U, -1, -2)) is None
    lam[2, 3, 0] = 0.0  # singular: 0 <= margin
    C = U * lam[..., None, :] @ np.swapaxes(U, -1, -2)
    C[3, 1] = np.eye(n)
    C[3, 1, 0, 1] = C[3, 1, 1, 0] = 1.5  # indefinite (eigenvalue -0.5), later in batch order
    scale = 10.0 ** rng.uniform(-4, 4, size=(4, 5, n))
    C = C * scale[..., :, None] * scale[..., None, :]
    index, reason = gaussian.not_positive_definite(C)
    assert index == (2, 3) and reason.startswith(" (singular): ")
    d = np.sqrt(np.diagonal(C[2, 3]))
    lowest = np.linalg.eigvalsh(C[2, 3] / np.outer(d, d))[0]
    assert f"is {lowest:.3g} (must exceed {gaussian.DEFINITE_TOL:g})" in reason
    C[2, 3] = np.eye(n)
    index, reason = gaussian.not_positive_definite(C)
    assert index == (3, 1) and reason.startswith(" (indefinite): ")
    C[0, 4, 1, 1] = 0.0
    assert gaussian.not_positive_definite(C) == ((0, 4), ": a diagonal entry is not positive")
    assert gaussian.not_positive_definite(np.eye(n)) is None
    near = np.eye(n)
    near[0, 1] = near[1, 0] = 1.0 - 0.5 * gaussian.DEFINITE_TOL  # eigenvalue 0.5·tol: refused
    assert gaussian.not_positive_definite(near) is not None
    near[0, 1] = near[1, 0] = 1.0 - 2.0 * gaussian.DEFINITE_TOL  # 2·tol: accepted
    assert gaussian.not_positive_definite(near) is None


@pytest.mark.parametrize("k", [2, 3, 4])
def test_difference_merge_gain_is_the_generalized_least_squares_merge(rng, k):
    """x̂ = z₁ - K d and C = C₁ - K Xᵀ are the GLS estimate of one vector measured k times
    with correlated errors: C = (Aᵀ Σ⁻¹ A)⁻¹, x̂ = C Aᵀ Σ⁻¹ z, A = [I; …; I] (batched)."""
    b = 3
    joint = random_covs(rng, (5,), n=b * k)
    z = rng.normal(size=(5, k, b))
    K, X, null = gaussian.difference_merge_gain(joint, b, k)
    assert K.shape == X.shape == (5, b, b * (k - 1))
    assert not null.any()
    d = (z[:, 1:] - z[:, :1]).reshape(5, b * (k - 1))
    mean = z[:, 0] - np.einsum("...ij,...j->...i", K, d)
    cov = joint[:, :b, :b] - K @ np.swapaxes(X, -1, -2)
    A = np.tile(np.eye(b), (k, 1))
    info = A.T @ np.linalg.inv(joint) @ A
    gls_cov = np.linalg.inv(info)
    gls_mean = np.einsum(
        "...ij,...j->...i", gls_cov @ A.T @ np.linalg.inv(joint), z.reshape(5, b * k)
    )
    np.testing.assert_allclose(cov, gls_cov, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(mean, gls_mean, rtol=1e-8, atol=1e-10)


def test_difference_merge_gain_finds_an_exactly_known_difference():
    """Two estimates both exact along x: their difference's x is exactly known (Cov(d) has a
    null direction), which check_agreement then tests."""
    joint = np.diag([0.0, 1.0, 0.0, 2.0])
    _, _, null = gaussian.difference_merge_gain(joint, 2, 2)
    np.testing.assert_allclose(np.abs(null[:, 0]), [1.0, 0.0])
    assert not null[:, 1].any()
