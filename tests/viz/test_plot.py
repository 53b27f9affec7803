"""relmap.viz.plot: every function takes and returns an Axes and draws something visible."""

from __future__ import annotations

import numpy as np
import pytest

import relmap as rm
from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.sim import montecarlo
from relmap.uncertain import gaussian
from relmap.viz import plot
from tests.helpers import fig3_bridge


def _pixels(fig) -> np.ndarray:
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3]


def bridge() -> rm.RelationalMap:
    g = fig3_bridge()
    g.add("z1", "z2", rm.AT([1.0, 0.0, 0.0]), name="elsewhere")  # not connected to w
    return g


def test_figure_needs_no_pyplot():
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig, axes = plot.figure(ncols=2)
    assert len(axes) == 2
    assert type(fig.canvas) is FigureCanvasAgg  # not a pyplot-managed window


def test_relational_map_draws_frames_arrows_and_ellipses():
    fig, ax = plot.figure()
    assert plot.relational_map(ax, bridge(), "w", 0.9, method="optimal") is ax
    texts = {t.get_text() for t in ax.texts}
    assert {"w", "t", "u", "v", "A", "B", "C", "D", "E"} <= texts
    assert "z1" not in texts  # frames not connected to the reference are left out
    assert ax.get_aspect() == 1.0 and ax.get_xlabel() == "x in w [m]"
    assert len(ax.collections) == 2  # ellipses and heading ticks
    assert _pixels(fig).var() > 0
    with pytest.raises(rm.errors.UnknownFrameError):
        plot.relational_map(ax, bridge(), "nowhere")


def test_monte_carlo_cloud_over_the_predicted_ellipse():
    a = rm.AT.from_sigmas([1.0, 0.0, 0.0], [0.02, 0.02, np.radians(10)])
    mc = montecarlo.simulate(se2.compose, a, a, n=3000, seed=0)
    _, ax = plot.figure()
    assert plot.monte_carlo(ax, mc, a @ a, 0.9, max_points=500) is ax
    (cloud,) = [ln for ln in ax.lines if len(ln.get_xdata()) == 500]
    assert cloud.get_label().startswith("Monte Carlo (500 of 3,000")
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any("first order" in s for s in labels) and any("samples" in s for s in labels)
    assert ax.get_xlabel() == "x [m]" and ax.get_aspect() == 1.0
    bad = montecarlo.SampleSet.of(np.tile([1.0, 0.0, 0.0], (3, 2, 1)))
    with pytest.raises(ShapeError):
        plot.monte_carlo(ax, bad)


@pytest.mark.parametrize("plane", ["xy", "xz", "yz"])
def test_ellipsoid_projection_touches_the_ellipsoid(plane):
    q = [0.0, 0.0, np.sin(np.pi / 8), np.cos(np.pi / 8)]
    cov = np.diag([0.04, 0.01, 0.09, 1e-4, 1e-4, 1e-4])
    cov[0, 1] = cov[1, 0] = 0.01
    at = rm.AT3([1.0, 2.0, 3.0], q, cov)
    _, ax = plot.figure()
    assert plot.ellipsoid(ax, at, 0.9, plane=plane) is ax
    (curve,) = ax.collections[0].get_segments()
    i, j = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}[plane]
    # The shadow's extent along an axis is k₃·σ along it (k₃ of the 3-D 90% ellipsoid).
    k3 = np.sqrt(gaussian.confidence_k2(0.9, 3))
    for axis, col in ((i, 0), (j, 1)):
        half = (curve[:, col].max() - curve[:, col].min()) / 2
        np.testing.assert_allclose(half, k3 * np.sqrt(cov[axis, axis]), rtol=2e-3)
    assert ax.get_xlabel() == f"{plane[0]} [m]"
    with pytest.raises(ParameterError):
        plot.ellipsoid(ax, at, plane="xx")


def test_trajectory_ellipses_have_no_tick_by_default():
    steps = rm.AT.from_sigmas(np.tile([0.2, 0.0, 0.05], (30, 1)), [0.01, 0.01, 0.01])
    track = rm.compound_chain(steps)
    _, ax = plot.figure()
    plot.trajectory(ax, track, ats=track, every=10)
    assert len(ax.collections) == 1  # the ellipses only
    plot.trajectory(ax, track, ats=track, every=10, tick=0.1)
    assert len(ax.collections) == 3


def test_save_png_writes_a_visible_image(tmp_path):
    from matplotlib.image import imread

    fig, ax = plot.figure()
    plot.ellipse(ax, rm.AT.from_sigmas([1.0, 2.0, 0.5], [0.2, 0.1, 0.1]))
    plot.save_png(fig, tmp_path / "e.png")
    img = imread(tmp_path / "e.png")
    assert img[..., :3].var() > 0
    assert [p.name for p in tmp_path.iterdir()] == ["e.png"]
