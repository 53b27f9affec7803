"""The batched path's fast helpers against their plain numpy definitions."""

from types import SimpleNamespace

import numpy as np
import pytest

from relmap import ekf


@pytest.mark.parametrize(
    "keys",
    [np.arange(50), np.array([3, 7, 100, 2000]), np.array([-5, 0, 9], np.int32),
     np.arange(0, 2**40, 2**35), np.array([0.5, 1.5, 7.0])],
)  # fmt: skip
def test_sorted_lookup_is_a_clipped_searchsorted(keys):
    rng = np.random.default_rng(0)
    for _ in range(20):
        values = rng.integers(-3000, 3000, (int(rng.integers(1, 20)), 7))
        if keys.dtype.kind == "f":
            values = values / 100.0
        expected = np.minimum(np.searchsorted(keys, values), len(keys) - 1)
        np.testing.assert_array_equal(ekf._sorted_lookup(keys, values), expected)


@pytest.mark.parametrize("C", [1, 5, 50, 64, 65, 200])
def test_clashes(C):
    rng = np.random.default_rng(C)
    for _ in range(50):
        pair = rng.integers(-1, C, (int(rng.integers(1, 20)), int(rng.integers(1, 30))))
        expected = [
            len(set(k)) < len(k) for k in ([c for c in col if c >= 0] for col in pair.T.tolist())
        ]
        np.testing.assert_array_equal(ekf._clashes(pair, C), expected)


@pytest.mark.parametrize("L", [1, 5, 50, 64, 65])
def test_compact(L):
    rng = np.random.default_rng(L)
    for _ in range(30):
        B = int(rng.integers(1, 40))
        mask = rng.random((L, B)) < rng.random()
        mask[0, 0] = True
        cand, ok = ekf._Job._compact(SimpleNamespace(L=L, B=B), mask)
        count = mask.sum(axis=0)
        assert cand.shape == ok.shape == (count.max(), B)
        for b in range(B):
            np.testing.assert_array_equal(cand[: count[b], b], np.flatnonzero(mask[:, b]))
            assert (cand[count[b] :, b] == 0).all()
            np.testing.assert_array_equal(ok[:, b], np.arange(len(ok)) < count[b])


def test_kernel_sin_cos_atan_are_accurate():
    """The EKF kernels' own sin, cos and small-angle atan (fdlibm's polynomials) against libm:
    within an ulp or two, over the angles the kernels see (and far beyond)."""
    numba = pytest.importorskip("numba")
    from relmap import _ekf_kernels as kernels

    @numba.njit
    def evaluate(a, y, x, out):
        for i in range(len(a)):
            out[0, i], out[1, i] = kernels.sincos(a[i])
            out[2, i] = kernels.atan2(y[i], x[i])

    rng = np.random.default_rng(0)
    n = 20_000
    a = np.concatenate([rng.uniform(-10, 10, n), rng.uniform(-1e6, 1e6, n), [0.0, np.pi / 2]])
    y = rng.uniform(-1, 1, len(a)) * rng.choice([1e-9, 0.01, 0.5, 3.0], len(a))
    x = rng.uniform(-1, 1.5, len(a))
    out = np.empty((3, len(a)))
    evaluate(a, y, x, out)
    np.testing.assert_allclose(out[0], np.sin(a), rtol=0, atol=2.3e-16)
    np.testing.assert_allclose(out[1], np.cos(a), rtol=0, atol=2.3e-16)
    ref = np.arctan2(y, x)
    assert (np.abs(out[2] - ref) <= 2 * np.spacing(np.abs(ref))).all()
