"""EKF localization with a known map on real logs, scored against ground truth.

Datasets (:mod:`relmap.io.datasets`): UTIAS MRCLAM (five robots, odometry velocities, barcoded
range-bearing readings of 15 surveyed landmarks, Vicon truth) and CMU Plaza (dead-reckoning
steps, range-only readings of 4 beacons, GPS truth). :func:`localize` runs one filter and
returns a :class:`Localization`: the estimate and dead reckoning at every filter time, scored.

The filter is :func:`relmap.filter.run` (lecture Eqs. 13-28); this module builds its log
(:meth:`relmap.filter.Log.from_velocities`: odometry times merged with reading times; MRCLAM's
``(v, ω)`` held until the next record, a Plaza step spread evenly over its span; the readings of
one time stamp corrected in one stacked update), its noise and its start, and scores what it
returns. ``associate="signatures"`` pairs a reading with its landmark by barcode (beacon id) and
offers no reading of a barcode that is no landmark; ``"mahalanobis"``, ``"euclidean"`` and
``"jcbb"`` offer every reading, the barcodes read only afterwards, to count. The filter starts at
the first odometry time inside the truth's span (Plaza: its second half), from the true pose with
covariance ``diag(START_SIGMA)²``. The noise comes from the run's own innovations
(:mod:`relmap.filter.autocalibration`, the default) or from another run against its ground truth
(:class:`Calibration`: :func:`relmap.models.calibration.fit_distance_noise` for the odometry, the
median absolute deviation of the readings' residuals for the sensor σ).

Scores (:class:`Score`) at every filter time, against the truth interpolated there: position and
wrapped heading RMSE; ``coverage_90``, the fraction of times the true position lies in the 90%
ellipse; ``anees``, the mean NEES ``eᵀ Σ⁻¹ e / 3`` (``e = truth ⊟ estimate``; 1 when consistent);
``rejected``, readings offered and not used (gated, lost to a closer reading, 0/0). Dead
reckoning (the same filter without readings) is scored alike. :attr:`Localization.warnings`
name an EKF worse than dead reckoning, an ANEES below 1/3 or above 3, and a covariance outside
a consistent filter's bands (:data:`CONSISTENT_COVERAGE`, :data:`CONSISTENT_ANEES`). What it
gives on the shared logs, and why: ``docs/consistency.md``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from relmap.errors import ParameterError, ShapeError
from relmap.filter import autocalibration
from relmap.filter.landmarks import Association, LandmarkMap, Status
from relmap.filter.logs import Trace, run
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
from relmap.models.base import Measurement
from relmap.models.calibration import fit_distance_noise
from relmap.models.odometry import DistanceNoise, Odometry
from relmap.models.range_bearing import RangeBearingSensor, RangeOnly
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain import gaussian
from relmap.uncertain.at import AT

__all__ = [
    "ASSOCIATIONS",
    "ODOMETRY_WINDOW",
    "START_SIGMA",
    "Calibration",
    "Localization",
    "Score",
    "calibrate_mrclam",
    "calibrate_plaza",
    "localize",
    "localize_mrclam",
    "localize_plaza",
    "noise_from_run",
    "score",
    "sensor_residuals",
]

#: Ways to pair readings with landmarks (:class:`relmap.filter.Association`).
ASSOCIATIONS = tuple(Association.choices())
#: Standard deviations ``(σx, σy, σθ)`` (m, m, rad) of the filters' start pose.
START_SIGMA = (0.02, 0.02, 0.02)
#: Where autocalibration starts: the odometry's ``(k_s, k_theta, k_theta_s)`` (m²/m, rad²/rad,
#: rad²/m) and the sensor's ``(σ range, σ bearing)`` (m, rad) — noisy, so that the first filters
#: are cautious and the search comes down to the data.
START_ODOMETRY = (0.05, 0.02, 0.005)
START_SENSOR = (0.5, 0.05)
#: Window (s) of the odometry-noise fit (:func:`relmap.models.calibration.fit_distance_noise`).
ODOMETRY_WINDOW = 10.0
#: σ of a normal distribution from its median absolute deviation.
MAD_TO_SIGMA = 1.4826
#: ANEES outside [1/3, 3] is "far from 1" (a warning).
ANEES_FAR = 3.0
#: The bands of a consistent filter's ``coverage_90`` and ANEES; a score outside either, but
#: not far from 1, is called cautious or overconfident (a warning).
CONSISTENT_COVERAGE = (0.85, 0.95)
CONSISTENT_ANEES = (0.7, 1.5)

Progress = Callable[[int, int], None]


# ------------------------------------------------------------------------------ results
class Calibration(NamedTuple):
    """Noise estimated from data (see the module docstring for the scheme)."""

    #: Odometry noise, fitted by :func:`relmap.models.calibration.fit_distance_noise`.
    odometry: DistanceNoise
    #: Robust σ of the range (m).
    sigma_range: float
    #: Robust σ of the bearing (rad); None for range-only sensors.
    sigma_bearing: float | None
    #: Median of the range residuals (m), reported, not corrected.
    range_bias: float
    #: Median of the bearing residuals (rad), reported, not corrected; None for range-only.
    bearing_bias: float | None
    #: How many readings the sensor σ came from.
    readings: int
    #: What the noise was estimated on, e.g. ``"robot 2"``.
    trained_on: str
    #: Measured range = ``range_scale`` × true range (Plaza: estimated; MRCLAM: 1, not fitted).
    #: The filter divides readings by it before use.
    range_scale: float = 1.0

    #: The readings' Student-t dof: Gaussian (the σ are robust standard deviations).
    nu = float("inf")

    @property
    def motion(self) -> Odometry:
        """The filter's motion model: the fitted odometry noise."""
        return Odometry(self.odometry)

    @property
    def sensor(self) -> Measurement:
        """The filter's sensor: Gaussian readings of the robust σ (no bias correction)."""
        if self.sigma_bearing is None:
            return RangeOnly(self.sigma_range)
        return RangeBearingSensor(self.sigma_range, self.sigma_bearing)

    @property
    def options(self) -> dict[str, float]:
        """The filter's weights: none (the readings are taken as Gaussian and white)."""
        return {"inflation": 1.0, "clutter": 0.0}


class Score(NamedTuple):
    """How an estimated trajectory compares with the ground truth (module docstring)."""

    rmse_position: float  #: m
    rmse_heading: float  #: rad
    coverage_90: float  #: fraction of times with the true position in the 90% ellipse
    anees: float  #: average NEES over the times, divided by 3 (≈ 1 when consistent)
    rejected: int  #: readings offered and not used

    def as_dict(self) -> dict[str, float | int]:
        return dict(self._asdict())


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
    #: the noise used and where it came from: the run's own innovations
    #: (:class:`relmap.filter.autocalibration.Calibrated`, the default) or another run's ground
    #: truth (:class:`Calibration`)
    calibration: Calibration | autocalibration.Calibrated
    score: Score  #: the EKF's score
    baseline: Score  #: dead reckoning's score
    readings: dict[str, int]  #: what happened to the readings (status names, "ignored", "wrong")
    trace: Trace  #: the filter's trace (innovations, S, statuses, NIS, log-likelihood)
    reading_t: FloatArray  #: ``(M,)`` the time of each reading offered to the filter

    @property
    def steps(self) -> int:
        """Number of filter times (odometry and reading times) scored."""
        return len(self.t)

    @property
    def nees(self) -> FloatArray:
        """``(n,)`` the NEES of the pose error at every time (3 dof)."""
        return _nees(self.estimate, self.truth)

    @property
    def anis(self) -> float:
        """The filter's NIS per innovation component (≈ 1 when consistent; NaN if none)."""
        dof = int(self.trace.dof)
        return float(self.trace.nis) / dof if dof else float("nan")

    @property
    def warnings(self) -> list[str]:
        """What a user should know about this run's result (module docstring)."""
        out = []
        s, b = self.score, self.baseline
        if s.rmse_position > b.rmse_position:
            out.append(
                f"the EKF ({self.associate}) ends worse than dead reckoning: position RMSE "
                f"{s.rmse_position:.3f} m against {b.rmse_position:.3f} m"
            )
        if not 1 / ANEES_FAR <= s.anees <= ANEES_FAR:
            out.append(
                f"the EKF ({self.associate}) is inconsistent: ANEES {s.anees:.3g} (1 if "
                "consistent); its ellipses do not describe its errors"
            )
        elif (side := _covariance_side(s)) is not None:
            (c0, c1), (a0, a1) = CONSISTENT_COVERAGE, CONSISTENT_ANEES
            out.append(
                f"the EKF's covariance ({self.associate}) is {side}: the true position is "
                f"inside its 90% ellipse {s.coverage_90:.1%} of the time, ANEES {s.anees:.2f} "
                f"(consistent: {c0:.0%}-{c1:.0%}, {a0:g}-{a1:g})"
            )
        return out

    def summary(self) -> dict[str, object]:
        """The JSON summary of ``relmap localize``."""
        s = self.score
        tr = self.trace
        return {
            "dataset": self.dataset,
            "robot": self.robot,
            "associate": self.associate,
            "steps": self.steps,
            "rmse_position": s.rmse_position,
            "rmse_heading": s.rmse_heading,
            "coverage_90": s.coverage_90,
            "anees": s.anees,
            "rejected": s.rejected,
            "dead_reckoning": self.baseline.as_dict(),
            "nis": {"sum": float(tr.nis), "dof": int(tr.dof), "anis": _finite_or_none(self.anis)},
            "loglik": float(tr.loglik),
            "parameters": _parameters(self.calibration),
            "calibration": _calibration_summary(self.calibration),
            "readings": {
                "used": self.readings["used"],
                "rejected": s.rejected,
                "wrong": self.readings["wrong"],
                "ignored": self.readings["ignored"],
                **{k: v for k, v in self.readings.items() if k not in ("used", "wrong", "ignored")},
            },
            "warnings": self.warnings,
        }


def _parameters(cal: Calibration | autocalibration.Calibrated) -> dict[str, float | None]:
    """The filter's noise by name: the models' parameters, the readings' dof and weights."""
    values = {k: float(getattr(m, k)) for m in (cal.motion, cal.sensor) for k in m.noise_parameters}
    return {**values, "nu": _finite_or_none(float(cal.nu)), **cal.options}


def _calibration_summary(cal: Calibration | autocalibration.Calibrated) -> dict[str, object]:
    if isinstance(cal, autocalibration.Calibrated):
        d = cal.as_dict()
        keep = ("delay", "range_scale", "turn_bias", "inflation", "correlation_before",
                "correlation_after", "loglik")  # fmt: skip
        return {"method": "auto", "trained_on": "this run's innovations",
                **{k: d[k] for k in keep}}  # fmt: skip
    return {
        "method": "from-run",
        "trained_on": cal.trained_on,
        "readings": cal.readings,
        "range_bias": cal.range_bias,
        "bearing_bias": cal.bearing_bias,
        "range_scale": cal.range_scale,
    }


def _covariance_side(s: Score) -> str | None:
    """``"cautious"`` (ellipses larger than the errors), ``"overconfident"``, ``"inconsistent"``
    (the coverage and ANEES disagree) or None (both inside the bands of a consistent filter)."""
    (c0, c1), (a0, a1) = CONSISTENT_COVERAGE, CONSISTENT_ANEES
    wide = s.coverage_90 > c1 or s.anees < a0
    narrow = s.coverage_90 < c0 or s.anees > a1
    if wide and narrow:
        return "inconsistent"
    return "cautious" if wide else "overconfident" if narrow else None


def _finite_or_none(v: float) -> float | None:
    return v if np.isfinite(v) else None


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
    d2_pos = gaussian.mahalanobis2(e[:, :2], 0.0, estimate.cov[:, :2, :2])
    return Score(
        rmse_position=float(np.sqrt(pos2.mean())),
        rmse_heading=float(np.sqrt((e[:, 2] ** 2).mean())),
        coverage_90=float((d2_pos <= gaussian.confidence_k2(0.9, 2)).mean()),
        anees=float(_nees(estimate, x).mean() / 3.0),
        rejected=int(rejected),
    )


def _nees(estimate: AT, truth: FloatArray) -> FloatArray:
    return gaussian.mahalanobis2(se2.minus(truth, estimate.mean), 0.0, estimate.cov)


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
    predicted = sensor.h(log.truth_at(t[keep]), data.landmark_xy[lm[keep]])
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
    if inside.sum() < 2:
        raise ParameterError(
            f"cannot calibrate the odometry noise on robot {robot}: {int(inside.sum())} odometry "
            "records inside its ground-truth span (at least 2 needed)"
        )
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


def noise_from_run(data: Mrclam, robot: int) -> Calibration:
    """The noise estimated on MRCLAM robot ``robot``'s run against its ground truth
    (:func:`calibrate_mrclam`): ``relmap localize --calibrate from-run N``."""
    return calibrate_mrclam(data, robot)


# ------------------------------------------------------------------------------ the runs
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


#: Progress stages of a localization: the four of the autocalibration, then the filter.
STAGES = 5


def _localization(
    what: tuple[str, int | None, str],
    recording: autocalibration.Recording,
    landmarks: FloatArray,
    cal: Calibration | autocalibration.Calibrated | None,
    truth_at: Callable[[FloatArray], FloatArray],
    *,
    sensor: Measurement,
    ignored: int,
    gate: float,
    progress: Progress | None,
) -> Localization:
    """Calibrate (``cal`` None: from the run's own innovations), run the filter and dead
    reckoning (the filter without readings) from the true start, and score both. Each
    reading's signature is its landmark's row (-1: none), for counting the wrong pairings of the
    association modes that do not read it. ``progress(k, STAGES)``."""
    dataset, robot, associate = what
    tick = progress or (lambda k, n: None)

    def start(t0: float) -> AT:
        return _start(truth_at(np.array([t0]))[0])

    noise: Calibration | autocalibration.Calibrated
    if cal is None:  # from the cautious start (autocalibration) to the run's own noise
        noise = autocalibration.calibrate(
            recording, Odometry(DistanceNoise(*START_ODOMETRY)), sensor, landmarks, start=start,
            associate=associate, gate=gate, progress=tick,
        )  # fmt: skip
    else:
        noise = cal
    if isinstance(noise, autocalibration.Calibrated):
        log = recording.log(*noise.clock)
    else:
        log = recording.log(0.0, noise.range_scale)
    tick(STAGES - 1, STAGES)
    landmark_map = LandmarkMap(landmarks)  # checked once for the filter and dead reckoning
    kw = dict(start=start(float(log.t[0])), gate=gate, **noise.options)
    trace = run(log, noise.motion, noise.sensor, landmark_map, associate=associate, **kw)
    quiet = log._replace(reading_index=log.reading_index[:0], z=log.z[:0], signature=None)
    dr = run(quiet, noise.motion, noise.sensor, landmark_map, associate="mahalanobis",
                 readings=False, **kw)  # fmt: skip
    tick(STAGES, STAGES)
    true_landmark = log.signature
    truth = truth_at(log.t)
    counts = {s.name.lower(): int(trace.count(s)) for s in Status}
    used = trace.status == Status.USED
    counts["wrong"] = int((used & (trace.landmark != true_landmark)).sum())
    counts["ignored"] = ignored
    counts["ambiguous"] = int(trace.ambiguous)
    not_in_map = true_landmark < 0 if true_landmark is not None else np.zeros(len(used), bool)
    counts["not_in_map"] = int(not_in_map.sum())
    counts["not_in_map_used"] = int((used & not_in_map).sum())
    rejected = counts["gated"] + counts["lost"] + counts["degenerate"]
    estimate, dead = trace.estimate(), dr.estimate()
    return Localization(
        dataset=dataset,
        robot=robot,
        associate=associate,
        t=log.t,
        estimate=estimate,
        dead_reckoning=dead,
        truth=truth,
        landmarks=np.asarray(landmarks),
        calibration=noise,
        score=score(estimate, truth, rejected=rejected),
        baseline=score(dead, truth),
        readings=counts,
        trace=trace,
        reading_t=log.t[log.reading_index],
    )


# ------------------------------------------------------------------------------ MRCLAM
def localize_mrclam(
    data: Mrclam,
    robot: int,
    *,
    associate: str = "signatures",
    gate: float = 0.99,
    calibration: Calibration | autocalibration.Calibrated | None = None,
    progress: Progress | None = None,
) -> Localization:
    """EKF localization of MRCLAM robot ``robot`` with the landmark map (module docstring).

    ``calibration`` None (the default): the noise from the run's own innovations
    (:func:`relmap.filter.autocalibration.calibrate`); or e.g. :func:`calibrate_mrclam` of another
    robot.
    """
    _check_associate(associate)
    log = _robot_log(data, robot)
    odo_t = log.odometry_t
    inside = _inside_truth(odo_t, log.truth_t)
    if inside.sum() < 2:
        raise ParameterError(f"robot {robot}: fewer than 2 odometry records inside ground truth")
    first, end = np.flatnonzero(inside)[[0, -1]]
    o = slice(first, None)
    lm_of = data.landmark_index(log.meas_subject)
    # by signatures a reading of no landmark has no candidate; the other modes offer every
    # reading: what is not in the map is the clutter's (relmap.filter, autocalibration.loglik)
    offered = lm_of >= 0 if associate == "signatures" else np.ones(len(lm_of), bool)
    z = np.column_stack([log.meas_range[offered], log.meas_bearing[offered]])
    rec = autocalibration.Recording(
        odo_t[o], log.odometry_v[o], log.odometry_w[o], log.meas_t[offered], z,
        lm_of[offered], float(odo_t[end]),
    )  # fmt: skip
    in_run = (log.meas_t >= odo_t[first]) & (log.meas_t <= odo_t[end])
    return _localization(
        ("mrclam", int(robot), associate), rec, data.landmark_xy, calibration, log.truth_at,
        sensor=RangeBearingSensor(*START_SENSOR), ignored=int((in_run & ~offered).sum()), gate=gate,
        progress=progress,
    )  # fmt: skip


# ------------------------------------------------------------------------------- Plaza
def localize_plaza(
    data: Plaza,
    *,
    associate: str = "signatures",
    gate: float = 0.99,
    calibration: Calibration | autocalibration.Calibrated | None = None,
    progress: Progress | None = None,
) -> Localization:
    """EKF localization on the second half of a Plaza run with range-only beacons (module
    docstring); ``calibration`` None (the default): the noise from the second half's own
    innovations; or e.g. :func:`calibrate_plaza` (the first half against its ground truth)."""
    _check_associate(associate)
    mid = _plaza_split(data)
    odo_t, v, w = _plaza_velocities(data)
    inside = _inside_truth(odo_t, data.truth_t) & (odo_t >= mid)
    if inside.sum() < 2:
        raise ParameterError("Plaza: fewer than 2 dead-reckoning records in the second half")
    first, end = np.flatnonzero(inside)[[0, -1]]
    o = slice(first, None)
    rec = autocalibration.Recording(
        odo_t[o], v[o], w[o], data.meas_t, data.meas_range, data.meas_beacon_index,
        float(odo_t[end]),
    )  # fmt: skip
    return _localization(
        ("plaza", None, associate), rec, data.beacon_xy, calibration, data.truth_at,
        sensor=RangeOnly(START_SENSOR[0]), ignored=0, gate=gate, progress=progress,
    )  # fmt: skip


# ------------------------------------------------------------------------------ any folder
def localize(
    folder: str | os.PathLike[str],
    *,
    robot: int | None = None,
    associate: str = "signatures",
    gate: float = 0.99,
    calibrate_from: int | None = None,
    progress: Progress | None = None,
) -> Localization:
    """Localize on the dataset in ``folder``, recognised by its files (MRCLAM or Plaza).

    MRCLAM: ``robot`` 1-5 (default 1). The noise: by default from the run's own innovations
    (:mod:`relmap.filter.autocalibration`, no ground truth); with ``calibrate_from`` N, from robot
    N's
    run against its ground truth (:func:`calibrate_mrclam`; never the robot itself). Plaza has
    one robot: ``robot`` and ``calibrate_from`` must be None. A folder that is neither raises
    :class:`relmap.errors.FileFormatError`.
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
        r = 1 if robot is None else robot
        cal = None
        if calibrate_from is not None:
            _robot_log(data, calibrate_from)
            if calibrate_from == r:
                raise ParameterError(
                    f"--calibrate from-run {calibrate_from}: the noise must come from another "
                    "robot than the one scored"
                )
            cal = calibrate_mrclam(data, calibrate_from)
        return localize_mrclam(
            data, r, associate=associate, gate=gate, calibration=cal, progress=progress
        )
    if robot is not None:
        raise ParameterError("a CMU Plaza folder holds one robot: leave out the robot number")
    if calibrate_from is not None:
        raise ParameterError("a CMU Plaza folder holds one run: no from-run N")
    return localize_plaza(read_plaza(folder), associate=associate, gate=gate, progress=progress)
