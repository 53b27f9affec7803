"""Noise of a pose filter estimated from its own innovations, with no ground truth.

The paper's §8 ("revise the error models … a form of autocalibration"). A run's raw streams (a
:class:`Recording`: odometry velocities and readings with their time stamps) are filtered with
:func:`relmap.filter.run` under candidate noise parameters — of any motion and measurement
models (:mod:`relmap.models`): their ``noise_parameters`` are what is fitted, from the values
the models are given (give cautious, large ones) — and the parameters are chosen by what the
innovations ``y`` (reading minus prediction) and their covariances ``S`` say. Ground truth is
never read. Three stages, each a standard tool of filter tuning:

1. **Maximum likelihood** of the innovation sequence (Mehra 1970). The readings are Student-t
   with dof ``nu`` and standard deviations ``sigma_r``, ``sigma_b`` (the t of that variance, so
   a few wild readings do not inflate the σ of all), and the filter is the linear one (``nu``
   inf in :func:`relmap.filter.run`): the Kalman filter is the best linear estimator for any
   noise
   of given second moments, and its ``P`` is then the covariance of its error, heavy tails or
   not. (relmap.filter.ekf's robust reweighting would instead give a reading near its prediction the
   t's *scale*, ``(ν - 2)/ν`` of its variance: on MRCLAM, where ν comes out near 3, a reading
   covariance about three times too small.) The innovations' likelihood is the t with
   covariance ``S``, each reading's innovation taken given the readings before it at its time
   (the prediction-error decomposition: the readings of one time share the pose's error).
   Every paired reading counts, the gated ones too (:func:`loglik`): a filter
   that lost its way and gates most of its readings must not look likely for having few terms.
   Fitted: the motion model's noise parameters (odometry: ``k_s, k_theta, k_theta_s`` of
   :class:`relmap.models.DistanceNoise`), the sensor's (``sigma_range, sigma_bearing``) and
   ``nu``, and, when the association is not by
   signatures, the clutter density ``clutter`` λ of readings of nothing in the map (a reading is
   of one of the L landmarks or, with probability π, uniform over the measurement volume the
   run's readings span: :func:`loglik`, :func:`measurement_volume`; the search starts at
   π = :data:`CLUTTER_START`; with signatures the signature names the landmark and λ is 0).
   (Reading biases are not fitted: on MRCLAM their maximum-likelihood values disagreed in sign
   with the ground-truth residuals and lowered coverage.) Found first by batched coordinate
   ascent from the cautious values given (every candidate move of every parameter one filter
   of one batch of :func:`relmap.filter.run`; the step shrinks when no move gains; coarse, to
   :data:`COARSE`, on the run's first :data:`COARSE_SHARE`; without signatures, once the
   clock is set, rounds on the whole run too), then refined on the whole run by Newton steps
   whose gradient and Hessian come from one batch of finite differences.
2. **The clock.** The odometry's time stamps may be offset from the readings' (MRCLAM's
   velocities are commands, executed about 0.2 s later). The offset ``delay`` is the
   maximum-likelihood one over :data:`DELAYS` (the motion stamped ``s`` happened at
   ``s + delay``); for range-only sensors a range scale (reading = scale × range; Plaza's
   radios read about 7% long) likewise over :data:`SCALES`. Then, when the association is by
   signatures, the odometry's turn-rate bias ``turn_bias`` (rad/s, subtracted from every ω
   record: a gyro's bias, which turns the dead-reckoned heading at a constant rate; Plaza's
   drifts by -0.0053 rad/s against its ground truth): the best of :data:`TURN_BIASES`, then
   of two grids each 4 times finer around the best. Each search is one batch of filters over
   as many logs (:func:`relmap.filter.run` of a sequence of logs), on the readings every
   delay keeps. Left to the random ``k_theta``, such a drift makes the filter believe
   every heading less and its position worse (Plaza: 0.418 m RMSE with no bias, 0.321 m at
   the fitted -0.0057 rad/s). Without signatures it is not fitted (:func:`_clock` says why).
3. **Whiteness.** The innovations of a consistent filter are white (Kailath 1968). A reading
   whose error repeats in the next readings of the same landmark (MRCLAM: a correlation of
   0.8-0.95 between consecutive range errors, still 0.2-0.6 twenty seconds apart) is counted
   again and again and makes the filter overconfident, which the likelihood of stage 1 cannot
   see. The correlations ``ρ1``, ``ρ2`` of normalized range innovations of one landmark one and
   two readings apart (at most :data:`PAIR_GAP` s per reading, :func:`innovation_correlation`)
   are measured, and the filter's update counts each reading as the variance factor of the mean
   of such a sequence says (:func:`variance_factor`: ``(1 + ρ)/(1 - ρ)`` for AR(1)): its gain
   and covariance use ``(inflation σ)²`` (:func:`relmap.filter.run`'s ``inflation``,
   the factor's square root), while association, gate and likelihood keep ``σ²``, the spread of
   one reading, which the correlation does not change (inflating ``σ`` itself made the
   Mahalanobis association pair neighbouring landmarks wrongly). The factor is the fixed
   point of that rule: one batch of filters over the factors :data:`INFLATIONS` measures the
   correlation each leaves and the factor it asks for; the grid's factor nearest the one that
   asks for itself is the filter's (:func:`_whitened`). White reading errors give ``ρ ≈ 0``
   and an inflation of 1. (The correlated part modelled instead as Gauss–Markov bias states
   of the filter, their σ and τ fitted to the innovations, was measured on MRCLAM: less
   accurate (mean RMSE 0.232 m against 0.200) and overconfident; ``docs/consistency.md``.)

Every constant of the method is fixed here, once, for all runs (:data:`NU_START`, :data:`DELAYS`,
:data:`SCALES`, :data:`TURN_BIASES`, :data:`PAIR_GAP`, :data:`INFLATIONS`,
:data:`ITERATIONS`, :data:`COARSE`, :data:`REFINE_STEPS`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from relmap.errors import ParameterError, ShapeError
from relmap.filter.landmarks import Association, LandmarkMap, Status
from relmap.filter.logs import Log, Trace, run
from relmap.models.base import Measurement, Motion
from relmap.typing import ArrayLike, FloatArray, IntArray
from relmap.uncertain.at import AT
from relmap.uncertain.gaussian import log_density

__all__ = [
    "CLUTTER_START",
    "COARSE",
    "COARSE_SHARE",
    "DELAYS",
    "INFLATIONS",
    "ITERATIONS",
    "NU_MAX",
    "NU_MIN",
    "NU_START",
    "PAIR_GAP",
    "REFINE_STEPS",
    "SCALES",
    "TURN_BIASES",
    "Calibrated",
    "Recording",
    "calibrate",
    "innovation_correlation",
    "loglik",
    "logpdf",
    "measurement_volume",
    "variance_factor",
]

#: The readings' Student-t dof where the search starts (the models' own parameters start where
#: they are given: cautious, so that the search comes down to the data).
NU_START = 4.0
#: The clutter fraction (readings of nothing in the map) where the search starts, when the
#: association is not by signatures (:func:`loglik`).
CLUTTER_START = 0.1
#: The smallest Student-t dof searched: below it the likelihood of a heavy-tailed reading
#: model with a vanishing scale grows without bound.
NU_MIN = 3.0
#: The largest dof searched: readings this close to Gaussian are Gaussian.
NU_MAX = 1000.0
#: Odometry clock offsets searched (s): the motion stamped ``s`` happened at ``s + delay``.
DELAYS = tuple(round(0.05 * k, 2) for k in range(9))
#: Range scales searched for range-only sensors (reading = scale × range).
SCALES = tuple(round(0.9 + 0.01 * k, 2) for k in range(31))
#: Turn-rate biases of the odometry searched first (rad/s; ±1.15°/s), before the bounded
#: refinement within one step of the best.
TURN_BIASES = tuple(round(0.002 * k, 3) for k in range(-10, 11))
#: Consecutive readings of one landmark at most this far apart (s) form a whiteness pair.
PAIR_GAP = 1.0
#: The update's σ factors of the whiteness stage's batch (×1.07 apart, up to the factor of a
#: correlation of 0.99).
INFLATIONS = tuple(round(float(v), 4) for v in np.geomspace(1.0, 16.0, 41))
#: At most this many rounds of coordinate ascent.
ITERATIONS = 40
#: The coarse fit stops when its log-scale step falls below this (a factor of 1.1).
COARSE = float(np.log(1.1))
#: The coarse fit and the clock read this first share of the run (its readings' times):
#: enough to come down from the cautious start, at a fraction of the cost. Without
#: signatures a quarter's pairings and clutter can mislead the search (MRCLAM JCBB robot 4:
#: 1.81 m), so the coarse fit then takes rounds on the whole run as well, at its first step
#: (×2, ×4, ×8 each way) until none gains (docs/consistency.md).
COARSE_SHARE = 0.25
#: The log-scale step of the coarse fit's first round (×2 per move); it shrinks by 3 when no
#: move gains. Each round moves a parameter by these multiples of the step, both ways.
_STEP = float(np.log(2.0))
_REACH = (1, 2, 3)
#: The refining fit's Newton steps at most; its log-scale difference step (2%: wider than the
#: kinks of the likelihood where a reading crosses the gate); the largest move of a field in
#: one step (log scale: a factor 1.65); the fractions of the Newton step it tries.
REFINE_STEPS = 2
_DIFF = 0.02
_MAX_STEP = 0.5
_LINE = (0.25, 0.5, 1.0, 1.5)

Progress = Callable[[int, int], None]
Params = dict[str, float]
Runner = Callable[[Log, Params], Trace]


class Recording(NamedTuple):
    """A run's raw streams, before a clock offset or a range scale is applied.

    Odometry: ``odometry_t`` (n,) s, velocities ``v`` (m/s) and ``w`` (rad/s), each held until
    the next record; readings at ``reading_t`` (M,) s: ``z`` (M, 2) range-bearing or (M,)
    ranges; ``signature`` (M,) landmark labels or None; ``end`` the last filter time (s).
    """

    odometry_t: FloatArray
    v: FloatArray
    w: FloatArray
    reading_t: FloatArray
    z: FloatArray
    signature: IntArray | None
    end: float

    def log(
        self, delay: float = 0.0, scale: float = 1.0, turn_bias: float = 0.0, *,
        since: float | None = None,
    ) -> Log:  # fmt: skip
        """The filter's :class:`relmap.filter.Log`, odometry stamps moved by ``delay`` (s),
        ranges divided by ``scale`` and ``turn_bias`` (rad/s) subtracted from the turn rates ``w``;
        odometry moved past ``end`` is dropped, and readings before ``since`` (s; default: the
        first odometry time, moved)."""
        if since is not None:
            keep = np.asarray(self.reading_t) >= since
            sig = None if self.signature is None else np.asarray(self.signature)[keep]
            kept = self._replace(reading_t=np.asarray(self.reading_t)[keep],
                                 z=np.asarray(self.z)[keep], signature=sig)  # fmt: skip
            return kept.log(delay, scale, turn_bias)
        z = np.array(self.z, dtype=np.float64)
        if z.ndim == 1:
            z = z / scale
        else:
            z[:, 0] /= scale
        t = np.asarray(self.odometry_t, dtype=np.float64) + delay
        w = np.asarray(self.w, dtype=np.float64) - turn_bias
        return Log.from_velocities(t, self.v, w, self.reading_t, z, self.signature, end=self.end)


class Calibrated(NamedTuple):
    """What :func:`calibrate` found: the filter's noise, and how it was found.

    Run the calibrated filter with ``relmap.filter.run(calibrated.log(recording), ...,
    **calibrated.options)`` and the models ``motion``, ``sensor``.
    """

    #: The motion model with its fitted noise parameters.
    motion: Motion
    #: The sensor with its fitted σ: the readings' standard deviations.
    sensor: Measurement
    #: The readings' Student-t dof (of the sensor's σ as standard deviations); the filter itself
    #: is the linear one (``nu`` inf in :func:`relmap.filter.run`).
    nu: float
    #: The clutter density λ (0 with signatures).
    clutter: float
    #: Odometry clock offset (s): build the log with ``recording.log(*calibrated.clock)``.
    delay: float
    #: Range scale (1 unless the sensor reads ranges only).
    scale: float
    #: The update's reading σ factor of the whiteness stage (√ of the variance factor).
    inflation: float
    #: Lag-one correlation of consecutive range innovations, before whitening and after.
    correlation: tuple[float, float]
    #: Log-likelihood of the innovations at the stage-1/2 parameters (before whitening).
    loglik: float
    #: The final filter's trace (readings kept: innovations, S, statuses).
    trace: Trace
    #: The clutter's volume per landmark ``V`` (:func:`loglik`): the measurement volume
    #: (:func:`measurement_volume`) over the number of landmarks.
    volume: float = 1.0
    #: The odometry's turn-rate bias (rad/s), subtracted from its turn rates.
    turn_bias: float = 0.0

    @property
    def clock(self) -> tuple[float, float, float]:
        """``(delay, scale, turn_bias)``: the arguments of :meth:`Recording.log`."""
        return self.delay, self.scale, self.turn_bias

    @property
    def options(self) -> dict[str, float]:
        """The filter's weights for :func:`relmap.filter.run`: ``inflation``, ``clutter``."""
        return {"inflation": self.inflation, "clutter": self.clutter}

    @property
    def clutter_fraction(self) -> float:
        """The fitted fraction of readings of nothing in the map, ``λV/(1 + λV)``."""
        lv = self.clutter * self.volume
        return lv / (1.0 + lv)

    def as_dict(self) -> dict[str, object]:
        """JSON-ready: the models' parameters by name, then how they were found."""
        c0, c1 = self.correlation

        def number(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None

        models = {k: number(getattr(m, k)) for m in (self.motion, self.sensor)
                  for k in m.noise_parameters}  # fmt: skip
        return {
            **models,
            "nu": number(self.nu),
            "clutter": self.clutter,
            "delay": self.delay,
            "range_scale": self.scale,
            "turn_bias": self.turn_bias,
            "inflation": self.inflation,
            "correlation_before": number(c0),
            "correlation_after": number(c1),
            "loglik": self.loglik,
            "clutter_fraction": self.clutter_fraction,
            "volume": self.volume,
        }


def innovation_correlation(
    trace: Trace, t: ArrayLike, *, lag: int = 1, gap: float = PAIR_GAP
) -> tuple[float, int]:
    """Correlation of the normalized innovations ``y_r/√S_rr`` (the reading's first component,
    a range for polar sensors) of used readings of one
    landmark ``lag`` readings apart and at most ``lag × gap`` s apart (one filter's trace; ``t``
    (M,) the readings' times). Normalized innovations are clipped to ±3 robust σ
    (1.4826·MAD), so a few wild readings do not decide it. Returns the correlation and the
    number of pairs (NaN with fewer than 10 pairs)."""
    y, S = np.asarray(trace.y), np.asarray(trace.S)
    yr, sr = (y, S) if y.ndim == 1 else (y[:, 0], S[:, 0, 0])
    idx = np.flatnonzero(np.asarray(trace.status) == Status.USED)
    if len(idx) <= lag:
        return float("nan"), 0
    tt, lm = np.asarray(t, dtype=np.float64)[idx], np.asarray(trace.landmark)[idx]
    u = yr[idx] / np.sqrt(sr[idx])
    order = np.lexsort((tt, lm))  # by landmark, then time
    u, tt, lm = u[order], tt[order], lm[order]
    same = (lm[lag:] == lm[:-lag]) & (tt[lag:] - tt[:-lag] <= lag * gap)
    n = int(same.sum())
    if n < 10:
        return float("nan"), n
    s = 1.4826 * np.median(np.abs(u - np.median(u)))
    c = np.clip(u / s, -3.0, 3.0)
    a, b = c[:-lag][same], c[lag:][same]
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).mean() / np.sqrt((a * a).mean() * (b * b).mean())), n


def variance_factor(rho1: float, rho2: float, pairs: int) -> float:
    """The variance factor ``1 + 2 Σ_k ρ_k`` of the mean of a correlated sequence whose
    autocorrelation is ``ρ1`` at lag one and decays geometrically from there by ``φ = ρ2/ρ1``
    (an ARMA(1,1) autocorrelation; φ kept in [ρ1, 0.99]): ``1 + 2ρ1/(1 - φ)``. For an AR(1)
    sequence (``ρ2 = ρ1²``) it is ``(1 + ρ1)/(1 - ρ1)``. 1 (white) unless ``ρ1`` is
    significant: above 3/√pairs, three standard errors of a correlation of ``pairs`` pairs."""
    if not np.isfinite(rho1) or rho1 <= 3.0 / np.sqrt(max(pairs, 1)):
        return 1.0
    r1 = min(rho1, 0.99)
    phi = min(max(rho2 / r1, r1), 0.99) if np.isfinite(rho2) else r1
    return 1.0 + 2.0 * r1 / (1.0 - phi)


def logpdf(d2: ArrayLike, logdet: ArrayLike, d: int, nu: ArrayLike) -> FloatArray:
    """Log-density of a ``d``-dimensional reading model at an innovation with Mahalanobis
    ``d2 = yᵀS⁻¹y`` and ``logdet = log det S``: Student-t with dof ``nu`` > 2 and *covariance*
    ``S`` (scale ``S (ν - 2)/ν``), or the normal for ``nu`` inf (all broadcast together):
    :func:`relmap.uncertain.gaussian.log_density` of the scale's distance and determinant."""
    d2, logdet, v = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (d2, logdet, nu))
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(np.isinf(v), 1.0, (v - 2.0) / v)  # scale / covariance
        return log_density(d2 / ratio, logdet + d * np.log(ratio), d, v)


def measurement_volume(z: ArrayLike) -> float:
    """The sensor's measurement volume ``V`` as a run's own readings span it: range span ×
    bearing span for range-bearing readings ``(M, 2)`` (m rad), range span for ranges ``(M,)``
    (m); non-finite readings left out, 1 when they span nothing. The clutter of :func:`loglik`
    is uniform over it."""
    zz = np.asarray(z, dtype=np.float64)
    zz = zz[:, None] if zz.ndim == 1 else zz
    zz = zz[np.isfinite(zz).all(axis=1)]
    if len(zz) < 2:
        return 1.0
    v = float(np.prod(zz.max(axis=0) - zz.min(axis=0)))
    return v if v > 0 else 1.0


def loglik(
    trace: Trace, nu: ArrayLike, clutter: ArrayLike = 0.0, volume: float = 1.0
) -> FloatArray:
    """Log-likelihood (*batch) of every paired reading's innovation, used or gated: Student-t
    with dof ``nu`` (*batch; inf: Gaussian) and covariance ``S``, each reading's innovation
    given the readings before it at its time (``trace.y_given``, ``S_given``: the
    prediction-error decomposition, Schweppe 1965; the trace must keep its readings). The
    readings of one time share the pose's error: summing their densities at the prior instead
    (``trace.y``, ``S``) counts that error once per reading, a composite likelihood whose
    maximum strays further than its curvature says (docs/consistency.md: a simulated robot
    reading five landmarks a scan, σ_b up to 8.5% too large where this one is within 0.5%).
    With a clutter density ``clutter`` λ > 0 (*batch; :func:`relmap.filter.run`'s) a reading
    is of one of the map's L landmarks, each equally likely a
    priori (its paired landmark's density g), or, with probability π, of clutter uniform over
    the sensor's measurement volume (:func:`measurement_volume`): the density
    ``(1 - π) g / L + π / V_m`` is, up to the constant ``-log L``, ``log(g + λ) - log(1 + λV)``
    per paired reading with ``volume`` ``V = V_m / L`` (the volume per landmark) and
    ``λ = π / ((1 - π) V)`` (clutter fraction ``λV/(1 + λV)``); a reading whose landmark went
    to a closer one (one to one: LOST) is clutter, ``log λ - log(1 + λV)``. λ = 0: the
    likelihood without clutter, bit for bit."""
    y, S = np.asarray(trace.y_given), np.asarray(trace.S_given)
    if y.ndim == S.ndim:  # range-only: (..., M) and (..., M)
        y, S = y[..., None], S[..., None, None]
    d = y.shape[-1]
    status = np.asarray(trace.status)
    paired = (status == Status.USED) | (status == Status.GATED)
    y = np.where(paired[..., None], y, 0.0)
    S = np.where(paired[..., None, None], S, np.eye(d))
    sign, logdet = np.linalg.slogdet(S)
    d2 = np.einsum("...i,...i->...", y, np.linalg.solve(S, y[..., None])[..., 0])
    each = logpdf(d2, logdet, d, np.asarray(nu, dtype=np.float64)[..., None])
    ok = paired & (sign > 0) & np.isfinite(each)
    total = np.where(ok, each, 0.0).sum(axis=-1) - 1e3 * (paired & ~ok).sum(axis=-1)
    lam = np.broadcast_to(np.asarray(clutter, dtype=np.float64), total.shape)
    if not (lam > 0).any():
        return total
    with np.errstate(divide="ignore"):
        loglam = np.log(lam)[..., None]
    norm = np.log1p(lam * volume)[..., None]
    with np.errstate(invalid="ignore"):
        mixed = np.logaddexp(each, loglam) - norm
    ok = paired & (sign > 0) & np.isfinite(mixed)
    lost = (status == Status.LOST).sum(axis=-1)
    withc = (np.where(ok, mixed, 0.0).sum(axis=-1) - 1e3 * (paired & ~ok).sum(axis=-1)
             + lost * (loglam - norm)[..., 0])  # fmt: skip
    return np.where(lam > 0, withc, total)


def _moves(p: Params, free: tuple[str, ...], step: float) -> list[tuple[str, float]]:
    """Each free parameter's values ``p[name] · exp(±j·step)``, j in :data:`_REACH`."""
    return [(name, p[name] * float(np.exp(sign * j * step)))
            for name in free for j in _REACH for sign in (-1.0, 1.0)]  # fmt: skip


def _fit(
    log: Log, p: Params, free: tuple[str, ...], run: Runner, step: float, tolerance: float
) -> tuple[Params, float]:
    """Batched coordinate ascent of the innovations' log-likelihood from ``p``. Each round is
    one batch of filters: every free parameter moved alone by log-scale multiples of ``step``
    (:func:`_moves`), and every parameter at once to its best gaining move of the round
    before. The best becomes the centre; the step shrinks by 3 when nothing gains, until it
    is below ``tolerance``."""
    best, combined = -np.inf, None
    for _ in range(ITERATIONS):
        if step < tolerance:
            break
        moves = _moves(p, free, step)
        batch = [{**p, name: v} for name, v in moves]
        batch += [p] if best == -np.inf else []  # (the start's own value, once)
        batch += [combined] if combined is not None else []
        ll = _logliks(log, batch, run)
        here = float(ll[len(moves)]) if best == -np.inf else best
        top: dict[str, tuple[float, float]] = {}  # each parameter's best gaining move
        for (name, v), value in zip(moves, ll, strict=False):
            if value > max(here, top.get(name, (0.0, -np.inf))[1]):
                top[name] = (v, float(value))
        combined = {**p, **{k: v for k, (v, _) in top.items()}} if len(top) > 1 else None
        i = int(ll.argmax())
        if ll[i] <= here + 1e-6:
            best = here
            step /= 3
            continue
        p, best = batch[i], float(ll[i])
    return p, best


def _logliks(log: Log | list[Log], batch: list[Params], run: Runner) -> FloatArray:
    """The log-likelihood of each parameter set of ``batch`` (one batch of filters); -inf where
    it is not finite or ``nu`` is outside [:data:`NU_MIN`, :data:`NU_MAX`]."""
    cols = {k: np.array([q[k] for q in batch]) for k in batch[0]}
    ll = np.asarray(run(log, cols).loglik, dtype=np.float64)
    nu = cols["nu"]
    return np.where(np.isfinite(ll) & (nu >= NU_MIN) & (nu <= NU_MAX), ll, -np.inf)


def _refine(log: Log, p: Params, free: tuple[str, ...], run: Runner) -> tuple[Params, float]:
    """Newton ascent of the log-likelihood over the free parameters' logarithms from ``p``
    (coordinate ascent stalls on the ridges where two noises trade, such as driving noise
    against range σ), at most :data:`REFINE_STEPS` steps. Each step: the gradient and the
    Hessian by finite differences of :data:`_DIFF` (central for the gradient and the diagonal,
    crossed for the rest) from one batch of ``2n + n(n-1)/2`` filters (the first step's with
    the start itself); the Hessian's eigenvalues made negative (``-|λ|``, at most
    ``-1e-6·max|λ|``: a saddle is climbed out of, not into); a parameter at its bound that the
    gradient pushes out held there; the Newton step, each component within ±:data:`_MAX_STEP`,
    tried at the lengths :data:`_LINE` in a second batch, beside the stencil's best point. It
    stops when nothing gains. ``nu`` stays in [:data:`NU_MIN`, :data:`NU_MAX`], the others
    within a factor 100 of ``p``."""
    x = np.log([p[k] for k in free])
    n, h = len(free), _DIFF
    # each field within ×/÷ 100 of where the coarse fit left it; nu in [NU_MIN, NU_MAX]
    nu = np.array([k == "nu" for k in free])
    lo = np.where(nu, np.log(NU_MIN), x - np.log(100))
    hi = np.where(nu, np.log(NU_MAX), x + np.log(100))
    lo, hi = lo + h, hi - h  # (x within them: its stencil within the bounds)
    x = np.clip(x, lo, hi)
    pairs = [(i, j) for i in range(n) for j in range(i)]
    eye = np.eye(n)

    def loglik_at(points: FloatArray) -> FloatArray:
        cols = {k: np.full(len(points), v) for k, v in p.items()}
        for j, name in enumerate(free):
            cols[name] = np.exp(points[:, j])
        ll = np.asarray(run(log, cols).loglik, dtype=np.float64)
        return np.where(np.isfinite(ll), ll, -np.inf)

    best = -np.inf
    for _ in range(REFINE_STEPS):
        stencil = np.concatenate([x - h * eye, x + h * eye,
                                  [x + h * (eye[i] + eye[j]) for i, j in pairs]])  # fmt: skip
        if best == -np.inf:  # (the start's own value, with the first stencil)
            f = loglik_at(np.vstack([stencil, x]))
            f, best = f[:-1], float(f[-1])
        else:
            f = loglik_at(stencil)
        if not np.isfinite(f).all():
            break
        minus, plus, cross = f[:n], f[n : 2 * n], f[2 * n :]
        g = (plus - minus) / (2 * h)
        H = np.diag((plus - 2 * best + minus) / h**2)
        for (i, j), fij in zip(pairs, cross, strict=True):
            H[i, j] = H[j, i] = (fij - plus[i] - plus[j] + best) / h**2
        # a parameter at its bound that the gradient pushes out stays there (the active set)
        held = ((x <= lo) & (g < 0)) | ((x >= hi) & (g > 0))
        lam, V = np.linalg.eigh(H[np.ix_(~held, ~held)])
        lam = np.minimum(-np.abs(lam), -1e-6 * max(np.abs(lam).max(initial=0.0), 1e-12))
        step = np.zeros(n)
        step[~held] = np.clip(-V @ ((V.T @ g[~held]) / lam), -_MAX_STEP, _MAX_STEP)
        # the step's lengths, and the stencil's best point (the surface has steps where a
        # reading crosses its gate: a point of the stencil may beat the quadratic's)
        trial = np.clip(x + np.multiply.outer(_LINE, step), lo, hi)
        ll = loglik_at(trial)
        j = int(np.argmax(np.where(((stencil >= lo) & (stencil <= hi)).all(axis=1), f, -np.inf)))
        trial, ll = np.vstack([trial, stencil[j]]), np.append(ll, f[j])
        k = int(np.argmax(ll))
        if ll[k] <= best + 1e-6:
            break
        x, best = trial[k], float(ll[k])
    return {**p, **{k: float(np.exp(v)) for k, v in zip(free, x, strict=True)}}, best


def _clock(
    recording: Recording, p: Params, run: Runner, ranges_only: bool, signatures: bool
) -> tuple[float, float, float]:
    """The maximum-likelihood odometry delay over :data:`DELAYS` (and, for a sensor of ranges
    only, range scale over :data:`SCALES`), then, with association by signatures, the turn-rate
    bias (:data:`TURN_BIASES`, then twice over a grid 4 times finer around the best), at the
    parameters ``p``: ``(delay, scale, turn_bias)``. Each search is one batch of filters, one
    log per candidate clock, on the readings every delay keeps. Without signatures the bias
    stays 0: a bias turns the robot onto other pairings, and the likelihood then rewards the
    pairings (other robots taken for landmarks) rather than the motion (MRCLAM, Mahalanobis:
    fitted biases of up to 0.004 rad/s where the runs with signatures find none, robot 4's
    RMSE 0.30 → 1.07 m; with each reading's landmark held where the unbiased filter paired it,
    up to 0.012 rad/s and worse still)."""
    since = float(recording.odometry_t[0]) + max(DELAYS)

    def best(clocks: list[tuple[float, float, float]]) -> tuple[float, float, float]:
        ll = _logliks([recording.log(*c, since=since) for c in clocks], [p], run)
        return clocks[int(np.argmax(ll))]

    clock = best([(d, 1.0, 0.0) for d in DELAYS])
    if ranges_only:
        clock = best([(clock[0], s, 0.0) for s in SCALES])
    if not signatures:
        return clock
    delay, scale, _ = clock
    clock = best([(delay, scale, b) for b in TURN_BIASES])
    spacing = TURN_BIASES[1] - TURN_BIASES[0]
    for _ in range(2):
        spacing /= 4
        clock = best([(delay, scale, clock[2] + j * spacing) for j in range(-4, 5)])
    return clock


def _whitened(log: Log, p: Params, run: Runner) -> tuple[float, float, Trace]:
    """The update's σ factor of the whiteness stage, the lag-one correlation without it, and
    the filter's trace with it: a batch of filters over the factors :data:`INFLATIONS`, each
    measuring the correlation :func:`innovation_correlation` of its innovations and the factor
    that correlation asks for (:func:`variance_factor`'s square root); the factor is the one of
    the grid nearest the fixed point where the two agree (linearly between the grid's
    factors; 1 when the filter without one is white: that filter runs alone first, and the
    batch only when it is not)."""
    f = np.array(INFLATIONS)  # (f[0] = 1: no factor)
    t = log.t[log.reading_index]

    def filters(factors: FloatArray) -> Trace:
        return run(log, {**{k: np.full(len(factors), v) for k, v in p.items()},
                         "inflation": factors})  # fmt: skip

    def asks(trace: Trace, j: int) -> tuple[float, float]:
        """The factor filter ``j``'s correlation asks for, and its lag-one correlation."""
        (r1, n1), (r2, _) = (innovation_correlation(_one(trace, j), t, lag=k) for k in (1, 2))
        return float(np.sqrt(variance_factor(r1, r2, n1))), r1

    first = filters(f[:1])
    asked0, rho0 = asks(first, 0)
    if asked0 <= f[0]:
        return float(f[0]), rho0, _one(first, 0)
    trace = filters(f)
    asked = np.array([asks(trace, j)[0] for j in range(len(f))])
    excess = asked - f  # > 0: the filter at this factor asks for more
    down = np.flatnonzero(excess <= 0)
    if not len(down):
        fixed = f[-1]
    elif down[0] == 0:
        fixed = 1.0
    else:  # between the last factor that asks for more and the first that does not
        j = int(down[0])
        fixed = f[j - 1] + excess[j - 1] / (excess[j - 1] - excess[j]) * (f[j] - f[j - 1])
    j = int(np.argmin(np.abs(np.log(f / fixed))))
    return float(f[j]), rho0, _one(trace, j)


def _one(trace: Trace, j: int) -> Trace:
    """Filter ``j`` of a batch's trace (a batch of one dimension)."""
    return Trace(*(a[j] if np.ndim(a) and k != "t" else a for k, a in trace._asdict().items()))


def calibrate(
    recording: Recording,
    motion: Motion,
    sensor: Measurement,
    landmarks: ArrayLike | LandmarkMap,
    *,
    start: Callable[[float], AT],
    associate: Association | str = Association.SIGNATURES,
    gate: float = 0.99,
    progress: Progress | None = None,
) -> Calibrated:
    """The noise of ``recording``'s filter from its own innovations (module docstring).

    ``motion`` and ``sensor`` are the filter's models; their ``noise_parameters`` are fitted,
    from the values given (cautious, large ones: the search comes down to the data), with the
    readings' Student-t dof (from :data:`NU_START`) and, without signatures, the clutter
    density. ``start(t0)`` gives the filter's start AT at the log's first time ``t0`` (which
    moves with the clock offset). ``associate`` and ``gate`` as in
    :func:`relmap.filter.run`: the calibration filters with the association it is for.
    """
    assoc = Association.parse(associate, "associate")
    lmap = landmarks if isinstance(landmarks, LandmarkMap) else LandmarkMap(landmarks)
    if not len(lmap):  # (the clutter's volume is per landmark)
        raise ShapeError(f"landmarks must have shape (L, p) with L ≥ 1; got {lmap.xy.shape}")
    if not len(recording.reading_t):
        raise ParameterError("cannot calibrate from innovations: the run has no readings")
    mnames, snames = motion.noise_parameters, sensor.noise_parameters
    if set(mnames) & set(snames) or {"nu", "clutter"} & {*mnames, *snames}:
        raise ParameterError("the motion's and the sensor's parameters need distinct names")

    def models(p: Params | dict[str, FloatArray]) -> tuple[Motion, Measurement]:
        return (motion.replace(**{k: p[k] for k in mnames}),
                sensor.replace(**{k: p[k] for k in snames}))  # fmt: skip

    def run_filters(log: Log | list[Log], p: Params | dict[str, FloatArray]) -> Trace:
        m, s = models(p)
        logs = [log] if isinstance(log, Log) else log
        starts = [start(float(one.t[0])) for one in logs]
        first = (
            starts[0]
            if len(starts) == 1
            else AT(np.stack([a.mean for a in starts]), np.stack([a.cov for a in starts]))
        )
        trace = run(log, m, s, lmap, start=first, associate=assoc, gate=gate, keep="summary",
                    inflation=p.get("inflation", 1.0), clutter=p["clutter"])  # fmt: skip
        return trace._replace(loglik=loglik(trace, p["nu"], p["clutter"], volume))

    signatures = assoc is Association.SIGNATURES
    free = (*mnames, *snames, "nu") + (() if signatures else ("clutter",))
    # a reading is of one of the L landmarks, equally likely a priori: the clutter's volume
    # per landmark (loglik)
    volume = measurement_volume(recording.z) / len(lmap)
    p0: Params = {**{k: float(getattr(motion, k)) for k in mnames},
                  **{k: float(getattr(sensor, k)) for k in snames},
                  "nu": NU_START, "clutter": 0.0}  # fmt: skip
    if not signatures:  # λ of the clutter fraction CLUTTER_START: π = λV / (1 + λV)
        p0["clutter"] = CLUTTER_START / ((1.0 - CLUTTER_START) * volume)
    tick = progress or (lambda k, n: None)
    tick(0, 3)
    t0 = float(recording.odometry_t[0])
    early = recording._replace(end=t0 + COARSE_SHARE * (recording.end - t0))
    if not np.any(np.asarray(early.reading_t) <= early.end):
        early = recording
    p, _ = _fit(early.log(), p0, free, run_filters, _STEP, COARSE)
    tick(1, 3)
    ranges_only = bool(sensor.ranges) and not sensor.angles
    delay, scale, turn_bias = _clock(early, p, run_filters, ranges_only, signatures)
    log = recording.log(delay, scale, turn_bias)
    if not signatures:  # rounds of the coarse fit on the whole run, at its first step only
        p, _ = _fit(log, p, free, run_filters, _STEP, _STEP)
    p, fitted = _refine(log, p, free, run_filters)
    tick(2, 3)
    factor, rho0, trace = _whitened(log, p, run_filters)
    tick(3, 3)
    rho = innovation_correlation(trace, log.t[log.reading_index])[0]
    m, s = models(p)
    return Calibrated(m, s, float(p["nu"]), float(p["clutter"]), delay, scale, factor,
                      (rho0, rho), fitted, trace, volume, turn_bias)  # fmt: skip
