"""Robots and maps with known noise, simulated: what tests and studies draw from.

- Random uncertain poses: :func:`random_poses`, :func:`random_covariances`, :func:`random_ats`
  (SE(2)), :func:`random_at3s` (SE(3)); random maps of point landmarks:
  :func:`random_landmarks`.
- A differential-drive robot, :func:`simulate`: it follows velocity commands ``(v, ω)`` — an
  array (open loop) or a controller that plans from its true pose (:class:`Patrol`) — and moves
  as a :class:`relmap.models.Odometry` says a commanded step goes wrong (the model's noise,
  known); at every ``every``-th odometry time it reads the landmarks of a map through any
  :class:`relmap.models.Measurement` (``z = h(x, l) + v``, ``v ~ N(0, R)``), in its field of
  view, some missed, with clutter if asked. The :class:`Simulation` holds the truth and gives
  each run as a filter's :class:`relmap.filter.Log` and as an autocalibration
  :class:`relmap.filter.autocalibration.Recording`.

Units: metres, radians, seconds. Poses are ``(x, y, θ)`` in the world frame, θ in [-π, π);
landmarks are world coordinates. Every function draws from ``seed`` (a
:class:`numpy.random.Generator`, an int or None): the same seed, the same draws.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from relmap.errors import ParameterError, ShapeError
from relmap.filter.autocalibration import Recording
from relmap.filter.logs import Log
from relmap.lie import se2
from relmap.models.base import Measurement
from relmap.models.odometry import DistanceNoise, Odometry, WheelNoise, increment
from relmap.typing import ArrayLike, FloatArray, IntArray, SeedLike
from relmap.uncertain.at import AT
from relmap.uncertain.at3 import AT3
from relmap.uncertain.gaussian import check_finite, real_array, sqrt_psd

__all__ = [
    "Controller",
    "Patrol",
    "Scans",
    "Simulation",
    "random_at3s",
    "random_ats",
    "random_covariances",
    "random_landmarks",
    "random_poses",
    "simulate",
]

Shape = int | tuple[int, ...]


# ------------------------------------------------------------------ random poses and maps
def _shape(shape: Shape) -> tuple[int, ...]:
    return (shape,) if isinstance(shape, (int, np.integer)) else tuple(shape)


def random_poses(seed: SeedLike, shape: Shape = (), scale: float = 3.0) -> FloatArray:
    """Random planar poses ``(*shape, 3)``: translations ~ N(0, scale²) (m), headings uniform
    in [-π, π)."""
    g = np.random.default_rng(seed)
    s = _shape(shape)
    t = g.normal(scale=scale, size=(*s, 2))
    th = g.uniform(-np.pi, np.pi, size=(*s, 1))
    return np.concatenate([t, th], axis=-1)


def random_covariances(
    seed: SeedLike, shape: Shape = (), n: int = 3, scale: float = 0.1
) -> FloatArray:
    """Random positive definite covariances ``(*shape, n, n)`` with varied correlations:
    ``L Lᵀ + 10⁻⁴ scale² I``, ``L``'s entries ~ N(0, scale²)."""
    g = np.random.default_rng(seed)
    L = g.normal(scale=scale, size=(*_shape(shape), n, n))
    return L @ np.swapaxes(L, -1, -2) + 1e-4 * scale**2 * np.eye(n)


def random_ats(
    seed: SeedLike, shape: Shape = (), scale: float = 0.1, pose_scale: float = 3.0
) -> AT:
    """Random ATs of batch ``shape``: means as :func:`random_poses` (``pose_scale``),
    covariances as :func:`random_covariances` (``scale``)."""
    g = np.random.default_rng(seed)
    return AT(random_poses(g, shape, pose_scale), random_covariances(g, shape, 3, scale))


def random_at3s(
    seed: SeedLike, shape: Shape = (), scale: float = 0.05, pose_scale: float = 2.0
) -> AT3:
    """Random AT3s of batch ``shape``: rotations uniform (unit quaternions of normal draws),
    translations ~ N(0, pose_scale²) (m), 6×6 covariances as :func:`random_covariances`."""
    g = np.random.default_rng(seed)
    s = _shape(shape)
    q = g.normal(size=(*s, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    t = g.normal(scale=pose_scale, size=(*s, 3))
    return AT3(t, q, random_covariances(g, s, 6, scale))


def random_landmarks(
    seed: SeedLike, count: int, low: ArrayLike = (-10.0, -10.0), high: ArrayLike = (10.0, 10.0)
) -> FloatArray:
    """``count`` point landmarks ``(count, p)`` uniform in the box ``[low, high]`` (world
    coordinates, p = len(low))."""
    lo, hi = real_array(low, "low"), real_array(high, "high")
    if lo.ndim != 1 or lo.shape != hi.shape or not (lo < hi).all():
        raise ShapeError(f"low and high must be (p,) with low < high; got {lo}, {hi}")
    if int(count) != count or count < 1:
        raise ParameterError(f"the number of landmarks must be a positive integer; got {count}")
    return np.random.default_rng(seed).uniform(lo, hi, (int(count), len(lo)))


# ------------------------------------------------------------------ controllers
#: A controller: ``(k, pose, dt) -> (v, ω)``, the velocity command ``(*batch, 2)`` (m/s, rad/s)
#: from odometry time ``k`` to ``k + 1`` given the true poses ``(*batch, 3)`` at ``k`` and the
#: step's length ``dt`` (s). :func:`simulate` calls it at ``k = 0, 1, …`` in order.
Controller = Callable[[int, FloatArray, float], FloatArray]


class Patrol:
    """Drive ``route`` (W, 2) again and again, as a differential-drive robot patrols: at each
    waypoint turn in place to face the next (at most ``turn_rate``, rad/s), then drive straight
    to it (at most ``speed``, m/s), each leg planned from the true pose where the last one
    ended, so the robot stays on its route however its odometry drifts. Turning in place and
    driving come in separate steps: the odometry's noise of each is identifiable.

    The first goal is ``route[0]``. A :class:`Controller` that remembers each run's leg; it
    starts afresh when called with ``k = 0``.
    """

    def __init__(self, route: ArrayLike, speed: float = 0.3, turn_rate: float = 0.3) -> None:
        r = real_array(route, "route")
        if r.ndim != 2 or r.shape[1] != 2 or len(r) < 2:
            raise ShapeError(f"a route is two or more waypoints (W, 2); got {r.shape}")
        check_finite(r, "route")
        if (np.hypot(*np.diff(r, axis=0, append=r[:1]).T) == 0).any():
            raise ParameterError("a route's consecutive waypoints must differ")
        if not (speed > 0 and turn_rate > 0):
            raise ParameterError(f"speed and turn_rate must be positive; got {speed}, {turn_rate}")
        self.route, self.speed, self.turn_rate = r, float(speed), float(turn_rate)
        self._leg: dict[str, np.ndarray] = {}

    def _plan(self, pose: FloatArray, which: np.ndarray, dt: float) -> None:
        """New legs for the runs ``which``, from their poses to their next waypoints."""
        leg = self._leg
        d = self.route[leg["goal"][which] % len(self.route)] - pose[which, :2]
        turn = se2.wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - pose[which, 2])
        dist = np.hypot(d[:, 0], d[:, 1])
        n = np.ceil(np.abs(turn) / (self.turn_rate * dt))
        m = np.ceil(dist / (self.speed * dt))
        leg["turns"][which], leg["w"][which] = n, turn / (np.maximum(n, 1) * dt)
        leg["drives"][which], leg["v"][which] = m, dist / (np.maximum(m, 1) * dt)
        leg["goal"][which] += 1

    def __call__(self, k: int, pose: FloatArray, dt: float) -> FloatArray:
        p = np.asarray(pose, dtype=np.float64).reshape(-1, 3)
        if k == 0:
            self._leg = {name: np.zeros(len(p)) for name in ("goal", "turns", "drives", "v", "w")}
            self._leg["goal"] = np.zeros(len(p), np.int64)
        leg = self._leg
        for _ in range(2):  # (a leg of no steps: at its waypoint already, on to the next)
            done = (leg["turns"] == 0) & (leg["drives"] == 0)
            if done.any():
                self._plan(p, done, dt)
        turning = leg["turns"] > 0
        driving = ~turning & (leg["drives"] > 0)
        leg["turns"] -= turning
        leg["drives"] -= driving
        out = np.stack([np.where(driving, leg["v"], 0.0), np.where(turning, leg["w"], 0.0)], -1)
        return out.reshape(*np.shape(pose)[:-1], 2)


def _open_loop(commands: FloatArray) -> Controller:
    """The controller that gives the commands ``(*batch, T, 2)`` whatever the pose."""
    return lambda k, pose, dt: commands[..., k, :]


# ------------------------------------------------------------------ the simulated robot
class Scans(NamedTuple):
    """The readings of every run by reading time, padded: ``reading_index`` (K,) the odometry
    time indices with readings (in any run); ``z`` (*batch, K, m, d), ``valid`` (*batch, K, m)
    (False: padding) and ``landmark`` (*batch, K, m) (the true row, -1: clutter or padding);
    m the most readings of a scan."""

    reading_index: IntArray
    z: FloatArray
    valid: np.ndarray
    landmark: IntArray


class Simulation(NamedTuple):
    """What :func:`simulate` gives; ``batch`` is ``(runs,)``, or ``()`` for one run.

    ``t`` (T+1,) the odometry times (s, from 0); ``truth`` (*batch, T+1, 3) the true poses at
    ``t``; ``commands`` (*batch, T, 2) the velocities ``(v, ω)`` held from ``t[k]`` to
    ``t[k+1]`` (what the odometry records); ``inputs`` (*batch, T, k) the motion model's
    inputs they make (``(v, ω)·dt``, or wheel increments with a :class:`DiffDrive`). Readings,
    all runs' in one flat list ordered by run and time (in random order within a scan):
    ``run`` (M,), ``reading_index`` (M,) the odometry time of each, ``z`` (M, d) and
    ``landmark`` (M,) the row of the landmark read (-1: clutter; 0 for readings of the state).
    ``motion``, ``sensor`` and ``landmarks`` are the true models and map.
    """

    t: FloatArray
    truth: FloatArray
    commands: FloatArray
    inputs: FloatArray
    run: IntArray
    reading_index: IntArray
    z: FloatArray
    landmark: IntArray
    motion: Odometry
    sensor: Measurement
    landmarks: FloatArray

    @property
    def runs(self) -> int:
        return int(np.prod(self.truth.shape[:-2], dtype=np.int64))

    def _rows(self, run: int) -> IntArray:
        if not 0 <= run < self.runs:
            raise ParameterError(f"run must be in [0, {self.runs}); got {run}")
        return np.flatnonzero(self.run == run)

    def log(self, run: int = 0) -> Log:
        """Run ``run``'s log for :func:`relmap.filter.run`: the inputs, the readings, and each
        reading's true landmark as its signature (-1: clutter)."""
        rows = self._rows(run)
        u = self.inputs.reshape(self.runs, *self.inputs.shape[-2:])[run]
        return Log(self.t, u, self.reading_index[rows], self.z[rows], self.landmark[rows])

    def recording(self, run: int = 0) -> Recording:
        """Run ``run``'s raw streams for :func:`relmap.filter.autocalibration.calibrate`: the
        velocities at the odometry times (the last held to the end) and the readings at theirs,
        the true landmark as signature. Its :meth:`Recording.log` is :meth:`log`."""
        if self.motion.drive is not None:
            raise ParameterError(
                "a Recording holds velocities (v, ω): simulate without a DiffDrive"
            )
        rows = self._rows(run)
        c = self.commands.reshape(self.runs, *self.commands.shape[-2:])[run]
        c = np.concatenate([c, c[-1:]])
        t = self.t
        return Recording(t, c[:, 0], c[:, 1], t[self.reading_index[rows]], self.z[rows],
                         self.landmark[rows], float(t[-1]))  # fmt: skip

    def scans(self) -> Scans:
        """The readings by reading time, padded (:class:`Scans`): for a batch of filters
        stepped together (:func:`relmap.filter.correct_landmarks` with ``valid``)."""
        index = np.unique(self.reading_index)
        j = np.searchsorted(index, self.reading_index)
        key = self.run * len(index) + j  # the scan of each reading, in order
        first = np.searchsorted(key, key, side="left")
        slot = np.arange(len(key)) - first
        m = int(slot.max()) + 1 if len(slot) else 0
        shape = (self.runs, len(index), m)
        z = np.full((*shape, self.z.shape[-1]), np.nan)
        valid = np.zeros(shape, bool)
        landmark = np.full(shape, -1, np.int64)
        z[self.run, j, slot], valid[self.run, j, slot] = self.z, True
        landmark[self.run, j, slot] = self.landmark
        batch = self.truth.shape[:-2]
        return Scans(index, z.reshape(*batch, *z.shape[1:]), valid.reshape(*batch, *shape[1:]),
                     landmark.reshape(*batch, *shape[1:]))  # fmt: skip


def _true_step(motion: Odometry, u: FloatArray, rng: np.random.Generator) -> FloatArray:
    """The step ``(..., 3)`` the robot really makes for inputs ``u`` (..., k): the model's noise
    sources ``w ~ N(0, Q_w)``. Noise on ``(Δs, Δθ)`` (:class:`DistanceNoise`,
    :class:`WheelNoise`) moves the robot by ``increment((Δs, Δθ) + w)`` exactly; other noise
    (the α-model) by the step perturbed to first order, ``Δ + J_w w``."""
    delta, J, Q = motion.step(u)
    w = np.einsum("...ij,...j->...i", sqrt_psd(Q), rng.standard_normal(Q.shape[:-1]))
    if isinstance(motion.noise, (DistanceNoise, WheelNoise)):
        m = u if motion.drive is None else motion.drive.motion(u)
        return increment(m + w, motion.integration)  # type: ignore[return-value]
    return se2.plus(delta, np.einsum("...ij,...j->...i", J, w))


def _commands(
    commands: ArrayLike | Controller, steps: int | None, batch: tuple[int, ...]
) -> tuple[Controller, int]:
    if callable(commands):
        if steps is None or int(steps) != steps or steps < 1:
            raise ParameterError(f"a controller needs the number of steps (≥ 1); got {steps}")
        return commands, int(steps)
    c = real_array(commands, "commands")
    if c.ndim not in (2, 3) or c.shape[-1] != 2 or not c.shape[-2]:
        raise ShapeError(f"commands must be velocities (T, 2) or (runs, T, 2); got {c.shape}")
    if c.ndim == 3 and c.shape[0] != int(np.prod(batch, dtype=np.int64)):
        raise ShapeError(f"commands (runs, T, 2) need runs = {batch}; got {c.shape}")
    check_finite(c, "commands")
    if steps is not None and steps != c.shape[-2]:
        raise ShapeError(f"{c.shape[-2]} commands for {steps} steps")
    c = c if c.ndim == 2 else c.reshape(*batch, *c.shape[1:])
    return _open_loop(c), c.shape[-2]


def _checked(
    motion: Odometry, sensor: Measurement, landmarks: ArrayLike, dt: float, every: int,
    detection: float, clutter: float,
) -> FloatArray:  # fmt: skip
    if not isinstance(motion, Odometry):
        raise ParameterError(f"the robot moves by an Odometry model; got {type(motion).__name__}")
    if not isinstance(sensor, Measurement):
        raise ParameterError(f"the sensor must be a Measurement model; got {type(sensor).__name__}")
    for model in (motion, sensor):
        if model.batch_shape != ():
            raise ParameterError(
                f"a simulation has one true noise: {type(model).__name__}'s parameters must be "
                f"numbers, not a batch {model.batch_shape}"
            )
    lm = real_array(landmarks, "landmarks")
    p = max(sensor.landmark_dim, 1)
    if lm.ndim != 2 or lm.shape[1] != p or (sensor.landmark_dim and not len(lm)):
        raise ShapeError(f"landmarks must have shape (L, {p}) for this sensor; got {lm.shape}")
    check_finite(lm, "landmarks")
    if not (np.isfinite(dt) and dt > 0):
        raise ParameterError(f"dt must be a positive number of seconds; got {dt}")
    if int(every) != every or every < 1:
        raise ParameterError(f"every must be a positive integer; got {every}")
    if not 0 < detection <= 1:
        raise ParameterError(f"detection must be a probability in (0, 1]; got {detection}")
    if not (np.isfinite(clutter) and clutter >= 0):
        raise ParameterError(f"clutter must be a non-negative mean count; got {clutter}")
    return lm


def simulate(
    commands: ArrayLike | Controller,
    motion: Odometry,
    sensor: Measurement,
    landmarks: ArrayLike,
    *,
    start: AT | ArrayLike,
    dt: float = 0.1,
    steps: int | None = None,
    every: int = 1,
    runs: int | None = None,
    detection: float = 1.0,
    clutter: float = 0.0,
    clutter_box: tuple[ArrayLike, ArrayLike] | None = None,
    visible: Callable[[FloatArray], np.ndarray] | None = None,
    seed: SeedLike = None,
) -> Simulation:
    """Simulate ``runs`` differential-drive robots (one when None) with known noise.

    **Motion.** ``commands`` are velocities ``(v, ω)`` (T, 2), shared, or (runs, T, 2), or a
    :data:`Controller` (then ``steps`` T is needed), one per odometry step of ``dt`` seconds.
    A step's input is the command times ``dt`` (``(Δs, Δθ)``, or wheel increments when
    ``motion`` has a :class:`relmap.models.DiffDrive`) — what the odometry records — and the
    robot really moves by the step the ``motion`` model draws for it (:func:`_true_step`:
    ``(Δs, Δθ) + w``, ``w ~ N(0, Q_w)``), compounded from the start pose: a draw of ``start``
    (an AT: the filter's prior; each run its own draw) or ``start`` itself (a pose (3,)).

    **Readings**, at odometry times ``every``, ``2·every``, …: of each landmark (L, p) — or of
    the state, for a sensor with ``landmark_dim`` 0 — ``z = ẑ ⊞ v`` with ``ẑ = h(truth, l)``
    and ``v ~ N(0, R(ẑ))`` (angles wrapped), where ``ẑ`` is usable (finite: a model may
    return NaN for a landmark it cannot see) and ``visible(ẑ)`` (default: the model's
    ``in_view`` if it has one), each read with probability ``detection``. ``clutter``: a mean
    number (Poisson) of spurious readings per scan, uniform in ``clutter_box`` ``(low, high)``
    (d,) each (default: the box of the true readings), landmark -1.

    ``motion``'s and ``sensor``'s noise parameters are numbers (the one true noise).
    """
    lm = _checked(motion, sensor, landmarks, dt, every, detection, clutter)
    if runs is not None and (int(runs) != runs or runs < 1):
        raise ParameterError(f"runs must be a positive integer or None; got {runs}")
    batch = () if runs is None else (int(runs),)
    R = int(np.prod(batch, dtype=np.int64))
    control, T = _commands(commands, steps, batch)
    rng = np.random.default_rng(seed)
    if isinstance(start, AT):
        if start.batch_shape != ():
            raise ShapeError(
                f"start must be one AT (every run draws from it); got {start.batch_shape}"
            )
        x0 = start.sample(R, seed=rng).reshape(*batch, 3)
    else:
        s0 = real_array(start, "start")
        if s0.shape != (3,):
            raise ShapeError(f"start must be an AT or a pose (3,); got shape {s0.shape}")
        check_finite(s0, "start")
        x0 = np.broadcast_to(s0, (*batch, 3))

    # the truth, step by step (a controller plans from it)
    t: FloatArray = np.arange(T + 1, dtype=np.float64) * float(dt)
    dts = np.diff(t)
    W = None if motion.drive is None else np.linalg.inv(motion.drive.wheel_map())
    truth = np.empty((*batch, T + 1, 3))
    truth[..., 0, :] = x0
    cmd = np.empty((*batch, T, 2))
    for k in range(T):
        c = np.broadcast_to(
            np.asarray(control(k, truth[..., k, :], float(dts[k])), float), (*batch, 2)
        )
        cmd[..., k, :] = c
        u = c * dts[k] if W is None else (c * dts[k]) @ W.T
        truth[..., k + 1, :] = se2.compose(truth[..., k, :], _true_step(motion, u, rng))
    check_finite(truth, "the simulated poses (commands or noise too large)")
    m = cmd * dts[:, None]
    inputs = m if W is None else m @ W.T

    run, index, z, landmark = _readings(
        truth.reshape(R, T + 1, 3), sensor, lm, every, detection, clutter, clutter_box,
        visible, rng,
    )  # fmt: skip
    return Simulation(t, truth, cmd, inputs, run, index, z, landmark, motion, sensor, lm)


def _readings(
    truth: FloatArray, sensor: Measurement, landmarks: FloatArray, every: int, detection: float,
    clutter: float, clutter_box: tuple[ArrayLike, ArrayLike] | None,
    visible: Callable[[FloatArray], np.ndarray] | None, rng: np.random.Generator,
) -> tuple[IntArray, IntArray, FloatArray, IntArray]:  # fmt: skip
    """The readings of runs' truths (R, T+1, 3): ``(run, reading_index, z, landmark)``,
    ordered by run and time, shuffled within a scan."""
    R, d = len(truth), sensor.dim
    ks = np.arange(every, truth.shape[1], every)
    X = truth[:, ks]  # (R, K, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        if sensor.landmark_dim:
            zh = sensor.h(X[:, :, None, :], landmarks)  # (R, K, L, d)
        else:
            zh = sensor.h(X)[:, :, None, :]
        zh = np.asarray(zh, dtype=np.float64)
        seen = sensor.usable(zh)
        view = visible if visible is not None else getattr(sensor, "in_view", None)
        if view is not None:
            seen &= np.asarray(view(np.where(seen[..., None], zh, 0.0)), bool) & seen
    seen &= rng.random(seen.shape) < detection
    r, j, lmk = np.nonzero(seen)
    zh = zh[r, j, lmk]
    noise = np.einsum("mij,mj->mi", sqrt_psd(sensor.noise(zh)), rng.standard_normal((len(zh), d)))
    z = sensor.reading_chart.plus(zh, noise)
    landmark = lmk if sensor.landmark_dim else np.zeros_like(lmk)
    if clutter > 0:
        count = rng.poisson(clutter, (R, len(ks)))
        rf, jf = np.nonzero(count)
        rf, jf = np.repeat(rf, count[rf, jf]), np.repeat(jf, count[rf, jf])
        if clutter_box is None:
            if not len(z):
                raise ParameterError("no true readings to span the clutter: give clutter_box")
            lo, hi = z.min(axis=0), z.max(axis=0)
        else:
            lo, hi = (real_array(b, "clutter_box") for b in clutter_box)
            if lo.shape != (d,) or hi.shape != (d,) or not (lo <= hi).all():
                raise ShapeError(f"clutter_box must be (low, high), each ({d},), low ≤ high")
        r, j = np.concatenate([r, rf]), np.concatenate([j, jf])
        z = np.concatenate([z, rng.uniform(lo, hi, (len(rf), d))])
        landmark = np.concatenate([landmark, np.full(len(rf), -1)])
    order = np.lexsort((rng.random(len(r)), j, r))
    return (r[order].astype(np.int64), ks[j[order]].astype(np.int64), z[order],
            landmark[order].astype(np.int64))  # fmt: skip
