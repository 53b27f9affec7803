"""Algebraic laws of ⊕, ᴿ and ⊗ as property tests, over batch shapes (), (1,), (3, 1, 2, 1).

Headings are drawn from the whole circle with explicit samples at and next to ±π.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import relmap as rm
from relmap.lie import se2
from tests.helpers import assert_poses_close

SHAPES = st.sampled_from([(), (1,), (3, 1, 2, 1)])
EDGE_ANGLES = [np.pi - 1e-12, -np.pi, -np.pi + 1e-12, 0.0, np.pi / 2, 3.0]
ANGLES = st.one_of(st.floats(-np.pi, np.pi, exclude_max=True), st.sampled_from(EDGE_ANGLES))
COORDS = st.floats(-10.0, 10.0)
# Covariance factors: zero or at least 1e-4 in size (variances ≥ 1e-8). Far smaller entries
# only probe float underflow (subnormal variances such as 1e-316), not relmap's algebra.
FACTOR = st.one_of(st.just(0.0), st.floats(1e-4, 0.3), st.floats(-0.3, -1e-4))


def _ats(draw, shape, heading=None):
    xy = draw(hnp.arrays(np.float64, (*shape, 2), elements=COORDS))
    th = draw(hnp.arrays(np.float64, (*shape, 1), elements=ANGLES)) if heading is None else heading
    L = draw(hnp.arrays(np.float64, (*shape, 3, 3), elements=FACTOR))
    return rm.AT(np.concatenate([xy, th], axis=-1), L @ np.swapaxes(L, -1, -2))


def _near(draw, a: rm.AT, floor: float = 1e-3):
    """An AT of the same relation as a (heading within ±1 rad), with a well-conditioned
    covariance (eigenvalues ≥ ``floor``): exactly known components have their own tests."""
    shape = a.batch_shape
    offset = draw(hnp.arrays(np.float64, (*shape, 3), elements=st.floats(-1.0, 1.0)))
    L = draw(hnp.arrays(np.float64, (*shape, 3, 3), elements=FACTOR))
    return rm.AT(se2.plus(a.mean, offset), L @ np.swapaxes(L, -1, -2) + floor * np.eye(3))


def _close_cov(a: np.ndarray, b: np.ndarray, rtol: float = 1e-9) -> None:
    """Equal to ``rtol`` relative to the larger matrix's largest entry (or 1e-15 absolute)."""
    scale = np.maximum(np.abs(a).max(axis=(-2, -1)), np.abs(b).max(axis=(-2, -1)))
    err = np.abs(a - b).max(axis=(-2, -1))
    assert np.all(err <= rtol * scale + 1e-15), (err, scale)


def _wrapped_range(at: rm.AT) -> None:
    assert np.all(at.mean[..., 2] >= -np.pi) and np.all(at.mean[..., 2] < np.pi)


@pytest.mark.slow
@given(st.data())
def test_compound_is_associative(data):
    shape = data.draw(SHAPES)
    a, b, c = (_ats(data.draw, shape) for _ in range(3))
    left, right = (a @ b) @ c, a @ (b @ c)
    assert_poses_close(left.mean, right.mean, atol=1e-11)
    _close_cov(left.cov, right.cov)
    _wrapped_range(left)


@given(st.data())
def test_reverse_is_an_involution(data):
    a = _ats(data.draw, data.draw(SHAPES))
    rr = a.reverse().reverse()
    assert_poses_close(rr.mean, a.mean, atol=1e-11)
    _close_cov(rr.cov, a.cov)
    _wrapped_range(a.reverse())


@given(st.data())
def test_compound_with_reverse_is_identity_mean(data):
    a = _ats(data.draw, data.draw(SHAPES))
    assert_poses_close((a @ a.reverse()).mean, np.zeros((*a.batch_shape, 3)), atol=1e-11)
    assert_poses_close((a.reverse() @ a).mean, np.zeros((*a.batch_shape, 3)), atol=1e-11)


@pytest.mark.slow
@given(st.data())
def test_reverse_distributes_over_compound(data):
    """(A ⊕ B)ᴿ = Bᴿ ⊕ Aᴿ, mean and first-order covariance."""
    shape = data.draw(SHAPES)
    a, b = _ats(data.draw, shape), _ats(data.draw, shape)
    lhs, rhs = (a @ b).reverse(), b.reverse() @ a.reverse()
    assert_poses_close(lhs.mean, rhs.mean, atol=1e-11)
    _close_cov(lhs.cov, rhs.cov)


def _unwrapped_heading(*ats: rm.AT) -> np.ndarray:
    """Heading of the merge computed with no wrapping at all (plain linear Kalman algebra,
    headings unwrapped onto the first AT's branch): where the merge really goes."""
    ref = ats[0].mean[..., 2]
    x, C = ats[0].mean.copy(), ats[0].cov
    for b in ats[1:]:
        y = b.mean.copy()
        y[..., 2] = ref + se2.angle_difference(y[..., 2], ref)
        K = C @ np.linalg.pinv(C + b.cov, hermitian=True)
        x = x + np.einsum("...ij,...j->...i", K, y - x)
        C = C - K @ C
    return x[..., 2] - ref


@pytest.mark.slow
@given(st.data())
def test_merge_is_commutative_and_associative(data):
    """Order does not matter, as long as no partial merge swings a heading past ±π.

    Strong correlations can extrapolate a merge far outside its inputs; a heading moved by more
    than π wraps, and the innovations that follow then pick a different 2π branch depending on
    the order. Realistic ATs stay far from this; the law is checked where every partial merge,
    computed without any wrapping, stays within 2 rad of the first AT's heading.
    """
    shape = data.draw(SHAPES)
    a = _near(data.draw, _ats(data.draw, shape))
    b, c = _near(data.draw, a), _near(data.draw, a)
    for group in ((a, b), (b, c), (c, a), (a, b, c)):
        assume(np.all(np.abs(_unwrapped_heading(*group)) < 2.0))
    ab, ba, bc = rm.merge(a, b), rm.merge(b, a), rm.merge(b, c)
    orders = [
        rm.merge(a, b, c),
        rm.merge(ab, c),
        rm.merge(a, bc),
        rm.merge(c, a, b),
        rm.merge(rm.merge(c, a), b),
    ]
    assert_poses_close(ab.mean, ba.mean, atol=1e-8)
    _close_cov(ab.cov, ba.cov, rtol=1e-8)
    for other in orders[1:]:
        assert_poses_close(other.mean, orders[0].mean, atol=1e-8)
        _close_cov(other.cov, orders[0].cov, rtol=1e-8)
    _wrapped_range(orders[0])


@given(st.data())
def test_merge_with_an_exact_at_returns_it(data):
    """An exactly known AT outweighs any uncertain one: the merge is the exact AT, either order."""
    a = _ats(data.draw, data.draw(SHAPES))
    exact = rm.AT(a.mean)
    b = _near(data.draw, a)
    for m in (rm.merge(exact, b), rm.merge(b, exact)):
        assert_poses_close(m.mean, exact.mean, atol=1e-12)
        assert np.abs(m.cov).max() <= 1e-12


@pytest.mark.slow
@given(st.data())
def test_merge_never_increases_uncertainty(data):
    """C₃ ⪯ C₁ and C₃ ⪯ C₂ (Loewner order): merging only adds information."""
    a = _ats(data.draw, data.draw(SHAPES))
    b = _near(data.draw, a)
    m = rm.merge(a, b)
    for c in (a.cov, b.cov):
        gap = np.linalg.eigvalsh(c - m.cov)[..., 0]
        assert np.all(gap >= -1e-9 * np.abs(c).max(axis=(-2, -1)))


@given(st.data())
def test_operations_preserve_psd(data):
    shape = data.draw(SHAPES)
    a = _ats(data.draw, shape)
    b = _near(data.draw, a)
    for result in (
        a @ b,
        a.reverse(),
        rm.merge(a, b),
        rm.compound_chain(rm.AT.stack([a, b], axis=-1)),
    ):
        # PSD to rounding, relative to the matrix's size: what floating point can promise. (Not
        # the unit-free input check: when a combination of correlated errors cancels, e.g. a
        # rank-1 covariance along (1, 1, 1) reversed from (0, -0.99999, 0), one variance ends
        # at 1e-10 of the others, computed to an absolute error of eps·‖C‖, which is 1e-6 of it.)
        C = result.cov
        np.testing.assert_array_equal(C, np.swapaxes(C, -1, -2))
        size = np.abs(C).max(axis=(-2, -1))
        assert np.all(np.linalg.eigvalsh(C)[..., 0] >= -1e-13 * size)
        _wrapped_range(result)


@pytest.mark.slow
@given(st.data())
def test_chain_equals_pairwise_compounding(data):
    shape = data.draw(SHAPES)
    a, b, c = (_ats(data.draw, shape) for _ in range(3))
    chain = rm.compound_chain(rm.AT.stack([a, b, c], axis=-1))
    for k, expected in enumerate((a, a @ b, (a @ b) @ c)):
        assert_poses_close(chain.mean[..., k, :], expected.mean, atol=1e-11)
        _close_cov(chain.cov[..., k, :, :], expected.cov, rtol=1e-9)
