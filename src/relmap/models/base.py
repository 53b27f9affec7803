"""The two protocols every estimator of relmap takes: motion models and measurement models.

A **motion model** moves a state by an input ``u`` (lecture Eq. 13): ``x⁻ = f(x, u)``, with noise
``Qu`` on the input, so that to first order ``P⁻ = F P Fᵀ + G Qu Gᵀ`` with ``F = ∂f/∂x`` and
``G = ∂f/∂u``. A **measurement model** predicts a reading ``z = h(x, l) + v``, ``v ~ N(0, R)``,
of the state alone (a position fix, a full pose) or of a landmark ``l`` (range-bearing, Eq. 20),
with ``H = ∂h/∂x`` and, for landmarks, ``∂h/∂l``. Each model states its mathematics once: the
prediction, its Jacobians (analytic where the model writes them, else central differences in
the model's charts, :func:`relmap.uncertain.propagate.numerical_jacobian`), its noise, which
components are angles, and its dimensions. The filter (:mod:`relmap.filter`), its runner over
logs and the autocalibration of its noise take any model through these bases, a user's too:
a subclass writes ``f`` (or ``h``) and its noise, and may write the Jacobians.

**Parameters, and batches of them.** A model's numbers (σ, odometry rates) are floats or arrays
of one batch shape: a batch of parameter sets is a batch of filters. ``noise_parameters`` names
the positive ones autocalibration may fit (on a log scale); :meth:`Model.replace` returns the
model with other values, :meth:`Model.batched` with its parameters shaped for inputs that carry
extra axes after the batch's.

**Charts.** States are vectors ``(..., n)`` in a :class:`relmap.uncertain.propagate.Chart`
(relmap's SE(2) chart for a pose: ``(x, y, θ)``, heading wrapped); readings are vectors
``(..., d)`` whose ``angles`` components are wrapped in differences (innovations).
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar, TypeVar

import numpy as np

from relmap.errors import ParameterError
from relmap.lie import se2
from relmap.typing import ArrayLike, FloatArray
from relmap.uncertain.propagate import EUCLIDEAN, SE2, Chart, numerical_jacobian

__all__ = ["Measurement", "Model", "Motion", "RelativeMotion", "angles_chart", "positive"]

_M = TypeVar("_M", bound="Model")


def positive(value: ArrayLike, name: str, *, strict: bool = False) -> float | FloatArray:
    """A model parameter: a float or an array of a batch of them, finite and non-negative
    (``strict``: positive), else a :class:`relmap.errors.ParameterError` naming it."""
    if isinstance(value, (bool, np.bool_)):
        raise ParameterError(f"{name} must be a number; got {value!r}")
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(
            f"{name} must be a number or an array of numbers; got {value!r}"
        ) from None
    bad = ~np.isfinite(a) | ((a <= 0) if strict else (a < 0))
    if bad.any():
        what = "positive" if strict else "non-negative"
        raise ParameterError(f"{name} must be finite and {what}; got {a[bad].flat[0]}")
    return float(a) if a.ndim == 0 else a


def angles_chart(angles: tuple[int, ...]) -> Chart:
    """The chart of vectors whose ``angles`` components are wrapped to [-π, π) (the others
    plain): ``plus(x, δ) = x + δ`` and ``minus(a, b) = a - b``, angles wrapped."""
    if not angles:
        return EUCLIDEAN
    consecutive = list(angles) == list(range(angles[0], angles[-1] + 1))
    index = slice(angles[0], angles[-1] + 1) if consecutive else list(angles)

    def wrap(v: FloatArray) -> FloatArray:
        v = np.array(v, dtype=np.float64)  # (a copy: the caller's array stays as it was)
        v[..., index] = se2.wrap_angle(v[..., index])
        return v

    return Chart(lambda x, d: wrap(np.add(x, d)), lambda a, b: wrap(np.subtract(a, b)))


@dataclasses.dataclass(frozen=True)
class Model:
    """The base of motion and measurement models: parameters, batches of them."""

    #: The parameters autocalibration may fit: positive numbers, attributes of the model.
    noise_parameters: ClassVar[tuple[str, ...]] = ()

    def replace(self: _M, **values: ArrayLike) -> _M:
        """The model with other parameter values (checked as the constructor checks them)."""
        return dataclasses.replace(self, **values)

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """The broadcast shape of the noise parameters: the batch of filters they describe."""
        return np.broadcast_shapes(*(np.shape(getattr(self, k)) for k in self.noise_parameters))

    def linear_basis(self: _M) -> tuple[_M, FloatArray] | None:
        """``(basis, weights)`` when the model's noise covariance is linear in (functions of)
        its noise parameters — ``Q(θ) = Σ_p w_p(θ) Q(basis_p)`` — else None: the model at the
        basis's P parameter sets (parameters of shape (P,)) and the weights (*batch, P)."""
        return None

    def batched(self: _M, axes: int) -> _M:
        """The model with each array parameter given ``axes`` trailing length-1 axes: for inputs
        shaped ``(*batch, k₁, …, k_axes, ...)`` (say, a batch of filters × their readings)."""
        values = {
            k: np.reshape(v, (*np.shape(v), *(1,) * axes))
            for k in self.noise_parameters
            if np.ndim(v := getattr(self, k))
        }
        return dataclasses.replace(self, **values) if values else self


@dataclasses.dataclass(frozen=True)
class Motion(Model):
    """``x⁻ = f(x, u)`` with input noise ``Qu(u)`` (lecture Eq. 13).

    A subclass writes :meth:`f` and :meth:`input_noise` (and may write :meth:`jacobians`);
    ``chart`` is the chart of the state it moves, ``inputs`` the input's dimension k.
    """

    chart: ClassVar[Chart] = SE2
    inputs: ClassVar[int] = 2

    def f(self, x: FloatArray, u: FloatArray) -> FloatArray:
        """The moved state ``(..., n)`` of ``x`` ``(..., n)`` under input ``u`` ``(..., k)``."""
        raise NotImplementedError

    def input_noise(self, u: FloatArray) -> FloatArray:
        """``Qu`` ``(..., k, k)``: the input's covariance."""
        raise NotImplementedError

    def jacobians(self, x: FloatArray, u: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``F = ∂f/∂x`` ``(..., n, n)`` and ``G = ∂f/∂u`` ``(..., n, k)`` in the state's chart
        (numeric unless a subclass writes them)."""
        # the helper perturbs along a new axis before the point's: the other input follows it
        F = numerical_jacobian(
            lambda xx: self.f(xx, u[..., None, :]), x, chart_in=self.chart, chart_out=self.chart
        )
        G = numerical_jacobian(lambda uu: self.f(x[..., None, :], uu), u, chart_out=self.chart)
        return F, G

    def linearize(
        self, x: FloatArray, u: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(f, F, G, Qu)`` at once (a model that computes them from shared pieces writes
        this)."""
        F, G = self.jacobians(x, u)
        return self.f(x, u), F, G, self.input_noise(u)


@dataclasses.dataclass(frozen=True)
class RelativeMotion(Motion):
    """A motion by a relative step of the pose: ``x⁻ = x ⊕ Δ(u)`` — the paper's compounding
    (Eqs. 1-4) with the step's AT, in SE(2) — whose noise enters through the step: ``Δ``'s
    covariance is ``J_w Q_w J_wᵀ`` for its noise sources ``w ~ N(0, Q_w)``.

    A subclass writes :meth:`step` (and :meth:`Model.linear_basis` when ``Q_w`` is linear in
    its noise parameters: the runner then composes a log's steps once for all parameter sets).
    Steps compound without the state, so a filter may compose the steps between two readings
    before it meets them (:mod:`relmap.filter.segments`).
    """

    def step(self, u: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(Δ, J_w, Q_w)``: the step ``(..., 3)`` in the robot frame, its Jacobian
        ``(..., 3, k)`` in its noise sources and their covariance ``(..., k, k)``."""
        raise NotImplementedError

    def f(self, x: FloatArray, u: FloatArray) -> FloatArray:
        """``x ⊕ Δ(u)``."""
        return se2.compose(x, self.step(u)[0])

    def input_noise(self, u: FloatArray) -> FloatArray:
        """``Q_w``: the covariance of the step's noise sources."""
        return self.step(u)[2]

    def jacobians(self, x: FloatArray, u: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``F = ∂(x ⊕ Δ)/∂x`` and ``G = ∂(x ⊕ Δ)/∂Δ · J_w`` (Eq. 3's H and K)."""
        return self.linearize(x, u)[1:3]

    def linearize(
        self, x: FloatArray, u: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(x ⊕ Δ, F, G, Q_w)`` from one step."""
        delta, J, Q = self.step(u)
        moved, F, K = se2.compose(x, delta, jacobians=True)
        return moved, F, K @ J, Q


@dataclasses.dataclass(frozen=True)
class Measurement(Model):
    """``z = h(x, l) + v`` with ``v ~ N(0, R)`` (the lecture's Eq. 20 for range-bearing).

    A subclass writes :meth:`h` and :meth:`noise` (and may write :meth:`jacobians` and
    :meth:`usable`), and states ``dim`` (d, the reading's size), ``angles`` (the components of
    z that are angles), ``ranges`` (those that are distances), ``landmark_dim`` (p: the size
    of a landmark, 0 for a reading of the state alone) and ``state_chart`` (the chart of the
    state it reads).
    """

    dim: ClassVar[int] = 2
    angles: ClassVar[tuple[int, ...]] = ()
    ranges: ClassVar[tuple[int, ...]] = ()
    landmark_dim: ClassVar[int] = 0
    state_chart: ClassVar[Chart] = SE2

    def h(self, x: FloatArray, landmark: FloatArray | None = None) -> FloatArray:
        """The predicted reading ``(..., d)`` of state ``x`` ``(..., n)`` (and ``landmark``
        ``(..., p)``)."""
        raise NotImplementedError

    def noise(self, z: FloatArray) -> FloatArray:
        """``R`` ``(..., d, d)``: the noise of a reading at ``z`` ``(..., d)`` (the predicted
        reading: a range-dependent noise is taken at the predicted range)."""
        raise NotImplementedError

    def jacobians(
        self, x: FloatArray, landmark: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray | None]:
        """``H = ∂h/∂x`` ``(..., d, n)`` in the state's chart and ``∂h/∂l`` ``(..., d, p)``
        (None without a landmark); numeric unless a subclass writes them."""
        out = self.reading_chart
        if landmark is None:
            return numerical_jacobian(self.h, x, chart_in=self.state_chart, chart_out=out), None
        lm = np.asarray(landmark, dtype=np.float64)
        H = numerical_jacobian(
            lambda xx: self.h(xx, lm[..., None, :]), x, chart_in=self.state_chart, chart_out=out
        )
        H_l = numerical_jacobian(lambda ll: self.h(x[..., None, :], ll), lm, chart_out=out)
        return H, H_l

    def linearize(
        self, x: FloatArray, landmark: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        """``(z, H, ∂h/∂l)``: the prediction and its Jacobians at once (a model that computes
        them from shared pieces writes this)."""
        H, H_l = self.jacobians(x, landmark)
        return self.h(x, landmark), H, H_l

    def usable(self, z: FloatArray) -> np.ndarray:
        """Which readings ``(..., d)`` the model can use: finite (subclasses add, e.g., a
        positive range)."""
        return np.isfinite(z).all(axis=-1)

    @property
    def reading_chart(self) -> Chart:
        """The chart of readings: the ``angles`` components wrapped."""
        return angles_chart(self.angles)

    def innovation(self, z: ArrayLike, z_predicted: FloatArray) -> FloatArray:
        """``y = z ⊖ ẑ`` ``(..., d)``: the reading minus its prediction, angles wrapped."""
        return self.reading_chart.minus(np.asarray(z, dtype=np.float64), z_predicted)
