"""The pose groups as values: what generic code (Monte Carlo, relational maps, numeric
Jacobians) needs to know about SE(2) or SE(3), so one code path serves both.

A :class:`Group` bundles a group module's functions with the shapes of its points and tangent
vectors. Points are ``(..., 3)`` vectors ``(x, y, θ)`` for :data:`SE2` and ``(..., 4, 4)``
homogeneous matrices for :data:`SE3`; tangent vectors (the covariance chart) are ``(..., dof)``.

**Interpolation** (:meth:`Group.interpolate`, :meth:`Group.at_times`) is the straight line in the
covariance chart, ``a ⊞ f·(b ⊟ a)``: the translation linearly, the rotation along the shorter arc
at a constant rate (SE(2): the heading, wrapped; SE(3): ``Exp(f·Log(R_b R_aᵀ)) R_a``, which is
slerp). That is how ``tf2`` and evo interpolate poses; it is not the group's geodesic
``a·Exp(f·Log(a⁻¹b))``, which moves the translation along a screw.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from relmap.lie import se2, se3
from relmap.typing import ArrayLike, FloatArray

__all__ = ["SE2", "SE3", "Group"]


class Group(NamedTuple):
    """A pose group: ``compose``/``inverse``/``between`` (with ``jacobians=True`` as in the group
    modules), the covariance chart's ``plus(x, δ)``/``minus(y, x)``, and ``identity(batch)``."""

    name: str
    dof: int
    point_shape: tuple[int, ...]
    compose: Callable[..., Any]
    inverse: Callable[..., Any]
    between: Callable[..., Any]
    plus: Callable[[FloatArray, FloatArray], FloatArray]
    minus: Callable[[FloatArray, FloatArray], FloatArray]
    identity: Callable[[tuple[int, ...]], FloatArray]

    @property
    def point_ndim(self) -> int:
        """Trailing axes of one point: 1 for SE(2) vectors, 2 for SE(3) matrices."""
        return len(self.point_shape)

    def batch_shape(self, points: FloatArray) -> tuple[int, ...]:
        """The leading (batch) axes of an array of points."""
        return np.shape(points)[: np.ndim(points) - self.point_ndim]

    def interpolate(self, a: FloatArray, b: FloatArray, f: ArrayLike) -> FloatArray:
        """The pose a fraction ``f`` (``(...)``; 0 gives ``a``, 1 gives ``b``) of the way from
        ``a`` to ``b``: ``a ⊞ f·(b ⊟ a)`` (module docstring); batch axes broadcast."""
        fraction = np.asarray(f, dtype=np.float64)[..., None]
        return self.plus(a, fraction * self.minus(b, a))

    def at_times(self, times: ArrayLike, points: FloatArray, t: ArrayLike) -> FloatArray:
        """A sampled path at times ``t`` (``(...)``): ``points`` ``(n, *point_shape)`` at
        ``times`` ``(n,)`` (non-decreasing), interpolated (:meth:`interpolate`) between the last
        sample at or before each time and the next one. ``t`` must lie within the samples' span
        (the caller checks; outside it, the nearest end's segment is extended); a time equal to
        repeated sample times takes the last of them; one sample is a constant path."""
        times = np.asarray(times, dtype=np.float64)
        t = np.asarray(t, dtype=np.float64)
        points = np.asarray(points, dtype=np.float64)
        n = len(times)
        i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, max(n - 2, 0))
        j = np.minimum(i + 1, n - 1)
        span = times[j] - times[i]
        f = np.divide(t - times[i], span, out=np.zeros_like(t), where=span > 0)
        return self.interpolate(points[i], points[j], f)

    def __repr__(self) -> str:
        return self.name


SE2 = Group(
    "SE(2)", se2.DOF, (3,), se2.compose, se2.inverse, se2.between, se2.plus, se2.minus, se2.identity
)
SE3 = Group(
    "SE(3)",
    se3.DOF,
    (4, 4),
    se3.compose,
    se3.inverse,
    se3.between,
    se3.plus,
    se3.minus,
    se3.identity,
)
