"""Plotting with matplotlib: confidence ellipses of ATs, relational maps, Monte Carlo clouds,
trajectories, 3-D ellipsoid projections (the figures of a localization run are
:mod:`relmap.viz.localization`; of a trajectory evaluation, :mod:`relmap.viz.trajectory`).

matplotlib is imported inside the functions, never by ``import relmap``. Every drawing
function takes a matplotlib ``Axes`` and returns it, so calls chain and compose with the
caller's own plotting; ``**style`` goes to matplotlib (``color``, ``linewidth``, ``alpha``,
``label``, ``zorder``, …). Figures are built without pyplot (``matplotlib.figure.Figure``), so
nothing here needs a display or changes global state.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import numpy as np

from relmap.errors import ParameterError, ShapeError
from relmap.uncertain.at import AT
from relmap.uncertain.gaussian import Ellipse

if TYPE_CHECKING:  # pragma: no cover
    from collections.abc import Hashable

    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from relmap.network.graph import RelationalMap
    from relmap.network.query import QueryMethod
    from relmap.sim.montecarlo import SampleSet
    from relmap.uncertain.at3 import AT3

__all__ = [
    "ellipse",
    "ellipsoid",
    "figure",
    "monte_carlo",
    "relational_map",
    "save_png",
    "trajectory",
]


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
    tick: float | None = 0.0,
    **style: Any,
) -> Axes:
    """Draw a path through ``poses`` (``(N, 2+)`` array of x, y[, θ], or an AT batch's means),
    and, when ``ats`` (an AT batch of the same length) is given, the ``probability`` ellipses
    of every ``every``-th of them (default: about ten along the path, first and last included)
    in the path's colour, solid and thinner than the path; ``tick`` is the heading tick of
    :func:`ellipse` (default none: the path shows the heading). ``style`` goes to
    ``Axes.plot``.
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
        ellipse(ax, ats[idx], probability, tick=tick, color=line.get_color(), linewidth=width)
    return ax


def figure(*, figsize: tuple[float, float] = (6.4, 4.8), ncols: int = 1) -> tuple[Figure, Any]:
    """A new figure without pyplot (Agg canvas: no display, no global state) and its axes
    (one ``Axes``, or an array of ``ncols`` side by side)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, ncols, squeeze=True)
    return fig, axes


def _metres(ax: Axes, x: str = "x", y: str = "y") -> None:
    ax.set_xlabel(f"{x} [m]")
    ax.set_ylabel(f"{y} [m]")
    ax.set_aspect("equal", adjustable="datalim")


def relational_map(
    ax: Axes,
    g: RelationalMap,
    reference: Hashable,
    probability: float = 0.9,
    *,
    method: QueryMethod | str = "auto",
    ellipses: bool = True,
    labels: bool = True,
    color: str = "C0",
) -> Axes:
    """Draw a relational map relative to the frame ``reference``: every frame connected to it
    at its estimated position (``g.query(reference, frame, method=method)``), each AT as an
    arrow from its source frame to its destination frame labelled with its name, and each
    frame's ``probability`` ellipse relative to ``reference`` (Appendix A). The reference frame
    is drawn as a square, with no ellipse (it is known exactly relative to itself). Equal
    aspect ratio, axes in metres (in ``reference``'s frame)."""
    from relmap.errors import DisconnectedError

    pose: dict[Hashable, AT] = {}
    for f in g.frames:
        try:
            pose[f] = g.query(reference, f, method=method).at  # type: ignore[assignment]
        except DisconnectedError:
            continue
    if not pose or not isinstance(pose[reference], AT):
        raise ParameterError("relational_map draws planar maps (AT), relative to a map frame")
    xy = {f: at.mean[:2] for f, at in pose.items()}
    for e in g.edges():
        if e.src not in xy or e.dst not in xy:
            continue
        a, b = xy[e.src], xy[e.dst]
        ax.annotate(
            "",
            xy=b,
            xytext=a,
            arrowprops={
                "arrowstyle": "-|>",
                "color": "0.45",
                "lw": 1.0,
                "shrinkA": 4,
                "shrinkB": 4,
            },
        )
        if labels:
            mid = (a + b) / 2
            ax.annotate(
                e.name,
                mid,
                color="0.25",
                fontsize="small",
                ha="center",
                va="center",
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8},
            )
    others = [f for f in pose if f != reference]
    if ellipses and others:
        ellipse(ax, AT.stack([pose[f] for f in others]), probability, color=color)
    ax.plot(*np.array([xy[f] for f in others]).T, "o", color=color, markersize=4)
    ax.plot(*xy[reference], "s", color="k", markersize=6)
    if labels:
        for f, p in xy.items():
            ax.annotate(
                str(f), p, xytext=(5, 5), textcoords="offset points", fontsize="medium", zorder=5
            )
    _metres(ax, f"x in {reference}", f"y in {reference}")
    return ax


def monte_carlo(
    ax: Axes,
    samples: SampleSet,
    predicted: AT | None = None,
    probability: float = 0.9,
    *,
    max_points: int = 5000,
    seed: int = 0,
    color: str = "C3",
) -> Axes:
    """A Monte Carlo cloud (the paper's Fig. 5): at most ``max_points`` of the samples'
    positions (a random subset), the ``probability`` ellipse of ``predicted`` (the first-order
    estimate, solid) and of the samples' own mean and covariance (dashed). Equal aspect ratio,
    axes in metres, a legend."""
    pts = np.asarray(samples.samples, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ShapeError(f"monte_carlo draws planar samples (n, 3); got {pts.shape}")
    if len(pts) > max_points:
        pts = pts[np.random.default_rng(seed).choice(len(pts), max_points, replace=False)]
    ax.plot(
        pts[:, 0],
        pts[:, 1],
        ".",
        color="0.35",
        markersize=1.5,
        alpha=0.5,
        label=f"Monte Carlo ({len(pts):,} of {samples.n:,} samples)",
        rasterized=True,
    )
    empirical = samples.as_at()
    assert isinstance(empirical, AT)
    ellipse(ax, empirical, probability, tick=0, color="C2", linestyle="--", linewidth=1.5)
    ax.plot([], [], color="C2", linestyle="--", label=f"{probability:.0%} ellipse of the samples")
    if predicted is not None:
        ellipse(ax, predicted, probability, tick=0, color=color, linewidth=1.8)
        ax.plot([], [], color=color, label=f"{probability:.0%} ellipse, first order")
    _metres(ax)
    ax.legend(loc="best", fontsize="small", markerscale=6)
    return ax


def ellipsoid(
    ax: Axes, at: AT3, probability: float = 0.9, *, plane: str = "xy", **style: Any
) -> Axes:
    """The shadow of an AT3's ``probability`` position ellipsoid (Appendix A, N = 3) on the
    ``plane`` ``"xy"``, ``"xz"`` or ``"yz"`` of the parent frame: the ellipse of the 2-D
    marginal scaled by the 3-D radius k (χ²₃), so it touches the ellipsoid's outline. A batch
    draws all of them. Axes labelled in metres, equal aspect ratio."""
    from relmap.uncertain import gaussian

    axes = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}
    if plane not in axes:
        raise ParameterError(f"plane must be 'xy', 'xz' or 'yz'; got {plane!r}")
    i, j = axes[plane]
    idx = np.array([i, j])
    mean = np.asarray(at.translation)[..., idx]
    cov = np.asarray(at.cov)[..., idx[:, None], idx[None, :]]
    e = gaussian.ellipse(mean, cov, probability)
    scale = float(np.sqrt(gaussian.confidence_k2(probability, 3))) / e.k
    shadow = e._replace(semi_major=e.semi_major * scale, semi_minor=e.semi_minor * scale)
    style.setdefault("color", "C0")
    ellipse(ax, shadow, **style)
    ax.plot(*np.reshape(mean, (-1, 2)).T, "+", color=style["color"])
    _metres(ax, plane[0], plane[1])
    return ax


def save_png(fig: Figure, path: str | os.PathLike[str], *, dpi: int = 100) -> None:
    """Write ``fig`` as a PNG to ``path`` by relmap's one writer
    (:func:`relmap.io.atomic.write_bytes_atomic`: atomic for a regular file, a symbolic link
    followed, a device or FIFO written in place; :class:`relmap.errors.OutputError` if the path
    cannot be written)."""
    import io

    from relmap.io.atomic import check_writable, write_bytes_atomic

    check_writable(path)  # before rendering
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    write_bytes_atomic(path, buf.getvalue())
