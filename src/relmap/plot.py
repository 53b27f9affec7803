"""Plotting with matplotlib: confidence ellipses of ATs, trajectories, localization runs.

matplotlib is imported inside the functions, never by ``import relmap``. Every drawing
function takes a matplotlib ``Axes`` and returns it, so calls chain and compose with the
caller's own plotting; ``**style`` goes to matplotlib (``color``, ``linewidth``, ``alpha``,
``label``, ``zorder``, …). Figures are built without pyplot (``matplotlib.figure.Figure``), so
nothing here needs a display or changes global state.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from relmap.at import AT
from relmap.errors import ParameterError, ShapeError
from relmap.gaussian import Ellipse

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from relmap.localize import Localization

__all__ = ["ellipse", "localization", "save_png", "trajectory"]


def ellipse(
    ax: Axes,
    at_or_ellipse: AT | Ellipse,
    probability: float = 0.9,
    *,
    tick: float | None = None,
    points: int = 64,
    **style: Any,
) -> Axes:
    """Draw the ``probability`` confidence ellipse of an AT's position (Appendix A).

    A batch of ATs draws all of them (one line collection). For an AT a short tick from the
    centre shows the heading: ``tick`` long (metres), by default the ellipse's semi-major axis;
    ``tick=0`` draws none. An :class:`relmap.Ellipse` is drawn as given (its own probability;
    no heading, no tick). ``style`` goes to ``LineCollection`` (default colour ``C0``).
    """
    from matplotlib.collections import LineCollection

    if isinstance(at_or_ellipse, AT):
        e = at_or_ellipse.ellipse(probability)
        heading: np.ndarray | None = np.asarray(at_or_ellipse.mean[..., 2]).reshape(-1)
    elif isinstance(at_or_ellipse, Ellipse):
        e, heading = at_or_ellipse, None
    else:
        raise TypeError(f"expected an AT or an Ellipse; got {type(at_or_ellipse).__name__}")
    if tick is not None and (not np.isfinite(tick) or tick < 0):
        raise ParameterError(f"tick must be a non-negative length; got {tick}")
    curves = e.boundary(points).reshape(-1, points, 2)
    style.setdefault("color", "C0")
    label = style.pop("label", None)
    ax.add_collection(LineCollection(list(curves), label=label, **style))
    if heading is not None and tick != 0:
        center = np.asarray(e.center).reshape(-1, 2)
        length = (
            np.asarray(e.semi_major).reshape(-1) if tick is None else np.full(len(center), tick)
        )
        tip = center + length[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
        ax.add_collection(LineCollection(list(np.stack([center, tip], axis=1)), **style))
    ax.autoscale_view()
    return ax


def trajectory(
    ax: Axes,
    poses: AT | np.ndarray,
    *,
    ats: AT | None = None,
    every: int | None = None,
    probability: float = 0.9,
    label: str | None = None,
    **style: Any,
) -> Axes:
    """Draw a path through ``poses`` (``(N, 2+)`` array of x, y[, θ], or an AT batch's means),
    and, when ``ats`` (an AT batch of the same length) is given, the ``probability`` ellipses
    of every ``every``-th of them (default: about ten along the path, first and last included)
    in the path's colour. ``style`` goes to ``Axes.plot``.
    """
    xy = np.asarray(poses.mean if isinstance(poses, AT) else poses, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] < 2 or not len(xy):
        raise ShapeError(f"poses must have shape (N, 2) or (N, 3); got {xy.shape}")
    (line,) = ax.plot(xy[:, 0], xy[:, 1], label=label, **style)
    if ats is not None:
        if ats.batch_shape != (len(xy),):
            raise ShapeError(
                f"ats must be an AT batch of the path's length {len(xy)}; got {ats.batch_shape}"
            )
        if every is None:
            idx = np.unique(np.linspace(0, len(xy) - 1, min(len(xy), 10)).round().astype(int))
        elif int(every) != every or every < 1:
            raise ParameterError(f"every must be a positive integer; got {every}")
        else:
            idx = np.arange(0, len(xy), int(every))
        width = 0.6 * float(line.get_linewidth())
        ellipse(ax, ats[idx], probability, color=line.get_color(), linewidth=width)
    return ax


def localization(ax: Axes, run: Localization, *, ellipses: int = 8) -> Axes:
    """A localization run (:func:`relmap.localize.localize`): ground truth, the EKF estimate
    with ``ellipses`` of its 90% ellipses along it, dead reckoning, and the landmarks; equal
    aspect ratio, axes in metres, a legend."""
    n = len(run.t)
    every = max(1, (n - 1) // max(ellipses - 1, 1))
    ax.plot(*run.landmarks.T, "^", color="C3", markersize=6, label="landmarks", zorder=4)
    trajectory(ax, run.truth, label="ground truth", color="k", linewidth=1.0)
    trajectory(ax, run.dead_reckoning, label="dead reckoning", color="C1", linewidth=1.0, ls="--")
    trajectory(
        ax,
        run.estimate,
        ats=run.estimate,
        every=every,
        label=f"EKF ({run.associate})",
        color="C0",
        linewidth=1.2,
    )
    ax.plot([], [], color="C0", linewidth=0.7, label="90% ellipses")
    who = "CMU Plaza" if run.dataset == "plaza" else f"MRCLAM robot {run.robot}"
    ax.set_title(
        f"{who}: position RMSE {run.score.rmse_position:.2f} m "
        f"(dead reckoning {run.baseline.rmse_position:.2f} m)"
    )
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="best", fontsize="small")
    return ax


def save_png(fig: Figure, path: str | os.PathLike[str], *, dpi: int = 100) -> None:
    """Write ``fig`` as a PNG to ``path`` atomically: a temporary file in the same folder, then
    ``os.replace``, so a reader never sees a half-written image and a failure leaves none."""
    target = Path(path)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".png")
    os.close(fd)
    try:
        fig.savefig(tmp, format="png", dpi=dpi)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
