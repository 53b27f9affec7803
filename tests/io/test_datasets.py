"""relmap.io.datasets: the UTIAS MRCLAM and CMU Plaza readers, on the real data and broken files."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from relmap.errors import FileFormatError, NonFiniteError, ParameterError
from relmap.io import Mrclam, Plaza, RobotLog, read_mrclam, read_plaza, recognise
from relmap.lie import se2

KINDS = ("Odometry", "Groundtruth", "Measurement")


@pytest.fixture(scope="module")
def mrclam_dir(data_dir):
    return data_dir / "landmarks" / "mrclam6"


@pytest.fixture(scope="module")
def plaza_dir(data_dir):
    return data_dir / "landmarks" / "plaza2"


@pytest.fixture(scope="module")
def mrclam(mrclam_dir) -> Mrclam:
    return read_mrclam(mrclam_dir)


@pytest.fixture(scope="module")
def plaza(plaza_dir) -> Plaza:
    return read_plaza(plaza_dir)


def _records(path):
    """Data lines of a file: every non-blank line that is not a '#' comment."""
    return [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]


def _angles_close(a, b, atol):
    return np.all(np.abs(se2.angle_difference(a, b)) <= atol)


# ------------------------------------------------------------------------------ MRCLAM
@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_mrclam_record_counts_match_the_files(mrclam, mrclam_dir, n):
    log = mrclam.robots[n - 1]
    assert log.robot == n
    odo, gt, meas = (len(_records(mrclam_dir / f"Robot{n}_{kind}.dat")) for kind in KINDS)
    assert odo > 50_000 and gt > 40_000 and meas > 1_000  # the counting itself is not vacuous
    assert log.odometry_t.shape == log.odometry_v.shape == log.odometry_w.shape == (odo,)
    assert log.truth_t.shape == (gt,) and log.truth.shape == (gt, 3)
    for arr in (log.meas_t, log.meas_barcode, log.meas_subject, log.meas_range, log.meas_bearing):
        assert arr.shape == (meas,)
    assert log.meas_barcode.dtype == log.meas_subject.dtype == np.int64
    assert not log.truth.flags.writeable and not log.meas_subject.flags.writeable
    # first and last records as written
    first = np.array(_records(mrclam_dir / f"Robot{n}_Odometry.dat")[0].split(), dtype=float)
    np.testing.assert_array_equal([log.odometry_t[0], log.odometry_v[0], log.odometry_w[0]], first)
    last = np.array(_records(mrclam_dir / f"Robot{n}_Groundtruth.dat")[-1].split(), dtype=float)
    np.testing.assert_array_equal(log.truth[-1, :2], last[1:3])
    assert _angles_close(log.truth[-1, 2], last[3], 1e-12)


def test_mrclam_barcode_table_matches_readme(mrclam):
    np.testing.assert_array_equal(mrclam.subjects, np.arange(1, 21))  # 1-5 robots, 6-20 landmarks
    assert len(np.unique(mrclam.barcodes)) == 20
    np.testing.assert_array_equal(mrclam.landmark_ids, np.arange(6, 21))  # 15 landmarks
    assert mrclam.landmark_xy.shape == mrclam.landmark_sigma.shape == (15, 2)
    assert np.all(mrclam.landmark_sigma > 0) and np.all(mrclam.landmark_sigma < 1e-3)
    np.testing.assert_array_equal(mrclam.landmark_index([6, 20, 3, -1, 99]), [0, 14, -1, -1, -1])
    np.testing.assert_allclose(mrclam.landmark_xy[0], [0.58831396, -4.28264845], rtol=0, atol=0)


def test_mrclam_measurements_map_barcodes_to_landmarks_only(mrclam):
    table = dict(zip(mrclam.barcodes.tolist(), mrclam.subjects.tolist(), strict=True))
    robot_barcodes = set(mrclam.barcodes[:5].tolist())
    unknown = []
    for log in mrclam.robots:
        for barcode, subject in zip(
            log.meas_barcode.tolist(), log.meas_subject.tolist(), strict=True
        ):
            if barcode in robot_barcodes or barcode not in table:
                assert subject == -1
            else:
                assert subject == table[barcode] and 6 <= subject <= 20
        of_robots = np.isin(log.meas_barcode, list(robot_barcodes))
        assert of_robots.sum() > 0 and np.all(log.meas_subject[of_robots] == -1)
        unknown.append(log.n_unknown_barcodes)
        assert log.n_unknown_barcodes == sum(b not in table for b in log.meas_barcode.tolist())
    assert unknown == [1, 0, 2, 3, 0]  # barcodes 43, 34 (twice) and 50 (three times)


def test_mrclam_times_are_ordered_and_headings_wrapped(mrclam):
    for log in mrclam.robots:
        for t in (log.odometry_t, log.truth_t, log.meas_t):
            assert np.all(np.isfinite(t)) and np.all(np.diff(t) >= 0)
        assert np.all((log.truth[:, 2] >= -np.pi) & (log.truth[:, 2] < np.pi))
        assert np.all(log.meas_range > 0)
    # the real files repeat times: many measurements per instant, a few odometry records
    assert np.count_nonzero(np.diff(mrclam.robots[0].meas_t) == 0) > 100
    assert sum(np.count_nonzero(np.diff(r.odometry_t) == 0) for r in mrclam.robots) == 23


def test_mrclam_measurement_noise_against_ground_truth(mrclam):
    log = mrclam.robots[0]
    rows = mrclam.landmark_index(log.meas_subject)
    seen = rows >= 0
    assert seen.sum() > 1000
    pose = log.truth_at(log.meas_t[seen])
    d = mrclam.landmark_xy[rows[seen]] - pose[:, :2]
    predicted_range = np.hypot(d[:, 0], d[:, 1])
    predicted_bearing = se2.angle_difference(np.arctan2(d[:, 1], d[:, 0]), pose[:, 2])
    range_error = np.median(np.abs(log.meas_range[seen] - predicted_range))
    bearing_error = np.median(
        np.abs(se2.angle_difference(log.meas_bearing[seen], predicted_bearing))
    )
    assert range_error < 0.3  # measured: 0.067 m
    assert bearing_error < 0.1  # measured: 0.0073 rad


def _log(t, poses) -> RobotLog:
    empty = np.empty(0)
    none = np.empty(0, dtype=np.int64)
    return RobotLog(1, empty, empty, empty, np.asarray(t, float), np.asarray(poses, float),
                    empty, none, none, empty, empty, 0)  # fmt: skip


def test_truth_at_interpolates_on_the_short_arc_and_refuses_outside_the_span():
    log = _log([0.0, 1.0, 1.0, 3.0], [[0, 0, 3.0], [2, 4, -3.0], [2, 4, -3.0], [4, 0, -1.0]])
    out = log.truth_at([[0.0, 0.5], [1.0, 3.0]])
    assert out.shape == (2, 2, 3)
    np.testing.assert_allclose(out[0, 0], [0, 0, 3.0])
    # halfway from 3.0 to -3.0 the short way round: through ±π, not through 0
    np.testing.assert_allclose(out[0, 1, :2], [1, 2])
    assert _angles_close(out[0, 1, 2], np.pi, 1e-12)
    np.testing.assert_allclose(out[1], [[2, 4, -3.0], [4, 0, -1.0]])
    np.testing.assert_allclose(log.truth_at(2.0), [3, 2, -2.0])  # after a repeated time
    assert np.all(np.isfinite(log.truth_at(np.linspace(0, 3, 101))))
    with pytest.raises(ParameterError, match="outside the span"):
        log.truth_at([0.5, 3.5])
    with pytest.raises(ParameterError, match="outside the span"):
        log.truth_at(-1e-9)
    with pytest.raises(NonFiniteError):
        log.truth_at([0.5, np.nan])


def test_truth_at_matches_the_records_on_real_data(mrclam):
    log = mrclam.robots[3]
    k = np.arange(0, len(log.truth_t), 997)
    np.testing.assert_allclose(log.truth_at(log.truth_t[k])[:, :2], log.truth[k, :2], atol=1e-12)
    assert _angles_close(log.truth_at(log.truth_t[k])[:, 2], log.truth[k, 2], 1e-12)


# ------------------------------------------------------------------------------- Plaza
def test_plaza_loads_with_file_counts(plaza, plaza_dir):
    n = len(_records(plaza_dir / "Plaza2_DR.txt"))
    p = len(_records(plaza_dir / "Plaza2_TD.txt"))
    assert (n, p) == (4090, 1816)
    assert plaza.dr_t.shape == plaza.dr_distance.shape == plaza.dr_dheading.shape == (n,)
    assert plaza.dr_pose.shape == (n + 1, 3) and plaza.truth.shape == (n + 1, 3)
    np.testing.assert_array_equal(plaza.dr_pose_t[1:], plaza.dr_t)  # DR t is the step's end
    assert plaza.meas_t.shape == plaza.meas_range.shape == (p,)
    np.testing.assert_array_equal(np.sort(plaza.beacon_ids), [0, 1, 5, 6])
    assert plaza.n_unknown_beacons == 0
    np.testing.assert_array_equal(plaza.beacon_ids[plaza.meas_beacon_index], plaza.meas_beacon)
    np.testing.assert_array_equal(np.unique(plaza.meas_sender), [2])
    assert not plaza.truth.flags.writeable


def test_plaza_corrected_heading_follows_the_direction_of_travel(plaza):
    step = np.diff(plaza.truth[:, :2], axis=0)
    moving = np.hypot(step[:, 0], step[:, 1]) > 0.02  # > 0.2 m/s at 10 Hz
    assert moving.sum() > 3000
    travel = np.arctan2(step[:, 1], step[:, 0])[moving]
    theta = plaza.truth[:, 2]
    heading = se2.wrap_angle(theta[:-1] + 0.5 * se2.angle_difference(theta[1:], theta[:-1]))
    off = np.abs(se2.angle_difference(travel, heading[moving]))
    assert np.median(off) < 0.3  # measured: 0.018 rad
    assert np.mean(off > np.pi / 2) < 0.01  # only the robot's short reversing at the very end
    raw = plaza.truth_raw_heading[:-1][moving]
    assert np.median(np.abs(se2.angle_difference(travel, raw))) > 3.0  # the file's θ: backwards
    assert _angles_close(plaza.truth[:, 2], plaza.truth_raw_heading + np.pi, 1e-12)
    assert _angles_close(plaza.truth[0], plaza.dr_pose[0], 1e-12)  # DRp starts at GT, turned


def test_plaza_midpoint_dead_reckoning_reproduces_drp(plaza):
    path = plaza.dead_reckoning()
    assert path.shape == plaza.dr_pose.shape
    assert _angles_close(path[:, 2], plaza.dr_pose[:, 2], 1e-9)  # the headings: exactly
    position_error = np.hypot(*(path[:, :2] - plaza.dr_pose[:, :2]).T)
    assert position_error.max() < 0.07  # measured 0.063 m over a 1.35 km run
    # step by step from DRp's own poses: a fraction of a millimetre (DRp's steps are not
    # exactly midpoint ones; the worst, 15 mm, is a 0.35 s gap turning 1.24 rad)
    heading = plaza.dr_pose[:-1, 2] + 0.5 * plaza.dr_dheading
    step = plaza.dr_pose[:-1, :2] + plaza.dr_distance[:, None] * _unit(heading)
    assert np.median(np.hypot(*(step - plaza.dr_pose[1:, :2]).T)) < 5e-4  # measured 0.2 mm
    # the rule matters: the heading at the start or at the end of each step is far worse
    turn = np.concatenate([[0.0], np.cumsum(plaza.dr_dheading)]) + plaza.dr_pose[0, 2]
    for heading in (turn[:-1], turn[1:]):
        xy = plaza.dr_pose[0, :2] + np.concatenate(
            [[[0.0, 0.0]], np.cumsum(plaza.dr_distance[:, None] * _unit(heading), axis=0)]
        )
        assert np.hypot(*(xy - plaza.dr_pose[:, :2]).T).max() > 0.3
    shifted = plaza.dead_reckoning(start=[1.0, 2.0, 0.5])
    np.testing.assert_allclose(shifted[0], [1.0, 2.0, 0.5])
    with pytest.raises(ParameterError):
        plaza.dead_reckoning(start=[1.0, 2.0])


def _unit(angle):
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1)


# ---------------------------------------------------------------------------- recognise
def test_recognise_by_files_present(mrclam_dir, plaza_dir, tmp_path):
    assert recognise(mrclam_dir) == "mrclam"
    assert recognise(plaza_dir) == "plaza"
    assert recognise(tmp_path) is None
    assert recognise(mrclam_dir.parent) is None
    assert recognise(tmp_path / "absent") is None
    assert recognise(mrclam_dir / "Barcodes.dat") is None
    _write_mrclam(tmp_path / "renamed")  # a folder is recognised by its files, not its name
    assert recognise(tmp_path / "renamed") == "mrclam"
    _write_plaza(tmp_path / "renamed")
    with pytest.raises(FileFormatError, match="both"):
        recognise(tmp_path / "renamed")


# --------------------------------------------------------------------- malformed files
HEADER = "# UTIAS\n# by\n# Format:\n# columns\n"
GOOD = {
    "Barcodes.dat": HEADER + "1\t5\n2\t14\n3\t41\n4\t32\n5\t23\n6\t63\n7\t81\n",
    "Landmark_Groundtruth.dat": HEADER + "6 0.5 -4.2 0.0001 0.0002\n7 0.6 -4.4 0.0001 0.0002\n",
    "Odometry": HEADER + "100.0 0.1 0.0\n100.5 0.1 0.2\n100.5 0.0 0.2\n101.0 0.0 0.0\n",
    "Groundtruth": HEADER + "99.0 0 0 3.1\n100.0 0.1 0 -3.1\n102.0 0.2 0 -3.0\n",
    "Measurement": HEADER + "100.2 63 3.5 0.1\n100.2 14 2.0 -0.1\n101.0 99 4.0 0.0\n",
}  # fmt: skip


def _write_mrclam(folder, **changes):
    folder.mkdir(exist_ok=True)
    for name in ("Barcodes.dat", "Landmark_Groundtruth.dat"):
        (folder / name).write_text(changes.get(name, GOOD[name]))
    for n in range(1, 6):
        for kind in KINDS:
            name = f"Robot{n}_{kind}.dat"
            (folder / name).write_text(changes.get(name, GOOD[kind]))
    return folder


def _write_plaza(folder, dr=None, td=None, mat=None):
    import scipy.io

    folder.mkdir(exist_ok=True)
    (folder / "Plaza2_DR.txt").write_text(dr or "1.1 0.5 0.1\n1.2 0.5 -0.1\n")
    (folder / "Plaza2_TD.txt").write_text(td or "1.15 2 0 10.5\n1.18 2 7 11.0\n")
    variables = {
        "GT": np.array([[1.0, 0, 0, np.pi - 0.1], [1.1, 0.5, 0, np.pi], [1.2, 1.0, 0, -3.0]]),
        "DRp": np.array([[1.0, 0, 0, -0.1], [1.1, 0.5, 0, 0.0], [1.2, 1.0, 0, -0.1]]),
        "TL": np.array([[0.0, 10.0, 0.0], [1.0, 0.0, 10.0]]),
    }
    variables.update(mat or {})
    scipy.io.savemat(folder / "Plaza2_.mat", variables)
    return folder


def test_synthetic_folders_read(tmp_path):
    m = read_mrclam(_write_mrclam(tmp_path / "m"))
    log = m.robots[2]
    np.testing.assert_array_equal(log.meas_subject, [6, -1, -1])  # landmark, robot 2, unknown
    assert log.n_unknown_barcodes == 1
    np.testing.assert_array_equal(log.odometry_t, [100.0, 100.5, 100.5, 101.0])  # repeats: fine
    np.testing.assert_allclose(log.truth[:, 2], [3.1, -3.1, -3.0])
    p = read_plaza(_write_plaza(tmp_path / "p"))
    np.testing.assert_array_equal(p.meas_beacon_index, [0, -1])
    assert p.n_unknown_beacons == 1
    np.testing.assert_allclose(p.truth[:, 2], [-0.1, 0.0, np.pi - 3.0], atol=1e-12)


def test_header_lines_are_optional(tmp_path):
    changes = {"Robot1_Odometry.dat": "# one header\n1.0 0.1 0.0\n\n2.0 0.1 0.0\n\n"}
    log = read_mrclam(_write_mrclam(tmp_path, **changes)).robots[0]
    np.testing.assert_array_equal(log.odometry_t, [1.0, 2.0])
    bad = {"Robot1_Odometry.dat": "1.0 0.1 0.0\n\n2.0 0.1 0.0\n1.5 0.1 0.0\n"}
    with pytest.raises(FileFormatError) as err:
        read_mrclam(_write_mrclam(tmp_path, **bad))
    assert err.value.line == 4  # the blank line still counts


BAD_MRCLAM = [
    ("Robot2_Odometry.dat", HEADER + "100.0 0.1 0.0\n100.5 0.1\n", 6, "expected 3 columns"),
    ("Robot2_Odometry.dat", HEADER + "100.0 0.1 0.0\n100.5 0.1 0.2 7\n", 6, "expected 3 columns"),
    ("Robot3_Groundtruth.dat", HEADER + "1 0 0 0\n2 0 zero 0\n", 6, "'zero' is not a number"),
    ("Robot3_Groundtruth.dat", HEADER + "1 0 0 0\n2 0 0 nan\n3 0 0 0\n", 6, "θ is not finite"),
    ("Robot4_Measurement.dat", HEADER + "1 63 3.5 0.1\n2 63 inf 0.1\n", 6, "range is not finite"),
    ("Robot4_Measurement.dat", HEADER + "1 63 3.5 0.1\n2 63.5 3.5 0.1\n", 6, "integer"),
    ("Robot4_Measurement.dat", HEADER + "1 63 3.5 0.1\n2 63 -3.5 0.1\n", 6, "negative"),
    ("Robot5_Odometry.dat", HEADER + "3 0 0\n4 0 0\n4 0 0\n3.5 0 0\n", 8, "goes backwards"),
    ("Robot5_Odometry.dat", HEADER + "3 0 0\n# late comment\n", 6, "not a number"),
    ("Barcodes.dat", GOOD["Barcodes.dat"] + "8 63\n", 12, "duplicate barcode 63"),
    ("Barcodes.dat", GOOD["Barcodes.dat"] + "7 70\n", 12, "duplicate subject 7"),
    ("Landmark_Groundtruth.dat", HEADER + "6 0 0 0 0\n8 0 0 0 0\n", 6, "no barcode"),
    ("Landmark_Groundtruth.dat", HEADER + "6 0 0 0 0\n3 0 0 0 0\n", 6, "robots"),
]


@pytest.mark.parametrize(("name", "text", "line", "message"), BAD_MRCLAM)
def test_malformed_mrclam_file_names_file_and_line(tmp_path, name, text, line, message):
    folder = _write_mrclam(tmp_path, **{name: text})
    with pytest.raises(FileFormatError, match=message) as err:
        read_mrclam(folder)
    assert err.value.path == str(folder / name)
    assert err.value.line == line
    assert f"{name}:{line}:" in str(err.value)


def test_mrclam_folder_missing_files_names_them(tmp_path):
    folder = _write_mrclam(tmp_path)
    (folder / "Robot3_Measurement.dat").unlink()
    (folder / "Barcodes.dat").unlink()
    with pytest.raises(FileFormatError, match=r"missing Barcodes\.dat, Robot3_Measurement\.dat"):
        read_mrclam(folder)
    with pytest.raises(FileFormatError, match="not a folder"):
        read_mrclam(tmp_path / "absent")
    with pytest.raises(
        FileFormatError, match=r"missing Barcodes\.dat, Landmark_Groundtruth\.dat, Robot1_Odometry"
    ):
        read_mrclam(_write_plaza(tmp_path / "plaza"))


@pytest.mark.parametrize(
    ("dr", "td", "name", "line", "message"),
    [
        ("1.1 0.5 0.1\n1.2 0.5\n", None, "Plaza2_DR.txt", 2, "expected 3 columns"),
        ("1.1 0.5 0.1\n1.2 0.5 x\n", None, "Plaza2_DR.txt", 2, "'x' is not a number"),
        ("1.1 0.5 0.1\n1.0 0.5 0.1\n", None, "Plaza2_DR.txt", 2, "goes backwards"),
        (None, "1.15 2 0 10.5\n1.18 2 0.5 11.0\n", "Plaza2_TD.txt", 2, "beacon must be an integer"),
        (None, "1.15 2 0 -inf\n", "Plaza2_TD.txt", 1, "range is not finite"),
    ],
)
def test_malformed_plaza_text_names_file_and_line(tmp_path, dr, td, name, line, message):
    folder = _write_plaza(tmp_path, dr=dr, td=td)
    with pytest.raises(FileFormatError, match=message) as err:
        read_plaza(folder)
    assert err.value.path == str(folder / name) and err.value.line == line


def test_malformed_plaza_mat_names_variable(tmp_path):
    bad_gt = np.array([[1.0, 0, 0, 0], [1.1, 0, np.nan, 0]])
    with pytest.raises(FileFormatError, match="GT row 2 is not finite"):
        read_plaza(_write_plaza(tmp_path / "a", mat={"GT": bad_gt}))
    with pytest.raises(FileFormatError, match=r"'TL' must be a numeric \(n, 3\)"):
        read_plaza(_write_plaza(tmp_path / "b", mat={"TL": np.zeros((2, 2))}))
    folder = _write_plaza(tmp_path / "c")
    (folder / "Plaza2_.mat").write_bytes(b"not a mat file at all")
    with pytest.raises(FileFormatError, match="not a readable MATLAB file"):
        read_plaza(folder)
    (folder / "Plaza2_.mat").unlink()
    with pytest.raises(FileFormatError, match=r"missing Plaza2_\.mat"):
        read_plaza(folder)


def test_importing_the_readers_keeps_scipy_io_unloaded():
    code = "import sys, relmap.io; print('scipy.io' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
