"""Trajectory files: real files read as evo reads them, round trips of every format, formats
recognised from content, bad input named by file and line, nothing half-written."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from relmap.errors import FileFormatError, ParameterError
from relmap.evaluate import evaluate
from relmap.io.trajectory import read_trajectory, recognise_trajectory, write_trajectory
from relmap.lie import so3
from relmap.uncertain.trajectory import Trajectory


@pytest.mark.real_data
@pytest.mark.parametrize(
    ("name", "reader"),
    [
        ("KITTI_00_gt.txt", "read_kitti_poses_file"),
        ("KITTI_00_ORB.txt", "read_kitti_poses_file"),
        ("V102.txt", "read_tum_trajectory_file"),
        ("V102_groundtruth.csv", "read_euroc_csv_trajectory"),
        ("freiburg1_xyz-groundtruth.txt", "read_tum_trajectory_file"),
        ("freiburg1_xyz-rgbdslam.txt", "read_tum_trajectory_file"),
    ],
)
def test_real_files_read_like_evo(data_dir, name, reader):  # type: ignore[no-untyped-def]
    fi = pytest.importorskip("evo.tools.file_interface")
    path = data_dir / "trajectories" / name
    theirs = getattr(fi, reader)(path)
    mine = read_trajectory(path)
    assert len(mine) == theirs.num_poses and not mine.has_cov
    np.testing.assert_array_equal(mine.positions, theirs.positions_xyz)
    np.testing.assert_allclose(mine.matrices, np.array(theirs.poses_se3), atol=1e-15)
    if hasattr(theirs, "timestamps"):
        np.testing.assert_array_equal(mine.stamps, theirs.timestamps)
    else:
        assert mine.stamps is None


@pytest.mark.real_data
def test_kitti_times_and_recognition_by_content(data_dir, tmp_path):  # type: ignore[no-untyped-def]
    folder = data_dir / "trajectories"
    gt = read_trajectory(folder / "KITTI_00_gt.txt", times=folder / "KITTI_00_gt_times.txt")
    assert len(gt.stamps) == len(gt) == 4541 and gt.duration > 400
    for name, fmt in [
        ("KITTI_00_ORB.txt", "kitti"),
        ("V102_groundtruth.csv", "euroc"),
        ("V102.txt", "tum"),
        ("ROS_example.bag", "bag"),
        ("nav2_turtlebot.mcap", "bag"),
        ("tf_example", "bag"),
    ]:
        src = folder / name
        if src.is_file():
            copy = tmp_path / f"renamed_{fmt}.dat"
            shutil.copyfile(src, copy)
            assert recognise_trajectory(copy) == fmt
        else:
            assert recognise_trajectory(src) == fmt


def planar(n=20, cov=True):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(1)
    x = np.column_stack(
        [np.cumsum(rng.normal(size=n)), np.cumsum(rng.normal(size=n)), rng.uniform(-3, 3, n)]
    )
    A = rng.normal(size=(n, 3, 3)) * 0.1
    return Trajectory.planar(
        x,
        5.0 + np.arange(n) * 0.1,
        A @ A.transpose(0, 2, 1) if cov else None,
        frame="world",
        child="robot",
    )


def spatial(n=20, cov=True):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(2)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    A = rng.normal(size=(n, 6, 6)) * 0.1
    return Trajectory.from_quaternions(
        rng.normal(size=(n, 3)) * 10,
        q,
        1e9 + np.arange(n) * 0.05,
        A @ A.transpose(0, 2, 1) if cov else None,
        frame="map",
        child="base",
    )


@pytest.mark.parametrize("make", [planar, spatial])
def test_relmap_format_round_trip_exact(tmp_path, make):  # type: ignore[no-untyped-def]
    traj = make()
    path = tmp_path / "t.txt"
    assert write_trajectory(path, traj) == "relmap"
    back = read_trajectory(path)
    assert back.is_planar == traj.is_planar and back.has_cov
    assert (back.frame, back.child) == (traj.frame, traj.child)
    np.testing.assert_array_equal(back.stamps, traj.stamps)
    np.testing.assert_array_equal(
        back.cov, np.triu(traj.cov) + np.swapaxes(np.triu(traj.cov, 1), 1, 2)
    )
    if traj.is_planar:
        np.testing.assert_array_equal(back.poses.mean, traj.poses.mean)
    else:
        np.testing.assert_allclose(back.matrices, traj.matrices, atol=1e-15)


@pytest.mark.parametrize("fmt", ["tum", "kitti", "euroc"])
def test_other_formats_round_trip(tmp_path, fmt):  # type: ignore[no-untyped-def]
    traj = spatial(cov=False)
    path = tmp_path / ("t.csv" if fmt == "euroc" else "t.txt")
    write_trajectory(path, traj, fmt)
    back = read_trajectory(path)
    assert recognise_trajectory(path) == fmt
    np.testing.assert_allclose(back.matrices, traj.matrices, atol=1e-14)
    if fmt == "kitti":
        assert back.stamps is None
    elif fmt == "euroc":
        np.testing.assert_allclose(back.stamps, traj.stamps, atol=1e-6)  # whole nanoseconds
    else:
        np.testing.assert_array_equal(back.stamps, traj.stamps)


@pytest.mark.real_data
def test_g2o_vertices(data_dir):  # type: ignore[no-untyped-def]
    traj = read_trajectory(data_dir / "posegraph2d" / "MIT.g2o")
    assert traj.is_planar and len(traj) == 808 and traj.stamps is None
    traj3 = read_trajectory(data_dir / "posegraph3d" / "smallGrid3D.g2o")
    assert not traj3.is_planar


GOOD = "1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n3.0 2 0 0 0 0 0 1\n"


@pytest.mark.parametrize(
    ("text", "line", "match"),
    [
        (GOOD.replace("3.0 2", "1.5 2"), 3, "must not decrease"),
        (GOOD.replace("2.0 1 0 0 0 0 0 1", "2.0 1 0 0 0 0 0 0"), 2, "quaternion zero"),
        (GOOD.replace("2.0 1 0 0 0 0 0 1", "2.0 1 0 0 0 0 0 2"), 2, "not a unit quaternion"),
        (GOOD.replace("2.0 1 0", "2.0 nan 0"), 2, "not finite"),
        (GOOD + "4.0 3 0 0.5\n", 4, "mixes formats"),
        (GOOD.replace("2.0 1", "2.0 one"), 2, "'one' is not a number"),
        ("# header\n1 0 0 0\n2 1 0 0\n3 1 1\n", 4, "mixes formats"),
        ("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 2 0 0 0 0 1 0\n", 2, "not a rotation"),
        ("1 0 0 0 1 0 0 1 0 -1\n", 1, "positive semi-definite|negative"),
        ("1 0 0 0 1 0 0 1 0 1\n2 0 0 0 -1 0 0 1 0 1\n", 2, "covariance marked unknown"),
    ],
    ids=[
        "stamps-back",
        "zero-quaternion",
        "non-unit",
        "nan",
        "mixed-2d-3d",
        "word",
        "short-row",
        "kitti-rotation",
        "bad-cov",
        "unknown-cov",
    ],
)
def test_bad_files_name_file_and_line(tmp_path, text, line, match):  # type: ignore[no-untyped-def]
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(FileFormatError, match=match) as info:
        read_trajectory(path)
    assert info.value.path == str(path)
    assert info.value.line == line


def test_eval_errors(tmp_path):  # type: ignore[no-untyped-def]
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text(GOOD)
    b.write_text(
        GOOD.replace("1.0 0", "101.0 0").replace("2.0 1", "102.0 1").replace("3.0 2", "103.0 2")
    )
    with pytest.raises(ParameterError, match=r"no time stamps .* match"):
        evaluate(read_trajectory(a), read_trajectory(b))
    c = tmp_path / "c.txt"
    c.write_text("1 0 0 0\n2 1 0 0\n3 2 0 0\n")
    with pytest.raises(ParameterError, match=r"planar.*3-D|3-D.*planar"):
        evaluate(read_trajectory(a), read_trajectory(c))


def test_nothing_half_written(tmp_path):  # type: ignore[no-untyped-def]
    from relmap.app.cli import main

    bad = tmp_path / "bad.txt"
    bad.write_text(GOOD.replace("2.0 1", "2.0 nan"))
    out = tmp_path / "out.txt"
    assert main(["convert", str(bad), str(out)]) == 2
    assert not out.exists() and list(tmp_path.iterdir()) == [bad]
    with pytest.raises(ParameterError, match="folder does not exist"):
        write_trajectory(tmp_path / "no" / "x.txt", spatial())
    with pytest.raises(ParameterError, match="needs time stamps"):
        write_trajectory(tmp_path / "x.txt", Trajectory.from_matrices(np.eye(4)[None]), "tum")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.txt"]


def test_quaternion_rotation_matches_so3():  # type: ignore[no-untyped-def]
    t = spatial(cov=False)
    np.testing.assert_allclose(
        t.matrices[:, :3, :3], so3.from_quaternion(t.poses.quaternion), atol=1e-14
    )


def test_a_bom_and_crlf_read_like_plain_text(tmp_path):  # type: ignore[no-untyped-def]
    """Trajectory files are read by relmap's one text reader (relmap.io.textfile): a UTF-8
    byte-order mark and CRLF line ends give the same trajectory as plain LF text."""
    text = "# t x y z qx qy qz qw\n0 0 0 0 0 0 0 1\n1 1 0.5 0 0 0 0.0998 0.995\n"
    plain, dos = tmp_path / "plain.txt", tmp_path / "dos.txt"
    plain.write_text(text)
    dos.write_bytes(b"\xef\xbb\xbf" + text.replace("\n", "\r\n").encode())
    a, b = read_trajectory(plain), read_trajectory(dos)
    np.testing.assert_array_equal(a.stamps, b.stamps)
    np.testing.assert_array_equal(a.matrices, b.matrices)
