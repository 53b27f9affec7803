"""Consistency of covariances: NEES against its definition, verdicts on estimates whose errors
are drawn from known covariances (Monte Carlo), alignment's exact covariance transform, and the
relative-pose NEES of solved pose graphs."""

from __future__ import annotations

import numpy as np
import pytest

from relmap.evaluate import align, consistency, relative_consistency
from relmap.lie import se2, se3
from relmap.uncertain import gaussian
from relmap.uncertain.trajectory import Trajectory


def _covs(rng, n, d, scale):  # type: ignore[no-untyped-def]
    A = rng.normal(size=(n, d, d)) * scale
    return A @ A.transpose(0, 2, 1) + 1e-4 * np.eye(d)


def planar_case(seed, n=3000, claimed=1.0):  # type: ignore[no-untyped-def]
    """Truth, and an estimate = truth ⊟ error, error ~ N(0, C); the estimate claims claimed·C."""
    rng = np.random.default_rng(seed)
    truth = np.column_stack(
        [np.cumsum(rng.normal(size=n)), np.cumsum(rng.normal(size=n)), rng.uniform(-3, 3, n)]
    )
    C = _covs(rng, n, 3, 0.1)
    err = np.einsum("nij,nj->ni", np.linalg.cholesky(C), rng.normal(size=(n, 3)))
    est = truth - err
    est[:, 2] = se2.wrap_angle(est[:, 2])
    t = np.arange(n) * 0.1
    return Trajectory.planar(truth, t), Trajectory.planar(est, t, claimed * C), err, C


def spatial_case(seed, n=3000, claimed=1.0):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    truth = Trajectory.from_quaternions(rng.normal(size=(n, 3)) * 5, q, np.arange(n) * 0.1)
    C = _covs(rng, n, 6, 0.05)
    err = np.einsum("nij,nj->ni", np.linalg.cholesky(C), rng.normal(size=(n, 6)))
    # truth = est ⊞ err  ⇔  est = (t - δt, Exp(-δφ) R)
    est_M = se3.plus(truth.matrices, -err)
    est_M[:, :3, 3] = truth.matrices[:, :3, 3] - err[:, :3]
    from relmap.lie import so3

    est_M[:, :3, :3] = so3.exp(-err[:, 3:]) @ truth.matrices[:, :3, :3]
    return truth, Trajectory.from_matrices(est_M, truth.stamps, claimed * C), err, C


@pytest.mark.parametrize("case", [planar_case, spatial_case])
def test_nees_is_its_definition(case):  # type: ignore[no-untyped-def]
    ref, est, err, C = case(0, n=50)
    c = consistency(ref, est)
    np.testing.assert_allclose(c.errors, err, atol=1e-9)
    direct = np.einsum("ni,ni->n", err, np.linalg.solve(C, err[..., None])[..., 0])
    np.testing.assert_allclose(c.blocks["pose"].values, direct, rtol=1e-8)
    h = err.shape[1] // 2 if err.shape[1] == 6 else 2
    pos = np.einsum("ni,ni->n", err[:, :h], np.linalg.solve(C[:, :h, :h], err[:, :h, None])[..., 0])
    np.testing.assert_allclose(c.blocks["position"].values, pos, rtol=1e-8)


@pytest.mark.parametrize("case", [planar_case, spatial_case])
@pytest.mark.parametrize(
    ("claimed", "verdict"),
    [
        (1.0, "consistent"),
        (0.25, "overconfident by a factor 4"),
        (4.0, "underconfident by a factor 4"),
    ],
)
def test_verdicts_monte_carlo(case, claimed, verdict):  # type: ignore[no-untyped-def]
    ref, est, _, _ = case(1, claimed=claimed)
    c = consistency(ref, est)
    assert c.blocks["pose"].verdict.startswith(verdict.split(" by")[0])
    if claimed != 1.0:
        factor = float(c.blocks["pose"].verdict.split("factor ")[1].split()[0])
        assert abs(factor - 4.0) < 0.3
    else:
        for p, cov in c.blocks["pose"].coverage.items():
            assert abs(cov - p) < 3 * np.sqrt(p * (1 - p) / len(est)) + 0.005
        assert np.all(np.abs(np.nanmean(c.normalized, axis=0)) < 0.08)
        assert np.all(np.abs(np.nanstd(c.normalized, axis=0) - 1) < 0.08)


def test_anees_interval_is_chi2():  # type: ignore[no-untyped-def]
    ref, est, _, _ = planar_case(2, n=100)
    lo, hi = consistency(ref, est).blocks["pose"].interval
    from scipy.stats import chi2

    np.testing.assert_allclose([lo, hi], chi2.ppf([0.025, 0.975], 300) / 300, rtol=1e-10)


def test_singular_covariance_uses_its_rank():  # type: ignore[no-untyped-def]
    """An exactly planar 3-D covariance (AMCL's: nothing in z, roll, pitch) has rank 3."""
    ref, est, _, _ = spatial_case(3, n=20)
    C = np.array(est.poses.cov)
    C[:, [2, 3, 4], :] = 0
    C[:, :, [2, 3, 4]] = 0
    flat_ref = Trajectory.from_matrices(est.matrices, est.stamps)
    c = consistency(flat_ref, Trajectory.from_matrices(est.matrices, est.stamps, C))
    assert np.all(c.blocks["pose"].dof == 3) and np.all(c.blocks["pose"].values == 0)
    assert np.isinf(
        consistency(ref, Trajectory.from_matrices(est.matrices, est.stamps, C))
        .blocks["pose"]
        .values
    ).all()


def test_alignment_moves_covariance_exactly():  # type: ignore[no-untyped-def]
    """After a Sim(3) alignment the NEES is unchanged when the reference moved the same way."""
    ref, est, _, _ = spatial_case(4, n=200)
    rng = np.random.default_rng(4)
    from relmap.lie import so3

    R, t, s = so3.exp(rng.normal(size=3)), rng.normal(size=3), 1.7
    moved = est.matrices.copy()
    moved[:, :3, 3] = (s * moved[:, :3, 3]) @ R.T + t
    moved[:, :3, :3] = R @ moved[:, :3, :3]
    ref_moved = Trajectory.from_matrices(
        np.array(moved), est.stamps
    )  # a reference in another frame
    aligned, a = align(est, ref_moved, "sim3")
    assert abs(a.scale - s) < 1e-9
    # the aligned estimate's covariance is the moved one: B C Bᵀ, B = blkdiag(sR, R)
    B = np.zeros((6, 6))
    B[:3, :3], B[3:, 3:] = s * R, R
    np.testing.assert_allclose(aligned.poses.cov, B @ est.poses.cov @ B.T, atol=1e-10)
    before = consistency(ref, est).blocks["pose"].values
    ref2 = Trajectory.from_matrices(_moved(ref.matrices, R, t, s), ref.stamps)
    after = consistency(ref2, aligned).blocks["pose"].values
    np.testing.assert_allclose(after, before, rtol=1e-6)


def _moved(M, R, t, s):  # type: ignore[no-untyped-def]
    out = M.copy()
    out[:, :3, 3] = (s * out[:, :3, 3]) @ R.T + t
    out[:, :3, :3] = R @ out[:, :3, :3]
    return out


def _graph_text(truth, rng, sigma, loops):  # type: ignore[no-untyped-def]
    info = f"{1 / sigma[0] ** 2} 0 0 {1 / sigma[0] ** 2} 0 {1 / sigma[1] ** 2}"
    lines = [f"VERTEX_SE2 {k} {x} {y} {th}" for k, (x, y, th) in enumerate(truth)]
    for i, j in [(k, k + 1) for k in range(len(truth) - 1)] + loops:
        z = se2.between(truth[i], truth[j])
        z = z + rng.normal(size=3) * [sigma[0], sigma[0], sigma[1]]
        lines.append(f"EDGE_SE2 {i} {j} {z[0]} {z[1]} {z[2]} {info}")
    return "\n".join(lines) + "\n"


@pytest.mark.slow
def test_relative_pose_nees_of_solved_graphs(tmp_path):  # type: ignore[no-untyped-def]
    """Many noisy solves of one small graph: the relative-pose NEES from the joint covariance
    averages its dof (isotropic noise, so g2o's body-frame information is the paper's too)."""
    from relmap.io import read_graph, solve_graph

    rng = np.random.default_rng(5)
    n = 12
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    truth = np.column_stack([5 * np.cos(th), 5 * np.sin(th), se2.wrap_angle(th + np.pi / 2)])
    values = []
    for run in range(60):
        path = tmp_path / f"g{run}.g2o"
        path.write_text(_graph_text(truth, rng, (0.02, 0.01), [(0, n - 1), (2, 8)]))
        sol = solve_graph(read_graph(path))
        values.append(
            relative_consistency(sol, truth, np.array([1, 3, 4]), np.array([6, 9, 11])).values
        )
    v = np.concatenate(values)
    anees = v.mean() / 3
    lo, hi = (gaussian.confidence_k2(p, 3 * len(v)) / (3 * len(v)) for p in (0.005, 0.995))
    assert lo < anees < hi, anees
