"""Algebraic laws of ⊕, ᴿ and ⊗ as property tests, each written once and run over {AT, AT3} ×
batch shapes (), (1,), (3, 1, 2, 1) by :func:`tests.uncertain.laws.law`.

Rotations are drawn from the whole circle with explicit samples at and next to ±π. Means are
compared in the chart (angles wrapped), covariances relative to their size.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume

import relmap as rm
from tests.uncertain.laws import law


@pytest.mark.slow
@law
def test_compound_is_associative(kind, shape, data):
    """(A ⊕ B) ⊕ C = A ⊕ (B ⊕ C): the means to rounding, and the first-order covariances too
    (each side's Jacobians are the chain rule's of one map, evaluated at the same means)."""
    a, b, c = (kind.ats(data.draw, shape) for _ in range(3))
    left, right = (a @ b) @ c, a @ (b @ c)
    kind.assert_same(left, right)
    kind.assert_valid(left)


@law
def test_identity_is_neutral(kind, shape, data):
    """A ⊕ I = I ⊕ A = A, covariance and all (I exactly known)."""
    a = kind.ats(data.draw, shape)
    identity = kind.cls.identity(shape)
    for result in (a @ identity, identity @ a):
        kind.assert_same(result, a, atol=1e-12, rtol=1e-12)


@law
def test_reverse_is_an_involution(kind, shape, data):
    a = kind.ats(data.draw, shape)
    kind.assert_same(a.reverse().reverse(), a)
    kind.assert_valid(a.reverse())


@law
def test_compound_with_reverse_is_identity_mean(kind, shape, data):
    a = kind.ats(data.draw, shape)
    zero = np.zeros((*shape, kind.group.dof))
    identity = kind.group.identity(shape)
    for result in (a @ a.reverse(), a.reverse() @ a):
        np.testing.assert_allclose(kind.group.minus(result.mean, identity), zero, atol=1e-11)


@pytest.mark.slow
@law
def test_reverse_distributes_over_compound(kind, shape, data):
    """(A ⊕ B)ᴿ = Bᴿ ⊕ Aᴿ, mean and first-order covariance."""
    a, b = kind.ats(data.draw, shape), kind.ats(data.draw, shape)
    kind.assert_same((a @ b).reverse(), b.reverse() @ a.reverse())


@pytest.mark.slow
@law
def test_merge_is_commutative_and_associative(kind, shape, data):
    """Order does not matter, as long as no partial merge swings a rotation past π.

    Strong correlations can extrapolate a merge far outside its inputs; a rotation moved by
    more than π wraps, and the innovations that follow then pick a different branch depending
    on the order. Realistic ATs stay far from this; the law is checked where every partial
    merge, computed without any wrapping, stays within 2 rad of the first AT's rotation.

    For AT3 the regrouping ``(A ⊗ B) ⊗ C`` is not the merge of all three: each merge fuses in
    the chart at its own common pose, and SE(3)'s rotation chart is curved, so regrouped merges
    agree only to second order in the inputs' spread; the order of the inputs of one merge
    (permutations, commutativity) does not matter for either kind.
    """
    spread = kind.merge_spread  # (AT3: see Kind.merge_spread)
    a = kind.near(data.draw, kind.ats(data.draw, shape), spread=spread)
    b, c = kind.near(data.draw, a, spread=spread), kind.near(data.draw, a, spread=spread)
    for group in ((a, b), (b, c), (c, a), (a, b, c)):
        assume(np.all(kind.excursion(*group) < 2.0))
    kind.assert_same(rm.merge(a, b), rm.merge(b, a), atol=1e-8, rtol=1e-8)
    abc = rm.merge(a, b, c)
    for other in (rm.merge(c, a, b), rm.merge(b, c, a)):
        kind.assert_same(other, abc, atol=1e-8, rtol=1e-8)
    if kind.cls is rm.AT:
        for other in (rm.merge(rm.merge(a, b), c), rm.merge(a, rm.merge(b, c)),
                      rm.merge(rm.merge(c, a), b)):  # fmt: skip
            kind.assert_same(other, abc, atol=1e-8, rtol=1e-8)
    kind.assert_valid(abc)


@law
def test_merge_with_an_exact_at_returns_it(kind, shape, data):
    """An exactly known AT outweighs any uncertain one: the merge is the exact AT, either order."""
    a = kind.ats(data.draw, shape)
    exact = kind.make(a.mean)
    b = kind.near(data.draw, a)
    for m in (rm.merge(exact, b), rm.merge(b, exact)):
        np.testing.assert_allclose(kind.group.minus(m.mean, exact.mean), 0.0, atol=1e-12)
        assert np.abs(m.cov).max() <= 1e-12


@pytest.mark.slow
@law
def test_merge_never_increases_uncertainty(kind, shape, data):
    """C₃ ⪯ C₁ and C₃ ⪯ C₂ (Loewner order): merging only adds information."""
    a = kind.ats(data.draw, shape)
    b = kind.near(data.draw, a)
    m = rm.merge(a, b)
    for c in (a.cov, b.cov):
        gap = np.linalg.eigvalsh(c - m.cov)[..., 0]
        assert np.all(gap >= -1e-9 * np.abs(c).max(axis=(-2, -1)))


@law
def test_operations_preserve_psd(kind, shape, data):
    a = kind.ats(data.draw, shape)
    b = kind.near(data.draw, a)
    for result in (
        a @ b,
        a.reverse(),
        rm.merge(a, b),
        rm.compound_chain(kind.cls.stack([a, b], axis=-1)),
    ):
        # PSD to rounding, relative to the matrix's size: what floating point can promise. (Not
        # the unit-free input check: when a combination of correlated errors cancels, e.g. a
        # rank-1 covariance along (1, 1, 1) reversed from (0, -0.99999, 0), one variance ends
        # at 1e-10 of the others, computed to an absolute error of eps·‖C‖, which is 1e-6 of it.)
        C = result.cov
        np.testing.assert_array_equal(C, np.swapaxes(C, -1, -2))
        size = np.abs(C).max(axis=(-2, -1))
        assert np.all(np.linalg.eigvalsh(C)[..., 0] >= -1e-13 * size)
        kind.assert_valid(result)


@pytest.mark.slow
@law
def test_chain_equals_pairwise_compounding(kind, shape, data):
    a, b, c = (kind.ats(data.draw, shape) for _ in range(3))
    chain = rm.compound_chain(kind.cls.stack([a, b, c], axis=-1))
    for k, expected in enumerate((a, a @ b, (a @ b) @ c)):
        kind.assert_same(chain[(slice(None),) * len(shape) + (k,)], expected)
