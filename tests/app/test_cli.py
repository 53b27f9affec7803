"""The relmap command: its version, usage and errors; the import stays light (what `relmap demo`
prints is checked in test_demo_report.py)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from relmap import __version__
from relmap.app.demo import fig1


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "relmap.app.cli", *args], capture_output=True, text=True, timeout=120
    )


def test_demo_merge_shrinks_uncertainty_and_monte_carlo_agrees():
    result = fig1()
    G = result.compounds[-1][3]
    assert np.all(result.merged.sigmas < G.sigmas)
    assert result.monte_carlo.cov_rel_error < 0.02


def test_version_and_usage():
    out = _run("--version")
    assert out.returncode == 0 and __version__ in out.stdout
    bad = _run("frobnicate")
    assert bad.returncode == 2 and "invalid choice" in bad.stderr


def test_import_stays_light():
    """`import relmap` and the first use of its main names must not pull in matplotlib,
    scipy.sparse/stats/special or yaml."""
    code = (
        "import sys, relmap; relmap.AT, relmap.AT3, relmap.RelationalMap, relmap.merge; "
        "heavy = [m for m in sys.modules if m.split('.')[0] in ('matplotlib', 'yaml') "
        "or m.startswith(('scipy.sparse', 'scipy.stats', 'scipy.special'))]; print(heavy)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "[]", out.stdout


def test_help_imports_neither_numpy_nor_scipy():
    """`relmap --help` starts light: the package's names are imported on first use only, and
    the trajectory commands' parsers (relmap.app.trajectory) are built only when they run."""
    code = (
        "import sys; from relmap.app.cli import main\n"
        "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
        "print([m for m in sys.modules if m.split('.')[0] in ('numpy', 'scipy', 'relmap') "
        "and m not in ('relmap', 'relmap._version', 'relmap.app', 'relmap.app.cli', "
        "'relmap.errors')], "
        "file=sys.stderr)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "usage: relmap" in out.stdout
    assert all(name in out.stdout for name in ("eval", "traj", "convert"))
    assert out.stderr.strip() == "[]", out.stderr


def test_a_trajectory_commands_parser_is_built_when_it_runs():
    """`relmap eval --help` builds eval's parser (its options are there)."""
    out = _run("eval", "--help")
    assert out.returncode == 0 and "--pairs-from-reference" in out.stdout


def test_relmap_typing_does_not_import_numpy_random():
    """The type aliases cost numpy alone: numpy.random is imported where randomness is drawn."""
    code = "import sys, relmap.typing; print('numpy.random' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "False", out.stdout + out.stderr


@pytest.mark.real_data
def test_validate_on_a_real_graph_prints_no_runaway_line(data_dir):
    """`relmap validate` on intel (2512 ATs) summarizes its list of sampled ATs (before: one
    16 313-character line); --verbose lists them all."""
    graph = str(data_dir / "posegraph2d" / "intel.g2o")
    proc = _run("validate", graph, "0", "1000", "-n", "2")
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert "sampled ATs: e0, e1" in out and "--verbose or --json for all" in out
    assert max(len(line) for line in out.splitlines()) <= 400
    full = _run("validate", graph, "0", "1000", "-n", "2", "--verbose").stdout
    assert ", e2511" in full


def test_solve_under_a_loss(tmp_path):
    """`relmap solve --loss huber:K`: the JSON summary names the loss and counts the edges it
    down-weighted (here the one false edge, whose pull Huber bounds)."""
    g2o = (
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n"
        "EDGE_SE2 0 1 1 0 0 100 0 0 100 0 1000\nEDGE_SE2 1 2 1 0 0 100 0 0 100 0 1000\n"
        "EDGE_SE2 0 2 2 0 0 100 0 0 100 0 1000\nEDGE_SE2 0 2 5 0 0 100 0 0 100 0 1000\n"
    )
    path = tmp_path / "g.g2o"
    path.write_text(g2o)
    plain = json.loads(_run("solve", str(path), "--json").stdout)
    robust = json.loads(_run("solve", str(path), "--json", "--loss", "huber:1").stdout)
    assert "loss" not in plain
    assert robust["loss"] == "Huber(k=1.0)" and robust["downweighted"] == 1
