"""Differential-drive odometry with covariance (lecture Eqs. 9-12), batched and loop-free.

A step of the robot is a small relative motion ``Δ = (Δx, Δy, Δθ)`` in the robot's own frame at
the start of the step, made of a travelled distance ``Δs`` and a turn ``Δθ``:

- midpoint integration (lecture Eq. 10): ``Δ = (Δs cos(Δθ/2), Δs sin(Δθ/2), Δθ)``;
- exact-arc integration (constant curvature): ``Δ = Exp(Δs, 0, Δθ)``, i.e.
  ``(Δs sin Δθ/Δθ, Δs (1 - cos Δθ)/Δθ, Δθ)``.

Each step is an AT in the robot frame with covariance ``J Σ_sθ Jᵀ`` (J = ∂Δ/∂(Δs, Δθ)), so a
whole run is the compound ``A₁ ⊕ A₂ ⊕ …`` — :func:`relmap.compound_chain`, one parallel scan,
no Python loop per step. This equals the lecture's recursion ``Σ_{k+1} = Gx Σ_k Gxᵀ + Gu Σu Guᵀ``
(Eq. 12) step for step (tested).

Where (Δs, Δθ) come from:

- wheel increments ``u = (Δφl, Δφr)`` (rad) of a :class:`DiffDrive` (wheel radius r, baseline b):
  ``Δs = r (Δφr + Δφl)/2``, ``Δθ = r (Δφr - Δφl)/b`` (Eq. 9);
- logged velocities ``(t, v, ω)`` (the MRCLAM format): ``Δs = v·dt``, ``Δθ = ω·dt`` with each
  sample held until the next (:func:`increments_from_velocities`).

Noise models (the covariance of one step):

- :class:`WheelNoise`: ``Σu = diag(σ² + k|Δφl|, σ² + k|Δφr|)`` on the wheel increments — the
  lecture's constant (k = 0) and proportional (σ = 0) models;
- :class:`DistanceNoise`: ``var Δs = k_s |Δs|``, ``var Δθ = k_θ |Δθ| + k_θs |Δs|`` — errors that
  accumulate like a random walk per metre travelled and per radian turned, so the result does
  not depend on the logging rate (the right model for 100 Hz velocity logs);
- :class:`AlphaNoise`: the α-model of probabilistic robotics on ``(δrot1, δtrans, δrot2)`` with
  ``δrot1 = δrot2 = Δθ/2``, ``δtrans = Δs``: ``var δrot = α1 δrot² + α2 δtrans²``,
  ``var δtrans = α3 δtrans² + α4 (δrot1² + δrot2²)`` (note: quadratic in the step, so its
  accumulated variance shrinks as steps get finer).

:class:`Odometry` is the motion model of a filter (:mod:`relmap.models.base`): a noise model
with its integration (and :class:`DiffDrive` for wheel increments), ``x⁻ = x ⊕ Δ(u)`` — the
paper's compounding (Eqs. 1-4) with the step's AT — whose noise enters through the step.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar, TypeVar

import numpy as np

from relmap._layout import components_outermost, matrix, stack_last
from relmap.errors import ParameterError, ShapeError
from relmap.lie import se2
from relmap.models.base import Model, RelativeMotion, positive
from relmap.typing import ArrayLike, FloatArray, Option
from relmap.uncertain.algebra import compound, compound_chain
from relmap.uncertain.at import AT
from relmap.uncertain.gaussian import check_finite, congruence, real_array
from relmap.uncertain.pose import check_result

__all__ = [
    "AlphaNoise",
    "DiffDrive",
    "DistanceNoise",
    "Integration",
    "Noise",
    "Odometry",
    "WheelNoise",
    "dead_reckon",
    "increment",
    "increments_from_velocities",
    "step",
]


class Integration(Option):
    """How a step ``(Δs, Δθ)`` becomes a relative motion."""

    MIDPOINT = "midpoint"  #: lecture Eq. 10: along the heading at the step's middle
    ARC = "arc"  #: along the arc of constant curvature


Sym2 = tuple[FloatArray, FloatArray, FloatArray]
_N = TypeVar("_N", bound=Model)


def _sym2(e: Sym2) -> FloatArray:
    s00, s01, s11 = e
    return matrix([[s00, s01], [s01, s11]], np.broadcast_shapes(*(np.shape(v) for v in e)))


def _number(value: object, name: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        raise ParameterError(f"{name} must be a number; got {value!r}")
    try:
        return float(value)
    except OverflowError:
        raise ParameterError(f"{name} is too large for a float") from None


def _positive(value: float, name: str) -> float:
    v = _number(value, name)
    if not np.isfinite(v) or v <= 0:
        raise ParameterError(f"{name} must be a positive number; got {value}")
    return v


def _non_negative(value: float, name: str) -> float:
    v = _number(value, name)
    if not np.isfinite(v) or v < 0:
        raise ParameterError(f"{name} must be non-negative; got {value}")
    return v


class DiffDrive:
    """A differential-drive robot: wheel radius r and baseline b (between the wheels), metres."""

    __slots__ = ("baseline", "wheel_radius")

    def __init__(self, wheel_radius: float, baseline: float) -> None:
        object.__setattr__(self, "wheel_radius", _positive(wheel_radius, "wheel radius"))
        object.__setattr__(self, "baseline", _positive(baseline, "baseline"))

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError("DiffDrive is immutable")

    def __repr__(self) -> str:
        return f"DiffDrive(wheel_radius={self.wheel_radius}, baseline={self.baseline})"

    def wheel_map(self) -> FloatArray:
        """``W`` (2, 2) with ``(Δs, Δθ) = W (Δφl, Δφr)`` (Eq. 9)."""
        r, b = self.wheel_radius, self.baseline
        return np.array([[r / 2, r / 2], [-r / b, r / b]])

    def motion(self, u: ArrayLike) -> FloatArray:
        """``(Δs, Δθ)`` (..., 2) from wheel increments ``u = (Δφl, Δφr)`` (..., 2), radians."""
        u = _pairs(u, "wheel increments")
        return u @ self.wheel_map().T


def _pairs(u: ArrayLike, name: str, *, finite: bool = True) -> FloatArray:
    """``u`` as a new float array (..., 2), checked (finite: unless the caller's core checks)."""
    arr = real_array(u, name)
    if arr.ndim == 0 or arr.shape[-1] != 2:
        raise ShapeError(f"{name} must have shape (..., 2); got {arr.shape}")
    if finite:
        check_finite(arr, name)
    return arr


# Below this |Δθ| the arc's closed forms lose digits to cancellation; the series, kept to the
# fifth order, are exact to float64 rounding there (the first omitted term is O(Δθ⁶)).
_ARC_SERIES = 1e-2


def increment(
    motion: ArrayLike, integration: Integration | str = "midpoint", *, jacobians: bool = False
) -> FloatArray | tuple[FloatArray, FloatArray]:
    """The step ``Δ = (Δx, Δy, Δθ)`` (..., 3) in the robot frame from ``(Δs, Δθ)`` (..., 2).

    With ``jacobians=True`` also returns ``∂Δ/∂(Δs, Δθ)``, (..., 3, 2).
    """
    m = _pairs(motion, "motion (Δs, Δθ)")
    return _increment(m, Integration.parse(integration, "integration"), jacobians)


def _increment(
    m: FloatArray, integration: Integration, jacobians: bool
) -> FloatArray | tuple[FloatArray, FloatArray]:
    """:func:`increment` of checked steps ``m`` (..., 2)."""
    ds, dt = m[..., 0], m[..., 1]
    a, b, da, db = _increment_parts(dt, integration)
    out = stack_last([ds * a, ds * b, dt], dt.shape)
    if not jacobians:
        return out
    J = matrix([[a, ds * da], [b, ds * db], [0.0, 1.0]], dt.shape)
    return out, J


def _increment_parts(
    dt: FloatArray, integration: Integration
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """``(a, b, a', b')`` with ``Δ = (Δs·a(Δθ), Δs·b(Δθ), Δθ)`` and their derivatives in Δθ."""
    if integration is Integration.MIDPOINT:
        if isinstance(dt, float):  # one step: math's cos and sin (bitwise numpy's, and faster)
            c, s = math.cos(dt / 2), math.sin(dt / 2)
        else:
            c, s = np.cos(dt / 2), np.sin(dt / 2)
        return c, s, -s / 2, c / 2
    if integration is Integration.ARC:
        small = np.abs(dt) < _ARC_SERIES
        t = np.where(small, 1.0, dt)
        t2 = dt * dt
        a = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, np.sin(t) / t)
        b = np.where(small, dt / 2 - dt * t2 / 24 + dt * t2 * t2 / 720, 2 * np.sin(t / 2) ** 2 / t)
        da = np.where(small, -dt / 3 + dt * t2 / 30, (t * np.cos(t) - np.sin(t)) / (t * t))
        db = np.where(
            small, 0.5 - t2 / 8 + t2 * t2 / 144, (t * np.sin(t) - 2 * np.sin(t / 2) ** 2) / (t * t)
        )
        return a, b, da, db
    raise ParameterError(f"integration must be 'midpoint' or 'arc'; got {integration!r}")


# ------------------------------------------------------------------ noise models
# Each noise model says where a step's noise enters: the Jacobian J_w of the step Δ in its noise
# sources w and their covariance Q_w, so that the step's covariance is J_w Q_w J_wᵀ.


@dataclasses.dataclass(frozen=True)
class WheelNoise(Model):
    """Independent wheel errors: ``Σu = diag(σ² + k|Δφl|, σ² + k|Δφr|)`` (rad², lecture Eq. 12).

    ``sigma`` (rad) alone is the constant model, ``k`` (rad) alone the proportional one. Needs
    the :class:`DiffDrive` to map wheel increments to the motion.
    """

    sigma: float | FloatArray = 0.0
    k: float | FloatArray = 0.0
    noise_parameters: ClassVar[tuple[str, ...]] = ("sigma", "k")

    def __post_init__(self) -> None:
        for name in self.noise_parameters:
            object.__setattr__(self, name, positive(getattr(self, name), name))

    def entries(self, motion: FloatArray, drive: DiffDrive | None = None) -> Sym2:
        """The distinct entries ``(s00, s01, s11)`` of the covariance of ``(Δs, Δθ)``."""
        if drive is None:
            raise ParameterError("WheelNoise needs the DiffDrive (wheel radius and baseline)")
        r, b = drive.wheel_radius, drive.baseline
        ds, dt = motion[..., 0], motion[..., 1]
        # back to the wheel increments: Δφl = (Δs - bΔθ/2)/r, Δφr = (Δs + bΔθ/2)/r
        vl = self.sigma**2 + self.k * np.abs((ds - b * dt / 2) / r)
        vr = self.sigma**2 + self.k * np.abs((ds + b * dt / 2) / r)
        # W diag(vl, vr) Wᵀ with W's columns (r/2, -r/b) and (r/2, r/b)
        return (r * r / 4 * (vl + vr), r * r / (2 * b) * (vr - vl), (r / b) ** 2 * (vl + vr))

    def covariance(self, motion: ArrayLike, drive: DiffDrive | None = None) -> FloatArray:
        """The covariance (..., 2, 2) of ``(Δs, Δθ)``."""
        return _sym2(self.entries(np.asarray(motion, dtype=np.float64), drive))

    def sources(
        self, motion: FloatArray, integration: Integration, drive: DiffDrive | None
    ) -> tuple[FloatArray, FloatArray]:
        """``(J_w, Q_w)``: the noise enters through ``(Δs, Δθ)``, ``J_w = ∂Δ/∂(Δs, Δθ)``."""
        return _increment(motion, integration, True)[1], self.covariance(motion, drive)

    def linear_basis(self) -> tuple[WheelNoise, FloatArray]:
        """Σu is linear in ``(σ², k)``."""
        weights = np.stack(np.broadcast_arrays(np.square(self.sigma), self.k), axis=-1)
        return WheelNoise(np.array([1.0, 0.0]), np.array([0.0, 1.0])), weights


@dataclasses.dataclass(frozen=True)
class DistanceNoise(Model):
    """Random-walk errors: ``var Δs = k_s|Δs|`` (m²/m), ``var Δθ = k_theta|Δθ| + k_theta_s|Δs|``
    (rad²/rad, rad²/m), independent. Independent of the logging rate."""

    k_s: float | FloatArray = 0.0
    k_theta: float | FloatArray = 0.0
    k_theta_s: float | FloatArray = 0.0
    noise_parameters: ClassVar[tuple[str, ...]] = ("k_s", "k_theta", "k_theta_s")

    def __post_init__(self) -> None:
        for name in self.noise_parameters:
            object.__setattr__(self, name, positive(getattr(self, name), name))

    def entries(self, motion: FloatArray, drive: DiffDrive | None = None) -> Sym2:
        """The distinct entries ``(s00, s01, s11)`` of the covariance of ``(Δs, Δθ)``."""
        ds, dt = np.abs(motion[..., 0]), np.abs(motion[..., 1])
        s11 = self.k_theta * dt + self.k_theta_s * ds
        return (self.k_s * ds, np.zeros(np.shape(s11)), s11)

    def covariance(self, motion: ArrayLike, drive: DiffDrive | None = None) -> FloatArray:
        """The covariance (..., 2, 2) of ``(Δs, Δθ)``."""
        return _sym2(self.entries(np.asarray(motion, dtype=np.float64), drive))

    def sources(
        self, motion: FloatArray, integration: Integration, drive: DiffDrive | None
    ) -> tuple[FloatArray, FloatArray]:
        """``(J_w, Q_w)``: the noise enters through ``(Δs, Δθ)``, ``J_w = ∂Δ/∂(Δs, Δθ)``."""
        return _increment(motion, integration, True)[1], self.covariance(motion, drive)

    def linear_basis(self) -> tuple[DistanceNoise, FloatArray]:
        """The variances are linear in ``(k_s, k_theta, k_theta_s)``."""
        return _unit_basis(self)


def _unit_basis(noise: _N) -> tuple[_N, FloatArray]:
    """A noise linear in its parameters: the model at the unit parameter sets, and the
    parameters as the weights."""
    names = noise.noise_parameters
    eye = np.eye(len(names))
    weights = np.stack(np.broadcast_arrays(*(getattr(noise, k) for k in names)), axis=-1)
    return noise.replace(**{k: eye[i] for i, k in enumerate(names)}), weights


@dataclasses.dataclass(frozen=True)
class AlphaNoise(Model):
    """The α-model on ``(δrot1, δtrans, δrot2)`` (Thrun et al., Probabilistic Robotics, 5.4)."""

    a1: float | FloatArray = 0.0
    a2: float | FloatArray = 0.0
    a3: float | FloatArray = 0.0
    a4: float | FloatArray = 0.0
    noise_parameters: ClassVar[tuple[str, ...]] = ("a1", "a2", "a3", "a4")

    def __post_init__(self) -> None:
        for name in self.noise_parameters:
            object.__setattr__(self, name, positive(getattr(self, name), name))

    def sources(
        self, motion: FloatArray, integration: Integration, drive: DiffDrive | None
    ) -> tuple[FloatArray, FloatArray]:
        """``(J_w, Q_w)`` on ``w = (δrot1, δtrans, δrot2)``, ``δrot1 = δrot2 = Δθ/2`` and
        ``δtrans = Δs``: ``Δ = (δtrans cos δrot1, δtrans sin δrot1, δrot1 + δrot2)``
        (midpoint integration only)."""
        if integration is not Integration.MIDPOINT:
            raise ParameterError("the α-model is defined for midpoint (rot-trans-rot) steps")
        ds, dt = motion[..., 0], motion[..., 1]
        rot = dt / 2
        v_rot = self.a1 * rot**2 + self.a2 * ds**2
        v_trans = self.a3 * ds**2 + self.a4 * 2 * rot**2
        c, s = np.cos(rot), np.sin(rot)
        J = matrix([[-ds * s, c, 0.0], [ds * c, s, 0.0], [1.0, 0.0, 1.0]], ds.shape)
        zero = np.zeros(np.broadcast_shapes(np.shape(v_rot), np.shape(v_trans)))
        Q = matrix([[v_rot, zero, zero], [zero, v_trans, zero], [zero, zero, v_rot]], zero.shape)
        return J, Q

    def linear_basis(self) -> tuple[AlphaNoise, FloatArray]:
        """The variances are linear in ``(a1, a2, a3, a4)``."""
        return _unit_basis(self)


Noise = WheelNoise | DistanceNoise | AlphaNoise


# ------------------------------------------------------------------ the motion model
@dataclasses.dataclass(frozen=True)
class Odometry(RelativeMotion):
    """Odometry as a filter's motion model: ``x⁻ = x ⊕ Δ(u)``, the pose compounded with the
    step's AT (Eqs. 1-4; lecture Eqs. 10-13).

    The input ``u`` is ``(Δs, Δθ)`` (..., 2), or wheel increments ``(Δφl, Δφr)`` with a
    :class:`DiffDrive`; ``noise`` says how the step's noise enters (its sources w, with
    ``Q = G Q_w Gᵀ`` and ``G = ∂(x ⊕ Δ)/∂Δ · ∂Δ/∂w``). The noise model's parameters are this
    model's (``noise_parameters``, :meth:`replace`).
    """

    noise: Noise
    integration: Integration = Integration.MIDPOINT
    drive: DiffDrive | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "integration", Integration.parse(self.integration, "integration"))

    @property
    def noise_parameters(self) -> tuple[str, ...]:  # type: ignore[override]
        return self.noise.noise_parameters

    def __getattr__(self, name: str) -> object:  # the noise's parameters read as the model's
        noise = self.__dict__.get("noise")  # (absent while a copy or unpickling builds it)
        if noise is not None and name in type(noise).noise_parameters:
            return getattr(noise, name)
        raise AttributeError(name)

    def replace(self, **values: ArrayLike) -> Odometry:
        """The model with other noise parameters."""
        return dataclasses.replace(self, noise=self.noise.replace(**values))

    def batched(self, axes: int) -> Odometry:
        return dataclasses.replace(self, noise=self.noise.batched(axes))

    def linear_basis(self) -> tuple[Odometry, FloatArray] | None:
        """The noise model's (the step's covariance is linear in Q_w)."""
        basis = self.noise.linear_basis()
        if basis is None:
            return None
        return dataclasses.replace(self, noise=basis[0]), basis[1]

    def step(self, u: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(Δ, J_w, Q_w)``: the step ``(..., 3)`` in the robot frame, its Jacobian in its noise
        sources and their covariance (the step's covariance is ``J_w Q_w J_wᵀ``)."""
        m = _pairs(u, "motion")
        if self.drive is not None:
            m = self.drive.motion(m)
        delta = _increment(m, self.integration, False)
        J, Q = self.noise.sources(m, self.integration, self.drive)
        return delta, J, Q  # type: ignore[return-value]

    def increment(self, u: ArrayLike) -> AT:
        """The step as an AT in the robot frame (batch of the inputs' and the noise's axes)."""
        delta, J, Q = self.step(u)
        C = congruence(J, Q)
        return AT._trusted(np.broadcast_to(delta, (*C.shape[:-2], 3)), C)


def step(
    pose: AT,
    motion: ArrayLike,
    noise: Noise,
    *,
    integration: Integration | str = "midpoint",
    drive: DiffDrive | None = None,
) -> tuple[AT, FloatArray, FloatArray]:
    """One odometry step (lecture Eqs. 11-12): ``(new pose, Gx, Gu)``.

    ``pose`` is the robot's AT in the world, ``motion`` the step ``(Δs, Δθ)`` — or wheel
    increments ``(Δφl, Δφr)`` when ``drive`` is given, in which case ``Gu`` is ``∂g/∂(Δφl, Δφr)``
    (3×2) as in the lecture. ``Σ' = Gx Σ Gxᵀ + Gu Σu Guᵀ``.
    """
    model = Odometry(noise, Integration.parse(integration, "integration"), drive)
    m = _pairs(motion, "motion")
    new = compound(pose, model.increment(m))
    W = np.eye(2) if drive is None else drive.wheel_map()
    if drive is not None:
        m = m @ W.T
    delta, J = _increment(m, model.integration, True)
    _, Gx, K = se2.compose(pose.mean, delta, jacobians=True)
    return new, Gx, K @ J @ W


def dead_reckon(
    motions: ArrayLike,
    noise: Noise,
    *,
    start: AT | None = None,
    integration: Integration | str = "midpoint",
    drive: DiffDrive | None = None,
) -> AT:
    """Every pose of a run, with covariance: an AT batch ``(N + 1,)`` from the start pose.

    ``motions`` (N, 2) are steps ``(Δs, Δθ)``, or wheel increments when ``drive`` is given;
    ``start`` the initial AT (default: exactly the identity, as odometry starts, Σ₀ = 0).
    All N steps are compounded by one parallel scan (:func:`relmap.compound_chain`).
    """
    m = _pairs(motions, "motions")
    if m.ndim != 2:
        raise ShapeError(f"motions must have shape (N, 2); got {m.shape}")
    start = AT.identity() if start is None else start
    steps = Odometry(noise, Integration.parse(integration, "integration"), drive).increment(m)
    check_result("dead reckoning (the steps' covariance)", steps.mean, steps.cov)
    n = len(m)
    mean = components_outermost(np.empty((n + 1, 3)), 1)
    cov = components_outermost(np.empty((n + 1, 3, 3)), 2)
    mean[0], mean[1:] = start.mean, steps.mean
    cov[0], cov[1:] = start.cov, steps.cov
    return compound_chain(AT._trusted(mean, cov))


def increments_from_velocities(t: ArrayLike, v: ArrayLike, w: ArrayLike) -> FloatArray:
    """Steps ``(Δs, Δθ)`` (N-1, 2) from logged velocities: each sample ``(v, ω)`` held over
    ``dt`` until the next time stamp (s, m/s, rad/s). Time must not go backwards."""
    t, v, w = real_array(t, "t"), real_array(v, "v"), real_array(w, "ω")
    if t.ndim != 1 or v.shape != t.shape or w.shape != t.shape:
        raise ShapeError(
            f"t, v and ω must be 1-D of one length; got {t.shape}, {v.shape}, {w.shape}"
        )
    for arr, name in ((t, "t"), (v, "v"), (w, "ω")):
        check_finite(arr, name)
    dt = np.diff(t)
    if (dt < 0).any():
        k = int(np.flatnonzero(dt < 0)[0])
        raise ParameterError(f"time goes backwards at sample {k + 1}: {t[k]} → {t[k + 1]}")
    out = np.column_stack([v[:-1] * dt, w[:-1] * dt])
    check_result("increments_from_velocities (v·dt, ω·dt)", out)
    return out
