"""The pose groups as values: what generic code (Monte Carlo, relational maps, numeric
Jacobians) needs to know about SE(2) or SE(3), so one code path serves both.

A :class:`Group` bundles a group module's functions with the shapes of its points and tangent
vectors. Points are ``(..., 3)`` vectors ``(x, y, θ)`` for :data:`SE2` and ``(..., 4, 4)``
homogeneous matrices for :data:`SE3`; tangent vectors (the covariance chart) are ``(..., dof)``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from relmap.lie import se2, se3
from relmap.typing import FloatArray

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
