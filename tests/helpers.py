"""Numeric helpers shared by the tests."""

from __future__ import annotations

import numpy as np


def wrapped(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-π, π) (for comparing headings modulo 2π)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def assert_poses_close(a: np.ndarray, b: np.ndarray, atol: float = 1e-12) -> None:
    """Poses ``(..., 3)`` equal, headings compared modulo 2π."""
    a, b = np.asarray(a), np.asarray(b)
    np.testing.assert_allclose(a[..., :2], b[..., :2], atol=atol, rtol=0)
    np.testing.assert_allclose(wrapped(a[..., 2] - b[..., 2]), 0.0, atol=atol)


def random_poses(
    rng: np.random.Generator, shape: tuple[int, ...], scale: float = 3.0
) -> np.ndarray:
    """Random poses ``(*shape, 3)``: translations ~ N(0, scale²), headings uniform."""
    t = rng.normal(scale=scale, size=(*shape, 2))
    th = rng.uniform(-np.pi, np.pi, size=(*shape, 1))
    return np.concatenate([t, th], axis=-1)


def random_covs(
    rng: np.random.Generator, shape: tuple[int, ...], n: int = 3, scale: float = 0.1
) -> np.ndarray:
    """Random SPD covariances ``(*shape, n, n)`` with varied correlations."""
    L = rng.normal(scale=scale, size=(*shape, n, n))
    return L @ np.swapaxes(L, -1, -2) + 1e-4 * scale**2 * np.eye(n)


def valid_cross_cov(
    cov_a: np.ndarray, cov_b: np.ndarray, seed: int, batch: tuple[int, ...] | None = None
) -> np.ndarray:
    """A random cross-covariance ``E[δa δbᵀ] = L_a K L_bᵀ`` (``L Lᵀ = C``, ‖K‖₂ = 0.9) that
    keeps the joint covariance ``[[C_a, X], [Xᵀ, C_b]]`` positive semi-definite, as relmap's
    compound requires; ``batch`` (default: the covariances' broadcast batch shape)."""
    n = cov_a.shape[-1]
    if batch is None:
        batch = np.broadcast_shapes(cov_a.shape[:-2], cov_b.shape[:-2])
    K = np.random.default_rng(seed).normal(size=(*batch, n, n))
    K *= 0.9 / np.linalg.norm(K, ord=2, axis=(-2, -1))[..., None, None]

    def root(C: np.ndarray) -> np.ndarray:
        lam, U = np.linalg.eigh(C)
        return U * np.sqrt(np.clip(lam, 0.0, None))[..., None, :]

    return root(cov_a) @ K @ np.swapaxes(root(cov_b), -1, -2)
