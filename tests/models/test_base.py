"""relmap.models.base: the motion and measurement protocols — a user's model written in a few
lines gets numeric Jacobians (central differences in its charts) equal to the analytic ones
written out here; the chart of readings with angles; parameters and batches of them."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np
import pytest

from relmap.errors import ParameterError
from relmap.lie import se2
from relmap.models.base import (
    Measurement,
    Motion,
    RelativeMotion,
    angles_chart,
    positive,
)
from relmap.uncertain.propagate import EUCLIDEAN, SE2, numerical_jacobian


# ------------------------------------------------------------------ a user's models
@dataclasses.dataclass(frozen=True)
class Compass(Measurement):
    """The heading read by a compass, σ ``sigma`` (rad): only ``h`` and ``noise`` written."""

    sigma: float
    noise_parameters: ClassVar[tuple[str, ...]] = ("sigma",)
    dim: ClassVar[int] = 1
    angles: ClassVar[tuple[int, ...]] = (0,)

    def h(self, x, landmark=None):
        return x[..., 2:3]

    def noise(self, z):
        return np.full((*np.shape(z)[:-1], 1, 1), self.sigma**2)


@dataclasses.dataclass(frozen=True)
class Beacon(Measurement):
    """Range and bearing of a landmark, no mount (Eq. 20): only ``h`` and ``noise`` written."""

    sigma: float
    noise_parameters: ClassVar[tuple[str, ...]] = ("sigma",)
    angles: ClassVar[tuple[int, ...]] = (1,)
    ranges: ClassVar[tuple[int, ...]] = (0,)
    landmark_dim: ClassVar[int] = 2

    def h(self, x, landmark=None):
        d = landmark - x[..., :2]
        phi = np.arctan2(d[..., 1], d[..., 0]) - x[..., 2]
        return np.stack([np.hypot(d[..., 0], d[..., 1]), se2.wrap_angle(phi)], axis=-1)

    def noise(self, z):
        return np.broadcast_to(self.sigma**2 * np.eye(2), (*np.shape(z)[:-1], 2, 2))


@dataclasses.dataclass(frozen=True)
class Unicycle(Motion):
    """``x⁻ = (x + v cos θ, y + v sin θ, θ + ω)`` for ``u = (v, ω)``: only ``f`` and the noise."""

    q: float

    def f(self, x, u):
        th = x[..., 2]
        return np.stack([x[..., 0] + u[..., 0] * np.cos(th), x[..., 1] + u[..., 0] * np.sin(th),
                         se2.wrap_angle(th + u[..., 1])], axis=-1)  # fmt: skip

    def input_noise(self, u):
        return np.broadcast_to(self.q * np.eye(2), (*np.shape(u)[:-1], 2, 2))


@dataclasses.dataclass(frozen=True)
class Straight(RelativeMotion):
    """A step straight ahead by ``u = (d,)`` with noise on its length and heading: only ``step``."""

    inputs: ClassVar[int] = 1

    def step(self, u):
        d = np.asarray(u, dtype=np.float64)[..., 0]
        delta = np.stack([d, np.zeros_like(d), np.zeros_like(d)], axis=-1)
        J = np.zeros((*d.shape, 3, 2))
        J[..., 0, 0] = 1.0
        J[..., 1, 1] = d / 2  # a heading error ε at the middle of the step moves it d ε / 2 ...
        J[..., 2, 1] = 1.0  # ... and turns the robot by ε
        return delta, J, np.broadcast_to(np.diag([0.01, 0.002]), (*d.shape, 2, 2))


def _poses(rng, n):
    # headings near ±π too: the charts must wrap there
    th = np.concatenate([rng.uniform(-np.pi, np.pi, n - 2), [np.pi - 1e-4, -np.pi + 1e-4]])
    return np.column_stack([rng.normal(size=(n, 2)) * 2, th])


def test_a_measurement_models_numeric_jacobians(rng):
    """``jacobians`` and ``linearize`` of a model that writes only ``h``: central differences
    in relmap's chart of the pose and the readings' chart (angles wrapped), equal to Eq. 20's
    Jacobians written out; a reading of the state alone (no landmark) too."""
    x = _poses(rng, 8)
    lm = rng.normal(size=(8, 2)) * 5
    beacon = Beacon(0.1)
    H, H_l = beacon.jacobians(x, lm)
    d = lm - x[:, :2]
    q = (d * d).sum(axis=-1)
    r = np.sqrt(q)
    dx, dy = d[:, 0], d[:, 1]
    H_l_want = np.stack([np.stack([dx / r, dy / r], -1), np.stack([-dy / q, dx / q], -1)], -2)
    H_want = np.concatenate([-H_l_want, np.stack([np.zeros(8), -np.ones(8)], -1)[..., None]], -1)
    np.testing.assert_allclose(H, H_want, atol=1e-8)
    np.testing.assert_allclose(H_l, H_l_want, atol=1e-8)
    z, H2, H_l2 = beacon.linearize(x, lm)
    np.testing.assert_array_equal(z, beacon.h(x, lm))
    np.testing.assert_array_equal(H2, H)
    np.testing.assert_array_equal(H_l2, H_l)
    Hc, none = Compass(0.01).jacobians(x)
    assert none is None
    np.testing.assert_allclose(Hc, np.broadcast_to([[0.0, 0.0, 1.0]], (8, 1, 3)), atol=1e-9)


def test_a_measurement_models_defaults():
    """The defaults a model inherits: ``usable`` = finite, ``innovation`` = ``z ⊖ ẑ`` with the
    ``angles`` wrapped, its reading chart that of :func:`angles_chart`."""
    beacon = Beacon(0.1)
    np.testing.assert_array_equal(
        beacon.usable(np.array([[1.0, 0.0], [np.nan, 0.0], [1.0, -np.inf]])), [True, False, False]
    )
    np.testing.assert_allclose(beacon.innovation([2.0, -3.0], np.array([1.5, 3.0])),
                               [0.5, 2 * np.pi - 6.0], atol=1e-15)  # fmt: skip
    np.testing.assert_allclose(Compass(0.1).innovation([3.1], np.array([-3.1])),
                               [6.2 - 2 * np.pi], atol=1e-15)  # fmt: skip


def test_a_motion_models_numeric_jacobians(rng):
    """``jacobians`` of a model that writes only ``f``: F = ∂f/∂x (relmap's chart in and out)
    and G = ∂f/∂u, equal to the unicycle's written out."""
    x = _poses(rng, 6)
    u = rng.normal(size=(6, 2)) * [0.5, 0.3]
    F, G = Unicycle(0.01).jacobians(x, u)
    c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
    F_want = np.broadcast_to(np.eye(3), (6, 3, 3)).copy()
    F_want[:, 0, 2], F_want[:, 1, 2] = -u[:, 0] * s, u[:, 0] * c
    G_want = np.zeros((6, 3, 2))
    G_want[:, 0, 0], G_want[:, 1, 0], G_want[:, 2, 1] = c, s, 1.0
    np.testing.assert_allclose(F, F_want, atol=1e-8)
    np.testing.assert_allclose(G, G_want, atol=1e-8)
    np.testing.assert_array_equal(Unicycle(0.01).input_noise(u), np.broadcast_to(0.01 * np.eye(2),
                                  (6, 2, 2)))  # fmt: skip


def test_a_relative_motion_is_the_compound_with_its_step(rng):
    """A model that writes only ``step``: ``f = x ⊕ Δ`` (Eqs. 1-2), its ``jacobians`` Eq. 3's
    ``∂(x ⊕ Δ)/∂x`` and ``∂(x ⊕ Δ)/∂Δ · J_w`` — the numeric Jacobians of ``x ⊕ Δ(w)`` in the
    noise sources, the step's own J_w (here written by hand) checked numerically first."""
    x = _poses(rng, 5)
    u = rng.uniform(0.1, 2.0, (5, 1))
    model = Straight()
    delta, J, Q = model.step(u)

    def moved(w):  # the step with its length d + w₀ and a heading error w₁ at its middle
        d = u[:, 0].reshape(-1, *(1,) * (w.ndim - 2)) + w[..., 0]
        return np.stack([d * np.cos(w[..., 1] / 2), d * np.sin(w[..., 1] / 2), w[..., 1]], -1)

    np.testing.assert_allclose(J, numerical_jacobian(moved, np.zeros((5, 2))), atol=1e-8)
    np.testing.assert_allclose(model.f(x, u), se2.compose(x, delta), atol=1e-15)
    F, G = model.jacobians(x, u)
    np.testing.assert_allclose(
        F,
        numerical_jacobian(
            lambda xx: se2.compose(xx, delta[:, None]), x, chart_in=SE2, chart_out=SE2
        ),
        atol=1e-8,
    )
    np.testing.assert_allclose(G, numerical_jacobian(lambda w: se2.compose(x[:, None], moved(w)),
                                                        np.zeros((5, 2)), chart_out=SE2),
                               atol=1e-8)  # fmt: skip
    np.testing.assert_array_equal(model.input_noise(u), Q)


# --------------------------------------------------------------------------- charts
def test_angles_chart_wraps_only_the_angles():
    chart = angles_chart((1, 3))
    a = np.array([10.0, 3.1, -7.0, -3.1])
    b = np.array([-10.0, -3.1, 7.0, 3.1])
    np.testing.assert_allclose(chart.minus(a, b), [20.0, 6.2 - 2 * np.pi, -14.0, 2 * np.pi - 6.2],
                               atol=1e-15)  # fmt: skip
    moved = chart.plus(a, np.array([1.0, 0.1, 1.0, -0.1]))
    np.testing.assert_allclose(moved, [11.0, 3.2 - 2 * np.pi, -6.0, 2 * np.pi - 3.2], atol=1e-15)
    # plus and minus undo each other (steps below π)
    d = np.array([0.3, -2.5, 5.0, 3.0])
    np.testing.assert_allclose(chart.minus(chart.plus(a, d), a), d, atol=1e-14)
    before = a.copy()
    chart.plus(a, d)
    chart.minus(a, b)
    np.testing.assert_array_equal(a, before)  # the caller's arrays stay as they were
    # batches; no angles: plain vectors
    np.testing.assert_allclose(chart.minus(np.stack([a, b]), b)[0], chart.minus(a, b))
    assert angles_chart(()) is EUCLIDEAN


# ----------------------------------------------------------------------- parameters
def test_parameters_and_batches_of_them():
    """``noise_parameters`` name the positive parameters; ``replace`` checks them as the
    constructor does; ``batch_shape`` is their broadcast shape; ``batched`` gives each array
    parameter trailing axes for the inputs'."""
    from relmap.models import RangeBearingSensor

    one = RangeBearingSensor(0.1, 0.02)
    assert one.noise_parameters == ("sigma_range", "sigma_bearing") and one.batch_shape == ()
    assert one.batched(2) is one  # no array parameter: nothing to reshape
    many = one.replace(sigma_range=np.array([[0.1], [0.2]]), sigma_bearing=np.full(3, 0.02))
    assert many.batch_shape == (2, 3)
    assert np.shape(many.batched(2).sigma_range) == (2, 1, 1, 1)
    assert np.shape(many.batched(2).sigma_bearing) == (3, 1, 1)
    assert many.batched(2).batch_shape == (2, 3, 1, 1)
    z = np.array([[2.0, 0.1], [3.0, 0.2], [4.0, 0.3], [5.0, 0.4]])  # 4 readings
    R = many.batched(1).noise(z)
    assert R.shape == (2, 3, 4, 2, 2)
    np.testing.assert_allclose(R[1, 2, 3], np.diag([0.04, 0.0004]), rtol=1e-15)
    assert not any(f.name == "dim" for f in dataclasses.fields(one))  # class facts, not fields
    with pytest.raises(ParameterError, match="sigma_bearing"):
        one.replace(sigma_bearing=-0.1)
    with pytest.raises(TypeError):
        one.replace(sigma=0.1)


def test_positive():
    assert positive(0.0, "s") == 0.0 and isinstance(positive(2, "s"), float)
    np.testing.assert_array_equal(positive([1.0, 2.0], "s"), [1.0, 2.0])
    for bad in (-1.0, np.nan, np.inf, [1.0, -2.0]):
        with pytest.raises(ParameterError, match="s must be finite and non-negative"):
            positive(bad, "s")
    with pytest.raises(ParameterError, match="positive"):
        positive(0.0, "s", strict=True)
    for bad in (True, "x", [[1.0], [2.0, 3.0]]):
        with pytest.raises(ParameterError, match="s must be a number"):
            positive(bad, "s")
    with pytest.raises(ParameterError, match="s must be"):
        positive(None, "s")
