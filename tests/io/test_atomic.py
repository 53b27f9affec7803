"""relmap's one writer (relmap.io.atomic) and everything that writes through it: graphs, map
files, PNGs and the report. What is at the output path must be respected: modes, owners, links,
device nodes and FIFOs (the latter only ever made inside the test's own temporary folder)."""

from __future__ import annotations

import os
import stat
import threading

import numpy as np
import pytest

import relmap as rm
from relmap.errors import OutputError
from relmap.io import load_map, save_map
from relmap.io.atomic import (
    check_writable,
    check_writable_folder,
    write_bytes_atomic,
    write_text_atomic,
)

ROOT = os.geteuid() == 0


@pytest.fixture
def umask_027():
    old = os.umask(0o027)
    yield 0o027
    os.umask(old)


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def test_new_file_gets_the_umask_mode(tmp_path, umask_027):
    p = tmp_path / "a.txt"
    write_text_atomic(p, "x")
    assert _mode(p) == 0o666 & ~umask_027  # 0o640, not mkstemp's 0o600
    assert p.read_text() == "x"


def test_new_file_mode_matches_open(tmp_path):
    ref = tmp_path / "ref"
    ref.write_text("")  # what any program's new file gets
    write_text_atomic(tmp_path / "a", "x")
    assert _mode(tmp_path / "a") == _mode(ref)


def test_overwrite_keeps_the_mode(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("old")
    os.chmod(p, 0o604)
    write_text_atomic(p, "new")
    assert _mode(p) == 0o604
    assert p.read_text() == "new"


@pytest.mark.skipif(not ROOT, reason="changing a file's owner needs root")
def test_overwrite_keeps_owner_and_group(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("old")
    os.chown(p, 1234, 4321)
    write_text_atomic(p, "new")
    st = os.stat(p)
    assert (st.st_uid, st.st_gid) == (1234, 4321)


def test_symlink_is_followed_not_replaced(tmp_path):
    target = tmp_path / "target.txt"
    target.write_text("old")
    link = tmp_path / "link.txt"
    link.symlink_to(target)
    write_text_atomic(link, "new")
    assert link.is_symlink()
    assert target.read_text() == "new"


def test_dangling_symlink_creates_its_target(tmp_path):
    link = tmp_path / "link.txt"
    link.symlink_to(tmp_path / "made.txt")
    write_text_atomic(link, "new")
    assert link.is_symlink() and (tmp_path / "made.txt").read_text() == "new"


def test_hard_links_all_see_the_new_content(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.write_text("old")
    os.link(a, b)
    write_text_atomic(a, "new")
    assert b.read_text() == "new"
    assert os.stat(a).st_ino == os.stat(b).st_ino


@pytest.mark.skipif(not ROOT, reason="mknod of a character device needs root")
def test_device_node_is_written_in_place_never_replaced(tmp_path):
    dev = tmp_path / "null"  # a private /dev/null, made for this test only
    os.mknod(dev, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    write_text_atomic(dev, "discarded")
    st = os.stat(dev)
    assert stat.S_ISCHR(st.st_mode) and st.st_rdev == os.makedev(1, 3)
    assert not [q for q in tmp_path.iterdir() if q.name != "null"]  # no temporary left


def test_fifo_is_written_in_place(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()))
    reader.start()
    write_bytes_atomic(fifo, b"through the pipe")
    reader.join(10)
    assert got == [b"through the pipe"]
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_no_temporary_left_after_a_failure(tmp_path, monkeypatch):
    def boom(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OutputError, match="No space left"):
        write_text_atomic(tmp_path / "a.txt", "x")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("where", "message"),
    [
        ("dir", "is a directory"),
        ("missing/a.txt", "does not exist"),
        ("x" * 5000, "too long"),
        ("file/a.txt", "not a folder"),
    ],
)
def test_unwritable_destinations_are_clear_errors(tmp_path, where, message):
    (tmp_path / "dir").mkdir()
    (tmp_path / "file").write_text("")
    with pytest.raises(OutputError, match=message):
        check_writable(tmp_path / where)
    with pytest.raises(OutputError, match=message):
        write_text_atomic(tmp_path / where, "x")


def test_proc_is_not_writable():
    with pytest.raises(OutputError, match="/proc"):
        check_writable("/proc/relmap-test.g2o")


@pytest.mark.skipif(ROOT, reason="root may write into a read-only folder")
def test_read_only_folder(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.raises(OutputError, match="cannot write"):
            check_writable(ro / "a.txt")
        with pytest.raises(OutputError):
            check_writable_folder(ro / "report")
    finally:
        ro.chmod(0o755)


def test_folder_check(tmp_path):
    assert check_writable_folder(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"
    (tmp_path / "f").write_text("")
    with pytest.raises(OutputError, match="not a folder"):
        check_writable_folder(tmp_path / "f" / "report")
    with pytest.raises(OutputError):
        check_writable_folder("/proc/relmap-report")


# ------------------------------------------------------------------ every output goes through it
def test_png_and_report_use_the_writer(tmp_path, umask_027):
    from matplotlib.figure import Figure

    from relmap.viz.plot import save_png
    from relmap.viz.report import Report

    fig = Figure()
    fig.add_subplot().plot([0, 1])
    target = tmp_path / "real.png"
    link = tmp_path / "link.png"
    link.symlink_to(target)
    save_png(fig, link)
    assert link.is_symlink() and target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert _mode(target) == 0o640
    with pytest.raises(OutputError):
        save_png(fig, tmp_path)
    rep = Report("t")
    rep.figure(fig, "f.png", "a figure")
    index = rep.write(tmp_path / "rep")
    assert _mode(index) == 0o640 and _mode(tmp_path / "rep" / "f.png") == 0o640
    with pytest.raises(OutputError):
        rep.write("/proc/relmap-report")


def test_graph_and_map_writers_follow_links(tmp_path):
    g = rm.RelationalMap()
    g.add("W", "A", rm.AT([1.0, 0.0, 0.1], np.eye(3) * 0.01), name="a")
    real = tmp_path / "real.json"
    link = tmp_path / "map.json"
    link.symlink_to(real)
    save_map(link, g)
    assert link.is_symlink() and load_map(real).frames == load_map(link).frames


# ------------------------------------------------------------------ save_map round trips
@pytest.mark.parametrize("frame", [(1, 2), 1.5, True, None, frozenset({1})])
def test_save_map_refuses_frames_load_map_cannot_read(tmp_path, frame):
    g = rm.RelationalMap()
    g.add("W", frame, rm.AT([1.0, 0.0, 0.0]), name="a")
    with pytest.raises(rm.errors.ParameterError, match="frame"):
        save_map(tmp_path / "m.json", g)
    assert not (tmp_path / "m.json").exists()


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
@pytest.mark.parametrize("frame", [np.int64(3), np.int32(-7), np.uint8(200), 5, "x"])
def test_save_map_round_trips_integer_frames(tmp_path, frame, suffix):
    g = rm.RelationalMap()
    g.add("W", frame, rm.AT([1.0, 0.0, 0.0]), name="a")
    save_map(tmp_path / f"m{suffix}", g)
    back = load_map(tmp_path / f"m{suffix}")
    assert back.frames == ["W", int(frame) if not isinstance(frame, str) else frame]
