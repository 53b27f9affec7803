"""`relmap demo`: the report builds, refers only to files that exist, its figures are not
blank, and the numbers printed and shown are the library's (one run of the command serves
every test; `relmap demo` as a process of its own is run by .ci/run from the installed wheel)."""

from __future__ import annotations

import contextlib
import io
import re

import numpy as np
import pytest

from relmap.app import demo as d

pytestmark = pytest.mark.slow  # every test shares one built report (a full demo run)

SAMPLES = 2000  # reduced Monte Carlo sizes: the test checks plumbing, not statistics


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """One ``relmap demo`` (the command, run in this process): the demo's result (seen on its
    way from :func:`relmap.app.demo.run` to the report), the report's index and what it printed."""
    from relmap.app.cli import main

    runs = []
    real_run, real_print = d.run, d.print_demo
    out = io.StringIO()

    def run(*args, **kwargs):  # the command's own call, recorded
        runs.append(real_run(*args, **kwargs))
        return runs[-1]

    def print_demo(demo, *args):  # its default stream is bound at import: say where to
        real_print(demo, out)

    folder = tmp_path_factory.mktemp("report") / "report"
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(out):
        mp.setattr(d, "run", run)
        mp.setattr(d, "print_demo", print_demo)
        code = main(["demo", "--seed", "3", "--samples", str(SAMPLES), "--out", str(folder)])
    assert code == 0 and len(runs) == 1
    return runs[0], folder / "index.html", out.getvalue()


def test_demo_prints_the_library_results(built):
    """The command prints the library's Fig. 1 compounds and merge, the Monte Carlo check and
    where the report went."""
    _, index, text = built
    result = d.fig1()
    rows = {
        m.group(1).strip(): m
        for m in re.finditer(r"^(\S+(?: = \S+ ⊕ \S+)?|G ⊗ Sᴿ|Sᴿ)\s+(\S+→\S+)\s+(.*)$", text, re.M)
    }
    for label, _, _, at in result.compounds:
        numbers = [float(v) for v in rows[label].group(3).split()]
        np.testing.assert_allclose(numbers[:2], at.mean[:2], atol=5e-4)
        np.testing.assert_allclose(numbers[2], np.degrees(at.mean[2]), atol=5e-3)
        e = at.ellipse(0.9)
        np.testing.assert_allclose(numbers[6:8], [e.semi_major, e.semi_minor], atol=5e-5)
    merged = [float(v) for v in rows["G ⊗ Sᴿ"].group(3).split()]
    np.testing.assert_allclose(merged[:2], result.merged.mean[:2], atol=5e-4)
    assert "Monte Carlo check of G" in text
    assert index.is_file()
    assert f"Report written to {index}" in text


def test_report_refers_only_to_files_that_exist(built):
    _, index, _ = built
    html = index.read_text(encoding="utf-8")
    refs = re.findall(r'(?:src|href)="([^"]+)"', html)
    assert len(refs) >= 5
    for ref in refs:
        assert not re.match(r"[a-z]+:", ref), ref  # nothing from the network
        assert (index.parent / ref).is_file(), ref
    for section in ("Fig. 1", "Wheatstone bridge", "§6.3", "Decisions ahead of time", "lecture"):
        assert section in html
    assert not list(index.parent.glob(".*"))  # no temporary files left


def test_every_figure_is_a_non_blank_png(built):
    from matplotlib.image import imread

    _, index, _ = built
    pngs = sorted(index.parent.glob("*.png"))
    assert {p.name for p in pngs} >= {"fig1.png", "bridge.png", "fig5.png", "decisions.png"}
    for p in pngs:
        assert p.stat().st_size > 1000
        img = imread(p)
        assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 200
        assert img[..., :3].var() > 1e-3, p.name  # not a blank canvas


def test_printed_and_reported_numbers_are_the_librarys(built):
    result, index, text = built
    html = index.read_text(encoding="utf-8")
    # §6.3 table: every cell printed and shown equals the computed check
    rows = d.fig5_rows(result.fig5)
    for row in rows:
        assert re.search(r"\s+".join(re.escape(c) for c in row), text), row
        assert all(f"<td>{c}</td>" in html for c in row), row
    c = result.fig5.get(d.CHAIN_LINKS, d.SIGMAS_DEG[-1])
    mean_err = np.linalg.norm(c.agreement.mean_error[:2]) / np.linalg.norm(c.samples.mean[:2])
    assert rows[-1][5] == f"{mean_err:.2%}"
    # the bridge: expressions and predicted sigmas equal fresh queries of the shipped map
    g = result.bridge.map()
    for (src, dst, method), v in result.bridge.checks.items():
        est = g.query(src, dst, method=method)
        np.testing.assert_allclose(v.estimate.at.cov, est.at.cov, rtol=1e-9, atol=1e-15)
        if est.expression:
            assert est.expression in text and est.expression in html
        sx = f"{est.at.sigmas[0]:.4f}"
        assert re.search(rf"^{src}→{dst}\s+{method}\s+{re.escape(sx)}\s", text, re.M)
    # decisions: printed probabilities are the decisions'
    for b, a in (result.decisions.door_decision, result.decisions.view_decision):
        assert f"P = {float(b.probability):.5f} → {float(a.probability):.5f}" in text
    # Fig. 1 rows still printed as before
    G = result.fig1.compounds[-1][3]
    assert re.search(rf"G = F ⊕ D\s+W→L4\s+{G.mean[0]:.3f}\s+{G.mean[1]:.3f}", text)
    assert f"{result.lecture.ekf_score.rmse_position:.3f} m" in text


def test_decisions_improve_after_sensing(built):
    result, _, _ = built
    for before, after in (result.decisions.door_decision, result.decisions.view_decision):
        assert after.probability > before.probability


def test_report_writes_atomically_and_rejects_bad_names(tmp_path):
    from relmap.errors import ParameterError
    from relmap.viz import plot
    from relmap.viz.report import Report

    rep = Report("t")
    fig, ax = plot.figure()
    ax.plot([0, 1], [0, 1])
    rep.figure(fig, "a.png", "a line")
    with pytest.raises(ParameterError):
        rep.figure(fig, "a.png", "again")
    with pytest.raises(ParameterError):
        rep.figure(fig, "../b.png", "outside")
    rep.paragraph("x < y & `A ⊕ B`")
    index = rep.write(tmp_path / "new")
    html = index.read_text(encoding="utf-8")
    assert "x &lt; y &amp; <code>A ⊕ B</code>" in html
    assert sorted(p.name for p in index.parent.iterdir()) == ["a.png", "index.html"]
