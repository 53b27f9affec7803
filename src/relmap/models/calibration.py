"""Odometry noise from data: fit a :class:`DistanceNoise` to logged velocities and ground truth.

The random-walk model says that over any stretch of driving the odometry's error has variance
``k_s·(distance)`` along the track and ``k_theta·(turned angle) + k_theta_s·(distance)`` in
heading — linear in the parameters. So the parameters follow from short windows of a run by
the method of moments: dead-reckon each window from the true pose at its start, compare its end
with the true relative pose, and regress the squared errors on the window's distance and
turned angle (non-negative least squares). The position error across the track comes from the
heading error and is not fitted separately. Windows are short (a few seconds) so that the
errors stay small and Gaussian; the fit is judged afterwards on whole runs (how often the truth
falls inside the predicted 90% ellipse).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.models.odometry import DistanceNoise, increment, increments_from_velocities
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain.algebra import compound_chain
from relmap.uncertain.at import AT

__all__ = ["NoiseFit", "fit_distance_noise"]


class NoiseFit(NamedTuple):
    """The fitted model and what it was fitted on."""

    noise: DistanceNoise
    windows: int  #: number of windows used
    window: float  #: window length, s
    residual_rms: FloatArray  #: RMS of (along-track, heading) errors over the windows (m, rad)


def fit_distance_noise(
    t: ArrayLike,
    v: ArrayLike,
    w: ArrayLike,
    truth_at: Callable[[FloatArray], FloatArray],
    *,
    window: float = 2.0,
    min_distance: float = 0.05,
) -> NoiseFit:
    """Fit ``DistanceNoise(k_s, k_theta, k_theta_s)`` to a velocity log ``(t, v, ω)``.

    ``truth_at(times) -> (k, 3)`` gives the true pose at any time (e.g. interpolated ground
    truth). Windows of ``window`` seconds in which the robot moved at least ``min_distance``
    metres are used. The along-track variance gives ``k_s``; the heading variance gives
    ``k_theta`` and ``k_theta_s`` by non-negative least squares.
    """
    from scipy.optimize import nnls

    t = np.asarray(t, dtype=np.float64)
    motion = increments_from_velocities(t, v, w)
    if not window > 0:
        raise ParameterError(f"window must be positive; got {window}")
    edges = np.arange(t[0], t[-1], window)
    start_idx = np.searchsorted(t, edges)
    start_idx = np.unique(start_idx[start_idx < len(t) - 1])
    if len(start_idx) < 3:
        raise ShapeError("the log is too short for the chosen window")
    bounds = np.append(start_idx, len(t) - 1)
    # The run's odometry poses: a window's odometry is between(P_a, P_b) (compounding is
    # associative), so one pass serves all windows.
    P = compound_chain(AT._trusted(increment(motion), np.zeros((len(motion), 3, 3)))).mean
    P = np.concatenate([np.zeros((1, 3)), P])
    cum_s = np.concatenate([[0.0], np.cumsum(np.abs(motion[:, 0]))])
    cum_t = np.concatenate([[0.0], np.cumsum(np.abs(motion[:, 1]))])
    a, b = bounds[:-1], bounds[1:]
    moved = (b - a >= 2) & (cum_s[b] - cum_s[a] >= min_distance)
    a, b = a[moved], b[moved]
    odo = se2.between(P[a], P[b])
    truth = se2.between(np.asarray(truth_at(t[a])), np.asarray(truth_at(t[b])))
    e = se2.minus(odo, truth)
    direction = np.arctan2(truth[:, 1], truth[:, 0])
    err_along = e[:, 0] * np.cos(direction) + e[:, 1] * np.sin(direction)
    err_heading = e[:, 2]
    rows = np.column_stack([cum_s[b] - cum_s[a], cum_t[b] - cum_t[a]])
    if len(rows) < 3:
        raise ShapeError("too few windows in which the robot moved")
    D, ea, eh = rows, err_along, err_heading
    # method of moments: E[e_along²] = k_s·s ; E[e_θ²] = k_theta·θ + k_theta_s·s
    k_s = float(np.sum(ea**2 * D[:, 0]) / np.sum(D[:, 0] ** 2))
    (k_theta, k_theta_s), _ = nnls(D[:, [1, 0]], eh**2)
    noise = DistanceNoise(max(k_s, 0.0), float(k_theta), float(k_theta_s))
    return NoiseFit(
        noise, len(rows), window, np.array([np.sqrt(np.mean(ea**2)), np.sqrt(np.mean(eh**2))])
    )
