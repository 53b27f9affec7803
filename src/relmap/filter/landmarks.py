"""Readings of point landmarks: association, gating, and one stacked update per time stamp.

:func:`correct_landmarks` takes the readings ``z`` (..., m, d) one sensor made at one time, any
:class:`relmap.models.Measurement` of a landmark (range-bearing, range only, bearing only, or a
user's), and a :class:`LandmarkMap`. It predicts each candidate landmark's reading
``ẑ = h(x, l)`` with ``H``, ``R`` and ``S = H P Hᵀ + R``, pairs readings with landmarks
(:class:`Association`: signatures, Mahalanobis (Eq. 23) or Euclidean (Eq. 22) nearest neighbour —
one to one, or each landmark its cheapest reading (Eq. 21, :class:`Pairing`) — or joint
compatibility branch and bound, JCBB, Neira & Tardós 2001), gates each pair at the χ²_d
quantile (Eq. 25), and corrects with all used pairs in one stacked update
(:func:`relmap.filter.ekf.update`). The searches that numpy cannot vectorize (greedy one-to-one
pairing, JCBB) are the compiled core's (``src/core/association.cpp``). Every reading gets a
:class:`Status`.

**Ambiguous readings.** A used reading with several landmarks inside its gate (Mahalanobis cost
or JCBB) is of one of them, which one unknown: it enters the update moment-matched to the
mixture of their likelihoods, with probabilities ``β_j ∝ |S_j|^(-1/2) exp(-d²_j/2)``
(probabilistic data association, Bar-Shalom & Tse 1975, the gate having rejected the rest), as a
reading of one virtual landmark: ``ẑ = Σ β_j h_j``, ``H = Σ β_j H_j``,
``R = Σ β_j R_j + Σ β_j (h_j - ẑ)(h_j - ẑ)ᵀ``. Its landmark stays its association's choice.

**How a used reading weighs.** With a finite Student-t dof ``nu`` its noise in the update is
``R / w`` with ``w = (ν + d)/(ν + d²)`` (the EM weight of a Student-t reading); ``inflation`` c
multiplies the update's σ (readings whose errors repeat carry less information than their
spread says: ``c² R``); with a clutter density ``clutter`` λ > 0 a reading is of its landmark
with probability ``g/(g + λ)`` (``g`` its density under the landmark hypothesis), which divides
its noise likewise. The association, the gate, ``S``, the NIS and the likelihood keep ``R``.
"""

from __future__ import annotations

import enum
import functools
from typing import NamedTuple

import numpy as np

from relmap import _core
from relmap.errors import NonFiniteError, ParameterError, ShapeError
from relmap.filter.ekf import _T, State, Update, _arrays, _like, update
from relmap.models.base import Measurement
from relmap.typing import ArrayLike, FloatArray, IntArray, Option
from relmap.uncertain.gaussian import check_probability, confidence_k2, inverse_pd, log_density
from relmap.uncertain.propagate import Chart

__all__ = [
    "JCBB_NODES",
    "Association",
    "LandmarkMap",
    "LandmarkUpdate",
    "Pairing",
    "Status",
    "correct_landmarks",
]


class Status(enum.IntEnum):
    """What became of a reading."""

    USED = 0  #: in the update
    GATED = 1  #: its pair lies outside the χ² gate (for JCBB: individually or jointly)
    UNKNOWN = 2  #: no landmark of the map can be it (its signature is not in the map)
    INVALID = 3  #: not a reading the model can use (not finite, a range not positive)
    ABSENT = 4  #: padding, no reading
    LOST = 5  #: its landmark went to a cheaper reading (one-to-one pairing)
    DEGENERATE = 6  #: no prediction: its landmark at the sensor

    @property
    def description(self) -> str:
        return _DESCRIPTIONS[self]


# (the statuses as plain integers, for numpy)
_USED, _GATED, _UNKNOWN, _INVALID, _LOST, _DEGENERATE = (
    int(s) for s in (Status.USED, Status.GATED, Status.UNKNOWN, Status.INVALID, Status.LOST,
                     Status.DEGENERATE))  # fmt: skip

_DESCRIPTIONS = {
    Status.USED: "used",
    Status.GATED: "outside the gate",
    Status.UNKNOWN: "no landmark of the map matches it",
    Status.INVALID: "not a reading the sensor can give",
    Status.ABSENT: "no reading (padding)",
    Status.LOST: "its landmark went to a closer reading",
    Status.DEGENERATE: "no prediction: its landmark at the sensor",
}


class Association(Option):
    """How readings are paired with the map's landmarks."""

    SIGNATURES = "signatures"  #: the landmark of the reading's signature (e.g. a barcode)
    MAHALANOBIS = "mahalanobis"  #: nearest by Mahalanobis distance (Eq. 23)
    EUCLIDEAN = "euclidean"  #: nearest by |z - h| (Eq. 22, metres and radians mixed)
    JCBB = "jcbb"  #: joint compatibility branch and bound (Neira & Tardós 2001)


class Pairing(Option):
    """How nearest-neighbour association resolves readings that want the same landmark."""

    ONE_TO_ONE = "one_to_one"  #: greedy, cheapest pair first; the others are LOST
    PER_LANDMARK = "per_landmark"  #: Eq. 21: each landmark takes its cheapest reading


#: JCBB explores at most this many nodes of its search tree per time stamp (then keeps the best
#: hypothesis found): bounds the cost of a crowded scan; chosen once.
JCBB_NODES = 10_000


class LandmarkMap:
    """A map of point landmarks, checked once: positions ``xy`` (L, p) in the world frame and
    integer ``signatures`` (L,) (e.g. barcodes; default the rows 0..L-1), read-only. Landmarks
    are referred to by their row.

    >>> import numpy as np, relmap as rm
    >>> from relmap.filter import landmarks
    >>> from relmap.models import RangeBearingSensor
    >>> lmap = landmarks.LandmarkMap([[4.0, 0.0], [0.0, 3.0]], signatures=[17, 42])
    >>> prior = rm.AT([0.0, 0.0, 0.0], np.diag([0.1, 0.1, 0.01]))
    >>> up = landmarks.correct_landmarks(prior, [[3.1, 1.6]], RangeBearingSensor(0.1, 0.01),
    ...                                  lmap, associate="signatures", signatures=[42])
    >>> print(up.landmark, up.status)  # the row of signature 42, used
    [1] [0]
    """

    __slots__ = ("_order", "_sorted", "signatures", "width", "xy")
    xy: FloatArray
    signatures: IntArray
    width: int  #: the most landmarks that share one signature

    def __init__(self, xy: ArrayLike, signatures: ArrayLike | None = None) -> None:
        lm = np.array(xy, dtype=np.float64)
        if lm.ndim != 2 or not lm.shape[1]:
            raise ShapeError(f"landmarks must have shape (L, p); got {lm.shape}")
        if not np.isfinite(lm).all():
            raise NonFiniteError("landmark positions must be finite")
        sig = np.arange(len(lm)) if signatures is None else np.array(signatures)
        if sig.shape != (len(lm),) or (sig.size and sig.dtype.kind not in "iu"):
            raise ShapeError(f"landmark signatures must be ({len(lm)},) integers; got {sig.shape}")
        sig = sig.astype(np.int64)
        lm.flags.writeable = sig.flags.writeable = False
        order = np.argsort(sig, kind="stable")
        width = int(np.unique(sig, return_counts=True)[1].max()) if len(sig) else 0
        for name, value in (("xy", lm), ("signatures", sig), ("_order", order),
                            ("_sorted", sig[order]), ("width", width)):  # fmt: skip
            object.__setattr__(self, name, value)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError("a LandmarkMap is immutable; build a new one")

    def __len__(self) -> int:
        return len(self.xy)

    def __repr__(self) -> str:
        return f"LandmarkMap({len(self)} landmarks)"

    def candidates(self, signatures: IntArray) -> IntArray:
        """The rows (..., m, width) of the landmarks of each reading's signature (..., m), in
        increasing row, padded with -1."""
        lo = np.searchsorted(self._sorted, signatures, side="left")
        hi = np.searchsorted(self._sorted, signatures, side="right")
        k = lo[..., None] + np.arange(self.width)
        rows = self._order[np.minimum(k, len(self._order) - 1)]
        return np.where(k < hi[..., None], rows, -1)


def _landmark_map(landmarks: LandmarkMap | ArrayLike) -> LandmarkMap:
    return landmarks if isinstance(landmarks, LandmarkMap) else LandmarkMap(landmarks)


@functools.lru_cache(maxsize=256)
def _gates(gate: float, d: int, k: int) -> tuple[float, FloatArray]:
    """The individual χ²_d gate and the joint χ²_{dj} gates for j = 0..k pairs (JCBB)."""
    check_probability(gate, "gate")
    joint = np.array([0.0] + [float(confidence_k2(gate, d * j)) for j in range(1, k + 1)])
    joint.flags.writeable = False
    return float(confidence_k2(gate, d)), joint


class LandmarkUpdate(NamedTuple):
    """The corrected state and what happened to every reading (arrays shaped like the readings'
    leading axes ``(..., m)``; per filter ``(...)``)."""

    state: State
    landmark: IntArray  #: row of the map each reading was paired with (-1: none)
    mahalanobis2: FloatArray  #: d² to the paired (or nearest) landmark, inf if none
    status: IntArray  #: a :class:`Status` per reading
    y: FloatArray  #: (..., m, d) innovation of the reading's pair (NaN: no pair)
    S: FloatArray  #: (..., m, d, d) its covariance (NaN: no pair)
    #: (..., m, d), (..., m, d, d): a paired reading's innovation and its covariance given the
    #: used readings before it in the stacked update (a gated one: given all the used ones),
    #: with R itself: the prediction-error decomposition, whose densities multiply to the
    #: stacked likelihood (NaN: no pair)
    y_given: FloatArray
    S_given: FloatArray
    loglik: FloatArray  #: (...) log-likelihood of the stacked innovation of the used pairs
    nis: FloatArray  #: (...) its yᵀ S⁻¹ y
    dof: IntArray  #: (...) its dimension
    ambiguous: IntArray  #: (...) used readings that entered as a mixture of landmarks

    def report(self) -> dict[str, int]:
        """How many readings ended in each status (by lower-case status name)."""
        return {s.name.lower(): int((self.status == s).sum()) for s in Status}


def _flat(a: ArrayLike, batch: tuple[int, ...], tail: tuple[int, ...], dtype: type) -> np.ndarray:
    """``a`` broadcast to ``(*batch, *tail)`` and flattened to ``(B, *tail)``."""
    b = np.broadcast_to(np.asarray(a, dtype=dtype), (*batch, *tail))
    return b.reshape(int(np.prod(batch, dtype=np.int64)), *tail)


class _Predicted(NamedTuple):
    """Landmarks' predicted readings, shaped ``(B, m', K, ...)`` to broadcast over the readings
    ``(B, m, 1, ...)``: ``rows`` the landmarks (-1: none), ``ok`` where a prediction exists."""

    rows: IntArray
    h: FloatArray
    H: FloatArray
    R: FloatArray
    S: FloatArray
    S_inv: FloatArray

    def at(self, name: str, i: IntArray | None, k: IntArray) -> FloatArray:
        """``name``'s entries of the pairs (reading i, candidate k), both (B, U) (i None: the
        readings in order): (B, U, ...)."""
        arr = getattr(self, name)
        if i is None and arr.shape[2] == 1 and arr.shape[1] == k.shape[1]:  # its own candidate
            return arr[:, :, 0]
        if i is None:
            i = np.broadcast_to(np.arange(k.shape[1]), k.shape)
        b = np.arange(len(arr))[:, None]
        return arr[b, i if arr.shape[1] > 1 else 0, k]


def _predict(
    x: FloatArray, P: FloatArray, rows: IntArray, lmap: LandmarkMap, sensor: Measurement
) -> _Predicted:
    """The readings of the landmarks ``rows`` (B, m', K) predicted from each filter's state
    ``x`` (B, n), ``P`` (B, n, n): ``ẑ = h(x, l)``, ``H``, ``R`` and ``S = H P Hᵀ + R`` (NaN
    where a landmark has no prediction: at the sensor)."""
    xy = lmap.xy[np.maximum(rows, 0)]  # (B', m', K, p)
    with np.errstate(invalid="ignore", divide="ignore"):
        h, H, _ = sensor.linearize(x[:, None, None, :], xy)
        R = sensor.noise(h)
        S = H @ P[:, None, None] @ _T(H) + R
        S_inv = inverse_pd(S)
    return _Predicted(rows, h, H, R, S, S_inv)


def _mixtures(
    used: np.ndarray, inside: np.ndarray, pred: _Predicted, d2: FloatArray, sensor: Measurement
) -> tuple[np.ndarray, FloatArray, FloatArray, FloatArray]:
    """The used readings ``(B, m)`` with several landmarks inside their gate (``inside``
    (B, m, K)), and their virtual landmark's ``ẑ``, ``H`` and ``R`` (module docstring; bearings
    averaged relative to the most probable landmark's)."""
    mixed = used & (inside.sum(axis=-1) >= 2)
    b, i = np.nonzero(mixed)
    j = i if pred.h.shape[1] > 1 else np.zeros_like(i)
    b_pred = b if len(pred.h) > 1 else np.zeros_like(b)
    h, H, R = pred.h[b_pred, j], pred.H[b_pred, j], pred.R[b_pred, j]  # (k, K, ...)
    logw = np.where(inside[b, i], -0.5 * d2[b, i] - 0.5 * np.linalg.slogdet(pred.S[b_pred, j])[1],
                    -np.inf)  # fmt: skip
    beta = np.exp(logw - logw.max(axis=-1, keepdims=True))
    beta /= beta.sum(axis=-1, keepdims=True)
    best = h[np.arange(len(b)), logw.argmax(axis=-1)]
    dh = sensor.innovation(h, best[:, None])  # relative to the most probable landmark's
    mean = np.einsum("kj,kja->ka", beta, dh)
    spread = dh - mean[:, None]
    R_mix = np.einsum("kj,kjab->kab", beta, R) + np.einsum("kj,kja,kjb->kab", beta, spread, spread)
    h_mix = sensor.reading_chart.plus(best, mean)
    return mixed, h_mix, np.einsum("kj,kjab->kab", beta, H), R_mix


def _per_landmark(
    cost: FloatArray, inside: np.ndarray, has: np.ndarray
) -> tuple[IntArray, IntArray, IntArray, np.ndarray]:
    """Eq. 21: each landmark takes its cheapest reading (ties: the lower reading). Returns each
    reading's candidate (B, m) — the first landmark it serves inside the gate, else the first
    that refused it, -1 for none — and its status, and the update's pairs (readings (B, K),
    their use (B, K)) in landmark order."""
    B, m, _ = cost.shape
    best = cost.argmin(axis=1)  # (B, K): each landmark's cheapest reading
    finite = np.isfinite(np.take_along_axis(cost, best[:, None], 1)[:, 0])
    take = finite & np.take_along_axis(inside, best[:, None], 1)[:, 0]
    status = np.full((B, m), -1, np.int64)
    chosen = np.full((B, m), -1, np.int64)
    for use, st in ((take, Status.USED), (finite & ~take, Status.GATED)):
        # a reading's first landmark (in landmark order) of this kind
        hit = use[:, None, :] & (best[:, None, :] == np.arange(m)[None, :, None])  # (B, m, K)
        first = np.where(hit.any(axis=-1), hit.argmax(axis=-1), -1)
        fresh = (chosen < 0) & (first >= 0)
        chosen[fresh], status[fresh] = first[fresh], int(st)
    status[has & (chosen < 0)] = int(Status.LOST)
    return chosen, status, best, take


class _Setup(NamedTuple):
    """What the corrections of one batch of filters share, prepared once (a run's every time)."""

    sensor: Measurement  #: its parameters shaped (B, 1, 1): over readings and candidates
    lmap: LandmarkMap
    association: Association
    per_landmark: bool
    gate2: float  #: the individual χ²_d gate
    joint: FloatArray  #: JCBB's joint gates by the number of pairs
    nu: FloatArray  #: (B, 1)
    inflation: FloatArray  #: (B, 1)
    clutter: FloatArray  #: (B, 1)
    reweighted: bool  #: whether any filter's update weights a reading
    given: bool  #: whether to give each reading's innovation given the ones before it


def _setup(
    sensor: Measurement, lmap: LandmarkMap, batch: tuple[int, ...], associate: object,
    pairing: object, gate: float, nu: ArrayLike, inflation: ArrayLike, clutter: ArrayLike,
    given: bool, most: int,
) -> _Setup:  # fmt: skip
    """The corrections' shared part for the batch's filters, ``most`` readings at a time."""
    a = Association.parse(associate, "associate")
    per_landmark = Pairing.parse(pairing, "pairing") is Pairing.PER_LANDMARK
    if lmap.xy.shape[1] != sensor.landmark_dim:
        raise ShapeError(f"the sensor reads landmarks of {sensor.landmark_dim} coordinates; "
                         f"the map's have {lmap.xy.shape[1]}")  # fmt: skip
    for k in sensor.noise_parameters:
        if not (np.asarray(getattr(sensor, k)) > 0).all():
            raise ParameterError(f"the sensor's {k} must be positive to correct with it")
    params = {k: _flat(getattr(sensor, k), batch, (), float) for k in sensor.noise_parameters}
    col = {k: _flat(v, batch, (), float)[:, None]
           for k, v in (("nu", nu), ("inflation", inflation), ("clutter", clutter))}  # fmt: skip
    if not (col["nu"] > 0).all() or not (col["inflation"] > 0).all() or (col["clutter"] < 0).any():
        raise ParameterError("nu and inflation must be positive and clutter non-negative")
    gate2, joint = _gates(float(gate), sensor.dim, most if a is Association.JCBB else 0)
    reweighted = bool(np.isfinite(col["nu"]).any() or (col["inflation"] != 1).any()
                      or (col["clutter"] > 0).any())  # fmt: skip
    return _Setup(sensor.replace(**params).batched(2), lmap, a, per_landmark, gate2, joint,
                  col["nu"], col["inflation"], col["clutter"], reweighted, given)  # fmt: skip


def _candidates(s: _Setup, signatures: IntArray | None, m: int) -> tuple[IntArray, np.ndarray]:
    """Each reading's candidates, for readings of signatures (..., m) or of none: ``rows``
    (..., m, K) of the map (-1: none), or (1, L) when every reading has every landmark, and
    ``cand`` (..., m, K): its signature's landmarks under signature association, else every
    landmark (of its signature, when given). Eq. 21's pairing needs a column per landmark (each
    takes its cheapest reading): every landmark, restricted to the reading's signature."""
    L = len(s.lmap)
    if s.association is Association.SIGNATURES and not s.per_landmark:
        rows = s.lmap.candidates(signatures)
        return rows, rows >= 0
    rows = np.arange(L)[None, :]
    if signatures is None:
        return rows, np.ones((m, L), bool)
    return rows, s.lmap.signatures == signatures[..., None]


def correct_landmarks(
    state: State,
    readings: ArrayLike,
    sensor: Measurement,
    landmarks: LandmarkMap | ArrayLike,
    *,
    associate: Association | str = Association.MAHALANOBIS,
    pairing: Pairing | str = Pairing.ONE_TO_ONE,
    signatures: ArrayLike | None = None,
    gate: float = 0.99,
    valid: ArrayLike | None = None,
    nu: ArrayLike = np.inf,
    inflation: ArrayLike = 1.0,
    clutter: ArrayLike = 0.0,
    given: bool = True,
) -> LandmarkUpdate:
    """Correct ``state`` with readings ``z`` (..., m, d) of the ``landmarks`` (L, p) (or a
    :class:`LandmarkMap`) by ``sensor`` (module docstring).

    ``signatures`` (..., m) pair a reading with the landmarks of its signature
    (``associate="signatures"``) and, when given, restrict the candidates under every
    association. ``valid`` (..., m) marks padding (ABSENT). The used pairs enter one stacked
    update, in reading order (Eq. 21: landmark order); ``nu``, ``inflation`` and ``clutter``
    (floats or batch arrays) weigh them (module docstring). The sensor's parameters may carry
    the batch's axes. ``given`` False: no ``y_given``, ``S_given`` (NaN; they cost a little).
    """
    if Association.parse(associate, "associate") is Association.SIGNATURES and signatures is None:
        raise ParameterError("signature association needs the signatures of the readings")
    lmap = _landmark_map(landmarks)
    x0, P0, chart = _arrays(state)
    d, n = sensor.dim, x0.shape[-1]
    z = np.asarray(readings, dtype=np.float64)
    if z.ndim < 2 or z.shape[-1] != d:
        raise ShapeError(f"readings must have shape (..., m, {d}); got {z.shape}")
    m = z.shape[-2]
    shapes = [x0.shape[:-1], z.shape[:-2], sensor.batch_shape]
    shapes += [np.shape(v) for v in (nu, inflation, clutter)]
    shapes += [np.shape(v)[:-1] for v in (valid, signatures) if v is not None]
    batch = np.broadcast_shapes(*shapes)
    s = _setup(sensor, lmap, batch, associate, pairing, gate, nu, inflation, clutter, given, m)
    zf = _flat(z, batch, (m, d), float)
    pending = sensor.usable(zf)
    if valid is not None:
        pending &= _flat(valid, batch, (m,), bool)
    sig = None if signatures is None else _flat(signatures, batch, (m,), np.int64)
    rows, cand = _candidates(s, sig, m)
    if s.association is not Association.SIGNATURES:  # (every reading has every landmark)
        rows = rows[None]
    r = _correct(s, chart, _flat(x0, batch, (n,), float), _flat(P0, batch, (n, n), float), zf,
                 pending, rows, cand if cand.ndim == 3 else cand[None])  # fmt: skip
    if valid is not None:
        r.status[~_flat(valid, batch, (m,), bool)] = Status.ABSENT
    shape = (*batch, m)
    x_new = r.x
    return LandmarkUpdate(
        _like(state, x_new.reshape(*batch, n), r.P.reshape(*batch, n, n)),
        r.landmark.reshape(shape), r.d2.reshape(shape), r.status.reshape(shape),
        r.y.reshape(*shape, d), r.S.reshape(*shape, d, d),
        np.full((*shape, d), np.nan) if r.y_given is None else r.y_given.reshape(*shape, d),
        np.full((*shape, d, d), np.nan) if r.S_given is None else r.S_given.reshape(*shape, d, d),
        r.loglik.reshape(batch), r.nis.reshape(batch),
        r.dof.reshape(batch), r.ambiguous.reshape(batch),
    )  # fmt: skip


class _Result(NamedTuple):
    """One correction of a batch of B filters with m readings (flat: (B, ...); ``y_given`` and
    ``S_given`` None unless asked)."""

    x: FloatArray
    P: FloatArray
    landmark: IntArray
    d2: FloatArray
    status: np.ndarray
    y: FloatArray
    S: FloatArray
    y_given: FloatArray | None
    S_given: FloatArray | None
    loglik: FloatArray
    nis: FloatArray
    dof: IntArray
    ambiguous: IntArray


def _correct(
    s: _Setup, chart: Chart, x: FloatArray, P: FloatArray, z: FloatArray, pending: np.ndarray,
    rows: IntArray, cand: np.ndarray,
) -> _Result:  # fmt: skip
    """The correction of the filters ``x`` (B, n), ``P`` (B, n, n) in ``chart`` with readings
    ``z`` (B', m, d) — B' 1 (shared) or B — of which ``pending`` (B', m) are usable, each with
    its candidates ``rows`` (B', m', K) and ``cand`` (B', m, K) (:func:`_candidates`)."""
    sensor, a = s.sensor, s.association
    B, m, d = len(x), z.shape[-2], z.shape[-1]
    if not len(s.lmap):  # an empty map: no reading has a candidate (the usable ones UNKNOWN)
        status = np.broadcast_to(np.where(pending, _UNKNOWN, _INVALID), (B, m)).astype(np.int8)
        y, S = np.full((B, m, d), np.nan), np.full((B, m, d, d), np.nan)
        given = (y.copy(), S.copy()) if s.given else (None, None)
        zero = np.zeros(B, np.int64)
        return _Result(x, P, np.full((B, m), -1), np.full((B, m), np.inf), status, y, S, *given,
                       np.zeros(B), np.zeros(B), zero, zero.copy())  # fmt: skip
    pred = _predict(x, P, rows, s.lmap, sensor)
    K = rows.shape[-1]
    v = sensor.innovation(z[:, :, None, :], pred.h)  # (B, m, K, d): every candidate pair
    with np.errstate(invalid="ignore"):
        d2 = (v[..., :, None] * pred.S_inv * v[..., None, :]).sum(axis=(-2, -1))  # vᵀ S⁻¹ v
    pair = pending[..., None] & cand & np.isfinite(d2)  # a prediction exists (not at the sensor)
    d2 = np.where(pair, d2, np.inf)
    inside = d2 <= s.gate2
    has = pair.any(axis=-1)
    # a reading with no pair: usable with candidates (but no prediction), usable, or not
    alone = np.where(pending, np.where(cand.any(axis=-1), _DEGENERATE, _UNKNOWN), _INVALID)

    # the pairing: each reading's candidate (B, m) (-1: none) and its status; the update's
    # pairs: readings (B, U), their candidates (B, U), and which are in the update (B, U)
    if s.per_landmark:
        chosen, st, best, take = _per_landmark(d2 if a is not Association.EUCLIDEAN
                                               else _euclid(v, pair), inside, has)  # fmt: skip
        status = np.where(has, st, alone).astype(np.int8)
        pair_reading, pair_k, pair_used = best, np.broadcast_to(np.arange(K), (B, K)), take
    elif a is Association.JCBB:
        choice = _core.jcbb(
            np.ascontiguousarray(np.broadcast_to(v, (B, m, K, d))),
            np.ascontiguousarray(np.broadcast_to(pred.H[:, 0], (B, K, d, P.shape[-1]))),
            np.ascontiguousarray(np.broadcast_to(pred.R[:, 0], (B, K, d, d))),
            np.ascontiguousarray(P), np.ascontiguousarray(d2),
            np.ascontiguousarray(inside & pair), s.joint, JCBB_NODES,
        )  # fmt: skip
        chosen = np.where(has & (choice < 0), d2.argmin(axis=-1), choice)  # nearest: gated
        pair_used = choice >= 0
        status = np.where(pair_used, _USED, np.where(has, _GATED, alone)).astype(np.int8)
    else:
        cost = d2 if a is not Association.EUCLIDEAN else _euclid(v, pair)
        chosen = _one_to_one(cost, inside, rows, len(s.lmap), a is not Association.EUCLIDEAN)
        got = chosen >= 0
        pair_used = got & (_pick(d2, np.maximum(chosen, 0)) <= s.gate2)
        status = np.where(pair_used, _USED, np.where(got, _GATED, np.where(has, _LOST, alone)))
        status = status.astype(np.int8)

    # each reading's report: its pair's landmark, d², y and S (no pair: the nearest d²)
    got = chosen >= 0
    k = np.maximum(chosen, 0)
    landmark = np.where(got, _pick(np.broadcast_to(rows, (B, m, K)), k), -1)
    # (no pair: the nearest candidate's d² — inf under Eq. 21, where a reading wants none)
    nearest = np.inf if s.per_landmark else d2.min(axis=-1)
    pair_d2 = np.where(got, _pick(d2, k), nearest)
    y, H, R, S = _pick(v, k), pred.at("H", None, k), pred.at("R", None, k), pred.at("S", None, k)
    ambiguous = np.zeros(B, np.int64)
    if K > 1 and a is not Association.EUCLIDEAN and not s.per_landmark:
        mixed, h_mix, H_mix, R_mix = _mixtures(pair_used, inside, pred, d2, sensor)
        if mixed.any():  # an ambiguous reading: its virtual landmark's y, H, R, S and d²
            y, H, R, S = y.copy(), H.copy(), R.copy(), S.copy()
            b, j = np.nonzero(mixed)
            y[b, j] = sensor.innovation(z[b if len(z) > 1 else 0, j], h_mix)
            H[b, j], R[b, j] = H_mix, R_mix
            S[b, j] = H_mix @ P[b] @ _T(H_mix) + R_mix
            pair_d2 = pair_d2.copy()
            yb = y[b, j]
            pair_d2[b, j] = (yb[:, None, :] @ inverse_pd(S[b, j]) @ yb[:, :, None])[:, 0, 0]
            ambiguous = mixed.sum(axis=-1)

    # the update's pairs in order (B, U, ...)
    if s.per_landmark:
        bb = np.arange(B)[:, None]
        y_u, d2_u = v[bb, pair_reading, pair_k], d2[bb, pair_reading, pair_k]
        H_u, R_u, S_u = (pred.at(name, pair_reading, pair_k) for name in ("H", "R", "S"))
    else:
        y_u, H_u, R_u, S_u, d2_u = y, H, R, S, pair_d2
    weights = _weights(d2_u, S_u, d, s.nu, s.inflation, s.clutter) if s.reweighted else None
    gain, stats, loglik, dof = _stacked(P, pair_used, y_u, H_u, R_u, weights, s.nu[:, 0], s.given)
    # a reading's innovation given the used ones before it (a gated one: given all of them)
    y_given = S_given = None
    if s.given:
        y_given, S_given = np.full((B, m, d), np.nan), np.full((B, m, d, d), np.nan)
        if s.per_landmark:
            b, u = np.nonzero(pair_used)
            y_given[b, pair_reading[b, u]] = stats.y_given[b, u]
            S_given[b, pair_reading[b, u]] = stats.S_given[b, u]
        else:
            y_given[pair_used] = stats.y_given[pair_used]
            S_given[pair_used] = stats.S_given[pair_used]
        gated = (status == _GATED) & got
        if gated.any():
            b, j = np.nonzero(gated)
            y_given[b, j] = y[b, j] - (H[b, j] @ stats.delta[b][..., None])[..., 0]
            S_given[b, j] = H[b, j] @ stats.P[b] @ _T(H[b, j]) + R[b, j]
    used_any = dof > 0
    return _Result(
        np.where(used_any[:, None], chart.plus(x, gain.delta), x),
        np.where(used_any[:, None, None], gain.P, P), landmark, pair_d2, status,
        np.where(got[..., None], y, np.nan), np.where(got[..., None, None], S, np.nan),
        y_given, S_given, loglik, np.where(used_any, stats.nis, 0.0), dof, ambiguous,
    )  # fmt: skip


def _pick(a: np.ndarray, k: IntArray) -> np.ndarray:
    """``a[b, i, k[b, i]]`` of ``a`` (B, m, K, ...)."""
    if a.shape[2] == 1:
        return a[:, :, 0]
    return np.take_along_axis(a, k.reshape(*k.shape, *(1,) * (a.ndim - 2)), axis=2)[:, :, 0]


def _euclid(v: FloatArray, pair: np.ndarray) -> FloatArray:
    """The Euclidean cost |v|² of the pairs (Eq. 22; inf where no pair)."""
    return np.where(pair, (v * v).sum(axis=-1), np.inf)


def _one_to_one(
    cost: FloatArray, inside: np.ndarray, rows: IntArray, L: int, split: bool
) -> IntArray:
    """Greedy one-to-one pairing, cheapest pair first (the compiled search; with ``split`` the
    pairs inside the gate first): each reading's candidate (B, m), -1 for none. Readings of one
    candidate each, no two of them the same landmark, need no search: each takes its own."""
    m, K = cost.shape[1:]
    finite = np.isfinite(cost)
    if K == 1:
        own = rows[..., 0][..., :m] if rows.shape[1] == m else None
        if own is not None and not _shared(np.where(finite[..., 0], own, -1 - np.arange(m))):
            return np.where(finite[..., 0], 0, -1)
    choice = _core.pair_one_to_one(_dense(cost, rows, L), _dense(inside, rows, L), split)
    return _column(choice, rows)


def _shared(ids: IntArray) -> bool:
    """Whether two readings of a filter (B', m) name the same landmark."""
    s = np.sort(ids, axis=-1)
    return bool((s[..., 1:] == s[..., :-1]).any())


def _dense(a: np.ndarray, rows: IntArray, L: int) -> np.ndarray:
    """Pair values ``a`` (B, m, K) over candidates ``rows`` as a dense (B, m, L) array of the
    map's landmarks (inf / False where a landmark is no candidate)."""
    if rows.shape[1] == 1:  # every landmark a candidate, in order
        return np.ascontiguousarray(np.broadcast_to(a, (*a.shape[:2], L)))
    out = np.full((*a.shape[:2], L), np.inf if a.dtype.kind == "f" else False, a.dtype)
    b, i, k = np.nonzero(rows >= 0)
    out[b, i, rows[b, i, k]] = a[b, i, k]
    return out


def _column(choice: IntArray, rows: IntArray) -> IntArray:
    """The candidate index (B, m) of each reading's chosen landmark row (-1: none)."""
    if rows.shape[1] == 1:  # every landmark a candidate, in order: the row is the index
        return choice
    hit = (rows == choice[..., None]) & (choice[..., None] >= 0)
    return np.where(hit.any(axis=-1), hit.argmax(axis=-1), -1)


def _weights(
    d2: FloatArray, S: FloatArray, d: int, nu: FloatArray, inflation: FloatArray,
    clutter: FloatArray,
) -> FloatArray:  # fmt: skip
    """The weight (B, U) of each pair's noise in the update (module docstring): the Student-t
    weight ``(ν + d)/(ν + d²)``, the inflation's ``1/c²`` and the landmark probability
    ``g/(g + λ)``."""
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        w = np.where(np.isfinite(nu), (nu + d) / (nu + d2), 1.0) / inflation**2
        if (clutter > 0).any():
            g = log_density(d2, np.linalg.slogdet(S)[1], d, nu)
            w = w * np.where(clutter > 0, 1.0 / (1.0 + np.exp(np.log(clutter) - g)), 1.0)
    return w


def _stacked(
    P: FloatArray, used: np.ndarray, y: FloatArray, H: FloatArray, R: FloatArray,
    weights: FloatArray | None, nu: FloatArray, given: bool,
) -> tuple[Update, Update, FloatArray, IntArray]:  # fmt: skip
    """The stacked update of the used pairs (B, U) — their noises divided by ``weights`` when
    given — and the statistics of their stacked innovation with R itself: ``(the update, the
    statistics, the log-likelihood (Gaussian, or the multivariate Student-t of scale S for a
    finite ``nu``), its dimension)``."""
    stats = update(P, y, H, R, used, given=given)
    gain = stats
    if weights is not None:  # the update's noise: R / w (a weight of 0: no information)
        with np.errstate(divide="ignore", invalid="ignore"):
            gain = update(P, y, H, R / weights[..., None, None], used & (weights > 0))
    dof = y.shape[-1] * used.sum(axis=-1)
    loglik = np.where(dof > 0, log_density(stats.nis, stats.logdet, dof, nu), 0.0)
    return gain, stats, loglik, dof
