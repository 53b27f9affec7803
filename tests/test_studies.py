"""The executable notes of docs/studies run, at a small size, and still show what they claim."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from tests.conftest import PROJECT_ROOT

STUDIES = PROJECT_ROOT / "docs" / "studies"


def run(name: str, *args: str) -> str:
    done = subprocess.run(
        [sys.executable, str(STUDIES / name), *args],
        capture_output=True,
        text=True,
        cwd=PROJECT_ROOT,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_every_note_is_run_here():
    assert {p.name for p in STUDIES.glob("*.py")} == {
        "moments.py",
        "delta_y.py",
        "sphere2500_information.py",
        "huber_false_closures.py",
    }


@pytest.mark.slow
def test_moments_exact_within_the_sample_error_and_first_order_not():
    out = run("moments.py", "--samples", "20000")
    rows = [r.split("|")[1:-1] for r in out.splitlines() if re.match(r"\| (straight|curved)", r)]
    assert len(rows) == 8
    for row in rows:
        first, _, _, exact, se = (float(c.strip(" %")) for c in row[2:7])
        assert exact < 3 * se  # the exact moments: within the Monte Carlo's own error
        if row[1].strip() == "10°":
            assert first > 30  # first order: 43% off at 10° per link
    assert "10,000 links" in out


@pytest.mark.slow
def test_delta_y_consistent_star_is_the_optimal_estimate_on_the_bridge():
    out = run("delta_y.py", "--samples", "500", "--solves", "10", "--maps", "10")
    rows = [r.split("|")[1:-1] for r in out.splitlines() if re.match(r"\| [\d.]+° \|", r)]
    assert len(rows) == 10
    assert all(r[2].strip() == "0.00%" and r[4].strip() == "0.00%" for r in rows)
    assert all(r[3].strip() != "0.00%" for r in rows)  # the paper's star is not
    assert "10 random maps" in out and "sampled bridges" in out


@pytest.mark.real_data
def test_sphere2500_is_whitened_by_its_numbers_read_as_square_root_information(data_dir):
    out = run("sphere2500_information.py", "--data", str(data_dir))
    chi2 = [float(x) for x in re.findall(r"χ² of the truth ([\d.]+)", out)]
    assert len(chi2) == 2
    assert chi2[0] < 0.5 and chi2[1] == pytest.approx(6.0, abs=0.3)


@pytest.mark.real_data
def test_huber_keeps_intel_near_its_optimum_with_one_false_closure(data_dir):
    out = run(
        "huber_false_closures.py",
        "--data",
        str(data_dir),
        "--graphs",
        "intel",
        "--counts",
        "1",
        "--seeds",
        "1",
    )
    rows = [r.split("|")[1:-1] for r in out.splitlines() if r.startswith("| intel |")]
    assert len(rows) == 1
    least, huber, huber_small = (float(c.split()[0]) for c in rows[0][3:6])
    assert least > 1.0 and huber < least / 5 and huber_small < least / 5
