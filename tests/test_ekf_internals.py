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
