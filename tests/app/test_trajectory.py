"""The ``relmap eval``, ``traj`` and ``convert`` commands, ``localize --out`` and
``solve --out-trajectory``: relmap's own estimates scored by ``relmap eval``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from relmap.app.cli import main
from relmap.io.trajectory import read_trajectory, write_trajectory
from relmap.uncertain.trajectory import Trajectory


def run(capsys, *argv):  # type: ignore[no-untyped-def]
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture
def pair(tmp_path):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(0)
    n = 200
    t = 10 + np.arange(n) * 0.1
    xyz = np.cumsum(rng.normal(size=(n, 3)) * 0.2, axis=0)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    ref = Trajectory.from_quaternions(xyz, q, t)
    C = np.broadcast_to(np.diag([0.01, 0.01, 0.01, 1e-4, 1e-4, 1e-4]), (n, 6, 6))
    noisy = xyz + rng.normal(size=(n, 3)) * 0.1
    from relmap.lie import so3

    M = ref.matrices.copy()
    M[:, :3, 3] = noisy
    M[:, :3, :3] = so3.exp(rng.normal(size=(n, 3)) * 0.01) @ M[:, :3, :3]
    est = Trajectory.from_matrices(M, t + 0.001, C)
    write_trajectory(tmp_path / "ref.txt", ref, "tum")
    write_trajectory(tmp_path / "est.txt", est)
    return tmp_path / "ref.txt", tmp_path / "est.txt"


def test_eval_json_and_text(capsys, pair, tmp_path):  # type: ignore[no-untyped-def]
    ref, est = pair
    code, out, _ = run(capsys, "eval", ref, est, "--rpe", "--delta", "2", "--unit", "m", "--json")
    assert code == 0
    s = json.loads(out)
    assert s["pairs"] == 200 and set(s["ape"]) == {"trans", "angle_deg"} and "rpe" in s
    assert s["consistency"]["verdict"].startswith("consistent")
    code, out, _ = run(
        capsys,
        "eval",
        ref,
        est,
        "--align",
        "se3",
        "--plot",
        tmp_path / "e.png",
        "--report",
        tmp_path / "rep",
    )
    assert code == 0 and "consistency: consistent" in out
    assert (tmp_path / "e.png").stat().st_size > 10_000 and (
        tmp_path / "rep" / "index.html"
    ).is_file()


def test_traj_and_convert(capsys, pair, tmp_path):  # type: ignore[no-untyped-def]
    ref, est = pair
    code, out, _ = run(capsys, "traj", ref, est, "--json", "--plot", tmp_path / "t.png")
    assert code == 0
    a, b = json.loads(out)
    assert a["covariance"] is False and b["covariance"] is True and a["poses"] == 200
    code, out, _ = run(capsys, "convert", est, tmp_path / "e.csv")
    assert code == 0 and "euroc" in out
    back = read_trajectory(tmp_path / "e.csv")
    np.testing.assert_allclose(back.positions, read_trajectory(est).positions, atol=1e-14)


def test_errors_are_one_line(capsys, pair, tmp_path):  # type: ignore[no-untyped-def]
    ref, _ = pair
    far = tmp_path / "far.txt"
    far.write_text("1e6 0 0 0 0 0 0 1\n")
    code, _, err = run(capsys, "eval", ref, far)
    assert code == 2 and err.count("\n") == 1 and "no time stamps" in err
    code, _, err = run(capsys, "eval", ref, tmp_path / "missing.txt")
    assert code == 2 and "no such file" in err


@pytest.mark.real_data
def test_nav2_amcl_against_odometry(capsys, data_dir, tmp_path):  # type: ignore[no-untyped-def]
    bag = data_dir / "trajectories" / "nav2_turtlebot.mcap"
    code, out, _ = run(
        capsys,
        "eval",
        bag,
        bag,
        "--topic",
        "/odom",
        "--topic",
        "/amcl_pose",
        "--align",
        "se3",
        "--t-max-diff",
        "0.05",
        "--json",
        "--plot",
        tmp_path / "nav2.png",
    )
    assert code == 0
    s = json.loads(out)
    assert s["pairs"] > 100 and s["consistency"]["pose"]["anees"] > 0
    assert (tmp_path / "nav2.png").is_file()


@pytest.mark.real_data
@pytest.mark.slow
def test_localize_out_scored_by_eval(capsys, data_dir, tmp_path):  # type: ignore[no-untyped-def]
    """relmap eval of ``localize --out`` (reference interpolated at the filter's times, as
    localize scores) reproduces localize's RMSE and 90% coverage."""
    folder = data_dir / "landmarks" / "mrclam6"
    out_file = tmp_path / "robot1.txt"
    # the noise from robot 2's run (one fit against its ground truth): what is checked here is
    # localize --out read back by eval, whatever the noise; the default calibration is
    # test_localize's (and three times as long)
    code, out, _ = run(
        capsys, "localize", folder, "--robot", "1", "--calibrate", "from-run", "2", "--json",
        "--out", out_file,
    )  # fmt: skip
    assert code == 0
    loc = json.loads(out)
    code, out, _ = run(
        capsys,
        "eval",
        folder / "Robot1_Groundtruth.dat",
        out_file,
        "--interpolate",
        "--relation",
        "trans",
        "--relation",
        "angle_rad",
        "--json",
    )
    assert code == 0
    ev = json.loads(out)
    assert ev["pairs"] == loc["steps"]
    assert abs(ev["ape"]["trans"]["rmse"] - loc["rmse_position"]) < 1e-12
    assert abs(ev["ape"]["angle_rad"]["rmse"] - loc["rmse_heading"]) < 1e-9
    assert ev["consistency"]["position"]["coverage"]["0.9"] == loc["coverage_90"]
    assert abs(ev["consistency"]["pose"]["anees"] - loc["anees"]) < 1e-9


@pytest.mark.real_data
def test_solve_out_trajectory(capsys, data_dir, tmp_path):  # type: ignore[no-untyped-def]
    from relmap.io import read_graph, solve_graph

    graph = data_dir / "posegraph2d" / "MIT.g2o"
    code, _, _ = run(capsys, "solve", graph, "--out-trajectory", tmp_path / "mit.txt")
    assert code == 0
    traj = read_trajectory(tmp_path / "mit.txt")
    sol = solve_graph(read_graph(graph))
    assert traj.is_planar and traj.has_cov and len(traj) == 808
    np.testing.assert_allclose(traj.poses.mean, sol.poses, atol=1e-9)
    np.testing.assert_allclose(traj.cov, sol.marginals(), rtol=1e-6, atol=1e-12)
