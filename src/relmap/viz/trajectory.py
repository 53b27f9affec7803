"""Plots of trajectories and their evaluation (matplotlib, imported when a function runs).

- :func:`paths`: trajectories in the x-y plane with the ``p`` ellipses of their positions'
  (x, y) marginals (Appendix A) where a covariance is known, the reference in black, the
  estimate's path coloured by its APE when given;
- :func:`error_components`: each chart error component ``truth ⊟ estimate`` over time with
  the ``±kσ`` band of the estimate's covariance;
- :func:`nees_plot`: NEES over time with the two-sided χ² bounds of one time;
- :func:`evaluation_figure` (all of them) and :func:`write_evaluation_report` (an HTML report
  with :class:`relmap.viz.report.Report`, the same writer as ``relmap demo``'s).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from relmap.uncertain import gaussian
from relmap.uncertain.trajectory import Trajectory
from relmap.viz.plot import ellipse, figure

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from relmap.evaluate import Evaluation

__all__ = [
    "error_components",
    "evaluation_figure",
    "nees_plot",
    "paths",
    "trajectories_figure",
    "write_evaluation_report",
]


def _xy_cov(traj: Trajectory) -> np.ndarray:
    return traj.poses.cov[:, :2, :2]


def _times(traj: Trajectory) -> tuple[np.ndarray, str]:
    if traj.stamps is None:
        return np.arange(len(traj), dtype=np.float64), "pose index"
    return traj.stamps - traj.stamps[0], "time [s]"


def paths(
    ax: Axes,
    trajs: Sequence[Trajectory],
    *,
    probability: float = 0.9,
    ellipses: int = 25,
    colour_by: np.ndarray | None = None,
    reference: Trajectory | None = None,
) -> Axes:
    """Paths in the x-y plane, ``ellipses`` position ellipses along each that has a covariance;
    with ``colour_by`` (one value per pose of the last trajectory, e.g. its APE) that path is
    drawn as coloured points with a colour bar."""
    if reference is not None:
        p = reference.positions
        ax.plot(p[:, 0], p[:, 1], color="k", linewidth=1.0, label=f"reference {_short(reference)}")
    for k, t in enumerate(trajs):
        p = t.positions
        colour = f"C{k}"
        last = k == len(trajs) - 1
        if colour_by is not None and last:
            sc = ax.scatter(p[:, 0], p[:, 1], c=colour_by, s=4, cmap="viridis", zorder=3)
            ax.figure.colorbar(sc, ax=ax, label="APE [m]")
        else:
            ax.plot(p[:, 0], p[:, 1], color=colour, linewidth=1.0, label=_short(t))
        if t.has_cov:
            idx = np.unique(np.linspace(0, len(t) - 1, min(len(t), ellipses)).round().astype(int))
            cov = _xy_cov(t)[idx]
            ok = np.trace(cov, axis1=1, axis2=2) > 0
            if ok.any():
                e = gaussian.ellipse(p[idx][ok, :2], cov[ok], probability)
                shade = "C3" if colour_by is not None and last else colour
                ellipse(ax, e, color=shade, linewidth=0.7)
                ax.plot([], [], color=shade, linewidth=0.7, label=f"{probability:.0%} ellipses")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="best", fontsize="small")
    return ax


def _short(t: Trajectory) -> str:
    s = t.source or "trajectory"
    return s if len(s) <= 40 else "…" + s[-39:]


def error_components(ax: Axes, ev: Evaluation, *, k: float = 3.0) -> Axes:
    """Chart error components over time with the ``±kσ`` bands of the estimate's covariance."""
    c = ev.consistency
    t, label = _times(ev.est)
    if c is None:
        ax.plot(t, ev.ape["trans"].values if "trans" in ev.ape else [], color="C0")
        ax.set_ylabel("APE [m]")
    else:
        keep = [i for i in range(c.errors.shape[1]) if (c.sigmas[:, i] > 0).any()]
        for n, i in enumerate(keep):
            colour = f"C{n}"
            ax.plot(t, c.errors[:, i], color=colour, linewidth=0.8, label=f"δ{c.axes[i]}")
            ax.fill_between(t, -k * c.sigmas[:, i], k * c.sigmas[:, i], color=colour, alpha=0.15)
        ax.set_ylabel(f"truth ⊟ estimate, ±{k:g}σ bands [m, rad]")
        ax.legend(loc="best", fontsize="small", ncol=3)
    ax.set_xlabel(label)
    return ax


def nees_plot(ax: Axes, ev: Evaluation, *, confidence: float = 0.95) -> Axes:
    """NEES of the full pose over time with the two-sided χ² bounds of one time."""
    c = ev.consistency
    t, label = _times(ev.est)
    if c is None:
        ax.text(0.5, 0.5, "no covariance: no NEES", ha="center", transform=ax.transAxes)
        return ax
    b = c.blocks["pose"]
    ax.semilogy(t, np.maximum(b.values, 1e-6), color="C0", linewidth=0.8, label="NEES (pose)")
    dof = int(np.median(b.dof))
    lo = float(gaussian.confidence_k2((1 - confidence) / 2, dof))
    hi = float(gaussian.confidence_k2(1 - (1 - confidence) / 2, dof))
    for v in (lo, hi):
        ax.axhline(v, color="k", linestyle="--", linewidth=0.8)
    ax.axhline(dof, color="C2", linewidth=0.8, label=f"dof = {dof}")
    ax.set_title(f"{b.verdict}; ANEES {b.anees:.3g}", fontsize="small")
    ax.set_xlabel(label)
    ax.set_ylabel(f"NEES, {confidence:.0%} χ²_{dof} bounds")
    ax.legend(loc="best", fontsize="small")
    return ax


def trajectories_figure(trajs: Sequence[Trajectory], *, probability: float = 0.9) -> Figure:
    """One x-y plot of several trajectories with their ellipses."""
    fig, ax = figure(figsize=(7.5, 6.5))
    paths(ax, trajs, probability=probability)
    fig.tight_layout()
    return fig


def evaluation_figure(ev: Evaluation, *, probability: float = 0.9) -> Figure:
    """Paths (estimate coloured by APE, ellipses), APE over time, error components with ±3σ
    bands, and NEES with its χ² bounds."""
    fig, _ = figure(figsize=(13, 10))
    fig.clear()
    axs = fig.subplots(2, 2)
    ape = ev.ape["trans"].values if "trans" in ev.ape else None
    paths(axs[0, 0], [ev.est], probability=probability, colour_by=ape, reference=ev.ref)
    axs[0, 0].set_title(f"{len(ev.est)} pairs, alignment {ev.alignment.mode}", fontsize="small")
    t, label = _times(ev.est)
    if ape is not None:
        axs[0, 1].plot(t, ape, color="C0", linewidth=0.8)
        axs[0, 1].set_ylabel("APE translation [m]")
        axs[0, 1].set_xlabel(label)
        s = ev.ape["trans"].stats()
        axs[0, 1].set_title(f"RMSE {s['rmse']:.4g} m, median {s['median']:.4g} m", fontsize="small")
    error_components(axs[1, 0], ev)
    nees_plot(axs[1, 1], ev)
    fig.tight_layout()
    return fig


def write_evaluation_report(ev: Evaluation, folder: str | os.PathLike[str]) -> Any:
    """An HTML report (:class:`relmap.viz.report.Report`) of an evaluation into ``folder``; returns
    the path of its ``index.html``."""
    from relmap.viz.report import Report

    rep = Report(f"relmap eval: {_short(ev.est)}")
    rep.paragraph(
        f"Estimate `{ev.est.source}` against reference `{ev.ref.source}`: {len(ev.est)} associated "
        f"poses, alignment `{ev.alignment.mode}` (scale {ev.alignment.scale:.6g})."
    )
    stats = ("rmse", "mean", "median", "std", "min", "max")
    rows = [[f"APE {k}", *(f"{e.stats()[s]:.5g}" for s in stats)] for k, e in ev.ape.items()]
    rows += [[f"RPE {k}", *(f"{e.stats()[s]:.5g}" for s in stats)] for k, e in ev.rpe.items()]
    rep.table(["error", *stats], rows, caption="Errors (evo's definitions)")
    c = ev.consistency
    if c is not None:
        rep.paragraph(f"Consistency of the estimate's covariance: {c.verdict}.")
        rows = [
            [
                name,
                f"{b.anees:.4g}",
                f"[{b.interval[0]:.4g}, {b.interval[1]:.4g}]",
                b.verdict,
                ", ".join(f"{p:.0%}: {v:.1%}" for p, v in b.coverage.items()),
            ]
            for name, b in c.blocks.items()
        ]
        rep.table(["block", "ANEES", "interval", "verdict", "coverage"], rows, caption="NEES")
    else:
        rep.paragraph("The estimate carries no covariance: no consistency check.")
    rep.figure(evaluation_figure(ev), "evaluation.png", "Paths, APE, errors with ±3σ bands, NEES")
    return rep.write(folder)
