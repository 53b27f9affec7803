"""The extended Kalman filter (lecture Eqs. 13-28): one implementation, batched and generic.

The arithmetic lives in relmap's compiled core (``relmap._core``, ``src/core/ekf.cpp``), once;
this module is its documented interface. Every function takes leading batch axes: one filter
and a thousand (Monte Carlo runs, or candidate noise parameters during calibration) go through
the same code, with no Python loop over filters or steps.

**Steps, in the textbook letters.** The belief is a mean ``x`` (..., n) and covariance ``P``
(..., n, n): a pose :class:`relmap.AT` (n = 3, relmap's chart, heading wrapped) or a
:class:`Belief` of any size.

- :func:`predict` (Eq. 13): ``x⁻ = f(x, u)``, ``P⁻ = F P Fᵀ + Q`` with ``F = ∂f/∂x`` and
  ``Q = G Qu Gᵀ``, ``G = ∂f/∂u``. The built-in model is differential-drive odometry: a step
  ``u = (Δs, Δθ)`` with :class:`relmap.models.DistanceNoise` (Eqs. 10-13, midpoint
  integration), i.e. the pose compounded with the step's AT (the paper's Eqs. 1-4). Other
  relmap.models noise models and integrations give their step AT through :mod:`relmap.models`.
  A user's :class:`Motion` gives ``f`` and optionally its Jacobians (else
  :func:`relmap.uncertain.propagate.numerical_jacobian` in the state's chart).
- :func:`correct` (Eqs. 26-28) with readings already paired: ``y = z ⊖ h(x⁻)``,
  ``S = H P⁻ Hᵀ + R``, ``K = P⁻ Hᵀ S⁻¹``, ``x = x⁻ ⊕ K y`` and the covariance in **Joseph form**
  ``P = (I - KH) P⁻ (I - KH)ᵀ + K R Kᵀ`` rather than Eq. 28's ``P⁻ - K S Kᵀ``: a sum of two
  congruences, so P stays symmetric positive semi-definite under rounding and for any gain
  (also a robust filter's reweighted one), even with a reading far more precise than the
  prior. A user's :class:`Sensor` gives ``h`` and optionally ``H``; the core does the update.
  Where S is not positive definite (a 0/0: e.g. no noise and no uncertainty), the state is
  left as it was and the step says so (``ok`` False, :attr:`Status.DEGENERATE`).
- :func:`correct_pose`: a full-pose reading (GPS + compass, Eqs. 14-19), ``h(x) = x``, ``H = I``
  — the paper's merge (§4) as an instance of :func:`correct`, behind a χ²₃ gate.
- :func:`correct_landmarks`: range-bearing readings (Eq. 20, from a sensor mounted on the
  robot) or range-only readings (its first row, e.g. radio beacons) of a known map, with
  association (:class:`Association`: signatures, Mahalanobis Eq. 23 or Euclidean Eq. 22
  nearest neighbour one to one, or the lecture's Eq. 21 per landmark (:class:`Pairing`), or
  joint compatibility branch and bound, JCBB, Neira & Tardós 2001), the χ² gate (Eq. 25),
  and one stacked update of all the readings of the time stamp; a reading with several
  landmarks inside its gate enters it as the mixture of them (see there). Every reading gets a
  :class:`Status`.

**Runs.** :func:`run` replays a whole :class:`Log` (odometry steps between the filter's times,
readings at some of them) for one filter or a batch of filters, each with its own
:class:`NoiseParameters` (odometry, sensor σ, biases, mount, Student-t dof): predict every
step, correct at the reading times with all readings of a time in one stacked update. It
returns a :class:`Trace`: states at the filter's times (``keep``), every reading's
innovation, S, status and landmark, and per filter the innovation log-likelihood, the NIS and
the counts — what likelihood-based calibration of the noise needs, for a batch of candidate
parameter sets in one call.

**Robust readings.** With a finite Student-t dof ``nu``, a used reading of dimension d and
Mahalanobis distance d² enters the update with weight ``w = (ν + d)/(ν + d²)``, i.e. with
noise ``R / w`` (the EM weight of a Student-t reading: a far reading counts less); the
likelihood of the stacked innovation is then the multivariate Student-t with scale S (not
reweighted) and ν dof, otherwise the Gaussian ``N(0, S)``. (The covariance then counts a reading
near its prediction as more precise than the t's variance; :mod:`relmap.filter.autocalibration`
filters linearly with the readings' standard deviations instead.)

**Correlated readings.** ``inflation`` c (:class:`NoiseParameters`) multiplies the σ of the
update only: the gain and the Joseph covariance use ``c² R`` (readings whose errors repeat carry
less information than their spread says), while the association, the gate, ``S``, the NIS and
the likelihood use ``R``.

**Clutter.** With ``clutter`` λ > 0 (:class:`NoiseParameters`) a reading may be of something
not in the map (another robot, an unknown object: probabilistic data association with clutter,
Bar-Shalom & Tse 1975): of its paired landmark with density ``g`` (the reading model at the
pair's innovation, ``N(y; 0, S)`` or for a robust filter the Student-t of scale ``S``; for an
ambiguous reading the mixture's virtual landmark), or of clutter, uniform over the sensor's
measurement volume ``V`` with density ``λ`` relative to it (clutter fraction
``π = λV/(1 + λV)``, per reading density ``(g + λ)/(1 + λV)``). A used reading enters the
update with the probability that it is of its landmark, ``w = g/(g + λ)``, as the weight of its
noise, ``R / w`` (like the Student-t weight, with which it multiplies): likely clutter barely
moves the filter. Association, gate, ``S``, the NIS and the likelihood of :class:`Trace` keep
``R`` (the landmark hypothesis); the mixture's likelihood, with ``V``, is
:func:`relmap.filter.autocalibration.loglik`'s. λ = 0 is the filter without clutter, bit for bit.
"""

from __future__ import annotations

import enum
import functools
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from relmap import _core
from relmap.errors import NonFiniteError, NumericalError, ParameterError, ShapeError
from relmap.lie import se2
from relmap.models.odometry import DiffDrive, DistanceNoise, Integration, Noise, _pairs, _step_ats
from relmap.models.range_bearing import RangeBearingSensor
from relmap.typing import ArrayLike, FloatArray, IntArray
from relmap.uncertain import gaussian
from relmap.uncertain.at import AT
from relmap.uncertain.propagate import EUCLIDEAN, SE2, numerical_jacobian

__all__ = [
    "Association",
    "Belief",
    "Correction",
    "Keep",
    "LandmarkMap",
    "LandmarkUpdate",
    "Log",
    "Motion",
    "NoiseParameters",
    "Pairing",
    "PoseUpdate",
    "Sensor",
    "SensorKind",
    "Status",
    "Trace",
    "correct",
    "correct_landmarks",
    "correct_pose",
    "predict",
    "run",
]


# ------------------------------------------------------------------------------ options
class Status(enum.IntEnum):
    """What became of a reading (the values are the core's)."""

    USED = 0  #: in the update
    GATED = 1  #: its pair lies outside the χ² gate (for JCBB: individually or jointly)
    UNKNOWN = 2  #: no landmark of the map can be it (its signature is not in the map)
    INVALID = 3  #: not a finite reading with a positive range
    ABSENT = 4  #: padding, no reading
    LOST = 5  #: its landmark went to a cheaper reading (one-to-one pairing)
    DEGENERATE = 6  #: 0/0: its landmark at the sensor, or S not positive definite

    @property
    def description(self) -> str:
        return _DESCRIPTIONS[self]


_DESCRIPTIONS = {
    Status.USED: "used",
    Status.GATED: "outside the gate",
    Status.UNKNOWN: "no landmark of the map matches it",
    Status.INVALID: "not a finite reading",
    Status.ABSENT: "no reading (padding)",
    Status.LOST: "its landmark went to a closer reading",
    Status.DEGENERATE: "0/0: landmark at the sensor or no innovation covariance",
}


class Association(str, enum.Enum):
    """How readings are paired with the map's landmarks."""

    SIGNATURES = "signatures"  #: the landmark of the reading's signature (e.g. a barcode)
    MAHALANOBIS = "mahalanobis"  #: nearest by Mahalanobis distance (Eq. 23)
    EUCLIDEAN = "euclidean"  #: nearest by |z - h| (Eq. 22, metres and radians mixed)
    JCBB = "jcbb"  #: joint compatibility branch and bound (Neira & Tardós 2001)


class Pairing(str, enum.Enum):
    """How nearest-neighbour association resolves readings that want the same landmark."""

    ONE_TO_ONE = "one_to_one"  #: greedy, cheapest pair first; the others are LOST
    PER_LANDMARK = "per_landmark"  #: Eq. 21: each landmark takes its cheapest reading


class Keep(str, enum.Enum):
    """Which states :func:`run` returns."""

    ALL = "all"  #: at every filter time (after the correction at that time)
    EVENTS = "events"  #: at the start and after each correction
    SUMMARY = "summary"  #: the final state only (large calibration batches)


class SensorKind(str, enum.Enum):
    """The built-in point-landmark sensors."""

    RANGE_BEARING = "range_bearing"  #: (r, φ), Eq. 20
    RANGE_ONLY = "range_only"  #: r, Eq. 20's first row


_NOISE_MODELS = {"constant": 0, "proportional": 1, "quadratic": 2}


def _option(kind: type[enum.Enum], value: object, name: str) -> enum.Enum:
    try:  # a dict look-up: an enum's call costs microseconds, and options come every step
        return _MEMBERS[kind][value]
    except (KeyError, TypeError):  # (TypeError: an unhashable value)
        names = ", ".join(str(m.value) for m in kind)  # type: ignore[attr-defined]
        raise ParameterError(f"{name} must be one of {names}; got {value!r}") from None


#: each option's members by value (a str enum's member hashes and compares as its value)
_MEMBERS: dict[type[enum.Enum], dict[object, enum.Enum]] = {
    kind: {m.value: m for m in kind} for kind in (Association, Pairing, Keep, SensorKind)
}


# ------------------------------------------------------------------------------ beliefs
class Belief(NamedTuple):
    """A Gaussian belief of any size: mean ``x`` (..., n), covariance ``P`` (..., n, n)."""

    x: FloatArray
    P: FloatArray


State = AT | Belief


def _arrays(state: State) -> tuple[FloatArray, FloatArray]:
    if isinstance(state, AT):
        return state.mean, state.cov
    x, P = np.asarray(state.x, dtype=np.float64), np.asarray(state.P, dtype=np.float64)
    if x.ndim < 1 or P.shape != (*x.shape, x.shape[-1]):
        raise ShapeError(f"a belief needs x (..., n) and P (..., n, n); got {x.shape}, {P.shape}")
    return x, P


def _like(state: State, x: FloatArray, P: FloatArray) -> State:
    if isinstance(state, AT):
        x = x.copy()
        x[..., 2] = se2.wrap_angle(x[..., 2])
        return AT._trusted(x, P)
    return Belief(x, P)


def _flat(a: FloatArray, batch: tuple[int, ...], tail: tuple[int, ...]) -> FloatArray:
    b = np.broadcast_to(a, (*batch, *tail))
    return np.ascontiguousarray(b, dtype=np.float64).reshape(int(np.prod(batch)), *tail)


# ------------------------------------------------------------------------------ models
class Motion(NamedTuple):
    """A motion model ``x⁻ = f(x, u)`` with input noise ``Qu(u)``.

    ``f(x, u)`` and ``noise(u)`` broadcast over leading axes; ``jacobians(x, u) -> (F, G)``
    (``∂f/∂x`` (..., n, n), ``∂f/∂u`` (..., n, k)) when known, else numeric (central
    differences through :func:`relmap.uncertain.propagate.numerical_jacobian`).
    """

    f: Callable[[FloatArray, FloatArray], FloatArray]
    noise: Callable[[FloatArray], FloatArray]
    jacobians: Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray]] | None = None


class Sensor(NamedTuple):
    """A sensor model ``z = h(x) + noise`` with noise covariance ``R`` (..., d, d).

    ``h(x)`` broadcasts over leading axes (close over the landmark for a landmark sensor);
    ``jacobian(x) -> H`` (..., d, n) when known, else numeric. ``angular`` lists the components
    of z that are angles (their innovations are wrapped).
    """

    h: Callable[[FloatArray], FloatArray]
    R: ArrayLike
    jacobian: Callable[[FloatArray], FloatArray] | None = None
    angular: tuple[int, ...] = ()


def _predict_covariance(P: FloatArray, F: FloatArray, Q: FloatArray) -> FloatArray:
    """``F P Fᵀ + Q`` over leading axes (the core)."""
    batch = np.broadcast_shapes(P.shape[:-2], F.shape[:-2], Q.shape[:-2])
    n = P.shape[-1]
    out = _core.ekf_predict_covariance(
        _flat(P, batch, (n, n)), _flat(F, batch, (n, n)), _flat(Q, batch, (n, n))
    )
    return out.reshape(*batch, n, n)


@functools.lru_cache(maxsize=64)
def _ones(batch: tuple[int, ...], m: int) -> np.ndarray:
    """A read-only (*batch, m) boolean array of ones ("every reading present"), cached."""
    a = np.ones((*batch, m), bool)
    a.flags.writeable = False
    return a


@functools.lru_cache(maxsize=64)
def _zeros(batch: tuple[int, ...], m: int) -> np.ndarray:
    """A read-only (*batch, m) int64 array of zeros (signatures unused), cached."""
    a = np.zeros((*batch, m), np.int64)
    a.flags.writeable = False
    return a


@functools.lru_cache(maxsize=64)
def _sensor_params(
    sigma_r: float, sigma_b: float, mount: tuple[float, ...], nu: float
) -> FloatArray:
    """The core's parameter row (1, 13) of a sensor (read-only, cached)."""
    p = np.zeros((1, _N_PARAMS))
    p[0, 3:5] = (sigma_r, sigma_b)
    p[0, 7:10] = mount
    p[0, 10] = nu
    p[0, 11] = 1.0
    p.flags.writeable = False
    return p


def predict(
    state: State,
    u: ArrayLike,
    model: Noise | Motion,
    *,
    integration: Integration = "midpoint",
    drive: DiffDrive | None = None,
) -> State:
    """The prediction (Eq. 13) of ``state`` (..., n) by input ``u`` (..., k) through ``model``.

    ``model`` a relmap.models noise model: odometry of a pose AT, ``u = (Δs, Δθ)`` (or wheel
    increments with ``drive``); a model whose ``core_params`` are given (DistanceNoise with
    midpoint integration) is the core's built-in model, the others give the step's AT through
    :mod:`relmap.models`. ``model`` a :class:`Motion`: any ``f`` (see there).
    """
    x, P = _arrays(state)
    if isinstance(model, Motion):
        uu = np.asarray(u, dtype=np.float64)
        chart = SE2 if isinstance(state, AT) else EUCLIDEAN
        x_new = np.asarray(model.f(x, uu), dtype=np.float64)
        if model.jacobians is not None:
            F, G = model.jacobians(x, uu)
        else:
            # the helper perturbs along a new axis before the point's: the other input follows
            F = numerical_jacobian(
                lambda xx: model.f(xx, uu[..., None, :]), x, chart_in=chart, chart_out=chart
            )
            G = numerical_jacobian(lambda v: model.f(x[..., None, :], v), uu, chart_out=chart)
        Qu = np.asarray(model.noise(uu), dtype=np.float64)
        Q = gaussian.congruence(G, Qu)
        return _like(state, x_new, _predict_covariance(P, np.asarray(F), Q))
    if not isinstance(state, AT):
        raise ParameterError("odometry predicts a pose AT; use a Motion model for a Belief")
    k = model.core_params(integration)
    m = _pairs(u, "motion", finite=k is None)  # (the core checks the steps it is given)
    if drive is not None:
        m = drive.motion(m)
    if k is not None:  # the core's built-in odometry model (k: one parameter row, shared)
        # one batch, or one step for every filter (the core shares it): no broadcasting
        if x.shape[:-1] == m.shape[:-1] or (m.ndim == 1 and P.shape[:-2] == x.shape[:-1]):
            xo, Po = _core.ekf_predict_odometry(x, P, m, k)
            return AT._trusted(xo, Po)
        batch = np.broadcast_shapes(x.shape[:-1], m.shape[:-1])
        xo, Po = _core.ekf_predict_odometry(
            _flat(x, batch, (3,)), _flat(P, batch, (3, 3)), _flat(m, batch, (2,)), k
        )
        return AT._trusted(xo.reshape(*batch, 3), Po.reshape(*batch, 3, 3))
    batch = np.broadcast_shapes(x.shape[:-1], m.shape[:-1])
    step = _step_ats(m, model, integration, drive)
    mean, F, G = se2.compose(x, step.mean, jacobians=True)
    Q = gaussian.congruence(G, step.cov)
    return AT._trusted(mean, _predict_covariance(P, F, Q))


class Correction(NamedTuple):
    """The corrected state and the step's innovation statistics (leading axes of the batch)."""

    state: State
    y: FloatArray  #: (..., d) innovation z ⊖ h(x⁻)
    S: FloatArray  #: (..., d, d) its covariance H P⁻ Hᵀ + R
    nis: FloatArray  #: (...) yᵀ S⁻¹ y (NaN where not ok)
    ok: np.ndarray  #: (...) False where S is not positive definite (state left unchanged)


def correct(state: State, z: ArrayLike, sensor: Sensor) -> Correction:
    """The correction (Eqs. 26-28, Joseph form) with a reading ``z`` (..., d) of ``sensor``."""
    x, P = _arrays(state)
    zz = np.asarray(z, dtype=np.float64)
    chart = SE2 if isinstance(state, AT) else EUCLIDEAN
    h = np.asarray(sensor.h(x), dtype=np.float64)
    if sensor.jacobian is not None:
        H = np.asarray(sensor.jacobian(x), dtype=np.float64)
    else:
        H = numerical_jacobian(sensor.h, x, chart_in=chart)
    y = zz - h
    for i in sensor.angular:
        y[..., i] = se2.wrap_angle(y[..., i])
    return _correct_arrays(state, x, P, y, H, np.asarray(sensor.R, dtype=np.float64))


def _correct_arrays(state, x, P, y, H, R) -> Correction:
    n, d = x.shape[-1], y.shape[-1]
    if not (np.isfinite(y).all() and np.isfinite(H).all() and np.isfinite(R).all()):
        raise NonFiniteError("the innovation, H and R must be finite")
    batch = np.broadcast_shapes(
        x.shape[:-1], P.shape[:-2], y.shape[:-1], H.shape[:-2], R.shape[:-2]
    )
    xo, Po, S, nis, _, ok = _core.ekf_correct(
        _flat(x, batch, (n,)), _flat(P, batch, (n, n)), _flat(y, batch, (d,)),
        _flat(H, batch, (d, n)), _flat(R, batch, (d, d)),
    )  # fmt: skip
    new = _like(state, xo.reshape(*batch, n), Po.reshape(*batch, n, n))
    return Correction(new, np.broadcast_to(y, (*batch, d)), S.reshape(*batch, d, d),
                      nis.reshape(batch), ok.reshape(batch))  # fmt: skip


class PoseUpdate(NamedTuple):
    """The corrected state and the gate's verdict on a full-pose reading."""

    state: AT
    mahalanobis2: FloatArray  #: (...) d² of the innovation under Σ⁻ + Σz
    accepted: np.ndarray  #: (...) whether the reading was used


def correct_pose(state: AT, reading: AT, *, gate: float | None = 0.999) -> PoseUpdate:
    """Correct with a full-pose reading (GPS + compass; Eqs. 14-19): ``h(x) = x``, ``H = I``,
    ``R`` the reading's covariance — the paper's merge of §4. The innovation (heading wrapped)
    is gated at the χ²₃ quantile ``gate`` (None: no gate); a gated-out reading leaves the state
    as it was."""
    y = se2.minus(reading.mean, state.mean)
    c = _correct_arrays(state, state.mean, state.cov, y, np.eye(3), reading.cov)
    d2 = np.where(c.ok, c.nis, np.inf)
    ok = c.ok if gate is None else c.ok & (d2 <= gaussian.confidence_k2(gate, 3))
    mean = np.where(ok[..., None], c.state.mean, np.broadcast_to(state.mean, c.state.mean.shape))
    cov = np.where(ok[..., None, None], c.state.cov, np.broadcast_to(state.cov, c.state.cov.shape))
    return PoseUpdate(AT._trusted(mean, cov), d2, ok)


# ------------------------------------------------------------------------ noise parameters
_FIELDS = ("k_s", "k_theta", "k_theta_s", "sigma_r", "sigma_b", "b_r", "b_b", "mx", "my",
           "mtheta", "nu", "inflation", "clutter")  # fmt: skip
_N_PARAMS = len(_FIELDS)


class NoiseParameters(NamedTuple):
    """The noise of a pose filter over a log, per filter: each field a float or an array of a
    batch shape (all broadcast together); a batch of parameters is a batch of filters.

    Odometry (:class:`relmap.models.DistanceNoise`): ``var Δs = k_s|Δs|`` (m²/m),
    ``var Δθ = k_theta|Δθ| + k_theta_s|Δs|`` (rad²/rad, rad²/m). Sensor: σ of range ``sigma_r``
    (m) and bearing ``sigma_b`` (rad), biases ``b_r`` (m), ``b_b`` (rad) subtracted from the
    readings, the sensor's mount ``(mx, my)`` (m) and heading ``mtheta`` (rad) on the robot,
    and the Student-t dof ``nu`` of the readings (inf: Gaussian; see the module notes).
    ``inflation``: the σ factor of the update for readings whose errors repeat from one reading
    to the next (:mod:`relmap.filter.autocalibration`'s whitening): the gain and the covariance use
    ``(inflation σ)²``, the association, the gate and the likelihood the readings' ``σ²``.
    ``clutter`` λ ≥ 0: the density of readings of nothing in the map (other robots, unknown
    objects), relative to a landmark's reading density ``g`` (same units, e.g. 1/(m rad)); a
    used reading is of its landmark with probability ``w = g/(g + λ)`` and enters the update
    with noise ``R / w`` (module notes). 0: every reading in the gate is of a landmark.
    """

    k_s: ArrayLike
    k_theta: ArrayLike
    k_theta_s: ArrayLike
    sigma_r: ArrayLike
    sigma_b: ArrayLike = 0.0
    b_r: ArrayLike = 0.0
    b_b: ArrayLike = 0.0
    mx: ArrayLike = 0.0
    my: ArrayLike = 0.0
    mtheta: ArrayLike = 0.0
    nu: ArrayLike = np.inf
    inflation: ArrayLike = 1.0
    clutter: ArrayLike = 0.0

    @classmethod
    def of(cls, odometry: DistanceNoise, sensor: RangeBearingSensor, *, nu: float = np.inf,
           b_r: float = 0.0, b_b: float = 0.0) -> NoiseParameters:  # fmt: skip
        """From a relmap.models odometry noise and a (constant-noise) sensor."""
        mx, my, mt = (float(v) for v in sensor.mount)
        return cls(odometry.k_s, odometry.k_theta, odometry.k_theta_s, sensor.sigma_range,
                   sensor.sigma_bearing, b_r, b_b, mx, my, mt, nu)  # fmt: skip

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return np.broadcast_shapes(*(np.shape(v) for v in self))

    def array(self) -> FloatArray:
        """``(B, 13)`` the fields in order, the batch flattened (checked)."""
        batch = self.batch_shape
        cols = [np.broadcast_to(np.asarray(v, dtype=np.float64), batch).reshape(-1) for v in self]
        a = np.column_stack(cols) if cols[0].size else np.zeros((0, _N_PARAMS))
        finite = np.isfinite(a[:, [*range(10), 11, 12]]).all(axis=1)
        if not finite.all():
            raise NonFiniteError("noise parameters must be finite (nu may be inf)")
        if (a[:, [0, 1, 2, 3, 4]] < 0).any():
            raise ParameterError("odometry coefficients and sensor σ must be non-negative")
        if not (a[:, 10] > 0).all():
            raise ParameterError("the Student-t dof nu must be positive (inf: Gaussian)")
        if not (a[:, 11] > 0).all():
            raise ParameterError("the update's σ inflation must be positive (1: none)")
        if (a[:, 12] < 0).any():
            raise ParameterError("the clutter density must be non-negative (0: none)")
        return np.ascontiguousarray(a)

    def as_dict(self) -> dict[str, float | list[float] | None]:
        """JSON-ready: scalars as floats (nu inf as None), arrays as lists."""
        out: dict[str, float | list[float] | None] = {}
        for k, v in zip(_FIELDS, self, strict=True):
            a = np.asarray(v, dtype=np.float64)
            if a.ndim == 0:
                out[k] = None if np.isinf(a) else float(a)
            else:
                out[k] = [None if np.isinf(e) else float(e) for e in a.reshape(-1)]  # type: ignore[misc]
        return out


# ------------------------------------------------------------------------ landmark readings
class LandmarkUpdate(NamedTuple):
    """The corrected state and what happened to every reading (arrays shaped like the readings'
    leading axes ``(..., m)``; per filter ``(...)``)."""

    state: AT
    landmark: IntArray  #: row of the map each reading was paired with (-1: none)
    mahalanobis2: FloatArray  #: d² to the paired (or nearest) landmark, inf if none
    status: IntArray  #: a :class:`Status` per reading
    y: FloatArray  #: (..., m, d) innovation of the reading's pair (NaN: no pair)
    S: FloatArray  #: (..., m, d, d) its covariance (NaN: no pair)
    loglik: FloatArray  #: (...) log-likelihood of the stacked innovation of the used pairs
    nis: FloatArray  #: (...) its yᵀ S⁻¹ y

    def report(self) -> dict[str, int]:
        """How many readings ended in each status (by lower-case status name)."""
        return {s.name.lower(): int((self.status == s).sum()) for s in Status}


def _association(
    associate: object, pairing: object, signatures: bool
) -> tuple[Association, int, int]:
    """``(association, method, cost)`` of the core (cached: a filter asks at every step)."""
    try:
        return _association_codes(associate, pairing, signatures)
    except TypeError:  # an unhashable option is no member: the uncached call says so
        return _association_codes.__wrapped__(associate, pairing, signatures)


@functools.lru_cache(maxsize=64)
def _association_codes(
    associate: object, pairing: object, signatures: bool
) -> tuple[Association, int, int]:
    a = _option(Association, associate, "associate")
    p = _option(Pairing, pairing, "pairing")
    if a is Association.SIGNATURES and not signatures:
        raise ParameterError("signature association needs the signatures of the readings")
    method = 2 if a is Association.JCBB else (1 if p is Pairing.PER_LANDMARK else 0)
    return a, method, 1 if a is Association.EUCLIDEAN else 0  # type: ignore[return-value]


@functools.lru_cache(maxsize=256)
def _gates(gate: float, d: int, k: int) -> tuple[float, FloatArray]:
    """The individual χ²_d gate and, for JCBB, the joint χ²_{dk} gates for k = 0..k pairs
    (cached: a filter's steps ask for the same gates again and again)."""
    gaussian.check_probability(gate, "gate")
    joint = np.array([0.0] + [float(gaussian.confidence_k2(gate, d * j)) for j in range(1, k + 1)])
    joint.flags.writeable = False
    return float(gaussian.confidence_k2(gate, d)), joint


class LandmarkMap:
    """A map of point landmarks, checked once: positions ``xy`` (L, 2) in the world frame and
    integer ``signatures`` (L,) (e.g. barcodes; default the rows 0..L-1), read-only.

    :func:`correct_landmarks` and :func:`run` take one in place of the positions array (an
    array given there is made into one at each call, through this class): a filter that
    corrects at every step with one map builds it once, and the checks (shapes, finite
    positions) and the core's preparation (the signatures sorted) are not redone at every step.
    Landmarks are referred to by their row, as ``LandmarkUpdate.landmark`` reports them.

    >>> import numpy as np, relmap as rm
    >>> from relmap import ekf
    >>> from relmap.models import RangeBearingSensor
    >>> landmarks = ekf.LandmarkMap([[4.0, 0.0], [0.0, 3.0]], signatures=[17, 42])
    >>> prior = rm.AT([0.0, 0.0, 0.0], np.diag([0.1, 0.1, 0.01]))
    >>> sensor = RangeBearingSensor(0.1, 0.01)
    >>> up = ekf.correct_landmarks(prior, [[3.1, 1.6]], sensor, landmarks,
    ...                            associate="signatures", signatures=[42])
    >>> print(up.landmark, up.status)  # the row of signature 42, used
    [1] [0]
    """

    __slots__ = ("_core", "signatures", "xy")
    xy: FloatArray
    signatures: IntArray

    def __init__(self, xy: ArrayLike, signatures: ArrayLike | None = None) -> None:
        lm = np.array(xy, dtype=np.float64)
        if lm.ndim != 2 or lm.shape[1] != 2:
            raise ShapeError(f"landmarks must have shape (L, 2); got {lm.shape}")
        if not np.isfinite(lm).all():
            raise NonFiniteError("landmark positions must be finite")
        if signatures is None:
            sig = np.arange(len(lm), dtype=np.int64)
        else:
            sig = np.array(signatures, dtype=np.int64)
            if sig.shape != (len(lm),):
                raise ShapeError(
                    f"landmark_signatures must have shape ({len(lm)},); got {sig.shape}"
                )
        lm.flags.writeable = sig.flags.writeable = False
        object.__setattr__(self, "xy", lm)
        object.__setattr__(self, "signatures", sig)
        object.__setattr__(self, "_core", _core.EkfMap(lm, sig))

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError("a LandmarkMap is immutable; build a new one")

    def __len__(self) -> int:
        return len(self.xy)

    def __repr__(self) -> str:
        return f"LandmarkMap({len(self)} landmarks)"


def _landmark_map(landmarks: LandmarkMap | ArrayLike, signatures: ArrayLike | None) -> LandmarkMap:
    """``landmarks`` as a :class:`LandmarkMap` (an array checked and prepared here)."""
    if isinstance(landmarks, LandmarkMap):
        if signatures is not None:
            raise ParameterError(
                "landmark_signatures belong to the LandmarkMap: give them when building it"
            )
        return landmarks
    return LandmarkMap(landmarks, signatures)


def _ndim(a: object) -> int:
    """``np.ndim(a)``, without its cost for None and arrays (called every step)."""
    if a is None:
        return 0
    return a.ndim if isinstance(a, np.ndarray) else np.ndim(a)


def _rows(a: ArrayLike, dtype: type, shape: tuple[int, ...]) -> np.ndarray:
    """``a`` as an array of ``dtype`` broadcast to ``shape`` (no broadcast when it has that
    shape already: np.broadcast_to costs microseconds). The core's bindings copy what is not
    C-contiguous."""
    arr = np.asarray(a, dtype=dtype)
    return arr if arr.shape == shape else np.broadcast_to(arr, shape)


def correct_landmarks(
    state: AT,
    readings: ArrayLike,
    sensor: RangeBearingSensor,
    landmarks: LandmarkMap | ArrayLike,
    *,
    associate: Association | str = Association.MAHALANOBIS,
    pairing: Pairing | str = Pairing.ONE_TO_ONE,
    signatures: ArrayLike | None = None,
    landmark_signatures: ArrayLike | None = None,
    gate: float = 0.99,
    valid: ArrayLike | None = None,
    range_only: bool = False,
    nu: float = np.inf,
) -> LandmarkUpdate:
    """Correct with readings of point landmarks ``(L, 2)`` (or a :class:`LandmarkMap`, checked
    once: a filter correcting at every step builds one): range-bearing ``(r, φ)``
    (..., m, 2) from ``sensor`` (Eq. 20, its mount and noise model), or with ``range_only``
    ranges (..., m) (Eq. 20's first row; σ = ``sensor.sigma_range``).

    Association (:class:`Association`): ``signatures`` pairs a reading with the landmark of
    equal signature (``signatures`` (..., m), ``landmark_signatures`` (L,), default the rows;
    a :class:`LandmarkMap` has its own);
    ``mahalanobis`` (Eq. 23) and ``euclidean`` (Eq. 22) with the nearest landmark, ``jcbb`` the
    largest jointly compatible set. Signatures, when given, restrict the candidates under every
    method. :class:`Pairing` one to one (greedy, cheapest pair first; the others LOST) or per
    landmark (Eq. 21). Pairs with ``d² > χ²_d(gate)`` are GATED (Eq. 25). A used reading with
    several landmarks inside its gate (Mahalanobis and JCBB) is of one of them, which one
    unknown: it enters the update moment-matched to the mixture of their likelihoods, with the
    association probabilities ``β_j ∝ |S_j|^(-1/2) exp(-d²_j/2)`` (probabilistic data
    association, Bar-Shalom & Tse 1975, without clutter: the gate has rejected the rest), as a
    reading of one virtual landmark with ``ẑ = Σ β_j h_j``, ``H = Σ β_j H_j`` and
    ``R = Σ β_j R_j + Σ β_j (h_j - ẑ)(h_j - ẑ)ᵀ``; its landmark (and status) stay the ones its
    association chose, its ``y``, ``S`` and d² are the virtual landmark's. (Landmarks closer
    together than a reading can tell apart then give their centroid with their spread as noise,
    not one of them taken wrongly with full confidence; one candidate of β ≈ 1 gives its own
    update.)
    ``valid`` (..., m) marks padding (ABSENT); NaN or non-positive ranges are INVALID. The used
    pairs form one stacked update (Eqs. 26-28, Joseph form); ``nu`` finite: Student-t readings
    (module notes).
    """
    d = 1 if range_only else 2
    z = np.asarray(readings, dtype=np.float64)
    if range_only:
        z = z[..., None]
    if z.ndim < 2 or z.shape[-1] != d:
        raise ShapeError(
            f"readings must have shape (..., m{', 2' if d == 2 else ''}); got {z.shape}"
        )
    m = z.shape[-2]
    lmap = _landmark_map(landmarks, landmark_signatures)
    a, method, cost = _association(associate, pairing, signatures is not None)
    if state.ndim == 0 and z.ndim == 2 and _ndim(valid) <= 1 and _ndim(signatures) <= 1:
        batch: tuple[int, ...] = ()  # one filter, one scan: no broadcasting to work out
    else:
        batch = np.broadcast_shapes(state.batch_shape, z.shape[:-2])
        if valid is not None:
            batch = np.broadcast_shapes(batch, np.shape(valid)[:-1])
        if signatures is not None:
            batch = np.broadcast_shapes(batch, np.shape(signatures)[:-1])
    rows = (*batch, m)
    present = _ones(batch, m) if valid is None else _rows(valid, bool, rows)
    sig = _zeros(batch, m) if signatures is None else _rows(signatures, np.int64, rows)
    params = _sensor_params(
        sensor.sigma_range, sensor.sigma_bearing, tuple(sensor.mount.tolist()), float(nu)
    )
    gate2, joint = _gates(gate, d, m if a is Association.JCBB else 0)
    x, P = state.mean, state.cov  # (float64 already: broadcast if the batch is larger)
    if x.shape[:-1] != batch:
        x, P = np.broadcast_to(x, (*batch, 3)), np.broadcast_to(P, (*batch, 3, 3))
    # the state, and packed outputs (*batch, F) and (*batch, I): see the core's
    # ekf_correct_readings
    xo, Po, f, i = _core.ekf_correct_readings(
        x, P, _rows(z, np.float64, (*rows, d)), present, sig, lmap._core, params,
        1 if range_only else 0, _NOISE_MODELS[sensor.noise_model], method, cost,
        signatures is not None, gate2, joint, _JCBB_NODES,
    )  # fmt: skip
    e, e2 = m * d, m * d + m * d * d
    y, S = f[..., :e].reshape(*rows, d), f[..., e:e2].reshape(*rows, d, d)
    if range_only:
        y, S = y[..., 0], S[..., 0, 0]
    return LandmarkUpdate(
        AT._trusted(xo, Po), i[..., m : 2 * m],
        f[..., e2 : e2 + m], i[..., :m], y, S, f[..., -2], f[..., -1],
    )  # fmt: skip


#: JCBB explores at most this many nodes of its search tree per time stamp (then keeps the
#: best hypothesis found): bounds the cost of a crowded scan; chosen once.
_JCBB_NODES = 10_000


# ------------------------------------------------------------------------------ runs
class Log(NamedTuple):
    """A time-ordered log for :func:`run`.

    ``t`` (T,) the filter's times, strictly increasing; ``motion`` (T-1, 2) the odometry step
    ``(Δs, Δθ)`` from ``t[k]`` to ``t[k+1]``; ``reading_index`` (M,) the time index of each
    reading (non-decreasing; readings of one index form one stacked update); ``z`` (M, 2)
    range-bearing readings or (M,) ranges; ``signature`` (M,) integers (e.g. barcodes) or None.
    """

    t: FloatArray
    motion: FloatArray
    reading_index: IntArray
    z: FloatArray
    signature: IntArray | None = None

    @classmethod
    def from_velocities(
        cls,
        odometry_t: ArrayLike,
        v: ArrayLike,
        w: ArrayLike,
        reading_t: ArrayLike,
        z: ArrayLike,
        signature: ArrayLike | None = None,
        *,
        end: float | None = None,
    ) -> Log:
        """A log from odometry velocities ``(v, ω)`` at times ``odometry_t`` (each held until
        the next record) and readings at times ``reading_t``: the filter's times are the
        odometry times up to ``end`` (default the last) merged with the reading times in
        ``[odometry_t[0], end]`` (readings outside are dropped)."""
        ot = np.asarray(odometry_t, dtype=np.float64)
        rt = np.asarray(reading_t, dtype=np.float64)
        vv, ww = np.asarray(v, dtype=np.float64), np.asarray(w, dtype=np.float64)
        zz = np.asarray(z, dtype=np.float64)
        if ot.ndim != 1 or not len(ot):
            raise ParameterError("the log has no odometry")
        if vv.shape != ot.shape or ww.shape != ot.shape:
            raise ShapeError("odometry times, v and ω must have the same length")
        if len(rt) != len(zz) or (signature is not None and np.shape(signature) != rt.shape):
            raise ShapeError("reading times, readings and signatures must have the same length")
        for name, a in (("odometry", ot), ("reading", rt)):
            if not np.isfinite(a).all():
                raise NonFiniteError(f"{name} time stamps must be finite")
            if (np.diff(a) < 0).any():
                k = int(np.flatnonzero(np.diff(a) < 0)[0])
                raise ParameterError(
                    f"{name} time stamps must not decrease: t[{k + 1}] = {a[k + 1]} < "
                    f"t[{k}] = {a[k]}"
                )
        if not (np.isfinite(vv).all() and np.isfinite(ww).all()):
            raise NonFiniteError("odometry velocities must be finite")
        stop = float(ot[-1]) if end is None else float(end)
        keep = (rt >= ot[0]) & (rt <= stop)
        t = np.unique(np.concatenate([ot[ot <= stop], rt[keep]]))
        k = np.searchsorted(ot, t, side="right") - 1  # last record at or before each time
        dt = np.diff(t)
        motion = np.column_stack([vv[k[:-1]] * dt, ww[k[:-1]] * dt])
        index = np.searchsorted(t, rt[keep])
        sig = None if signature is None else np.asarray(signature, dtype=np.int64)[keep]
        return cls(t, motion, index, zz[keep], sig)


class Trace(NamedTuple):
    """What :func:`run` returns; ``batch`` is the parameters' batch shape.

    States at times ``t`` (see :class:`Keep`): ``mean`` (*batch, T, 3), ``cov``
    (*batch, T, 3, 3). Per reading (*batch, M, …): innovation ``y`` (M, d) and its ``S``
    (M, d, d) for the reading's pair (NaN: none), ``mahalanobis2``, ``status`` (a
    :class:`Status`), ``landmark`` (row, -1: none). Per filter (*batch): ``loglik`` the sum of the
    log-likelihoods of the stacked innovations (Gaussian, or Student-t with scale S), ``nis``
    the sum of their ``yᵀS⁻¹y`` over ``dof`` components (NIS/dof ≈ 1 when consistent),
    ``updates`` time stamps corrected, ``counts`` (*batch, 7) readings per status,
    ``ambiguous`` used readings that had several landmarks inside their gate and entered the
    update as the mixture of them (:func:`correct_landmarks`). Per reading again, ``y_given``
    (M, d) and ``S_given`` (M, d, d): the innovation and its covariance given the readings
    before it in its time's stacked update (the used ones in update order, a gated one given
    all the used ones; R itself, not inflated nor reweighted): the prediction-error
    decomposition, whose densities multiply to the stacked likelihood ``loglik`` (the
    readings of one time share the pose's error, so ``y`` and ``S`` at the prior are not
    independent; NaN: no pair or a 0/0 update).
    """

    t: FloatArray
    mean: FloatArray
    cov: FloatArray
    y: FloatArray
    S: FloatArray
    mahalanobis2: FloatArray
    status: IntArray
    landmark: IntArray
    loglik: FloatArray
    nis: FloatArray
    dof: IntArray
    updates: IntArray
    counts: IntArray
    ambiguous: IntArray
    y_given: FloatArray
    S_given: FloatArray

    def estimate(self) -> AT:
        """The kept states as an AT batch (*batch, T)."""
        return AT._trusted(self.mean, self.cov)

    def count(self, status: Status) -> IntArray:
        """Readings of ``status`` per filter (*batch)."""
        return self.counts[..., int(status)]


def run(
    log: Log,
    landmarks: LandmarkMap | ArrayLike,
    params: NoiseParameters,
    *,
    start: AT,
    association: Association | str = Association.SIGNATURES,
    pairing: Pairing | str = Pairing.ONE_TO_ONE,
    landmark_signatures: ArrayLike | None = None,
    gate: float = 0.99,
    sensor: SensorKind | str = SensorKind.RANGE_BEARING,
    noise_model: str = "constant",
    keep: Keep | str = Keep.ALL,
    readings: bool = True,
) -> Trace:
    """Run pose filters over ``log`` with the map ``landmarks`` (L, 2) or a
    :class:`LandmarkMap`: one filter per parameter set of ``params`` (its batch shape), each
    from ``start`` (an AT, broadcast to the batch). Predict every odometry step (built-in
    odometry model), correct at every time index with readings (all of them in one stacked
    update; association, gate and sensor as in :func:`correct_landmarks`). ``readings=False``
    skips the per-reading arrays (then empty). All loops run in the core; the filters of a
    batch are independent (each gives what it gives alone, bitwise)."""
    kind = _option(SensorKind, sensor, "sensor")
    d = 1 if kind is SensorKind.RANGE_ONLY else 2
    kp = _option(Keep, keep, "keep")
    if noise_model not in _NOISE_MODELS:
        raise ParameterError(f"noise_model must be one of {', '.join(_NOISE_MODELS)}")
    t = np.asarray(log.t, dtype=np.float64)
    if t.ndim != 1 or not len(t):
        raise ParameterError("the log is empty: it needs at least its start time")
    if not np.isfinite(t).all() or (np.diff(t) <= 0).any():
        raise ParameterError("the log's times must be finite and strictly increasing")
    motion = np.ascontiguousarray(log.motion, dtype=np.float64)
    if motion.shape != (len(t) - 1, 2):
        raise ShapeError(f"motion must have shape ({len(t) - 1}, 2); got {motion.shape}")
    if not np.isfinite(motion).all():
        raise NonFiniteError("odometry steps must be finite")
    z = np.asarray(log.z, dtype=np.float64)
    z = np.ascontiguousarray(z[:, None] if d == 1 and z.ndim == 1 else z)
    M = len(z)
    if z.shape != (M, d):
        raise ShapeError(f"readings must have shape (M, {d}) for {kind.value}; got {z.shape}")
    index = np.ascontiguousarray(log.reading_index, dtype=np.int64)
    if index.shape != (M,):
        raise ShapeError(f"reading_index must have shape ({M},); got {index.shape}")
    if M and (index[0] < 0 or index[-1] >= len(t) or (np.diff(index) < 0).any()):
        raise ParameterError("reading_index must be non-decreasing time indices of the log")
    a, method, cost = _association(association, pairing, log.signature is not None)
    use_sig = a is Association.SIGNATURES  # else signatures only label the readings
    sig = (np.zeros(M, np.int64) if log.signature is None
           else np.ascontiguousarray(log.signature, dtype=np.int64))  # fmt: skip
    lmap = _landmark_map(landmarks, landmark_signatures)
    p = params.array()
    batch = params.batch_shape
    B = len(p)
    if start.ndim not in (0, len(batch)) or (start.ndim and start.batch_shape != batch):
        raise ShapeError(f"start must be one pose or a batch {batch}; got {start.batch_shape}")
    per_event = int(np.bincount(index).max()) if M and a is Association.JCBB else 0
    gate2, joint = _gates(gate, d, per_event)
    x0 = _flat(start.mean, batch, (3,)).reshape(B, 3)
    P0 = _flat(start.cov, batch, (3, 3)).reshape(B, 3, 3)
    keep_code = {"summary": 0, "events": 1, "all": 2}[kp.value]
    r = _core.ekf_run(
        x0, P0, motion, index, z, sig, lmap._core, p, 1 if d == 1 else 0,
        _NOISE_MODELS[noise_model], method, cost, use_sig, gate2, joint, _JCBB_NODES, keep_code,
        readings,
    )  # fmt: skip
    bad = r["overflow"]
    if (bad >= 0).any():
        f = int(np.flatnonzero(bad >= 0)[0])
        raise NumericalError(
            f"the filter overflowed the floating-point range at time {t[bad[f]]} (index "
            f"{bad[f]}, filter {f}): inputs too large (odometry, readings or noise)"
        )
    times = {Keep.ALL: t, Keep.EVENTS: np.concatenate([t[:1], t[r["event_index"]]]),
             Keep.SUMMARY: t[-1:]}[kp]  # fmt: skip
    Mo = M if readings else 0
    y, S = r["y"].reshape(*batch, Mo, d), r["S"].reshape(*batch, Mo, d, d)
    yg, Sg = r["y_given"].reshape(*batch, Mo, d), r["S_given"].reshape(*batch, Mo, d, d)
    if d == 1:
        y, S, yg, Sg = y[..., 0], S[..., 0, 0], yg[..., 0], Sg[..., 0, 0]
    T = len(times)
    return Trace(
        times, r["mean"].reshape(*batch, T, 3), r["cov"].reshape(*batch, T, 3, 3),
        y, S, r["d2"].reshape(*batch, Mo), r["status"].reshape(*batch, Mo),
        r["landmark"].reshape(*batch, Mo), r["loglik"].reshape(batch), r["nis"].reshape(batch),
        r["dof"].reshape(batch), r["updates"].reshape(batch),
        r["counts"].reshape(*batch, len(Status)), r["ambiguous"].reshape(batch), yg, Sg,
    )  # fmt: skip
