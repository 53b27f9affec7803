"""relmap.uncertain.pose: what AT and AT3 share (storage, stacking, indexing, sampling, the ellipse)
behaves the same for both kinds (the free functions on both: tests/uncertain/test_algebra.py)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

import relmap as rm
from relmap.errors import ArgumentTypeError
from relmap.uncertain.pose import UncertainPose


def _planar(rng: np.random.Generator, n: int) -> rm.AT:
    mean = np.column_stack([rng.normal(size=(n, 2)), rng.uniform(-3, 3, n)])
    return rm.AT.from_sigmas(mean, rng.uniform(0.01, 0.2, (n, 3)))


@pytest.mark.parametrize("kind", ["AT", "AT3"])
def test_both_kinds_share_the_base(rng, kind):
    a = _planar(rng, 4)
    x = a if kind == "AT" else rm.AT3.from_planar(a)
    assert isinstance(x, UncertainPose)
    assert x.batch_shape == (4,) and x.ndim == 1 and len(x) == 4
    assert [y.batch_shape for y in x] == [()] * 4
    s = type(x).stack([x[0], x[1]], axis=0)
    np.testing.assert_array_equal(s.cov, x.cov[:2])
    with pytest.raises(IndexError):
        x[..., 0]  # Ellipsis would reach the pose's own axes
    with pytest.raises(IndexError):
        x[0, 0]
    with pytest.raises(TypeError):
        len(x[0])
    with pytest.raises(AttributeError):
        x._mean = None  # type: ignore[misc]
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(x)).cov, x.cov)
    e = type(x).identity((2,))
    assert e.batch_shape == (2,) and not e.cov.any()
    with pytest.raises(ArgumentTypeError):
        type(x).stack([x[0], "no"])  # type: ignore[list-item]


def test_the_xy_ellipse_of_a_planar_at3_is_the_ats(rng):
    """The AT3 of a planar AT has the same (x, y) marginal, so the same Appendix-A ellipse."""
    a = _planar(rng, 3)
    e2, e3 = a.ellipse(0.9), rm.AT3.from_planar(a).ellipse(0.9)
    for u, v in zip(e2, e3, strict=True):
        np.testing.assert_allclose(u, v, rtol=1e-12, atol=1e-15)


def test_sampling_goes_through_the_chart(rng):
    """Samples of both kinds scatter in the chart with the AT's covariance (law of large
    numbers: 20 000 draws give the covariance to a few percent)."""
    a = rm.AT([1.0, 2.0, 0.5], np.diag([0.04, 0.01, 0.0025]))
    d = rm.lie.se2.minus(a.sample(20_000, seed=1), a.mean)
    np.testing.assert_allclose(np.cov(d.T), a.cov, atol=0.004)
    q = rm.AT3.from_planar(a)
    d3 = rm.lie.se3.minus(q.sample(20_000, seed=1), q.mean)
    np.testing.assert_allclose(np.cov(d3.T)[np.ix_([0, 1, 5], [0, 1, 5])], a.cov, atol=0.004)


@pytest.mark.parametrize("kind", ["AT", "AT3"])
def test_what_generic_code_reads_instead_of_the_kind(rng, kind):
    """``dim``, ``position_cov`` and ``vector``: the space's dimension (the translation's
    length), the position block of the covariance, and the mean as files write it."""
    a = _planar(rng, 4)
    x = a if kind == "AT" else rm.AT3.from_planar(a)
    n = 2 if kind == "AT" else 3
    assert type(x).dim == x.dim == n
    assert x.dim * (x.dim + 1) // 2 == x.group.dof
    assert x._position().shape == (4, x.dim)  # the translation has dim entries
    np.testing.assert_array_equal(x.position_cov, x.cov[:, :n, :n])
    np.testing.assert_allclose(x.position_cov[:, :2, :2], a.cov[:, :2, :2], atol=1e-15)
    if kind == "AT":
        np.testing.assert_array_equal(x.vector, a.mean)
    else:  # [x, y, z, qx, qy, qz, qw] of the planar pose: qz = sin(θ/2), qw = cos(θ/2)
        half = a.mean[:, 2] / 2
        sign = np.sign(np.cos(half))
        expected = np.column_stack(
            [a.mean[:, :2], np.zeros((4, 3)), sign * np.sin(half), sign * np.cos(half)]
        )
        np.testing.assert_allclose(x.vector, expected, atol=1e-12)
        np.testing.assert_array_equal(rm.AT3.from_vector(x.vector, x.cov).vector, x.vector)
