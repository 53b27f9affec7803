"""Helpers shared by the tests: numeric comparisons, a valid cross-covariance, the Fig. 3 bridge,
relmap's pose-graph residual as a GTSAM custom factor's error; random poses and ATs are
relmap.sim's (re-exported here under the tests' short names)."""

from __future__ import annotations

import numpy as np

from relmap.lie import se2
from relmap.sim.robots import random_at3s, random_ats, random_poses
from relmap.sim.robots import random_covariances as random_covs

__all__ = [
    "assert_poses_close",
    "fig3_bridge",
    "gtsam_between_error",
    "random_at3s",
    "random_ats",
    "random_covs",
    "random_poses",
    "valid_cross_cov",
    "wrapped",
]


def wrapped(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-π, π) (for comparing headings modulo 2π)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def assert_poses_close(a: np.ndarray, b: np.ndarray, atol: float = 1e-12) -> None:
    """Poses ``(..., 3)`` equal, headings compared modulo 2π."""
    a, b = np.asarray(a), np.asarray(b)
    np.testing.assert_allclose(a[..., :2], b[..., :2], atol=atol, rtol=0)
    np.testing.assert_allclose(wrapped(a[..., 2] - b[..., 2]), 0.0, atol=atol)


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


def fig3_bridge(sigmas=None):  # -> relmap.RelationalMap
    """The Wheatstone bridge of Figs. 3-4 as shipped in ``relmap/data/fig3.json`` (ATs A w→t,
    B w→v, C t→v, D t→u, E u→v); ``sigmas`` ``(σx, σy, σθ)`` replaces every AT's
    standard deviations (the file's are 5 cm, 5 cm, 1°)."""
    from importlib import resources

    import relmap as rm
    from relmap.io.mapfile import read_records

    with resources.as_file(resources.files("relmap") / "data" / "fig3.json") as path:
        records = read_records(path)
    g = rm.RelationalMap()
    for r in records:
        at = r.at if sigmas is None else rm.AT.from_sigmas(r.at.mean, sigmas)
        g.add(r.src, r.dst, at, name=r.name)
    return g


def gtsam_between_error(zk: np.ndarray):
    """The error function of a ``gtsam.CustomFactor`` on two Pose2 keys with relmap's
    residual of the measured AT ``zk`` (``between(a, b) ⊟ zk``, in relmap's chart), its
    Jacobians mapped to GTSAM's right perturbations: GTSAM then minimizes relmap's objective."""

    def error(this, values, H):
        a, b = this.keys()
        pa, pb = values.atPose2(a), values.atPose2(b)
        va = np.array([pa.x(), pa.y(), pa.theta()])
        vb = np.array([pb.x(), pb.y(), pb.theta()])
        d, Ja, Jb = se2.between(va, vb, jacobians=True)
        if H is not None:  # GTSAM perturbs on the right: δ(chart) = M δξ
            H[0] = Ja @ se2.body_to_chart(va)
            H[1] = Jb @ se2.body_to_chart(vb)
        return se2.minus(d, zk)

    return error
