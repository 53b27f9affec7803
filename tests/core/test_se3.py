"""relmap._core's SE(3) part (src/core/se3.cpp) through relmap.uncertain.at3, against the textbook
form
(full 6×6 Jacobians of relmap.lie.se3, batched matmul): batch sizes around the core's chunk of
lanes, strided and broadcast inputs (views the core reads in place), and the core's contract."""

from __future__ import annotations

import numpy as np
import pytest

import relmap as rm
from relmap import _core
from relmap.uncertain import at3
from tests.helpers import random_at3s, valid_cross_cov
from tests.uncertain.test_at3 import _close, _reference_compound, _reference_reverse


@pytest.mark.parametrize("n", [1, 2, 15, 16, 17, 31, 32, 33, 100])
def test_every_batch_size_and_its_ragged_last_chunk(n):
    a, b = random_at3s(41, n), random_at3s(42, n)
    X = valid_cross_cov(a.cov, b.cov, 43)
    _close(a @ b, *_reference_compound(a, b))
    _close(rm.compound(a, b, cross_cov=X), *_reference_compound(a, b, X))
    _close(a.reverse(), *_reference_reverse(a))


def test_strided_and_broadcast_views_are_read_in_place():
    a, b = random_at3s(51, 90), random_at3s(52, 45)
    sa, sb = a[::2], b[::-1]  # strides 2 and -1 along the batch
    _close(sa @ sb, *_reference_compound(sa, sb))
    _close(sa.reverse(), *_reference_reverse(sa))
    one = b[3]  # one AT3 against a batch: stride 0
    _close(sa @ one, *_reference_compound(sa, one))
    _close(one @ sa, *_reference_compound(one, sa))
    # one cross-covariance for all 45 pairs (a stride-0 view), small enough for every pair:
    # ‖X‖₂ ≤ √(λmin(C_a) λmin(C_b)) keeps each joint covariance PSD
    K = np.random.default_rng(53).normal(size=(6, 6))
    floor = np.sqrt(np.linalg.eigvalsh(sa.cov)[:, 0] * np.linalg.eigvalsh(sb.cov)[:, 0]).min()
    X = np.broadcast_to(0.9 * floor * K / np.linalg.norm(K, 2), (45, 6, 6))
    _close(rm.compound(sa, sb, cross_cov=X), *_reference_compound(sa, sb, X))
    grid = rm.AT3._trusted(  # a 2-D batch stored in numpy's default layout, transposed
        np.ascontiguousarray(a.mean.reshape(9, 10, 4, 4)).swapaxes(0, 1),
        np.ascontiguousarray(a.cov.reshape(9, 10, 6, 6)).swapaxes(0, 1),
    )
    _close(grid @ grid, *_reference_compound(grid, grid))


def test_the_core_returns_new_arrays_and_checks_its_contract():
    a = random_at3s(61, 5)
    T, C = at3._planes(a.mean, (5,), 5), at3._planes(a.cov, (5,), 5)
    To, Co, finite = _core.compound3(T, C, T, C, None)
    assert finite
    assert To.shape == (4, 4, 5) and Co.shape == (6, 6, 5)
    assert To.flags.c_contiguous and To.flags.writeable and not np.shares_memory(To, T)
    with pytest.raises(ValueError, match="batch sizes differ"):
        _core.compound3(T, C, T[..., :4], C[..., :4], None)
    with pytest.raises(TypeError):  # a (6, 6, N) where a pose (4, 4, N) belongs
        _core.reverse3(C, C)
