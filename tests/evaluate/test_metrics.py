"""RPE pairing and association against their plain statements (brute force, in the tests)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from relmap.evaluate import associate, pairs, statistics
from relmap.evaluate.association import _nearest
from relmap.uncertain.trajectory import Trajectory


def brute_all_pairs(D, delta, tol):  # type: ignore[no-untyped-def]
    out = []
    for i in range(len(D) - 1):
        rest = D[i + 1 :] - D[i]
        k = int(np.argmin(np.abs(rest - delta)))
        if abs(rest[k] - delta) <= tol:
            out.append((i, k + i + 1))
    return out


def poses(steps):  # type: ignore[no-untyped-def]
    M = np.broadcast_to(np.eye(4), (len(steps) + 1, 4, 4)).copy()
    M[1:, 0, 3] = np.cumsum(steps)
    return M


@given(
    st.lists(st.sampled_from([0.0, 0.25, 0.5, 1.0, 0.3, 0.7]), min_size=2, max_size=60),
    st.sampled_from([0.5, 1.0, 1.3, 2.0]),
)
def test_all_pairs_in_metres_is_the_argmin(steps, delta):  # type: ignore[no-untyped-def]
    """Repeated positions (zero steps) make ties: the first index of the minimum wins."""
    M = poses(steps)
    D = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(M[:, :3, 3], axis=0), axis=1))))
    i, j = pairs(M, delta, "m", all_pairs=True)
    assert list(zip(i.tolist(), j.tolist(), strict=True)) == brute_all_pairs(D, delta, 0.1 * delta)


def test_seconds_pair_like_frames_for_uniform_stamps():  # type: ignore[no-untyped-def]
    M = poses(np.ones(40))
    t = np.arange(41) * 0.25
    a = pairs(M, 1.0, "s", stamps=t)
    b = pairs(M, 4, "frames")
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


@given(
    st.lists(st.floats(0, 10, allow_nan=False), min_size=1, max_size=30),
    st.lists(st.floats(-1, 11, allow_nan=False), min_size=1, max_size=30),
    st.floats(0.0, 0.5),
)
def test_nearest_stamp(long, short, max_diff):  # type: ignore[no-untyped-def]
    """Each matched stamp is a nearest one; unmatched ones have none within max_diff."""
    long_a, short_a = np.sort(np.array(long)), np.array(short)
    k, ok = _nearest(short_a, long_a, max_diff)
    for s, kk, m in zip(short_a, k, ok, strict=True):
        best = np.min(np.abs(long_a - s))
        if m:
            assert abs(long_a[kk] - s) == best and best <= max_diff
        else:  # none within max_diff (up to rounding of the differences at the boundary)
            assert best >= max_diff - 1e-12


def test_association_takes_repeats_and_offset():  # type: ignore[no-untyped-def]
    ref = Trajectory.planar(np.zeros((5, 3)), [0.0, 1.0, 2.0, 3.0, 4.0])
    est = Trajectory.planar(np.zeros((3, 3)), [10.0, 10.004, 12.0])
    a = associate(ref, est, max_diff=0.01, offset=-10.0)
    assert a.ref_index.tolist() == [0, 0, 2] and a.est_index.tolist() == [0, 1, 2]


def test_statistics_are_evos_definitions():  # type: ignore[no-untyped-def]
    e = np.array([1.0, 2.0, 4.0])
    s = statistics(e)
    assert s["rmse"] == np.sqrt(21 / 3) and s["sse"] == 21 and s["median"] == 2.0
    assert s["std"] == np.std(e) and s["min"] == 1 and s["max"] == 4 and s["mean"] == 7 / 3
