"""The numba kernels of relmap.at3 (relmap._at3_kernels) against its numpy path (RELMAP_NUMBA=0)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import relmap as rm
from relmap import _numba, at3
from relmap.lie import se3

from .helpers import random_covs, valid_cross_cov

pytestmark = pytest.mark.skipif(not _numba.enabled(), reason="numba kernels not in use")

RTOL = 1e-13


def random_at3s(
    seed: int, shape: tuple[int, ...], *, angle: float | None = None, spread: float = 2.0
) -> rm.AT3:
    """Random AT3s of batch ``shape``: uniform rotations, or rotations of exactly ``angle`` about
    random axes; Gaussian translations; dense random covariances."""
    g = np.random.default_rng(seed)
    n = int(np.prod(shape))
    if angle is None:
        rot = Rotation.random(n, random_state=seed).as_matrix()
    else:
        axis = g.normal(size=(n, 3))
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        rot = Rotation.from_rotvec(angle * axis).as_matrix()
    t = g.normal(scale=spread, size=(n, 3))
    cov = random_covs(g, (n,), n=6, scale=0.05)
    T = se3.from_parts(t, rot).reshape(*shape, 4, 4)
    return rm.AT3._trusted(T, cov.reshape(*shape, 6, 6))


def _small_cross_cov(seed: int, batch: tuple[int, ...]) -> np.ndarray:
    """A cross-covariance valid with every pair of :func:`random_at3s` covariances (whose
    eigenvalues are at least 1e-4 · 0.05²): spectral norm 0.8 of that."""
    K = np.random.default_rng(seed).normal(size=(*batch, 6, 6))
    return 0.8e-4 * 0.05**2 * K / np.linalg.norm(K, ord=2, axis=(-2, -1))[..., None, None]


def both_paths(monkeypatch: pytest.MonkeyPatch, fn: Callable[[], rm.AT3]) -> tuple[rm.AT3, rm.AT3]:
    """``fn()`` with the numba kernels, then with the numpy path."""
    with monkeypatch.context() as m:
        m.setenv("RELMAP_NUMBA", "1")
        m.setattr(_numba, "LARGE", 0)  # the kernels for the small batches of these tests
        assert at3._kernels(1) is not None
        fast = fn()
    with monkeypatch.context() as m:
        m.setenv("RELMAP_NUMBA", "0")
        assert at3._kernels(1) is None
        slow = fn()
    return fast, slow


def assert_same(fast: rm.AT3, slow: rm.AT3) -> None:
    """Equal to rounding (relative to each matrix's largest entry), exactly symmetric
    covariances, read-only arrays of the same shapes."""
    assert fast.mean.shape == slow.mean.shape and fast.cov.shape == slow.cov.shape
    for x, y in ((fast.mean, slow.mean), (fast.cov, slow.cov)):
        scale = np.abs(y).max(axis=(-2, -1), keepdims=True, initial=0.0)
        assert (np.abs(x - y) <= RTOL * np.maximum(scale, 1e-300)).all()
        assert not x.flags.writeable
    assert np.array_equal(fast.cov, np.swapaxes(fast.cov, -1, -2))
    assert (fast.mean[..., 3, :] == [0.0, 0.0, 0.0, 1.0]).all()


SHAPES = [
    ((), ()),
    ((1,), ()),
    ((), (7,)),
    ((600,), (600,)),  # several chunks of the kernels, a ragged last one
    ((3, 1, 2, 1), (1, 4, 1, 3)),
    ((3, 1, 2, 1), ()),
    ((0,), (0,)),
]


@pytest.mark.parametrize(("shape_a", "shape_b"), SHAPES)
@pytest.mark.parametrize("angle", [None, 1e-9, 0.0, np.pi - 1e-9, np.pi])
def test_compound_and_reverse_kernels_equal_the_numpy_path(monkeypatch, shape_a, shape_b, angle):
    a = random_at3s(1, shape_a, angle=angle)
    b = random_at3s(2, shape_b, angle=None if angle is None else np.pi - angle)
    batch = np.broadcast_shapes(shape_a, shape_b)
    X = valid_cross_cov(a.cov, b.cov, 3, batch)
    assert_same(*both_paths(monkeypatch, lambda: a @ b))
    assert_same(*both_paths(monkeypatch, lambda: b @ a))
    assert_same(*both_paths(monkeypatch, lambda: rm.compound(a, b, cross_cov=X)))
    assert_same(*both_paths(monkeypatch, a.reverse))
    assert_same(*both_paths(monkeypatch, b.reverse))


def test_kernels_read_views_and_broadcast_cross_covariances(monkeypatch):
    a, b = random_at3s(4, (40, 5)), random_at3s(5, (40, 5))
    plain = rm.AT3._trusted(np.ascontiguousarray(a.mean), np.ascontiguousarray(a.cov))
    X = _small_cross_cov(6, (5,))  # broadcast over axis 0
    for fn in (
        lambda: a[::2, 2] @ b[1::2, 3],  # strided slices
        lambda: a[3] @ b,  # one row against the batch
        lambda: plain @ b,  # numpy's default layout
        lambda: plain.reverse(),
        lambda: a[:, 1].reverse(),
        lambda: rm.compound(a, b, cross_cov=X),
        lambda: rm.compound(a[0, 0], b[1, 1], cross_cov=X[0].T),  # a non-contiguous X
    ):
        assert_same(*both_paths(monkeypatch, fn))


def test_views_of_large_batches_go_through_the_kernels_in_slices(monkeypatch):
    monkeypatch.setattr(at3, "_KERNEL_CHUNK", 64)  # several slices and a ragged last one
    a, b = random_at3s(10, (2, 300)), random_at3s(11, (300,))
    X = _small_cross_cov(12, ())
    for fn in (
        lambda: a[0, 0] @ b,  # one AT3 broadcast against the batch
        lambda: a[1] @ b[0],
        lambda: a[:, ::2] @ b[::2],  # strided slices
        lambda: a[:, 1:].reverse(),
        lambda: rm.compound(a[1], b, cross_cov=X),
    ):
        assert_same(*both_paths(monkeypatch, fn))


def test_kernels_keep_the_reversal_cross_covariance_identity(monkeypatch):
    """A ⊕ Aᴿ with the cross-covariance ``C Jᵀ`` is exactly known (the identity, zero cov)."""
    monkeypatch.setenv("RELMAP_NUMBA", "1")
    monkeypatch.setattr(_numba, "LARGE", 0)
    a = random_at3s(7, (300,))
    r, J = at3.reverse3(a, jacobian=True)
    out = rm.compound(a, r, cross_cov=a.cov @ np.swapaxes(J, -1, -2))
    np.testing.assert_allclose(out.mean, np.broadcast_to(np.eye(4), out.mean.shape), atol=1e-14)
    assert np.abs(out.cov).max() <= 1e-14 * np.abs(a.cov).max() * 100


def _stepwise(steps: rm.AT3, axis: int) -> rm.AT3:
    """Every prefix by one batched compound per step."""
    index = (slice(None),) * (axis % steps.ndim)
    acc = steps[(*index, 0)]
    out = [acc]
    for k in range(1, steps.batch_shape[axis]):
        acc = acc @ steps[(*index, k)]
        out.append(acc)
    return rm.AT3.stack(out, axis=axis % steps.ndim)


@pytest.mark.parametrize(
    ("shape", "axis"),
    [((5,), 0), ((1, 1), 1), ((3, 300), 1), ((300, 3), 0), ((300, 3), 1), ((40, 2, 50), 0)],
)
def test_chain_kernel_equals_compounding_step_by_step(monkeypatch, shape, axis):
    """Both the vectorized path (≥ 32 chains) and the one-chain-at-a-time scan."""
    steps = random_at3s(8, shape, spread=0.5)
    fast, slow = both_paths(monkeypatch, lambda: at3.compound_chain3(steps, axis=axis))
    assert_same(fast, slow)
    monkeypatch.setenv("RELMAP_NUMBA", "1")
    monkeypatch.setattr(_numba, "LARGE", 0)
    ref = _stepwise(steps, axis)
    if steps.ndim == 1:  # single pairs step by step: the numpy path, equal to rounding
        assert_same(fast, ref)
    else:  # batched kernels step by step: bitwise
        assert np.array_equal(fast.mean, ref.mean) and np.array_equal(fast.cov, ref.cov)
    first = (slice(None),) * axis + (0,)
    assert np.array_equal(fast.cov[first], steps.cov[first])  # prefix 0 is step 0


def test_chain_edge_cases():
    steps = random_at3s(9, (4, 3))
    assert at3.compound_chain3(steps[:0], axis=1).batch_shape == (0, 3)
    with pytest.raises(rm.errors.ShapeError):
        at3.compound_chain3(steps[0, 0])
    with pytest.raises(rm.errors.ShapeError):
        at3.compound_chain3(steps, axis=2)
    with pytest.raises(TypeError):
        at3.compound_chain3(steps.mean)  # type: ignore[arg-type]
