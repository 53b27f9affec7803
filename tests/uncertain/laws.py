"""One decorator for the group laws: a law runs over {AT, AT3} × batch shapes (jaxlie's habit).

``@law`` parametrizes a test ``f(kind, shape, data)`` over :data:`KINDS` × :data:`SHAPES` and
gives it hypothesis's ``data``; the kind draws its ATs (:meth:`Kind.ats`, :meth:`Kind.near`)
and compares them (:meth:`Kind.assert_same`), so each law is written once for both. Rotations
come from the whole circle (SE(2): the heading; SE(3): an angle about a random axis) with
explicit samples at and next to ±π.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import relmap as rm
from relmap.lie import so3
from relmap.lie.group import SE2, SE3, Group

#: The batch shapes every law runs over.
SHAPES = [(), (1,), (3, 1, 2, 1)]
EDGE_ANGLES = [np.pi - 1e-12, -np.pi, -np.pi + 1e-12, 0.0, np.pi / 2, 3.0]
ANGLES = st.one_of(st.floats(-np.pi, np.pi, exclude_max=True), st.sampled_from(EDGE_ANGLES))
COORDS = st.floats(-10.0, 10.0)
# Covariance factors: zero or at least 1e-4 in size (variances ≥ 1e-8). Far smaller entries
# only probe float underflow (subnormal variances such as 1e-316), not relmap's algebra.
FACTOR = st.one_of(st.just(0.0), st.floats(1e-4, 0.3), st.floats(-0.3, -1e-4))
#: Examples per (kind, shape): the profile's count spread over the six cases, so that a law
#: costs about what it cost when it drew its shape at random (at least 10 each).
EXAMPLES = max(10, settings().max_examples // 6)


class Kind(NamedTuple):
    """An uncertain pose kind as the laws see it."""

    name: str
    cls: type
    group: Group
    rotation: slice  #: the rotation's components in the chart (tangent vectors)
    #: How far apart (each chart component, ±) the means of the merge laws' ATs are drawn.
    #: AT3's merge iterates to a common pose and stops after 50 iterations: at ±1 about 11% of
    #: random triples (correlated covariances) have not converged there and their merge
    #: depends on the order (by up to 1.9 rad); at ±0.3, none of 500.
    merge_spread: float

    def make(self, mean: np.ndarray, cov: np.ndarray | None = None) -> Any:
        """The AT of points ``mean`` of the group (checked by the public constructors)."""
        if self.cls is rm.AT:
            return rm.AT(mean, cov)
        return rm.AT3.from_matrix(mean, cov)

    def means(self, draw: Callable, shape: tuple[int, ...]) -> np.ndarray:
        """Random points ``(*shape, *point)``: translations in ±10 m, rotations by
        :data:`ANGLES` (SE(3): about a random axis)."""
        angle = draw(hnp.arrays(np.float64, shape, elements=ANGLES))
        if self.cls is rm.AT:
            xy = draw(hnp.arrays(np.float64, (*shape, 2), elements=COORDS))
            return np.concatenate([xy, angle[..., None]], axis=-1)
        t = draw(hnp.arrays(np.float64, (*shape, 3), elements=COORDS))
        axis = draw(hnp.arrays(np.float64, (*shape, 3), elements=st.floats(-1.0, 1.0)))
        norm = np.linalg.norm(axis, axis=-1, keepdims=True)
        axis = np.where(norm > 1e-3, axis / np.maximum(norm, 1e-3), [1.0, 0.0, 0.0])
        T = np.zeros((*shape, 4, 4))
        T[..., :3, :3], T[..., :3, 3], T[..., 3, 3] = so3.exp(angle[..., None] * axis), t, 1.0
        return T

    def covs(self, draw: Callable, shape: tuple[int, ...], floor: float = 0.0) -> np.ndarray:
        """Random covariances ``L Lᵀ + floor·I`` (L's entries :data:`FACTOR`): singular ones
        (exactly known directions) too unless ``floor`` > 0."""
        n = self.group.dof
        L = draw(hnp.arrays(np.float64, (*shape, n, n), elements=FACTOR))
        return L @ np.swapaxes(L, -1, -2) + floor * np.eye(n)

    def ats(self, draw: Callable, shape: tuple[int, ...]) -> Any:
        """Random ATs of batch ``shape``."""
        return self.make(self.means(draw, shape), self.covs(draw, shape))

    def near(self, draw: Callable, a: Any, floor: float = 1e-3, spread: float = 1.0) -> Any:
        """An AT of the same relation as ``a`` (each chart component within ±``spread`` of
        it), with a well-conditioned covariance (eigenvalues ≥ ``floor``): exactly known
        components have their own tests."""
        shape = a.batch_shape
        within = st.floats(-spread, spread)
        offset = draw(hnp.arrays(np.float64, (*shape, self.group.dof), elements=within))
        return self.make(self.group.plus(a.mean, offset), self.covs(draw, shape, floor))

    def assert_same(self, a: Any, b: Any, atol: float = 1e-11, rtol: float = 1e-9) -> None:
        """Means equal to ``atol`` in the chart (``b ⊟ a``: metres and radians, angles
        wrapped); covariances to ``rtol`` of the larger's largest entry (or 1e-15)."""
        gap = np.abs(self.group.minus(b.mean, a.mean)).max(axis=-1)
        assert np.all(gap <= atol), gap.max()
        assert_close_cov(a.cov, b.cov, rtol)

    def assert_valid(self, a: Any) -> None:
        """The mean is a point of the group: a heading in [-π, π), or a rotation matrix."""
        if self.cls is rm.AT:
            assert np.all(a.mean[..., 2] >= -np.pi) and np.all(a.mean[..., 2] < np.pi)
        else:
            R = a.mean[..., :3, :3]
            np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.eye(3) + 0 * R, atol=1e-12)
            np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)

    def excursion(self, *ats: Any) -> np.ndarray:
        """How far the merge of ``ats`` turns from the first's rotation (rad), computed as plain
        linear Kalman algebra in the chart at the first (nothing wrapped): where the merge
        really goes."""
        ref = ats[0].mean
        x, C = np.zeros((*ats[0].batch_shape, self.group.dof)), ats[0].cov
        for b in ats[1:]:
            K = C @ np.linalg.pinv(C + b.cov, hermitian=True)
            x = x + np.einsum("...ij,...j->...i", K, self.group.minus(b.mean, ref) - x)
            C = C - K @ C
        return np.linalg.norm(x[..., self.rotation], axis=-1)


KINDS = [Kind("AT", rm.AT, SE2, slice(2, 3), 1.0), Kind("AT3", rm.AT3, SE3, slice(3, 6), 0.3)]


def assert_close_cov(a: np.ndarray, b: np.ndarray, rtol: float = 1e-9) -> None:
    """Equal to ``rtol`` relative to the larger matrix's largest entry (or 1e-15 absolute)."""
    scale = np.maximum(np.abs(a).max(axis=(-2, -1)), np.abs(b).max(axis=(-2, -1)))
    err = np.abs(a - b).max(axis=(-2, -1))
    assert np.all(err <= rtol * scale + 1e-15), (err, scale)


def law(f: Callable[..., None]) -> Callable[..., None]:
    """Run the law ``f(kind, shape, data)`` for every kind of :data:`KINDS` and batch shape of
    :data:`SHAPES`, :data:`EXAMPLES` hypothesis examples each."""
    test = settings(max_examples=EXAMPLES)(given(data=st.data())(f))
    test = pytest.mark.parametrize("shape", SHAPES, ids=lambda s: f"shape{s}")(test)
    return pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.name)(test)
