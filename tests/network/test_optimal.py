"""The optimal estimate on real pose graphs, against GTSAM on the same problems."""

from __future__ import annotations

import json
import subprocess
import sys

import gtsam
import numpy as np
import pytest

import relmap as rm
from relmap.io import read_graph, solve_graph, write_graph
from relmap.lie import se2
from tests.helpers import gtsam_between_error


def _gtsam_native(graph, prior: bool = True):
    """GTSAM's own BetweenFactorPose2 graph built from relmap's parse of the file."""
    g = gtsam.NonlinearFactorGraph()
    ids = graph.vertex_ids
    for k in range(len(graph.edge_from)):
        z = gtsam.Pose2(*graph.measurements.mean[k])
        noise = gtsam.noiseModel.Gaussian.Information(np.array(graph.information[k]))
        g.add(gtsam.BetweenFactorPose2(int(graph.edge_from[k]), int(graph.edge_to[k]), z, noise))
    values = gtsam.Values()
    for k, pose in zip(ids.tolist(), graph.poses, strict=True):
        values.insert(k, gtsam.Pose2(*pose))
    if prior:
        g.add(
            gtsam.PriorFactorPose2(
                int(ids[0]), gtsam.Pose2(*graph.poses[0]), gtsam.noiseModel.Isotropic.Sigma(3, 1e-9)
            )
        )
    return g, values


def _values_of(poses, ids):
    values = gtsam.Values()
    for k, pose in zip(ids.tolist(), poses, strict=True):
        values.insert(k, gtsam.Pose2(*pose))
    return values


def _poses_of(values, ids):
    return np.array(
        [
            [values.atPose2(k).x(), values.atPose2(k).y(), values.atPose2(k).theta()]
            for k in ids.tolist()
        ]
    )


def _gtsam_relative(graph_g, result, a: int, b: int) -> rm.AT:
    marginals = gtsam.Marginals(graph_g, result)
    keys = gtsam.KeyVector()
    keys.append(a)
    keys.append(b)
    joint = marginals.jointMarginalCovariance(keys).fullMatrix()
    pa, pb = result.atPose2(a), result.atPose2(b)
    Ha, Hb = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
    d = pa.between(pb, Ha, Hb)
    J = np.hstack([Ha, Hb])
    return rm.AT.from_body([d.x(), d.y(), d.theta()], J @ joint @ J.T)


def test_same_optimum_as_gtsam_with_the_same_residual(data_dir):
    """GTSAM minimizing relmap's own residual (a CustomFactor) from the file's guess: same
    objective (1e-6 relative; measured 4e-15), same poses, same relative AT of the first and
    last pose (means 1e-6 m/rad, covariance 1e-6 relative; measured 1e-8 and 4e-10).

    FR079 (TORO) because GTSAM's Python CustomFactor takes 7 s here (intel: 15 s; MIT: 18 s and
    so ill-conditioned that both optima agree only to 3e-5 m, where the objective is flat to
    1e-13 relative)."""
    graph = read_graph(data_dir / "posegraph2d" / "FR079_P_toro.graph")
    sol = solve_graph(graph, rtol=1e-14)  # to rounding, as GTSAM below
    ids = graph.vertex_ids
    g = gtsam.NonlinearFactorGraph()
    for k in range(len(graph.edge_from)):
        noise = gtsam.noiseModel.Gaussian.Covariance(np.array(graph.measurements.cov[k]))
        keys = [int(graph.edge_from[k]), int(graph.edge_to[k])]
        error = gtsam_between_error(np.array(graph.measurements.mean[k]))
        g.add(gtsam.CustomFactor(noise, keys, error))
    g.add(
        gtsam.PriorFactorPose2(
            int(ids[0]), gtsam.Pose2(*graph.poses[0]), gtsam.noiseModel.Isotropic.Sigma(3, 1e-9)
        )
    )
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(1e-14)
    params.setMaxIterations(100)
    result = gtsam.LevenbergMarquardtOptimizer(g, _values_of(graph.poses, ids), params).optimize()
    assert abs(2 * g.error(result) - sol.final_error) <= 1e-6 * sol.final_error
    np.testing.assert_allclose(se2.minus(_poses_of(result, ids), sol.poses), 0.0, atol=1e-6)
    far = len(ids) - 1
    theirs = _gtsam_relative(g, result, int(ids[0]), int(ids[far]))
    ours = sol.relative(0, far)
    np.testing.assert_allclose(se2.minus(ours.mean, theirs.mean), 0.0, atol=1e-6)
    assert np.linalg.norm(ours.cov - theirs.cov) / np.linalg.norm(theirs.cov) < 1e-6


@pytest.mark.parametrize(
    ("name", "objective_tol", "mean_tol", "cov_tol"),
    [  # measured: objective 2.9e-6, 2.0e-4, 2.0e-3, 1.9e-10, 4.2e-11; means ≤ 4.6e-4; cov ≤ 9.4e-4
        ("intel.g2o", 1e-5, 1e-3, 3e-4),
        ("FR079_P_toro.graph", 1e-3, 2e-3, 2e-3),
        ("CSAIL_P_toro.graph", 1e-2, 5e-4, 3e-3),
        ("manhattanOlson3500.g2o", 1e-8, 5e-5, 1e-3),
        ("city10000.g2o", 1e-8, 2e-5, 4e-3),
    ],
)
def test_same_optimum_as_gtsam_native(data_dir, name, objective_tol, mean_tol, cov_tol):
    """GTSAM's native BetweenFactorPose2 minimizes the SE(2)-log residual, relmap the paper's
    chart residual: the two optima differ at second order in the residuals. So GTSAM's own
    objective at relmap's optimum is within a stated gap of its optimum (tiny on the synthetic
    graphs, up to 2e-3 on the real CSAIL with its large residuals), and the relative AT of the
    first and last pose agrees within the chart differences (tolerances stated per graph)."""
    graph = read_graph(data_dir / "posegraph2d" / name)
    sol = solve_graph(graph)
    g, values = _gtsam_native(graph)
    result = gtsam.LevenbergMarquardtOptimizer(
        g, values, gtsam.LevenbergMarquardtParams()
    ).optimize()
    theirs_at_ours = g.error(_values_of(sol.poses, graph.vertex_ids))
    theirs = g.error(result)
    assert abs(theirs_at_ours - theirs) <= objective_tol * theirs
    ids = graph.vertex_ids
    far = len(ids) - 1
    gt_rel = _gtsam_relative(g, result, int(ids[0]), int(ids[far]))
    ours = sol.relative(0, far)
    assert np.abs(se2.minus(ours.mean, gt_rel.mean)).max() < mean_tol
    assert np.linalg.norm(ours.cov - gt_rel.cov) / np.linalg.norm(gt_rel.cov) < cov_tol


def test_city10000_against_ground_truth(data_dir):
    graph = read_graph(data_dir / "posegraph2d" / "city10000.g2o")
    sol = solve_graph(graph)
    truth = np.loadtxt(data_dir / "posegraph2d" / "city10000_groundtruth.txt")
    err = se2.minus(se2.between(sol.poses[0], sol.poses), se2.between(truth[0], truth))
    rmse = np.sqrt((err[:, :2] ** 2).sum(axis=1).mean())
    assert rmse < 0.1  # measured 0.058 m; the initial guess is off by hundreds of metres
    start = se2.minus(se2.between(graph.poses[0], graph.poses), se2.between(truth[0], truth))
    assert np.sqrt((start[:, :2] ** 2).sum(axis=1).mean()) > 10 * rmse


def test_all_marginals_equal_column_solves(data_dir):
    graph = read_graph(data_dir / "posegraph2d" / "intel.g2o")
    sol = solve_graph(graph)
    all_blocks = sol.marginals()
    assert np.all(all_blocks[0] == 0)
    for k in (1, 500, len(graph.vertex_ids) - 1):
        np.testing.assert_allclose(all_blocks[k], sol.joint_cov([k]), rtol=1e-8, atol=1e-14)


def test_solve_command_writes_the_optimum(data_dir, tmp_path):
    out = tmp_path / "mit_opt.g2o"
    src = data_dir / "posegraph2d" / "MIT.g2o"
    run = subprocess.run(
        [sys.executable, "-m", "relmap.app.cli", "solve", str(src), "--out", str(out), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert set(summary) == {
        "poses",
        "edges",
        "iterations",
        "converged",
        "initial_error",
        "final_error",
        "seconds",
    }
    assert summary["final_error"] < summary["initial_error"] and summary["converged"] is True
    written = read_graph(out)
    sol = solve_graph(read_graph(src))
    np.testing.assert_allclose(se2.minus(written.poses, sol.poses), 0.0, atol=1e-12)
    np.testing.assert_array_equal(written.information, read_graph(src).information)
    again = solve_graph(written)
    assert again.final_error == pytest.approx(sol.final_error, rel=1e-9)


def test_query_command_on_files(data_dir, tmp_path):
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "relmap.app.cli",
            "query",
            str(data_dir / "posegraph2d" / "intel.g2o"),
            "0",
            "1727",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert (
        out["from"] == 0
        and out["to"] == 1727
        and out["method"] == "optimal"
        and out["expression"] is None
    )
    sol = solve_graph(read_graph(data_dir / "posegraph2d" / "intel.g2o"))
    # covariances at the last Gauss-Newton iterate of each solve (anchored differently)
    np.testing.assert_allclose(out["cov"], sol.relative(0, 1727).cov, rtol=1e-6)
    bad = subprocess.run(
        [
            sys.executable,
            "-m",
            "relmap.app.cli",
            "query",
            str(data_dir / "posegraph2d" / "intel.g2o"),
            "0",
            "99999",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert bad.returncode == 2 and "no frame '99999'" in bad.stderr
    write_graph(tmp_path / "copy.g2o", read_graph(data_dir / "posegraph2d" / "MIT.g2o"))
    assert (tmp_path / "copy.g2o").stat().st_size > 0
