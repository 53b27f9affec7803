"""The figures of ``relmap localize --plot``: what every filter paper shows.

:func:`figure` draws five panels of a filter's run against ground truth (a :class:`Run`, such as
``relmap localize``'s result): the map (truth, the EKF with its 90% ellipses in a colour of their
own, dead reckoning, landmarks); the position and
heading errors against time with the filter's ±2σ bands; the NEES against time with its χ²₃
95% bounds; the normalised innovations of the used readings against the noise model's
density; and each used reading's NIS against time with its χ²_d 95% bounds. :func:`map_axes`
draws the map panel alone on a caller's axes. matplotlib is imported here only (through
:mod:`relmap.viz.plot`), when a figure is drawn.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Protocol

import numpy as np

from relmap.filter import autocalibration
from relmap.filter.landmarks import Status
from relmap.filter.logs import Trace
from relmap.lie import se2
from relmap.typing import FloatArray
from relmap.uncertain import gaussian
from relmap.uncertain.at import AT

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["Run", "figure", "map_axes"]


class Score(Protocol):
    rmse_position: float


class Calibration(Protocol):
    nu: float


class Run(Protocol):
    """What the figures read of a filter's run against ground truth."""

    dataset: str  #: "plaza" or another dataset's name (the title)
    robot: int | None  #: the robot's number, for the title
    associate: str  #: how readings were paired (the legend)
    t: FloatArray  #: (n,) the filter's times
    estimate: AT  #: (n,) its poses
    dead_reckoning: AT  #: (n,) odometry alone
    truth: FloatArray  #: (n, 3) ground truth at the times
    landmarks: FloatArray  #: (L, 2)
    calibration: Calibration  #: the noise (its Student-t dof ``nu``)
    score: Score  #: the filter's score
    baseline: Score  #: dead reckoning's
    trace: Trace  #: the filter's trace
    reading_t: FloatArray  #: (M,) the readings' times

    @property
    def nees(self) -> FloatArray: ...

    @property
    def anis(self) -> float: ...


#: Colours: truth, EKF, its ellipses, dead reckoning, landmarks.
TRUTH, EKF, ELLIPSES, DEAD_RECKONING, LANDMARKS = "k", "C0", "C2", "C1", "C3"


def map_axes(ax: Axes, run: Run, *, ellipses: int = 8) -> Axes:
    """Ground truth, the EKF estimate with ``ellipses`` of its 90% ellipses along it (their own
    colour), dead reckoning, and the landmarks; equal aspect ratio, metres, a legend."""
    from relmap.viz.plot import ellipse, trajectory

    ax.plot(*run.landmarks.T, "^", color=LANDMARKS, markersize=6, label="landmarks", zorder=4)
    trajectory(ax, run.truth, label="ground truth", color=TRUTH, linewidth=1.0)
    trajectory(ax, run.dead_reckoning, label="dead reckoning", color=DEAD_RECKONING,
               linewidth=1.0, ls="--")  # fmt: skip
    trajectory(ax, run.estimate, label=f"EKF ({run.associate})", color=EKF, linewidth=1.2)
    idx = np.unique(np.linspace(0, len(run.t) - 1, max(ellipses, 1)).astype(int))
    ellipse(ax, run.estimate[idx], 0.9, color=ELLIPSES, linewidth=1.0)
    ax.plot([], [], color=ELLIPSES, linewidth=1.0, label="EKF 90% ellipses")
    who = "CMU Plaza" if run.dataset == "plaza" else f"MRCLAM robot {run.robot}"
    ax.set_title(
        f"{who}: position RMSE {run.score.rmse_position:.2f} m "
        f"(dead reckoning {run.baseline.rmse_position:.2f} m)",
        fontsize="medium",
    )
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="best", fontsize="small")
    return ax


def figure(run: Run, *, ellipses: int = 12) -> Figure:
    """The five-panel figure of a localization run (module docstring)."""
    from relmap.viz.plot import figure as new_figure

    fig, _ = new_figure(figsize=(13, 9))
    fig.clear()
    grid = fig.add_gridspec(3, 2, width_ratios=(1.1, 1.0))
    ax_map = fig.add_subplot(grid[:2, 0])
    ax_err = fig.add_subplot(grid[0, 1])
    ax_head = fig.add_subplot(grid[1, 1], sharex=ax_err)
    ax_nees = fig.add_subplot(grid[2, 1], sharex=ax_err)
    sub = grid[2, 0].subgridspec(1, 2)
    ax_hist, ax_nis = fig.add_subplot(sub[0]), fig.add_subplot(sub[1])
    map_axes(ax_map, run, ellipses=ellipses)

    t = run.t - run.t[0]
    e = se2.minus(run.truth, run.estimate.mean)
    sd = np.sqrt(np.diagonal(run.estimate.cov, axis1=-2, axis2=-1))
    for i, (name, colour) in enumerate((("x", "C0"), ("y", "C4"))):
        ax_err.plot(t, e[:, i], color=colour, linewidth=0.7, label=f"error {name}")
        ax_err.fill_between(t, -2 * sd[:, i], 2 * sd[:, i], color=colour, alpha=0.15,
                            label=f"±2σ {name}")  # fmt: skip
    ax_err.set_ylabel("position error [m]")
    ax_err.legend(loc="upper right", fontsize="x-small", ncol=2)
    ax_err.set_title("truth ⊟ estimate, with the filter's ±2σ", fontsize="medium")
    ax_head.plot(t, e[:, 2], color="C0", linewidth=0.7, label="error θ")
    ax_head.fill_between(t, -2 * sd[:, 2], 2 * sd[:, 2], color="C0", alpha=0.15, label="±2σ θ")
    ax_head.set_ylabel("heading error [rad]")
    ax_head.legend(loc="upper right", fontsize="x-small")

    nees = run.nees
    lo, hi = (float(gaussian.confidence_k2(p, 3)) for p in (0.025, 0.975))
    ax_nees.semilogy(t, np.maximum(nees, 1e-6), color="C0", linewidth=0.6, label="NEES")
    ax_nees.axhline(lo, color="k", ls=":", linewidth=0.8, label="χ²₃ 95% bounds")
    ax_nees.axhline(hi, color="k", ls=":", linewidth=0.8)
    ax_nees.axhline(3.0, color="k", linewidth=0.6, alpha=0.5)
    inside = float(((nees >= lo) & (nees <= hi)).mean())
    ax_nees.set_title(
        f"NEES (3 dof; 3 if consistent): {inside:.0%} inside the 95% bounds", fontsize="medium"
    )
    ax_nees.set_xlabel("time [s]")
    ax_nees.legend(loc="upper right", fontsize="x-small")

    tr = run.trace
    used = tr.status == Status.USED
    y, S = tr.y, tr.S
    if y.ndim == 1:  # range only
        y, S = y[:, None], S[:, None, None]
    d = y.shape[-1]
    nu = float(run.calibration.nu)
    for i, name in enumerate(("range", "bearing")[:d]):
        w = y[used, i] / np.sqrt(S[used, i, i])
        ax_hist.hist(np.clip(w, -6, 6), bins=60, range=(-6, 6), density=True, histtype="step",
                     color=f"C{i}", label=f"{name} (used)")  # fmt: skip
    x = np.linspace(-6, 6, 400)
    model = "model" + (f" (Student-t, ν={nu:.3g})" if math.isfinite(nu) else "")
    density = np.exp(autocalibration.logpdf(x * x, 0.0, 1, nu))  # unit variance
    ax_hist.plot(x, density, color="k", linewidth=1.0, label=model)
    ax_hist.set_yscale("log")
    ax_hist.set_ylim(1e-4, 1.0)
    ax_hist.set_xlabel("innovation / predicted σ")
    ax_hist.legend(loc="lower center", fontsize="x-small")
    ax_hist.set_title("innovations vs\nthe noise model", fontsize="medium")

    rt = run.reading_t - run.t[0]
    ax_nis.semilogy(rt[used], np.maximum(tr.mahalanobis2[used], 1e-6), ".", markersize=1.5,
                    color="C0")  # fmt: skip
    lo, hi = (float(gaussian.confidence_k2(p, d)) for p in (0.025, 0.975))
    ax_nis.axhline(lo, color="k", ls=":", linewidth=0.8)
    ax_nis.axhline(hi, color="k", ls=":", linewidth=0.8)
    ax_nis.set_xlabel("time [s]")
    title = f"NIS per reading ({d} dof),\nNIS/dof {run.anis:.2f}"
    inflation = getattr(run.calibration, "inflation", 1.0)
    if inflation > 1.05:  # whitened readings: S holds the inflated R, so NIS < dof by design
        title += f" (σ ×{inflation:.2f}: < 1 by design)"
    ax_nis.set_title(title, fontsize="medium")
    fig.tight_layout()
    return fig
