"""The command line's errors: one line ``relmap <command>: error: …`` on stderr, exit 2 for bad
input and 1 for a failed computation, no traceback unless --debug, numbers range-checked by
argparse, outputs checked before the work, and a closed pipe ends quietly."""

from __future__ import annotations

import gzip
import os
import subprocess
import sys

import pytest

from relmap.app import cli
from relmap.errors import NumericalError

G2O = (
    "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n"
    "EDGE_SE2 0 1 1 0 0 100 0 0 100 0 1000\nEDGE_SE2 1 2 1 0 0 100 0 0 100 0 1000\n"
)


@pytest.fixture
def graph(tmp_path):
    p = tmp_path / "g.g2o"
    p.write_text(G2O)
    return p


def run(capsys, *argv: str) -> tuple[int, str, str]:
    try:
        status = cli.main([str(a) for a in argv])
    except SystemExit as exc:  # argparse
        status = int(exc.code or 0)
    out, err = capsys.readouterr()
    return status, out, err


def assert_one_line_error(err: str, command: str) -> None:
    lines = err.strip("\n").split("\n")
    assert len(lines) == 1, err
    assert lines[0].startswith(f"relmap {command}: error: "), err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    ("argv", "what"),
    [
        (["solve", "{g}", "--max-iterations", "-5"], "--max-iterations"),
        (["solve", "{g}", "--max-iterations", "0"], "--max-iterations"),
        (["solve", "{g}", "--max-iterations", "many"], "--max-iterations"),
        (["solve", "{g}", "--loss", "cauchy"], "--loss"),
        (["solve", "{g}", "--loss", "huber:0"], "--loss"),
        (["validate", "{g}", "0", "2", "--seed", "-1"], "--seed"),
        (["validate", "{g}", "0", "2", "-n", str(10**20)], "-n"),
        (["validate", "{g}", "0", "2", "-n", str(10**9)], "-n"),
        (["validate", "{g}", "0", "2", "-n", "0"], "-n"),
        (["validate", "{g}", "0", "2", "-n", "1.5"], "-n"),
        (["demo", "--samples", "5", "--out", "{tmp}/r"], "--samples"),
        (["demo", "--seed", "-3", "--out", "{tmp}/r"], "--seed"),
        (["localize", "{tmp}", "--robot", "9"], "--robot"),
    ],
)
def test_numbers_are_range_checked_by_argparse(capsys, graph, tmp_path, argv, what):
    argv = [a.format(g=graph, tmp=tmp_path) for a in argv]
    status, _out, err = run(capsys, *argv)
    assert status == 2
    assert_one_line_error(err, argv[0])
    assert what in err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["solve", "{g}", "--out", "{tmp}"], "is a directory"),
        (["solve", "{g}", "--out", "/proc/relmap.g2o"], "/proc"),
        (["solve", "{g}", "--out", "{tmp}/missing/out.g2o"], "does not exist"),
        (["solve", "{g}", "--out", "{tmp}/" + "x" * 5000], "too long"),
        (["localize", "{tmp}", "--plot", "/proc/p.png"], "/proc"),
        (["localize", "{tmp}", "--plot", "{tmp}"], "is a directory"),
        (["demo", "--out", "/proc/relmap-report"], "/proc"),
        (["demo", "--out", "{g}"], "not a folder"),
    ],
)
def test_outputs_are_checked_before_any_work(capsys, graph, tmp_path, argv, message, monkeypatch):
    def no_work(*args, **kwargs):  # the check must come first: reaching the work is a failure
        raise AssertionError("the work started before the output was checked")

    monkeypatch.setattr("relmap.io.read_graph", no_work)
    monkeypatch.setattr("relmap.app.localize.localize", no_work)
    monkeypatch.setattr("relmap.app.demo.run", no_work)
    argv = [a.format(g=graph, tmp=tmp_path) for a in argv]
    status, _out, err = run(capsys, *argv)
    assert status == 2
    assert_one_line_error(err, argv[0])
    assert message in err
    assert len(err) < 400  # a 5000-character name is not echoed whole


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write into a read-only folder")
def test_read_only_folder_output(capsys, graph, tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        status, _, err = run(capsys, "solve", graph, "--out", ro / "out.g2o")
    finally:
        ro.chmod(0o755)
    assert status == 2
    assert_one_line_error(err, "solve")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["query", "{tmp}/" + "q" * 5000, "0", "1"], "too long"),
        (["query", "{tmp}", "0", "1"], "directory"),
        (["query", "{tmp}/nope.g2o", "0", "1"], "no such file"),
        (["query", "{g}", "0", "7"], "no frame"),
        (["solve", "{tmp}/" + "s" * 5000], "too long"),
        (["validate", "{tmp}/bad.json", "a", "b"], "duplicate key"),
    ],
)
def test_bad_input_is_one_line_exit_2(capsys, graph, tmp_path, argv, message):
    (tmp_path / "bad.json").write_text('{"ats": [], "ats": []}')
    argv = [a.format(g=graph, tmp=tmp_path) for a in argv]
    status, _out, err = run(capsys, *argv)
    assert status == 2
    assert_one_line_error(err, argv[0])
    assert message in err
    assert len(err) < 400


def test_computation_failure_exits_1_and_debug_shows_the_traceback(capsys, graph, monkeypatch):
    def overflow(*args, **kwargs):
        raise NumericalError("compound overflowed the floating-point range")

    monkeypatch.setattr("relmap.network.graph.RelationalMap.query", overflow)
    status, _, err = run(capsys, "query", graph, "0", "2")
    assert status == 1
    assert_one_line_error(err, "query")
    status, _, err = run(capsys, "--debug", "query", graph, "0", "2")
    assert status == 1 and "Traceback" in err and err.rstrip().endswith("floating-point range")
    status, _, err = run(capsys, "query", graph, "0", "2", "--debug")
    assert status == 1 and "Traceback" in err


def test_unexpected_errors_are_one_line_too(capsys, graph, monkeypatch):
    def bug(*args, **kwargs):
        raise ZeroDivisionError("float division by zero")

    monkeypatch.setattr("relmap.network.graph.RelationalMap.query", bug)
    status, _, err = run(capsys, "query", graph, "0", "2")
    assert status == 1
    assert_one_line_error(err, "query")
    assert "ZeroDivisionError" in err and "--debug" in err


def test_pipes_and_gzip_are_read_like_files(capsys, tmp_path):
    gz = tmp_path / "g.g2o.gz"
    gz.write_bytes(gzip.compress(G2O.encode()))
    status, out, err = run(capsys, "query", gz, "0", "2", "--json")
    assert status == 0, err
    r, w = os.pipe()  # what `relmap query <(zcat g.g2o.gz)` hands over: /dev/fd/N
    os.write(w, G2O.encode())
    os.close(w)
    try:
        status, piped, err = run(capsys, "query", f"/dev/fd/{r}", "0", "2", "--json")
    finally:
        os.close(r)
    assert status == 0, err
    assert piped == out


def test_closed_pipe_ends_quietly(tmp_path):
    """``relmap query … | head -c 20``: no BrokenPipeError traceback, no error line."""
    g = tmp_path / "g.g2o"
    g.write_text(G2O)
    proc = subprocess.Popen(
        [sys.executable, "-c", "import sys; from relmap.app.cli import main; sys.exit(main())",
         "query", str(g), "0", "2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # the reader goes away (as head does) before the command prints
    err = proc.stderr.read().decode()
    proc.wait(60)
    assert "Traceback" not in err and "BrokenPipe" not in err
    assert err == ""


@pytest.mark.real_data
def test_localize_on_overflowing_odometry_is_one_line_and_a_failure(data_dir, tmp_path):
    """A log with a 1e300 m/s velocity: exit 1 with one error line naming the overflow, no
    numpy warnings and no score printed (before: exit 0 with an inf RMSE and a NaN ANEES)."""
    source = data_dir / "landmarks" / "mrclam6"
    for f in source.iterdir():
        (tmp_path / f.name).symlink_to(f)
    odometry = tmp_path / "Robot1_Odometry.dat"
    lines = odometry.read_text().splitlines()
    odometry.unlink()
    fields = lines[200].split()
    fields[1] = "1e300"
    lines[200] = "  ".join(fields)
    odometry.write_text("\n".join(lines) + "\n")
    run = "import sys; from relmap.app.cli import main; sys.exit(main())"
    proc = subprocess.run(  # a process of its own: stderr as a user sees it
        [sys.executable, "-c", run, "localize", str(tmp_path), "--robot", "1"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    out, err = proc.stdout, proc.stderr
    assert proc.returncode == 1 and "RMSE" not in out
    assert err.count("\n") == 1 and err.startswith("relmap localize: error: ")
    assert "overflow" in err
