"""relmap.io.formats, the format registry: inputs read once (a pipe, a FIFO, /dev/stdin), every
writable format written and read back through the registry, recognisers that never overlap,
clear refusals listing the known formats, and entry points that find a format registered later."""

from __future__ import annotations

import gzip
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

import relmap as rm
from relmap.errors import FileFormatError, ParameterError
from relmap.io import ATRecord, PoseGraph, formats, load_map, read_graph, read_records
from relmap.io.posegraph import file_information
from relmap.io.textfile import read_input
from relmap.io.trajectory import read_trajectory, recognise_trajectory, write_trajectory
from relmap.uncertain.trajectory import Trajectory

MAP_YAML = (
    "ats:\n  - {name: A, from: W, to: L, mean: [1, 2, 0.5], sigma: [0.1, 0.1, 0.01]}\n"
    "  - {name: B, from: L, to: M, mean: [1, 0, 0], sigma: [0.1, 0.1, 0.01]}\n"
)
G2O = (
    "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 9 2 0 0\n"
    "EDGE_SE2 0 1 1 0 0 100 0 0 100 0 1000\nEDGE_SE2 1 9 1 0 0 100 0 0 100 0 1000\n"
)
TUM = "# t x y z qx qy qz qw\n1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n3.0 2 0.5 0 0 0 0 1\n"


# ------------------------------------------------------------------------------ pipes
def _pipe(data: bytes) -> tuple[str, int]:
    """A real pipe holding ``data`` (written and closed), by the name ``/dev/fd/N`` a shell's
    process substitution gives; the read end to close afterwards."""
    r, w = os.pipe()
    os.write(w, data)
    os.close(w)
    return f"/dev/fd/{r}", r


def _check_map(g) -> None:  # type: ignore[no-untyped-def]
    assert set(g.frames) == {"W", "L", "M"}


def _check_graph(g) -> None:  # type: ignore[no-untyped-def]
    np.testing.assert_array_equal(g.vertex_ids, [0, 1, 9])


def _check_trajectory(t) -> None:  # type: ignore[no-untyped-def]
    np.testing.assert_array_equal(t.stamps, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(t.positions[:, 0], [0.0, 1.0, 2.0])


def _check_graph_map(g) -> None:  # type: ignore[no-untyped-def]
    assert set(g.frames) == {0, 1, 9}


CASES = [
    ("map", MAP_YAML, load_map, _check_map),
    ("g2o graph", G2O, read_graph, _check_graph),
    ("g2o map", G2O, load_map, _check_graph_map),
    ("trajectory", TUM, read_trajectory, _check_trajectory),
]


@pytest.mark.parametrize(("name", "text", "reader", "check"), CASES, ids=[c[0] for c in CASES])
@pytest.mark.parametrize("compressed", [False, True], ids=["plain", "gzip"])
def test_a_pipe_is_read_once(name, text, reader, check, compressed):
    """Before the registry, the trajectory sniffer read the pipe's first 4 KiB itself and the
    reader then found it empty ("no poses in the file")."""
    data = text.encode()
    path, r = _pipe(gzip.compress(data) if compressed else data)
    try:
        check(reader(path))
    finally:
        os.close(r)


@pytest.mark.parametrize(("name", "text", "reader", "check"), CASES, ids=[c[0] for c in CASES])
def test_a_fifo_is_read_once(tmp_path, name, text, reader, check):
    fifo = tmp_path / "input"
    os.mkfifo(fifo)
    writer = threading.Thread(target=lambda: fifo.write_text(text), daemon=True)
    writer.start()
    check(reader(fifo))
    writer.join(timeout=10)


def _relmap(*args: str, stdin: bytes | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "relmap.app.cli", *args],
        input=None if stdin is None else stdin.decode(),
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.parametrize(
    ("args", "text", "expect"),
    [
        (["traj", "/dev/stdin", "--json"], TUM, '"poses": 3'),
        (["query", "/dev/stdin", "W", "M", "--json"], MAP_YAML, '"from": "W", "to": "M"'),
        (["query", "/dev/stdin", "0", "9", "--json"], G2O, '"mean": [2.0'),
        (["solve", "/dev/stdin", "--json"], G2O, '"poses": 3'),
        (["convert", "/dev/stdin", "{out}"], TUM, "3 poses written"),
    ],
    ids=["traj", "query map", "query g2o", "solve", "convert"],
)
def test_commands_read_dev_stdin(tmp_path, args, text, expect):
    args = [a.format(out=tmp_path / "out.txt") for a in args]
    out = _relmap(*args, stdin=text.encode())
    assert out.returncode == 0, out.stderr
    assert expect in out.stdout


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash's process substitution")
def test_eval_of_two_process_substitutions(tmp_path):
    """``relmap eval <(zcat ref.gz) <(cat est)``: the README's kind of pipe, two at once."""
    (tmp_path / "ref.txt.gz").write_bytes(gzip.compress(TUM.encode()))
    (tmp_path / "est.txt").write_text(TUM)
    script = f"{sys.executable} -m relmap.app.cli eval <(gzip -dc ref.txt.gz) <(cat est.txt) --json"
    out = subprocess.run(
        ["bash", "-c", script], capture_output=True, text=True, timeout=120, cwd=tmp_path
    )
    assert out.returncode == 0, out.stderr
    assert '"pairs": 3' in out.stdout


# ------------------------------------------------------------------------- round trips
def _planar(cov: bool) -> Trajectory:
    rng = np.random.default_rng(4)
    x = np.column_stack([rng.normal(size=(12, 2)), rng.uniform(-np.pi, np.pi, 12)])
    A = rng.normal(size=(12, 3, 3)) * 0.1
    C = A @ np.swapaxes(A, 1, 2) if cov else None
    return Trajectory.planar(x, 100 + np.arange(12) * 0.25, C, frame="map", child="robot")


def _spatial(cov: bool) -> Trajectory:
    rng = np.random.default_rng(5)
    q = rng.normal(size=(12, 4))
    A = rng.normal(size=(12, 6, 6)) * 0.1
    C = A @ np.swapaxes(A, 1, 2) if cov else None
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return Trajectory.from_quaternions(rng.normal(size=(12, 3)), q, 1e9 + np.arange(12), C)


def _graph(dim: int) -> PoseGraph:
    rng = np.random.default_rng(6)
    if dim == 2:
        poses = np.column_stack([rng.normal(size=(5, 2)), rng.uniform(-3, 3, 5)])
        z = rm.AT.stack([rm.AT(rng.normal(size=3) * 0.5, np.diag([0.01, 0.02, 0.001]))] * 4)
    else:
        poses = rm.AT3.stack([rm.AT3.from_vector([*rng.normal(size=3), 0, 0, 0, 1])] * 5).matrix
        z = rm.AT3.stack(
            [
                rm.AT3.from_sigmas(
                    rng.normal(size=3), [0, 0, np.sin(0.1), np.cos(0.1)], [0.1] * 3 + [0.01] * 3
                )
            ]
            * 4
        )
    return PoseGraph(
        "g2o",
        np.array([3, 5, 8, 13, 21]),
        poses,
        np.array([3, 5, 8, 13]),
        np.array([5, 8, 13, 21]),
        z,
        file_information(z),
        np.array([3]),
    )


def _same_trajectory(back: Trajectory, traj: Trajectory, fmt: str) -> None:
    np.testing.assert_allclose(back.matrices, traj.matrices, atol=1e-14)
    if fmt == "kitti":
        assert back.stamps is None
    else:
        np.testing.assert_allclose(
            back.stamps, traj.stamps, rtol=1e-15, atol=1e-6 * (fmt == "euroc")
        )
    if fmt == "relmap":
        assert back.is_planar == traj.is_planar and back.has_cov == traj.has_cov
        if traj.has_cov:
            np.testing.assert_array_equal(back.cov, traj.cov)


def _same_graph(back: PoseGraph, graph: PoseGraph, fmt: str) -> None:
    np.testing.assert_array_equal(back.vertex_ids, graph.vertex_ids)
    np.testing.assert_array_equal(back.edge_from, graph.edge_from)
    np.testing.assert_allclose(back.poses, graph.poses, atol=1e-15)
    np.testing.assert_allclose(back.measurements.mean, graph.measurements.mean, atol=1e-15)
    np.testing.assert_allclose(
        back.measurements.cov, graph.measurements.cov, rtol=1e-12, atol=1e-15
    )
    assert back.format == fmt


def _same_records(back: list[ATRecord], records: list[ATRecord], fmt: str) -> None:
    assert [(r.name, r.src, r.dst) for r in back] == [(r.name, r.src, r.dst) for r in records]
    for a, b in zip(back, records, strict=True):
        np.testing.assert_array_equal(a.at.cov, b.at.cov)


_RECORDS = [
    ATRecord("a", "W", "L", rm.AT([1.0, 2.0, 0.3], np.diag([0.01, 0.02, 0.003]))),
    ATRecord("b", "L", 7, rm.AT([0.5, -1.0, -2.0], np.diag([0.04, 0.01, 0.001]))),
]
#: For every writable format: what to write (several shapes of it) and how to compare.
SAMPLES = {
    "map": ([_RECORDS, _RECORDS], _same_records),  # YAML, then JSON
    "g2o": ([_graph(2), _graph(3)], _same_graph),
    "toro": ([_graph(2)._replace(fixed=np.empty(0, np.int64))], _same_graph),
    "tum": ([_spatial(False), _planar(False)], _same_trajectory),
    "kitti": ([_spatial(False)], _same_trajectory),
    "euroc": ([_spatial(False)], _same_trajectory),
    "relmap": ([_planar(True), _planar(False), _spatial(True), _spatial(False)], _same_trajectory),
}


def test_every_writable_format_has_a_round_trip_here():
    assert {f.name for f in formats.formats(writable=True)} == set(SAMPLES)


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_round_trip_through_the_registry(tmp_path, name):
    """Written by the registered writer, recognised as that format (and as no other), and read
    back by the registered reader to the same content."""
    fmt = formats.get(name, writable=True)
    objects, same = SAMPLES[name]
    for k, obj in enumerate(objects):
        path = tmp_path / f"{k}.{'json' if name == 'map' and k else 'txt'}"
        fmt.write(path, obj)
        source = read_input(path)
        recognised = formats.recognise(source)
        if name == "relmap" and not obj.is_planar and not obj.has_cov:
            assert recognised.name == "tum"  # relmap 3-D without covariance is TUM
        else:
            assert recognised is fmt
        same(recognised.read(source), obj, name)


def test_a_legacy_3d_graph_is_written_as_g2o_with_its_information_converted(tmp_path):
    info = " ".join(map(str, np.eye(6)[np.triu_indices(6)] * 100))
    path = tmp_path / "legacy.graph"
    path.write_text(
        f"VERTEX3 0 0 0 0 0 0 0\nVERTEX3 1 1 0 0 0 0 0.2\nEDGE3 0 1 1 0 0 0 0 0.2 {info}\n"
    )
    legacy = read_graph(path)
    with pytest.raises(ParameterError, match="read only"):
        formats.get("toro").write(tmp_path / "out.graph", legacy)
    formats.get("g2o").write(tmp_path / "out.g2o", legacy)
    back = read_graph(tmp_path / "out.g2o")
    _same_graph(back, legacy._replace(format="g2o"), "g2o")


# ----------------------------------------------------------------- recognition, refusals
EDGE_CASES = [
    "FOO BAR: x",  # a YAML key with a space: the tag FOO
    "ATS: []",  # an upper-case YAML key
    "EDGE_SE3:QUAT 0 1",
    "-1.5 0 0 0",  # a negative stamp
    "NAN 0 0 0",
    "nan 0 0 0",
    "---",
    "- a",
    "{}",
    "'ats': []",
    "1,2,3,4,5,6,7,8",
    "1, 2, 3",
    "t, x, y",
    "1 2 3 4 5",
    "x 1 2 3",
    "1e3 0 0 0 0 0 0 1",
]


@pytest.mark.parametrize("record", EDGE_CASES)
def test_recognisers_never_overlap(tmp_path, record):
    """At most one format claims any input: registration order never decides."""
    path = tmp_path / "f.txt"
    path.write_text(f"# a comment\n\n{record}\n")
    head = formats.Head(path, False, path.read_bytes(), record, 3)
    claims = [f.name for f in formats.formats() if f.recognise(head)]
    assert len(claims) <= 1, claims
    assert formats.recognise(path) is (formats.get(claims[0]) if claims else None)


@pytest.mark.real_data
def test_the_shared_files_are_recognised(data_dir):
    expected = {
        "posegraph2d/MIT.g2o": "g2o",
        "posegraph2d/CSAIL_P_toro.graph": "toro",
        "posegraph3d/sphere2500.g2o": "g2o",
        "trajectories/KITTI_00_gt.txt": "kitti",
        "trajectories/V102_groundtruth.csv": "euroc",
        "trajectories/V102.txt": "tum",
        "trajectories/ROS_example.bag": "bag",
        "trajectories/nav2_turtlebot.mcap": "bag",
        "trajectories/tf_example": "bag",
        "landmarks/mrclam6/Robot1_Groundtruth.dat": "relmap",
    }
    for name, fmt in expected.items():
        assert formats.recognise(data_dir / name).name == fmt, name


@pytest.mark.parametrize(
    ("reader", "kind"),
    [
        (load_map, ("map", "graph")),
        (read_graph, ("graph",)),
        (read_trajectory, ("trajectory", "graph")),
    ],
    ids=["load_map", "read_graph", "read_trajectory"],
)
def test_an_unknown_format_is_refused_listing_the_known_ones(tmp_path, reader, kind):
    known = [f.name for f in formats.formats(*kind)]
    path = tmp_path / "what.txt"
    path.write_text("# header\nhello world\n")
    with pytest.raises(
        FileFormatError, match=r"unknown format \(first record 'hello world'\)"
    ) as e:
        reader(path)
    assert e.value.line == 2 and str(e.value).startswith(f"{path}:2: ")
    assert str(e.value).endswith(", ".join(known))
    path.write_bytes(b"\x00\x01binary")
    with pytest.raises(FileFormatError, match="binary content in no format") as e:
        reader(path)
    assert str(e.value).endswith(", ".join(known))
    with pytest.raises(FileFormatError, match="cannot read: it is a directory") as e:
        reader(tmp_path)
    assert str(e.value).endswith(", ".join(known))


def test_a_file_of_another_kind_is_refused_naming_its_format(tmp_path):
    traj = tmp_path / "t.txt"
    traj.write_text(TUM)
    with pytest.raises(FileFormatError, match=r"a tum file .* holds a trajectory, not a map"):
        load_map(traj)
    with pytest.raises(
        FileFormatError, match=r"not a pose graph; relmap reads pose graphs from g2o"
    ):
        read_graph(traj)
    m = tmp_path / "m.yaml"
    m.write_text(MAP_YAML)
    with pytest.raises(FileFormatError, match=r"a map file .* holds a map, not a trajectory"):
        read_trajectory(m)
    g = tmp_path / "g.g2o"
    g.write_text(G2O)
    with pytest.raises(FileFormatError, match="holds a pose graph, not a map"):
        read_records(g)
    assert recognise_trajectory(g) == "g2o"  # graphs give trajectories: their vertices
    with pytest.raises(FileFormatError, match="holds a map, not a trajectory"):
        recognise_trajectory(m)


def test_names_and_options(tmp_path):
    with pytest.raises(
        ParameterError,
        match="'xyz' is an unknown format: relmap writes trajectories as euroc, kitti, relmap, tum",
    ):
        write_trajectory(tmp_path / "t.txt", _spatial(False), "xyz")
    with pytest.raises(ParameterError, match="'bag' is not a format relmap writes trajectories as"):
        write_trajectory(tmp_path / "t.txt", _spatial(False), "bag")
    assert not list(tmp_path.iterdir())
    path = tmp_path / "t.txt"
    path.write_text(TUM)
    with pytest.raises(
        ParameterError, match=r"the option 'topic' is for bag files; .*t\.txt is a tum file"
    ):
        read_trajectory(path, topic="/odom")
    with pytest.raises(ParameterError, match="registered already"):
        formats.register(formats.get("tum"))


def test_a_bag_is_not_read_from_a_pipe(data_dir):
    data = (data_dir / "trajectories" / "ROS_example.bag").read_bytes()[:100_000]
    path, r = _pipe(data[:60_000])  # a pipe holds 64 KiB
    try:
        with pytest.raises(FileFormatError, match="read from its file or folder, not from a pipe"):
            read_trajectory(path, topic="groundtruth")
    finally:
        os.close(r)


# ------------------------------------------------------------ a format registered later
def _read_xy(source):  # type: ignore[no-untyped-def]
    rows = [line.split()[1:] for line in source.text.splitlines() if line.startswith("XY ")]
    x = np.array(rows, dtype=float)
    return Trajectory.planar(np.column_stack([x, np.zeros(len(x))]), np.arange(len(x), dtype=float))


def _write_xy(path, traj):  # type: ignore[no-untyped-def]
    Path(path).write_text("".join(f"XY {x} {y}\n" for x, y, _ in traj.poses.mean))


def test_entry_points_find_a_format_registered_later(monkeypatch, tmp_path, capsys):
    """A user's own format, registered once, is recognised, read and written by the library's
    entry points and the commands alike."""
    from relmap.app.cli import main

    monkeypatch.setattr(formats, "_REGISTRY", dict(formats._REGISTRY))
    formats.register(
        formats.Format(
            "xy",
            "trajectory",
            "XY x y lines",
            lambda head: head.record.startswith("XY "),
            _read_xy,
            _write_xy,
        )
    )
    path = tmp_path / "p.xy"
    write_trajectory(path, _planar(False), "xy")
    assert path.read_text().startswith("XY ")
    assert recognise_trajectory(path) == "xy"
    np.testing.assert_allclose(
        read_trajectory(path).positions[:, :2], _planar(False).positions[:, :2]
    )
    assert main(["traj", str(path), "--json"]) == 0
    assert '"poses": 12' in capsys.readouterr().out
    assert main(["convert", str(path), str(tmp_path / "q.xy"), "--format", "xy"]) == 0
    assert (tmp_path / "q.xy").read_text() == path.read_text()
    with pytest.raises(FileFormatError, match=r"not a map; relmap reads maps from map, g2o, toro"):
        load_map(path)
