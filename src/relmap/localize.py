"""EKF localization with a known map on real logs, scored against ground truth.

Two datasets (:mod:`relmap.io.datasets`): **UTIAS MRCLAM** (five robots, odometry velocities at
~100 Hz, barcoded range-bearing readings of 15 surveyed landmarks, Vicon ground truth) and **CMU
Plaza** (one robot, dead-reckoning steps every ~0.1 s, range-only readings of 4 radio beacons,
GPS ground truth). :func:`localize` runs one filter and returns a :class:`Localization`: the
estimate and dead reckoning at every filter time, and their :class:`Score` against the truth.

**The filter** (lecture Eqs. 13-28, :mod:`relmap.ekf`). Odometry and readings are processed in
time order. The filter's times are the odometry times merged with the reading times; between
two of them the odometry velocity (MRCLAM: each record's ``(v, ω)`` held until the next record;
Plaza: each step's Δdistance and Δheading spread evenly over the step) gives one step
``(Δs, Δθ)``, predicted with midpoint integration (Eq. 10) and the odometry noise. At a reading
time the state is predicted up to that time and corrected with all readings sharing the time
stamp, in one stacked update (Eqs. 26-28, Joseph form). The prediction over the odometry
steps between two reading times is one compound with the AT of those steps taken together —
exactly the repeated :func:`relmap.ekf.predict` of Eq. 13, since first-order compounding is
associative (tested) — and the ATs of all such stretches come from prefix sums over the run
(``_Odometry``), so there is no Python loop per odometry step, only one per reading time. The
state at the odometry times between readings (for scoring and plots) is the last posterior
compounded with the odometry since.

- MRCLAM, ``associate="signatures"``: each reading's barcode names its landmark; readings of
  barcodes that are no landmark (other robots, unknown barcodes) are not offered to the filter
  (counted as ``ignored``). A pair whose innovation lies outside the χ²₂ gate (``gate``,
  default 0.99) is rejected.
- MRCLAM, ``associate="mahalanobis"`` or ``"euclidean"`` (unknown correspondences): the barcode
  is used only to drop the readings of other robots and of unknown barcodes, as above (moving
  robots are no part of a static map, and the data's README says they are not landmarks);
  which landmark a reading is of is left to the association: one to one with the nearest
  landmark (Eq. 23, or Eq. 22 mixing metres and radians), then gated likewise.
- Plaza: range-only readings (the first row of Eq. 20), corrected by :func:`correct_ranges` (the
  same stacked Joseph update, χ²₁ gate). ``"signatures"`` pairs a reading with its beacon by
  the beacon id; ``"mahalanobis"``/``"euclidean"`` ignore the id and take the beacon whose
  predicted range is nearest (each reading on its own).

**Start and end.** MRCLAM: the filter starts at the first odometry time inside the ground
truth's span, from the true pose there with covariance ``diag(σ², σ², σθ²)``,
σ = :data:`START_SIGMA` (2 cm, 0.02 rad: Vicon is far better, but the filter should not start
exactly certain), and stops at the last odometry time inside that span. Plaza: the same, on the
second half of the run (below).

**Noise from data, never from the run being scored** (:class:`Calibration`).

- MRCLAM, leave-one-out by neighbour: robot k is scored with noise estimated on robot
  ``k mod 5 + 1`` alone (robot 1 on robot 2, …, robot 5 on robot 1), so every robot is scored
  and none with its own data. Odometry: :func:`relmap.robot.calibration.fit_distance_noise` on
  the training robot's whole run (inside its ground-truth span), windows of
  :data:`ODOMETRY_WINDOW` seconds (10 s: longer than the typical gap between readings, so the
  fit sees the errors that accumulate between corrections, including some of the systematic
  part; chosen once, not per robot). Sensor: residuals of the training robot's landmark
  readings (barcodes of landmarks only) against the reading predicted from the interpolated
  ground truth; σ = 1.4826·MAD (median absolute deviation about the median), robust to the heavy
  tails. The medians (biases) are reported but not corrected.
- Plaza (one run): the ground-truth span is cut at its midpoint time. The noise comes from the
  first half: odometry by the same windowed fit; the ranges' scale, ``median(z / r_true)``
  (measured ranges are about 7% long, in proportion to the range: with the scale removed the
  residuals have σ ≈ 0.5 m instead of a 2.8 m median bias), and the range σ by MAD of
  ``z / scale - r_true``. The filter divides readings by the scale, and runs and is scored on
  the second half only.

**Scores** (:class:`Score`), at every filter time, against the ground truth interpolated there
(``truth_at``): RMSE of the position and of the wrapped heading; ``coverage_90``, the fraction of
the times at which the true position lies inside the estimate's 90% position ellipse (nearly
uniform odometry times, so it is a fraction of time); ``anees``, the average over the times of
the NEES ``eᵀ Σ⁻¹ e`` (``e = truth ⊟ estimate``, 3 dof) divided by 3, so a consistent filter
gives about 1; ``rejected``, readings offered to the filter and not used (gated, or lost to a
closer reading of the same landmark). Dead reckoning from the same start with the same noise is
scored the same way (rejected 0).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from relmap import ekf, gaussian
from relmap.at import AT, compound, compound_chain
from relmap.errors import ParameterError, ShapeError
from relmap.io.datasets import (
    DatasetKind,
    Mrclam,
    Plaza,
    RobotLog,
    read_mrclam,
    read_plaza,
    recognise,
)
from relmap.lie import se2
from relmap.robot.calibration import fit_distance_noise
from relmap.robot.motion import DistanceNoise, _step_ats, increments_from_velocities
from relmap.sensors.polar import RangeBearingSensor
from relmap.typing import ArrayLike, FloatArray, IntArray

__all__ = [
    "ASSOCIATIONS",
    "ODOMETRY_WINDOW",
    "START_SIGMA",
    "Calibration",
    "Localization",
    "Score",
    "calibrate_mrclam",
    "calibrate_plaza",
    "correct_ranges",
    "localize",
    "localize_mrclam",
    "localize_plaza",
    "score",
    "sensor_residuals",
]

#: Ways to pair readings with landmarks (see :func:`relmap.ekf.correct_landmarks`).
ASSOCIATIONS = ("signatures", "mahalanobis", "euclidean")
#: Standard deviations ``(σx, σy, σθ)`` (m, m, rad) of the filters' start pose.
START_SIGMA = (0.02, 0.02, 0.02)
#: Window (s) of the odometry-noise fit (:func:`relmap.robot.calibration.fit_distance_noise`).
ODOMETRY_WINDOW = 10.0
#: σ of a normal distribution from its median absolute deviation.
MAD_TO_SIGMA = 1.4826

Progress = Callable[[int, int], None]


# ------------------------------------------------------------------------------ results
class Calibration(NamedTuple):
    """Noise estimated from data (see the module docstring for the scheme)."""

    #: Odometry noise, fitted by :func:`relmap.robot.calibration.fit_distance_noise`.
    odometry: DistanceNoise
    #: Robust σ of the range (m).
    sigma_range: float
    #: Robust σ of the bearing (rad); None for range-only sensors.
    sigma_bearing: float | None
    #: Median of the range residuals (m), not corrected.
    range_bias: float
    #: Median of the bearing residuals (rad), not corrected; None for range-only sensors.
    bearing_bias: float | None
    #: How many readings the sensor σ came from.
    readings: int
    #: What the noise was estimated on, e.g. ``"robot 2"``.
    trained_on: str
    #: Measured range = ``range_scale`` × true range (Plaza: estimated; MRCLAM: 1, not fitted).
    #: The filter divides readings by it before use.
    range_scale: float = 1.0


class Score(NamedTuple):
    """How an estimated trajectory compares with the ground truth (module docstring)."""

    rmse_position: float  #: m
    rmse_heading: float  #: rad
    coverage_90: float  #: fraction of times with the true position in the 90% ellipse
    anees: float  #: average NEES over the times, divided by 3 (≈ 1 when consistent)
    rejected: int  #: readings offered and not used


class Localization(NamedTuple):
    """One EKF run on a dataset, with dead reckoning for comparison and both scores."""

    dataset: DatasetKind  #: ``"mrclam"`` or ``"plaza"``
    robot: int | None  #: MRCLAM robot number; None for Plaza
    associate: str  #: how readings were paired with landmarks
    t: FloatArray  #: ``(n,)`` the filter's times (s)
    estimate: AT  #: ``(n,)`` the EKF's pose at each time (after any correction at that time)
    dead_reckoning: AT  #: ``(n,)`` odometry alone from the same start, same noise
    truth: FloatArray  #: ``(n, 3)`` ground truth interpolated at the times
    landmarks: FloatArray  #: ``(L, 2)`` the map (landmarks or beacons)
    calibration: Calibration  #: the noise used, and where it came from
    score: Score  #: the EKF's score
    baseline: Score  #: dead reckoning's score
    readings: dict[str, int]  #: what happened to the readings (ekf status names, "ignored")

    @property
    def steps(self) -> int:
        """Number of filter times (odometry and reading times) scored."""
        return len(self.t)

    def summary(self) -> dict[str, object]:
        """The JSON summary of ``relmap localize``: exactly these keys."""
        s = self.score
        return {
            "dataset": self.dataset,
            "robot": self.robot,
            "steps": self.steps,
            "rmse_position": s.rmse_position,
            "rmse_heading": s.rmse_heading,
            "coverage_90": s.coverage_90,
            "anees": s.anees,
            "rejected": s.rejected,
        }


# ------------------------------------------------------------------------------ scoring
def score(estimate: AT, truth: ArrayLike, *, rejected: int = 0) -> Score:
    """Score an estimated trajectory ``(n,)`` against true poses ``(n, 3)`` (module docstring)."""
    x = np.asarray(truth, dtype=np.float64)
    if estimate.ndim != 1 or x.shape != (*estimate.batch_shape, 3):
        raise ShapeError(
            f"need an AT batch (n,) and truth (n, 3); got {estimate.batch_shape} and {x.shape}"
        )
    e = se2.minus(x, estimate.mean)
    pos2 = e[:, 0] ** 2 + e[:, 1] ** 2
    d2_pos = _quadratic(e[:, :2], estimate.cov[:, :2, :2])
    nees = _quadratic(e, estimate.cov)
    return Score(
        rmse_position=float(np.sqrt(pos2.mean())),
        rmse_heading=float(np.sqrt((e[:, 2] ** 2).mean())),
        coverage_90=float((d2_pos <= gaussian.confidence_k2(0.9, 2)).mean()),
        anees=float(nees.mean() / 3.0),
        rejected=int(rejected),
    )


def _quadratic(e: FloatArray, cov: FloatArray) -> FloatArray:
    """``eᵀ C⁻¹ e`` per row, for positive-definite C (the filters start with Σ₀ > 0)."""
    return np.einsum("...i,...i->...", e, np.linalg.solve(cov, e[..., None])[..., 0])


# -------------------------------------------------------------------------- calibration
def _check_readings(count: int, what: str) -> None:
    """A ParameterError unless ``what`` has at least two readings to estimate a noise from."""
    if count < 2:
        raise ParameterError(
            f"cannot calibrate the sensor noise on {what}: {count} usable readings inside its "
            "ground-truth span (at least 2 needed)"
        )


def _robust(residuals: FloatArray, what: str) -> tuple[float, float]:
    """``(σ, median)``: σ = 1.4826·median(|r - median(r)|) of ``what``'s residuals."""
    _check_readings(len(residuals), what)
    med = float(np.median(residuals))
    return MAD_TO_SIGMA * float(np.median(np.abs(residuals - med))), med


def sensor_residuals(data: Mrclam, robot: int) -> FloatArray:
    """``(p, 2)`` range and bearing residuals (reading minus prediction from ground truth) of
    robot ``robot``'s landmark readings inside its ground-truth span; bearings wrapped."""
    log = _robot_log(data, robot)
    lm = data.landmark_index(log.meas_subject)
    t = log.meas_t
    keep = (lm >= 0) & (t >= log.truth_t[0]) & (t <= log.truth_t[-1])
    sensor = RangeBearingSensor(0.0, 0.0)
    predicted = sensor.predict(log.truth_at(t[keep]), data.landmark_xy[lm[keep]])
    out = np.column_stack([log.meas_range[keep], log.meas_bearing[keep]]) - predicted
    out[:, 1] = se2.wrap_angle(out[:, 1])
    return out


def _inside_truth(t: FloatArray, truth_t: FloatArray) -> np.ndarray:
    return (t >= truth_t[0]) & (t <= truth_t[-1])


def calibrate_mrclam(data: Mrclam, robot: int, *, window: float = ODOMETRY_WINDOW) -> Calibration:
    """Noise estimated on robot ``robot``'s data alone: odometry by the windowed fit, sensor σ
    by the MAD of its landmark readings' residuals (module docstring)."""
    log = _robot_log(data, robot)
    inside = _inside_truth(log.odometry_t, log.truth_t)
    fit = fit_distance_noise(
        log.odometry_t[inside],
        log.odometry_v[inside],
        log.odometry_w[inside],
        log.truth_at,
        window=window,
    )
    res = sensor_residuals(data, robot)
    sr, br = _robust(res[:, 0], f"robot {robot}")
    sb, bb = _robust(res[:, 1], f"robot {robot}")
    return Calibration(fit.noise, sr, sb, br, bb, len(res), f"robot {robot}")


def _plaza_velocities(data: Plaza) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(t, v, ω)`` of the DR steps: step k spans ``dr_pose_t[k] → dr_pose_t[k + 1]``."""
    t = np.asarray(data.dr_pose_t, dtype=np.float64)
    dt = np.diff(t)
    if len(t) != len(data.dr_distance) + 1 or (dt <= 0).any():
        raise ParameterError("Plaza DRp times must bracket every DR step, strictly increasing")
    v = np.append(data.dr_distance / dt, 0.0)
    w = np.append(data.dr_dheading / dt, 0.0)
    return t, v, w


def _plaza_split(data: Plaza) -> float:
    return 0.5 * (float(data.truth_t[0]) + float(data.truth_t[-1]))


def calibrate_plaza(data: Plaza, *, window: float = ODOMETRY_WINDOW) -> Calibration:
    """Noise estimated on the first half (in time) of a Plaza run (module docstring)."""
    mid = _plaza_split(data)
    t, v, w = _plaza_velocities(data)
    first = _inside_truth(t, data.truth_t) & (t <= mid)
    fit = fit_distance_noise(t[first], v[first], w[first], data.truth_at, window=window)
    keep = (
        (data.meas_beacon_index >= 0)
        & _inside_truth(data.meas_t, data.truth_t)
        & (data.meas_t <= mid)
    )
    _check_readings(int(keep.sum()), "the first half of the Plaza run")
    xy = data.truth_at(data.meas_t[keep])[:, :2]
    predicted = np.hypot(*(data.beacon_xy[data.meas_beacon_index[keep]] - xy).T)
    scale = float(np.median(data.meas_range[keep] / predicted))
    sr, br = _robust(data.meas_range[keep] / scale - predicted, "the first half of the Plaza run")
    return Calibration(
        fit.noise, sr, None, br, None, int(keep.sum()), "Plaza first half", range_scale=scale
    )


# ------------------------------------------------------------------------ range-only
def correct_ranges(
    state: AT,
    ranges: ArrayLike,
    beacons: ArrayLike,
    sigma: float,
    *,
    beacon: ArrayLike | None = None,
    associate: str = "signatures",
    gate: float = 0.99,
) -> ekf.LandmarkUpdate:
    """Correct a pose with range-only readings (the first row of lecture Eq. 20) of beacons.

    ``state`` is one pose AT (no batch), ``ranges`` ``(m,)`` metres, ``beacons`` ``(B, 2)``,
    ``sigma`` the range σ (constant). Association: ``"signatures"`` takes each reading's beacon
    row from ``beacon`` ``(m,)`` (``-1``: no beacon, UNKNOWN); ``"mahalanobis"`` the beacon of
    least ``v²/S`` and ``"euclidean"`` of least ``|v|``, each reading on its own (two readings
    may use one beacon). A pair with ``v²/S > χ²₁(gate)`` is GATED (Eq. 25); the used pairs form
    one stacked update (Eqs. 26-28) in Joseph form. Returns :class:`relmap.ekf.LandmarkUpdate`
    (landmark = beacon row).
    """
    z = np.asarray(ranges, dtype=np.float64)
    b = np.asarray(beacons, dtype=np.float64)
    if state.ndim != 0:
        raise ShapeError("correct_ranges takes one pose (no batch axes)")
    if z.ndim != 1 or b.ndim != 2 or b.shape[1] != 2 or not len(b):
        raise ShapeError(f"need ranges (m,) and beacons (B, 2); got {z.shape}, {b.shape}")
    if associate not in ASSOCIATIONS:
        raise ParameterError(f"associate must be one of {', '.join(ASSOCIATIONS)}; got {associate}")
    gaussian.check_probability(gate, "gate")
    m, P, x = len(z), state.cov, state.mean
    dx, dy = b[:, 0] - x[0], b[:, 1] - x[1]
    r = np.hypot(dx, dy)  # (B,)
    H = np.column_stack([-dx / r, -dy / r, np.zeros_like(r)])  # ∂r/∂(x, y, θ)
    S = np.einsum("bi,ij,bj->b", H, P, H) + sigma**2
    v = z[:, None] - r[None, :]  # (m, B)
    d2 = v * v / S
    usable = np.isfinite(z) & (z > 0)
    if associate == "signatures":
        if beacon is None:
            raise ParameterError("signature association needs the beacon of each reading")
        row = np.asarray(beacon, dtype=np.int64)
        if row.shape != (m,):
            raise ShapeError(f"beacon must have shape ({m},); got {row.shape}")
        known = (row >= 0) & (row < len(b))
    else:
        row = np.argmin(d2 if associate == "mahalanobis" else np.abs(v), axis=1)
        known = np.ones(m, bool)
    row = np.where(known, row, 0)
    pair_d2 = np.where(known & usable, d2[np.arange(m), row], np.inf)
    used = known & usable & (pair_d2 <= gaussian.confidence_k2(gate, 1))
    status = np.where(
        ~usable, ekf.INVALID, np.where(~known, ekf.UNKNOWN, np.where(used, ekf.USED, ekf.GATED))
    ).astype(np.int64)
    landmark = np.where(known & usable, row, -1).astype(np.int64)
    if not used.any():
        return ekf.LandmarkUpdate(state, landmark, pair_d2, status)
    Hs = H[row[used]]  # (k, 3)
    vs = v[np.flatnonzero(used), row[used]]
    PHt = P @ Hs.T
    Sk = Hs @ PHt + sigma**2 * np.eye(len(vs))
    K = np.linalg.solve(Sk, PHt.T).T  # Σ⁻ Hᵀ S⁻¹
    I_KH = np.eye(3) - K @ Hs
    cov = I_KH @ P @ I_KH.T + sigma**2 * (K @ K.T)
    mean = se2.plus(x, K @ vs)
    return ekf.LandmarkUpdate(AT._trusted(mean, 0.5 * (cov + cov.T)), landmark, pair_d2, status)


# ------------------------------------------------------------------------------ the loop
def _grid(
    odo_t: FloatArray, odo_v: FloatArray, odo_w: FloatArray, event_t: FloatArray, end: float
) -> tuple[FloatArray, FloatArray, IntArray]:
    """The filter's times, the steps ``(Δs, Δθ)`` between them, and each event's time index.

    Times: the odometry times in ``[odo_t[0], end]`` and the event times in that range, merged
    (unique). The velocity of the last odometry record at or before a time holds until the next
    time.
    """
    start = odo_t[0]
    ev = event_t[(event_t >= start) & (event_t <= end)]
    t = np.unique(np.concatenate([odo_t[odo_t <= end], ev]))
    k = np.searchsorted(odo_t, t, side="right") - 1  # last record at or before each time
    motion = increments_from_velocities(t, odo_v[k], odo_w[k])
    return t, motion, np.searchsorted(t, np.unique(ev))


class _Odometry:
    """The odometry of a run as relative ATs between any two of its times, in O(1) each.

    ``P_j`` is the odometry pose at time j from the first time (exact SE(2) composition of the
    step means: headings add, translations add after rotation). The AT from time a to time b
    is the compound of the steps a+1..b; its first-order covariance (the same as compounding
    the steps one by one, or :func:`relmap.compound_chain`, to rounding) is
    ``Σ H(p_b - p_i) C_i H(p_b - p_i)ᵀ`` over the steps, with ``C_i`` step i's covariance
    turned into the first frame's axes and ``H(d)`` the shear of Eq. 3 by the displacement
    ``d`` still to go. Expanding ``H`` turns the sum into differences of 15 prefix sums
    (weights 1, x, y, x², xy, y² of the step's end position), so every relative AT of a run
    costs a few array operations, with no loop over steps.
    """

    def __init__(self, motion: FloatArray, noise: DistanceNoise) -> None:
        steps = _step_ats(motion, noise, "midpoint", None)
        m = np.ascontiguousarray(steps.mean)
        c = np.ascontiguousarray(steps.cov)
        n = len(m) + 1
        theta = np.concatenate([[0.0], np.cumsum(m[:, 2])])  # unwrapped heading of P_j
        co, si = np.cos(theta[:-1]), np.sin(theta[:-1])
        x = np.concatenate([[0.0], np.cumsum(co * m[:, 0] - si * m[:, 1])])
        y = np.concatenate([[0.0], np.cumsum(si * m[:, 0] + co * m[:, 1])])
        # step covariances turned into the first frame's axes: blkdiag(R, 1) C blkdiag(R, 1)ᵀ
        cxx, cxy, cyy = c[:, 0, 0], c[:, 0, 1], c[:, 1, 1]
        cxt, cyt, ctt = c[:, 0, 2], c[:, 1, 2], c[:, 2, 2]
        rxx = co * co * cxx - 2 * co * si * cxy + si * si * cyy
        rxy = co * si * (cxx - cyy) + (co * co - si * si) * cxy
        ryy = si * si * cxx + 2 * co * si * cxy + co * co * cyy
        rxt = co * cxt - si * cyt
        ryt = si * cxt + co * cyt
        xe, ye = x[1:], y[1:]  # position after each step
        terms = np.stack(
            [
                *(rxx, rxy, ryy, rxt, ryt, ctt),
                *(ye * rxt, xe * rxt, xe * ryt, ye * ryt),
                *(xe * ctt, ye * ctt, xe * xe * ctt, ye * ye * ctt, xe * ye * ctt),
            ]
        )
        self.sums = np.zeros((15, n))
        np.cumsum(terms, axis=1, out=self.sums[:, 1:])
        self.pose = np.column_stack([x, y, theta])
        self.n = n

    def between(self, a: IntArray, b: IntArray) -> tuple[FloatArray, FloatArray]:
        """Mean ``(k, 3)`` and covariance ``(k, 3, 3)`` of the ATs from times a to b (a ≤ b),
        in the frame of time a."""
        a, b = np.asarray(a), np.asarray(b)
        d = self.sums[:, b] - self.sums[:, a]
        sxx, sxy, syy, sxt, syt, stt, y_xt, x_xt, x_yt, y_yt, x_tt, y_tt, xx_tt, yy_tt, xy_tt = d
        X, Y = self.pose[b, 0], self.pose[b, 1]
        cov = np.empty((*np.shape(a), 3, 3))
        cov[..., 0, 0] = sxx - 2 * (Y * sxt - y_xt) + (Y * Y * stt - 2 * Y * y_tt + yy_tt)
        cov[..., 0, 1] = (
            sxy + (X * sxt - x_xt) - (Y * syt - y_yt) - (X * Y * stt - X * y_tt - Y * x_tt + xy_tt)
        )
        cov[..., 1, 1] = syy + 2 * (X * syt - x_yt) + (X * X * stt - 2 * X * x_tt + xx_tt)
        cov[..., 0, 2] = sxt - (Y * stt - y_tt)
        cov[..., 1, 2] = syt + (X * stt - x_tt)
        cov[..., 2, 2] = stt
        cov[..., 1, 0], cov[..., 2, 0], cov[..., 2, 1] = (
            cov[..., 0, 1],
            cov[..., 0, 2],
            cov[..., 1, 2],
        )
        # into the axes of the frame at time a
        t = self.pose[a, 2]
        M = np.zeros((*np.shape(a), 3, 3))
        M[..., 0, 0], M[..., 0, 1] = np.cos(t), np.sin(t)
        M[..., 1, 0], M[..., 1, 1] = -np.sin(t), np.cos(t)
        M[..., 2, 2] = 1.0
        cov = M @ cov @ np.swapaxes(M, -1, -2)
        mean = se2.between(self.pose[a], self.pose[b])
        return mean, 0.5 * (cov + np.swapaxes(cov, -1, -2))


def _run(
    odometry: _Odometry,
    start: AT,
    events: IntArray,
    correct: Callable[[int, AT], AT],
    progress: Progress | None,
) -> AT:
    """The EKF at every time: predict between events (Eq. 13), correct at each event's time
    index; then every time's state as the last posterior compounded with the odometry since."""
    n, ne = odometry.n, len(events)
    post_mean, post_cov = np.empty((ne + 1, 3)), np.empty((ne + 1, 3, 3))
    post_mean[0], post_cov[0] = start.mean, start.cov
    at_index = np.concatenate([[0], events])  # time index of each posterior
    seg_mean, seg_cov = odometry.between(at_index[:-1], at_index[1:])
    state = start
    for k in range(ne):
        prior = compound(state, AT._trusted(seg_mean[k], seg_cov[k]))
        state = correct(k, prior)
        post_mean[k + 1], post_cov[k + 1] = state.mean, state.cov
        if progress is not None and (k % 64 == 0 or k == ne - 1):
            progress(k + 1, ne)
    last = np.searchsorted(at_index, np.arange(n), side="right") - 1  # posterior in force
    rel_mean, rel_cov = odometry.between(at_index[last], np.arange(n))
    return compound(AT._trusted(post_mean[last], post_cov[last]), AT._trusted(rel_mean, rel_cov))


def _dead_reckoning(motion: FloatArray, noise: DistanceNoise, start: AT) -> AT:
    """Odometry alone from ``start``: one parallel scan (:func:`relmap.compound_chain`)."""
    steps = _step_ats(motion, noise, "midpoint", None)
    return compound_chain(
        AT._trusted(
            np.concatenate([start.mean[None], steps.mean]),
            np.concatenate([start.cov[None], steps.cov]),
        )
    )


def _start(pose: FloatArray) -> AT:
    return AT._trusted(np.array(pose, dtype=np.float64), np.diag(np.square(START_SIGMA)))


def _robot_log(data: Mrclam, robot: int) -> RobotLog:
    n = len(data.robots)
    if isinstance(robot, bool) or not isinstance(robot, (int, np.integer)) or not 1 <= robot <= n:
        raise ParameterError(
            f"robot must be a robot number 1-{n} of this MRCLAM dataset; got {robot}"
        )
    return data.robots[int(robot) - 1]


def _check_associate(associate: str) -> None:
    if associate not in ASSOCIATIONS:
        raise ParameterError(
            f"associate must be one of {', '.join(ASSOCIATIONS)}; got {associate!r}"
        )


def _statuses(updates: list[ekf.LandmarkUpdate], ignored: int) -> dict[str, int]:
    counts = {name: 0 for name in ekf.STATUS.values()}
    for up in updates:
        for name, c in up.report().items():
            counts[name] += c
    counts["ignored"] = ignored
    return counts


def _rejected(counts: dict[str, int]) -> int:
    return counts[ekf.STATUS[ekf.GATED]] + counts[ekf.STATUS[ekf.LOST]]


# ------------------------------------------------------------------------------ MRCLAM
def localize_mrclam(
    data: Mrclam,
    robot: int,
    *,
    associate: str = "signatures",
    gate: float = 0.99,
    calibration: Calibration | None = None,
    progress: Progress | None = None,
) -> Localization:
    """EKF localization of MRCLAM robot ``robot`` with the landmark map (module docstring).

    ``calibration`` defaults to :func:`calibrate_mrclam` on robot ``robot mod 5 + 1``.
    """
    _check_associate(associate)
    log = _robot_log(data, robot)
    n_robots = len(data.robots)
    cal = calibration or calibrate_mrclam(data, robot % n_robots + 1)
    sensor = RangeBearingSensor(cal.sigma_range, cal.sigma_bearing or 0.0)
    odo_t = log.odometry_t
    inside = _inside_truth(odo_t, log.truth_t)
    if inside.sum() < 2:
        raise ParameterError(f"robot {robot}: fewer than 2 odometry records inside ground truth")
    first, end = np.flatnonzero(inside)[[0, -1]]
    o = slice(first, None)
    offered = data.landmark_index(log.meas_subject) >= 0
    meas_t = log.meas_t[offered]
    t, motion, events = _grid(
        odo_t[o], log.odometry_v[o], log.odometry_w[o], meas_t, float(odo_t[end])
    )
    z = np.column_stack([log.meas_range[offered], log.meas_bearing[offered]])
    subject = log.meas_subject[offered]
    # readings of each event: rows lo:hi of the (time-sorted) offered readings
    lo = np.searchsorted(meas_t, t[events], side="left")
    hi = np.searchsorted(meas_t, t[events], side="right")
    signatures = associate == "signatures"
    updates: list[ekf.LandmarkUpdate] = []

    def correct(k: int, state: AT) -> AT:
        rows = slice(lo[k], hi[k])
        up = ekf.correct_landmarks(
            state,
            z[rows],
            sensor,
            data.landmark_xy,
            associate=associate,  # type: ignore[arg-type]
            gate=gate,
            signatures=subject[rows] if signatures else None,
            landmark_signatures=data.landmark_ids if signatures else None,
        )
        updates.append(up)
        return up.state

    in_run = (log.meas_t >= t[0]) & (log.meas_t <= t[-1])
    return _localization(
        ("mrclam", int(robot), associate), t, motion, events, correct, progress, cal,
        log.truth_at, data.landmark_xy, updates, int((in_run & ~offered).sum()),
    )  # fmt: skip


def _localization(
    what: tuple[str, int | None, str],
    t: FloatArray,
    motion: FloatArray,
    events: IntArray,
    correct: Callable[[int, AT], AT],
    progress: Progress | None,
    cal: Calibration,
    truth_at: Callable[[FloatArray], FloatArray],
    landmarks: ArrayLike,
    updates: list[ekf.LandmarkUpdate],
    ignored: int,
) -> Localization:
    """Run the filter and dead reckoning from the true start, and score both."""
    start = _start(truth_at(t[0]))
    estimate = _run(_Odometry(motion, cal.odometry), start, events, correct, progress)
    dr = _dead_reckoning(motion, cal.odometry, start)
    truth = truth_at(t)
    counts = _statuses(updates, ignored)  # after the run: the updates are complete
    dataset, robot, associate = what
    return Localization(
        dataset=dataset,
        robot=robot,
        associate=associate,
        t=t,
        estimate=estimate,
        dead_reckoning=dr,
        truth=truth,
        landmarks=np.asarray(landmarks),
        calibration=cal,
        score=score(estimate, truth, rejected=_rejected(counts)),
        baseline=score(dr, truth),
        readings=counts,
    )


# ------------------------------------------------------------------------------- Plaza
def localize_plaza(
    data: Plaza,
    *,
    associate: str = "signatures",
    gate: float = 0.99,
    calibration: Calibration | None = None,
    progress: Progress | None = None,
) -> Localization:
    """EKF localization on the second half of a Plaza run with range-only beacons (module
    docstring); ``calibration`` defaults to :func:`calibrate_plaza` (the first half)."""
    _check_associate(associate)
    cal = calibration or calibrate_plaza(data)
    mid = _plaza_split(data)
    odo_t, v, w = _plaza_velocities(data)
    inside = _inside_truth(odo_t, data.truth_t) & (odo_t >= mid)
    if inside.sum() < 2:
        raise ParameterError("Plaza: fewer than 2 dead-reckoning records in the second half")
    first, end = np.flatnonzero(inside)[[0, -1]]
    o = slice(first, None)
    t, motion, events = _grid(odo_t[o], v[o], w[o], data.meas_t, float(odo_t[end]))
    lo = np.searchsorted(data.meas_t, t[events], side="left")
    hi = np.searchsorted(data.meas_t, t[events], side="right")
    updates: list[ekf.LandmarkUpdate] = []

    def correct(k: int, state: AT) -> AT:
        rows = slice(lo[k], hi[k])
        up = correct_ranges(
            state,
            data.meas_range[rows] / cal.range_scale,
            data.beacon_xy,
            cal.sigma_range,
            beacon=data.meas_beacon_index[rows],
            associate=associate,
            gate=gate,
        )
        updates.append(up)
        return up.state

    return _localization(
        ("plaza", None, associate), t, motion, events, correct, progress, cal, data.truth_at,
        data.beacon_xy, updates, 0,
    )  # fmt: skip


# ------------------------------------------------------------------------------ any folder
def localize(
    folder: str | os.PathLike[str],
    *,
    robot: int | None = None,
    associate: str = "signatures",
    gate: float = 0.99,
    progress: Progress | None = None,
) -> Localization:
    """Localize on the dataset in ``folder``, recognised by its files (MRCLAM or Plaza).

    MRCLAM: ``robot`` 1-5 (default 1). Plaza has one robot: ``robot`` must be None. A folder
    that is neither raises :class:`relmap.errors.FileFormatError`.
    """
    from relmap.errors import FileFormatError

    kind = recognise(folder)
    if kind is None:
        raise FileFormatError(
            folder,
            "is neither an MRCLAM folder (Barcodes.dat, Landmark_Groundtruth.dat, "
            "RobotN_{Odometry,Groundtruth,Measurement}.dat) nor a CMU Plaza folder "
            "(P_DR.txt, P_TD.txt, P_.mat)",
        )
    _check_associate(associate)
    if kind == "mrclam":
        data = read_mrclam(folder)
        return localize_mrclam(
            data, 1 if robot is None else robot, associate=associate, gate=gate, progress=progress
        )
    if robot is not None:
        raise ParameterError("a CMU Plaza folder holds one robot: leave out the robot number")
    return localize_plaza(read_plaza(folder), associate=associate, gate=gate, progress=progress)
