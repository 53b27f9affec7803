"""relmap.uncertain.algebra: one set of free functions (compound, reverse, merge, compound_chain)
for both kinds, dispatching on the kind (not isinstance); ``a @ b`` and ``a.reverse()`` are the
same operations; ``jacobians=True`` returns the reversal's Jacobian, checked against a numeric one.
"""

from __future__ import annotations

import numpy as np
import pytest

import relmap as rm
from relmap.errors import ArgumentTypeError, ParameterError, ShapeError
from relmap.uncertain.propagate import SE2, SE3, numerical_jacobian
from tests.helpers import random_at3s, random_ats


def _planar(rng: np.random.Generator, n: int) -> rm.AT:
    mean = np.column_stack([rng.normal(size=(n, 2)), rng.uniform(-3, 3, n)])
    return rm.AT.from_sigmas(mean, rng.uniform(0.01, 0.2, (n, 3)))


def test_free_functions_take_either_kind_and_refuse_a_mix(rng):
    a = _planar(rng, 2)
    q = rm.AT3.from_planar(a)
    # the planar AT3's operations are the AT's (the paper's chart is the AT3's in the plane)
    np.testing.assert_allclose(
        rm.compound(q[0], q[1]).cov[np.ix_([0, 1, 5], [0, 1, 5])],
        rm.compound(a[0], a[1]).cov,
        atol=1e-15,
    )
    np.testing.assert_allclose(
        rm.reverse(q).cov[:, [0, 1, 5]][:, :, [0, 1, 5]], rm.reverse(a).cov, atol=1e-15
    )
    np.testing.assert_allclose(
        rm.merge(q[0], q[1]).cov[np.ix_([0, 1, 5], [0, 1, 5])], rm.merge(a[0], a[1]).cov, atol=1e-15
    )
    np.testing.assert_allclose(
        rm.compound_chain(q).cov[:, [0, 1, 5]][:, :, [0, 1, 5]],
        rm.compound_chain(a).cov,
        atol=1e-15,
    )
    for call in (lambda: rm.compound(a[0], q[0]), lambda: rm.merge(q[0], a[0]),
                 lambda: rm.compound(1.0, a[0]), lambda: rm.reverse("a")):  # fmt: skip
        with pytest.raises(ArgumentTypeError):
            call()
    with pytest.raises(ParameterError, match="SE\\(2\\)"):
        rm.compound(q[0], q[1], moments="exact")
    with pytest.raises(ShapeError):
        rm.merge(q, rm.AT3.stack([q[0], q[0], q[0]]))


@pytest.mark.parametrize("kind", ["AT", "AT3"])
def test_the_operators_are_the_free_functions(kind):
    """``a @ b`` is ``compound(a, b)`` and ``a.reverse()`` is ``reverse(a)``, bit for bit."""
    x = random_ats(4, (5,)) if kind == "AT" else random_at3s(4, 5)
    a, b = x[:4], x[1:]
    for left, right in ((a @ b, rm.compound(a, b)), (a.reverse(), rm.reverse(a))):
        assert type(left) is type(right)
        np.testing.assert_array_equal(left.mean, right.mean)
        np.testing.assert_array_equal(left.cov, right.cov)
    assert a.__matmul__(np.eye(3)) is NotImplemented  # numpy defers: a TypeError, not a cast
    with pytest.raises(TypeError):
        a @ np.eye(3)  # type: ignore[operator]


@pytest.mark.parametrize("kind", ["AT", "AT3"])
def test_reverse_with_jacobians_returns_the_numeric_jacobian(kind):
    """The Jacobian ``reverse(a, jacobians=True)`` returns is the numeric Jacobian of the
    group's inverse in the covariance's chart (central differences, relmap.uncertain.propagate)."""
    x = random_ats(7, (3,)) if kind == "AT" else random_at3s(7, 3)
    r, J = rm.reverse(x, jacobians=True)
    assert J.shape == (3, x.group.dof, x.group.dof)
    np.testing.assert_array_equal(r.cov, rm.reverse(x).cov)
    chart = SE2 if kind == "AT" else SE3
    for i in range(3):
        numeric = numerical_jacobian(x.group.inverse, x.mean[i], chart_in=chart, chart_out=chart)
        np.testing.assert_allclose(J[i], numeric, atol=1e-7)
        np.testing.assert_allclose(r.cov[i], J[i] @ x.cov[i] @ J[i].T, rtol=1e-10, atol=1e-15)
