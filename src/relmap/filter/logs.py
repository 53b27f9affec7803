"""Filters over whole logs: one filter, or a batch of them with their own noise.

:func:`run` replays a time-ordered :class:`Log` — the motion model's inputs between the filter's
times, the readings at some of them — through the filter of :mod:`relmap.filter.ekf`: predict,
and at every time with readings correct with all of them in one stacked update
(:func:`relmap.filter.landmarks.correct_landmarks`: association, gating, weights). The batch is
the broadcast of the models' parameters, of ``nu``, ``inflation`` and ``clutter``, of the
start and of the logs (several logs read at the same times with their own motion inputs and
reading values, say under several clock offsets, or Monte Carlo runs): a batch of candidate
noise parameters is one call. It returns a :class:`Trace`: states at the kept times, every
reading's innovation, S, status and landmark, and per filter the log-likelihood of the
innovations, the NIS and the counts.

A :class:`relmap.models.RelativeMotion` (odometry) needs no Python per step: the steps between two
reading times are compounded first (:mod:`relmap.filter.segments`), and the filter predicts once
per reading time; any other motion model is stepped.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from relmap.errors import NonFiniteError, NumericalError, ParameterError, ShapeError
from relmap.filter.ekf import predict
from relmap.filter.landmarks import (
    Association,
    LandmarkMap,
    Pairing,
    Status,
    _candidates,
    _correct,
    _landmark_map,
    _setup,
)
from relmap.filter.segments import chains
from relmap.models.base import Measurement, Motion, RelativeMotion
from relmap.typing import ArrayLike, FloatArray, IntArray, Option
from relmap.uncertain.algebra import compound
from relmap.uncertain.at import AT, compound_arrays
from relmap.uncertain.propagate import SE2

__all__ = ["Keep", "Log", "Trace", "run"]


class Keep(Option):
    """Which states :func:`run` returns."""

    ALL = "all"  #: at every filter time (after the correction at that time)
    EVENTS = "events"  #: at the start and after each correction
    SUMMARY = "summary"  #: the final state only (large calibration batches)


class Log(NamedTuple):
    """A time-ordered log for :func:`run`.

    ``t`` (T,) the filter's times, strictly increasing; ``motion`` (T-1, k) the motion model's
    input from ``t[j]`` to ``t[j+1]`` (odometry: the step ``(Δs, Δθ)``); ``reading_index`` (M,)
    the time index of each reading (non-decreasing; readings of one index form one stacked
    update); ``z`` (M, d) the readings ((M,) for d = 1); ``signature`` (M,) integers (e.g.
    barcodes) or None.
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
        ``[odometry_t[0], end]`` (readings outside are dropped); the steps ``(v dt, ω dt)``."""
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
        log = cls(t, motion, index, zz[keep], sig)
        for a in log:
            if a is not None:
                a.flags.writeable = False  # (a log is a value; its steps' chains are memoized)
        return log


class Trace(NamedTuple):
    """What :func:`run` returns; ``batch`` is the filters' batch shape.

    States at times ``t`` (see :class:`Keep`): ``mean`` (*batch, T, n), ``cov``
    (*batch, T, n, n). Per reading (*batch, M, …): innovation ``y`` (M, d) and its ``S``
    (M, d, d) for the reading's pair (NaN: none), ``mahalanobis2``, ``status`` (a
    :class:`Status`), ``landmark`` (row, -1: none), and ``y_given`` (M, d), ``S_given``
    (M, d, d): the innovation and its covariance given the used readings before it in its
    time's stacked update (a gated one: given all of them; R itself): the prediction-error
    decomposition, whose densities multiply to the stacked likelihood. Per filter (*batch):
    ``loglik`` the sum of the log-likelihoods of the stacked innovations (Gaussian, or Student-t
    of scale S), ``nis`` the sum of their ``yᵀS⁻¹y`` over ``dof`` components (NIS/dof ≈ 1 when
    consistent), ``updates`` the times corrected, ``counts`` (*batch, 7) readings per status,
    ``ambiguous`` used readings that entered as a mixture of landmarks. For d = 1 the reading
    axes of ``y`` and ``S`` are dropped.
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


def _checked(log: Log, sensor: Measurement) -> tuple[FloatArray, FloatArray, IntArray, FloatArray]:
    t = np.asarray(log.t, dtype=np.float64)
    if t.ndim != 1 or not len(t):
        raise ParameterError("the log is empty: it needs at least its start time")
    if not np.isfinite(t).all() or (np.diff(t) <= 0).any():
        raise ParameterError("the log's times must be finite and strictly increasing")
    u = np.asarray(log.motion, dtype=np.float64)
    if u.ndim != 2 or len(u) != len(t) - 1:
        raise ShapeError(f"motion must have shape ({len(t) - 1}, k); got {u.shape}")
    if not np.isfinite(u).all():
        raise NonFiniteError("the motion inputs must be finite")
    d = sensor.dim
    z = np.asarray(log.z, dtype=np.float64)
    z = z[:, None] if d == 1 and z.ndim == 1 else z
    M = len(z)
    if z.shape != (M, d):
        raise ShapeError(f"readings must have shape (M, {d}) for this sensor; got {z.shape}")
    index = np.asarray(log.reading_index, dtype=np.int64)
    if index.shape != (M,):
        raise ShapeError(f"reading_index must have shape ({M},); got {index.shape}")
    if M and (index[0] < 0 or index[-1] >= len(t) or (np.diff(index) < 0).any()):
        raise ParameterError("reading_index must be non-decreasing time indices of the log")
    return t, u, index, z


def run(
    log: Log | Sequence[Log],
    motion: Motion,
    sensor: Measurement,
    landmarks: LandmarkMap | ArrayLike,
    *,
    start: AT,
    associate: Association | str = Association.SIGNATURES,
    pairing: Pairing | str = Pairing.ONE_TO_ONE,
    gate: float = 0.99,
    nu: ArrayLike = np.inf,
    inflation: ArrayLike = 1.0,
    clutter: ArrayLike = 0.0,
    keep: Keep | str = Keep.ALL,
    readings: bool = True,
) -> Trace:
    """Run filters over ``log`` with the map ``landmarks`` (L, p) or a :class:`LandmarkMap`,
    from ``start`` (an AT, broadcast to the batch); association, gate and weights as in
    :func:`relmap.filter.landmarks.correct_landmarks` (the log's signatures restrict the
    candidates when ``associate`` is ``"signatures"``; otherwise they only label the readings).
    ``readings=False`` skips the per-reading arrays (then empty). The filters of a batch are
    independent: each gives what it gives alone.

    ``log`` may be a sequence of logs with the same reading times and signatures and their own
    motion inputs and reading values (say, under several clock offsets or range scales): they
    form a batch axis of their own (the last one, broadcast with the others'), each filter on
    its log; then ``keep`` is ``"summary"`` and ``Trace.t`` holds each filter's last time,
    shaped (*batch, 1), or, for logs with the same times (e.g. Monte Carlo runs, unseen
    landmarks' readings NaN), ``"events"``."""
    kp = Keep.parse(keep, "keep")
    a = Association.parse(associate, "associate")
    logs = [log] if isinstance(log, Log) else list(log)
    if not logs:
        raise ParameterError("run needs a log")
    checked = [_checked(one, sensor) for one in logs]
    t, _, index, z = checked[0]
    if len(logs) > 1:
        shared_t = all(np.array_equal(c[0], t) for c in checked)
        if not (kp is Keep.SUMMARY or (kp is Keep.EVENTS and shared_t)):
            raise ParameterError(
                "a batch of logs keeps the final states (keep='summary'), or, when the logs "
                "share their times, the states after each reading time (keep='events')"
            )
        _same_readings(logs, checked)
    if a is Association.SIGNATURES and logs[0].signature is None:
        raise ParameterError("signature association needs the signatures of the readings")
    lmap = _landmark_map(landmarks)
    shapes = [motion.batch_shape, sensor.batch_shape, start.batch_shape]
    shapes += [np.shape(v) for v in (nu, inflation, clutter)]
    batch = np.broadcast_shapes(*shapes, *([(len(logs),)] if len(logs) > 1 else []))
    B, M, d = int(np.prod(batch, dtype=np.int64)), len(z), sensor.dim
    which = np.zeros(B, np.int64)  # each filter's log
    if len(logs) > 1:
        which = np.broadcast_to(np.arange(len(logs)), batch).reshape(B)
    motion_b = motion.replace(**_flat_params(motion, batch, B))
    x = AT._trusted(
        np.broadcast_to(start.mean, (*batch, 3)).reshape(B, 3),
        np.broadcast_to(start.cov, (*batch, 3, 3)).reshape(B, 3, 3),
    )
    times, first = np.unique(index, return_index=True)  # the time stamps with readings
    bounds = np.append(first, M)
    Mo = M if readings else 0
    out_f = {"y": np.full((B, Mo, d), np.nan), "S": np.full((B, Mo, d, d), np.nan),
             "y_given": np.full((B, Mo, d), np.nan), "S_given": np.full((B, Mo, d, d), np.nan),
             "d2": np.full((B, Mo), np.inf)}  # fmt: skip
    status = np.full((B, M), int(Status.ABSENT), np.int8)
    landmark = np.full((B, Mo), -1, np.int64)
    moves = _Prediction(motion_b, [c[1] for c in checked], [c[2] for c in checked], which,
                        kp is Keep.ALL)  # fmt: skip
    most = int(np.diff(bounds).max()) if M else 0
    setup = _setup(sensor, lmap, batch, a, pairing, gate, nu, inflation, clutter, readings, most)
    if len(logs) > 1 and any(not np.array_equal(c[3], z, equal_nan=True) for c in checked):
        z = np.stack([c[3] for c in checked])[which]  # each filter's readings (B, M, d)
    else:
        z = z[None]  # shared (1, M, d)
    usable = sensor.usable(z)
    # every reading's candidates (the signatures label the readings only, unless they pair them)
    sig = None if logs[0].signature is None else np.asarray(logs[0].signature, dtype=np.int64)
    rows, cand = _candidates(setup, sig if a is Association.SIGNATURES else None, M)
    shared = a is not Association.SIGNATURES  # (every reading has every landmark)
    totals = []  # each time's (log-likelihood, NIS, dof, ambiguous) per filter
    posteriors: list[tuple[FloatArray, FloatArray]] = []
    x, P = x.mean, x.cov
    for e in range(len(times)):
        x, P = moves.advance(x, P, e)
        sl = slice(bounds[e], bounds[e + 1])
        up = _correct(setup, SE2, x, P, z[:, sl], usable[:, sl],
                      rows[None] if shared else rows[None, sl], cand[None, sl])  # fmt: skip
        x, P = up.x, up.P
        if not (np.isfinite(x).all() and np.isfinite(P).all()):
            _overflow(x, P, t, int(times[e]))
        status[:, sl] = up.status
        totals.append((up.loglik, up.nis, up.dof, up.ambiguous))
        if readings:
            out_f["y"][:, sl], out_f["S"][:, sl], out_f["d2"][:, sl] = up.y, up.S, up.d2
            out_f["y_given"][:, sl], out_f["S_given"][:, sl] = up.y_given, up.S_given
            landmark[:, sl] = up.landmark
        if kp is not Keep.SUMMARY:
            posteriors.append((x, P))
    x_end = AT._trusted(*moves.advance(x, P, len(times)))
    if not (np.isfinite(x_end.mean).all() and np.isfinite(x_end.cov).all()):
        _overflow(x_end.mean, x_end.cov, t, len(t) - 1)
    # (each filter's sums over its own row: a filter of a batch adds as it does alone)
    loglik, nis, dof, ambiguous = (np.stack([r[j] for r in totals], axis=-1).sum(axis=-1)
                                   if totals else np.zeros(B, int if j >= 2 else float)
                                   for j in range(4))  # fmt: skip
    updates = np.sum([r[2] > 0 for r in totals], axis=0) if totals else np.zeros(B, np.int64)
    mean, cov, kept_t = _kept(kp, t, times, x_end, posteriors, moves, start, batch, B)
    if len(logs) > 1 and kp is Keep.SUMMARY:  # each filter's last time
        kept_t = np.array([c[0][-1] for c in checked])[which].reshape(*batch, 1)
    counts = np.stack([(status == s).sum(axis=-1) for s in Status], axis=-1)
    y, S, yg, Sg = out_f["y"], out_f["S"], out_f["y_given"], out_f["S_given"]
    if d == 1:
        y, S, yg, Sg = y[..., 0], S[..., 0, 0], yg[..., 0], Sg[..., 0, 0]
    n = mean.shape[-1]
    rs = (*batch, Mo)
    return Trace(
        kept_t, mean.reshape(*batch, -1, n), cov.reshape(*batch, -1, n, n),
        y.reshape(*rs, *y.shape[2:]), S.reshape(*rs, *S.shape[2:]), out_f["d2"].reshape(rs),
        (status if readings else status[:, :0]).reshape(rs), landmark.reshape(rs),
        loglik.reshape(batch), nis.reshape(batch), dof.reshape(batch), updates.reshape(batch),
        counts.reshape(*batch, len(Status)), ambiguous.reshape(batch),
        yg.reshape(*rs, *yg.shape[2:]), Sg.reshape(*rs, *Sg.shape[2:]),
    )  # fmt: skip


def _same_readings(logs: list[Log], checked: list[tuple]) -> None:
    """Logs of one batch read at the same times, with the same signatures."""
    t0, _, i0, z0 = checked[0]
    for j, (one, (t, _, index, z)) in enumerate(zip(logs, checked, strict=True)):
        same_sig = (one.signature is None) == (logs[0].signature is None) and (
            one.signature is None or np.array_equal(one.signature, logs[0].signature)
        )
        if not (len(z) == len(z0) and np.array_equal(t[index], t0[i0]) and same_sig):
            raise ParameterError(
                f"the logs of a batch must read at the same times with the same signatures: "
                f"log {j} differs from log 0"
            )


def _flat_params(model: Motion | Measurement, batch: tuple[int, ...], B: int) -> dict:
    """The model's noise parameters broadcast to the batch and flattened to (B,)."""
    return {k: np.broadcast_to(np.asarray(getattr(model, k), float), batch).reshape(B)
            for k in model.noise_parameters}  # fmt: skip


def _overflow(x: FloatArray, P: FloatArray, t: FloatArray, k: int) -> None:
    """The error of filters that left the floating-point range at time index ``k``."""
    bad = ~(np.isfinite(x).all(axis=-1) & np.isfinite(P).all(axis=(-2, -1)))
    if bad.any():
        f = int(np.flatnonzero(bad)[0])
        raise NumericalError(
            f"the filter overflowed the floating-point range at time {t[k]} (index {k}, filter "
            f"{f}): inputs too large (motion, readings or noise)"
        )


class _Prediction:
    """How each filter moves to the next time with readings (and at last to its log's end): by
    the compounded steps of a relative motion (the chains ending at those times), or by stepping
    any motion model, keeping the states on the way when asked. Event ``e`` is the e-th time
    with readings (the same readings in every log); event E, the log's last time."""

    def __init__(self, motion: Motion, inputs: list[FloatArray], indices: list[IntArray],
                 which: IntArray, keep_all: bool) -> None:  # fmt: skip
        self.motion, self.which, self.keep_all = motion, which, keep_all
        self.relative = isinstance(motion, RelativeMotion)
        self.inputs, self.cuts = inputs, []
        self.targets = []  # per log: the time index of each event, then the last
        for u, index in zip(inputs, indices, strict=True):
            times = np.unique(index)
            cut = np.zeros(len(u) + 1, bool)
            cut[0] = cut[times] = True
            self.cuts.append(cut)
            self.targets.append(np.append(times, len(u)))
        self.steps: dict[int, AT] = {}  # stepped states by time index (keep_all)
        if self.relative:
            self._chains()

    def _chains(self) -> None:
        """Each filter's chain to each event from the one before it: ``mean`` (E + 1, 3) for
        one log (else (B, E + 1, 3)), ``cov`` (B, E + 1, 3, 3); the identity where a filter
        does not move (its log's last time has readings)."""
        B, E1 = len(self.which), len(self.targets[0])
        self.mean = np.zeros((len(self.inputs), E1, 3))
        self.cov = np.zeros((B, E1, 3, 3))
        names = self.motion.noise_parameters
        for j, (u, cut, to) in enumerate(zip(self.inputs, self.cuts, self.targets, strict=True)):
            moving = to > np.append(0, to[:-1])
            if not moving.any():  # (a log of its start time alone: no step to compound)
                continue
            mine = self.which == j
            motion = (
                self.motion
                if len(self.inputs) == 1
                else self.motion.replace(**{k: getattr(self.motion, k)[mine] for k in names})
            )
            ch = chains(motion, u, cut, to[moving])
            self.mean[j, moving] = ch.mean
            self.cov[np.ix_(mine, moving)] = ch.cov
        self.mean = self.mean[0] if len(self.inputs) == 1 else self.mean[self.which]

    def advance(self, x: FloatArray, P: FloatArray, e: int) -> tuple[FloatArray, FloatArray]:
        """The filters ``(x, P)`` at event ``e - 1`` (the start for 0) moved to event ``e``."""
        if self.relative:  # x ⊕ Δ_seg (Eqs. 1-4)
            mean = self.mean[e] if self.mean.ndim == 2 else self.mean[:, e]
            return compound_arrays(x, P, mean, self.cov[:, e])
        if len(self.inputs) == 1:
            to = self.targets[0]
            state = AT._trusted(x, P)
            for j in range(to[e - 1] if e else 0, to[e]):
                state = predict(state, self.inputs[0][j], self.motion)
                if self.keep_all:
                    self.steps[j + 1] = state
            return state.mean, state.cov
        # several logs: each filter steps through its own log's inputs, the others wait
        begin = np.array([to[e - 1] if e else 0 for to in self.targets])[self.which]
        count = np.array([to[e] for to in self.targets])[self.which] - begin
        for j in range(int(count.max(initial=0))):
            active = j < count
            u = np.stack([self.inputs[w][min(b + j, len(self.inputs[w]) - 1)]
                          for w, b in zip(self.which, begin, strict=True)])  # fmt: skip
            moved = predict(AT._trusted(x, P), u, self.motion)
            x = np.where(active[:, None], moved.mean, x)
            P = np.where(active[:, None, None], moved.cov, P)
        return x, P


def _kept(
    kp: Keep, t: FloatArray, times: IntArray, x_end: AT,
    posteriors: list[tuple[FloatArray, FloatArray]],
    moves: _Prediction, start: AT, batch: tuple[int, ...], B: int,
) -> tuple[FloatArray, FloatArray, FloatArray]:  # fmt: skip
    """The kept states ``(mean (B, K, 3), cov (B, K, 3, 3), times (K,))``."""
    x0 = AT._trusted(np.broadcast_to(start.mean, (*batch, 3)).reshape(B, 3),
                     np.broadcast_to(start.cov, (*batch, 3, 3)).reshape(B, 3, 3))  # fmt: skip
    if kp is Keep.SUMMARY:
        return x_end.mean[:, None], x_end.cov[:, None], t[-1:]
    if kp is Keep.EVENTS:
        mean = np.stack([x0.mean, *(x for x, _ in posteriors)], axis=1)
        cov = np.stack([x0.cov, *(P for _, P in posteriors)], axis=1)
        return mean, cov, np.concatenate([t[:1], t[times]])
    T = len(t)
    # each time's anchor: the state after the last time with readings before it (or the start)
    a_mean = np.stack([x0.mean, *(x for x, _ in posteriors)], axis=1)  # (B, E + 1, 3)
    a_cov = np.stack([x0.cov, *(P for _, P in posteriors)], axis=1)
    at_reading = np.zeros(T, bool)
    at_reading[times] = True
    last = np.searchsorted(times, np.arange(T), side="left")  # readings strictly before k
    if moves.relative and len(moves.inputs[0]):  # (a log of its start time alone: no step)
        ch = chains(moves.motion, moves.inputs[0], moves.cuts[0])  # from the last cut before k
        moved = compound(AT._trusted(a_mean[:, last], a_cov[:, last]),
                         AT._trusted(ch.mean, ch.cov))  # fmt: skip
        mean, cov = np.array(moved.mean), np.array(moved.cov)
    else:
        mean = np.empty((B, T, 3))
        cov = np.empty((B, T, 3, 3))
        mean[:, 0], cov[:, 0] = x0.mean, x0.cov
        for k, s in moves.steps.items():
            mean[:, k], cov[:, k] = s.mean, s.cov
    # at a time with readings: the state after them (its posterior)
    mean[:, at_reading] = a_mean[:, 1:]
    cov[:, at_reading] = a_cov[:, 1:]
    if not at_reading[0]:
        mean[:, 0], cov[:, 0] = x0.mean, x0.cov
    return mean, cov, t
