"""relmap._core's association part (src/core/association.cpp) against the plain statement of its
mathematics, written here in Python:

- ``pair_one_to_one``: the greedy run over the candidate pairs sorted by (cost, reading,
  landmark), a pair taken when its reading and its landmark are both still free; with ``split``
  the pairs inside the gate first, then those outside.
- ``jcbb``: brute force over every one-to-one set of individually compatible pairs, with the
  joint d² of a set from numpy's stacked ``S = H P Hᵀ + R`` and a solve. The search (Neira &
  Tardós 2001) builds a set reading by reading and keeps a partial set only if it passes the
  joint gate of its size, so a set is reachable when every prefix of it (in reading order)
  passes its gate; of the reachable sets it returns a largest, of those the least joint d².
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.stats import chi2

from relmap import _core

INF = np.inf

# ----------------------------------------------------------------------------------------------
# Greedy one-to-one pairing


def _greedy(cost: np.ndarray, inside: np.ndarray, split: bool) -> list[int]:
    """One filter's pairing: the candidates (cost < +inf; NaN is not) sorted by (cost, i, lm),
    taken when reading and landmark are free; with split, those inside the gate first."""
    m, L = cost.shape
    pairs = sorted((cost[i, lm], i, lm) for i in range(m) for lm in range(L) if cost[i, lm] < INF)
    if split:
        passes = [
            [p for p in pairs if inside[p[1], p[2]]],
            [p for p in pairs if not inside[p[1], p[2]]],
        ]
    else:
        passes = [pairs]
    landmark, taken = [-1] * m, set()
    for candidates in passes:
        for _, i, lm in candidates:
            if landmark[i] < 0 and lm not in taken:
                landmark[i] = lm
                taken.add(lm)
    return landmark


def _random_costs(rng: np.random.Generator, B: int, m: int, L: int):
    """Costs with many ties (small integers), +inf and NaN (not candidates), a few -inf."""
    cost = rng.integers(0, 5, (B, m, L)).astype(float)
    u = rng.random((B, m, L))
    cost[u < 0.2] = INF
    cost[(u >= 0.2) & (u < 0.25)] = np.nan
    cost[u > 0.99] = -INF
    inside = rng.random((B, m, L)) < 0.5
    return cost, inside


@pytest.mark.parametrize("B", [1, 7])
@pytest.mark.parametrize("split", [False, True])
@pytest.mark.parametrize("seed", range(8))
def test_pair_one_to_one_equals_the_greedy_over_sorted_pairs(B, split, seed):
    rng = np.random.default_rng(seed)
    m, L = int(rng.integers(0, 9)), int(rng.integers(0, 9))
    cost, inside = _random_costs(rng, B, m, L)
    got = _core.pair_one_to_one(cost, inside, split)
    assert got.shape == (B, m) and got.dtype == np.int64
    for b in range(B):
        assert got[b].tolist() == _greedy(cost[b], inside[b], split)


@given(
    hnp.arrays(
        np.float64,
        hnp.array_shapes(min_dims=3, max_dims=3, max_side=6),
        elements=st.sampled_from([0.0, 1.0, 1.0, 2.5, 3.0, INF, np.nan]),
    ),
    st.integers(0, 2**32 - 1),
    st.booleans(),
)
def test_pair_one_to_one_property(cost, seed, split):
    inside = np.random.default_rng(seed).random(cost.shape) < 0.5
    got = _core.pair_one_to_one(cost, inside, split)
    for b in range(cost.shape[0]):
        assert got[b].tolist() == _greedy(cost[b], inside[b], split)


def test_pair_one_to_one_by_hand():
    no = np.zeros((1, 2, 2), bool)
    # both readings want landmark 0: the cheaper pair takes it, the other reading the next
    assert _core.pair_one_to_one(np.array([[[1.0, 5.0], [2.0, 3.0]]]), no, False).tolist() == [
        [0, 1]
    ]
    assert _core.pair_one_to_one(np.array([[[2.0, 5.0], [1.0, 3.0]]]), no, False).tolist() == [
        [1, 0]
    ]
    # ties: the lower reading, then the lower landmark
    assert _core.pair_one_to_one(np.ones((1, 2, 2)), no, False).tolist() == [[0, 1]]
    # no candidate left: -1 (a landmark pairs with one reading only)
    assert _core.pair_one_to_one(np.array([[[1.0, INF], [2.0, np.nan]]]), no, False).tolist() == [
        [0, -1]
    ]
    # a cheaper pair outside the gate loses to one inside with split, wins without
    cost = np.array([[[1.0, 6.0], [3.0, INF]]])
    inside = np.array([[[False, False], [True, False]]])
    assert _core.pair_one_to_one(cost, inside, True).tolist() == [[1, 0]]
    assert _core.pair_one_to_one(cost, inside, False).tolist() == [[0, -1]]


def test_pair_one_to_one_reads_views_and_checks_shapes():
    rng = np.random.default_rng(3)
    cost, inside = _random_costs(rng, 3, 5, 4)
    view = np.asfortranarray(cost)  # (copied to C order by the binding)
    np.testing.assert_array_equal(
        _core.pair_one_to_one(view, inside, True), _core.pair_one_to_one(cost, inside, True)
    )
    with pytest.raises(ValueError, match="inside"):
        _core.pair_one_to_one(cost, inside[:, :4], True)
    with pytest.raises(ValueError, match="cost"):
        _core.pair_one_to_one(cost[0], inside[0], True)


# ----------------------------------------------------------------------------------------------
# JCBB


def _spd(rng: np.random.Generator, k: int, scale: float) -> np.ndarray:
    A = rng.normal(size=(k, k))
    return scale * (A @ A.T / k + 0.2 * np.eye(k))


def _problem(rng: np.random.Generator, m: int, L: int, n: int, d: int, spread: float = 2.0):
    """A filter's problem: P, each landmark's H and R, innovations v ~ N(0, c S) with c up to
    `spread` per pair, each pair's own d² and the individually compatible pairs (95% gate)."""
    P = _spd(rng, n, 1.0)
    H = rng.normal(size=(L, d, n))
    R = np.stack([_spd(rng, d, 0.05) for _ in range(L)])
    S = H @ P @ H.transpose(0, 2, 1) + R
    C = np.linalg.cholesky(S)
    c = rng.uniform(0.1 * spread, spread, (m, L))
    v = np.sqrt(c)[..., None] * np.einsum("lab,mlb->mla", C, rng.normal(size=(m, L, d)))
    d2 = np.einsum("mla,mla->ml", v, np.linalg.solve(S[None], v[..., None])[..., 0])
    inside = d2 <= chi2.ppf(0.95, d)
    return v, H, R, P, d2, inside


def _joint_d2(pairs, v, H, R, P) -> float:
    """The stacked yᵀ S⁻¹ y of a set of pairs (i, lm), S = H P Hᵀ + blockdiag(R); +inf if S is
    not positive definite."""
    if not pairs:
        return 0.0
    y = np.concatenate([v[i, lm] for i, lm in pairs])
    Hs = np.concatenate([H[lm] for _, lm in pairs])
    d = H.shape[1]
    Rs = np.zeros((len(y), len(y)))
    for k, (_, lm) in enumerate(pairs):
        Rs[k * d : (k + 1) * d, k * d : (k + 1) * d] = R[lm]
    S = Hs @ P @ Hs.T + Rs
    if np.any(np.linalg.eigvalsh(0.5 * (S + S.T)) <= 0.0):
        return INF
    return float(y @ np.linalg.solve(S, y))


def _gate(gates: np.ndarray, k: int) -> float:
    return gates[k] if k < len(gates) else INF


def _reachable(pairs, v, H, R, P, gates) -> bool:
    """Every prefix of the set (in reading order) passes the joint gate of its size."""
    return all(
        (q := _joint_d2(pairs[:k], v, H, R, P)) < INF and q <= _gate(gates, k)
        for k in range(1, len(pairs) + 1)
    )


def _brute_force(v, H, R, P, inside, gates, every_prefix=True):
    """Every one-to-one set of compatible pairs that passes the joint gate (every prefix of it,
    as the search builds it; or only the whole set): (size, joint d², landmark per reading)."""
    m, L = inside.shape
    options = [[-1] + [lm for lm in range(L) if inside[i, lm]] for i in range(m)]
    sets = []
    for choice in itertools.product(*options):
        used = [lm for lm in choice if lm >= 0]
        if len(used) != len(set(used)):
            continue
        pairs = [(i, lm) for i, lm in enumerate(choice) if lm >= 0]
        q = _joint_d2(pairs, v, H, R, P)
        passes = (
            _reachable(pairs, v, H, R, P, gates) if every_prefix else q <= _gate(gates, len(pairs))
        )
        if passes:
            sets.append((len(pairs), q, list(choice)))
    return sets


def _check_best(got, sets, v, H, R, P):
    """got is a largest reachable set of least joint d² (to rounding)."""
    size = max(s[0] for s in sets)
    least = sorted(s[1] for s in sets if s[0] == size)
    pairs = [(i, lm) for i, lm in enumerate(got) if lm >= 0]
    assert len(pairs) == size
    q = _joint_d2(pairs, v, H, R, P)
    assert q <= least[0] * (1 + 1e-9) + 1e-300
    if len(least) == 1 or least[1] > least[0] * (1 + 1e-9):  # a unique best: exactly it
        best = next(s[2] for s in sets if s[0] == size and s[1] == least[0])
        assert list(got) == best


def _run(problems, gates, max_nodes=10**9):
    v, H, R, P, d2, inside = (np.stack(x) for x in zip(*problems, strict=True))
    return _core.jcbb(v, H, R, P, d2, inside, gates, max_nodes)


@pytest.mark.parametrize("d", [1, 2])
@pytest.mark.parametrize("seed", range(12))
def test_jcbb_equals_brute_force(d, seed):
    """Batches of 7 filters with χ² joint gates; across the seeds the joint gate must bind
    (a set smaller than the largest one-to-one set of compatible pairs) for the test to bite."""
    rng = np.random.default_rng(100 * d + seed)
    m, L = int(rng.integers(1, 5)), int(rng.integers(1, 5))
    gates = chi2.ppf(0.95, d * np.arange(8))
    gates[0] = 0.0
    problems = [_problem(rng, m, L, 3, d) for _ in range(7)]
    got = _run(problems, gates)
    assert got.shape == (7, m)
    for b, (v, H, R, P, _, inside) in enumerate(problems):
        sets = _brute_force(v, H, R, P, inside, gates)
        _check_best(got[b], sets, v, H, R, P)


def test_the_joint_gate_binds_in_these_problems():
    """The brute-force test above is not just "pair every compatible reading": in its problems
    the joint gate often makes JCBB's set smaller than the largest one-to-one set of
    individually compatible pairs."""
    smaller = 0
    for d in (1, 2):
        for seed in range(12):
            rng = np.random.default_rng(100 * d + seed)
            m, L = int(rng.integers(1, 5)), int(rng.integers(1, 5))
            gates = chi2.ppf(0.95, d * np.arange(8))
            gates[0] = 0.0
            problems = [_problem(rng, m, L, 3, d) for _ in range(7)]
            got = _run(problems, gates)
            for b, (*_, inside) in enumerate(problems):
                options = [[-1, *np.flatnonzero(inside[i]).tolist()] for i in range(m)]
                largest = max(
                    len(used)
                    for choice in itertools.product(*options)
                    if len(used := [lm for lm in choice if lm >= 0]) == len(set(used))
                )
                smaller += np.count_nonzero(got[b] >= 0) < largest
    assert smaller >= 10


@pytest.mark.parametrize("seed", range(6))
def test_jcbb_with_a_constant_gate_is_the_largest_jointly_compatible_set(seed):
    """With a gate that does not grow with k, a set's subsets pass whenever it does (a marginal
    d² is at most the joint one), so the search finds the largest set whose stacked d² passes."""
    rng = np.random.default_rng(700 + seed)
    d = 1 + seed % 2
    m, L = 4, 4
    problems = [_problem(rng, m, L, 3, d, spread=1.0) for _ in range(3)]
    gates = np.full(m + 1, 6.0)
    gates[0] = 0.0
    got = _run(problems, gates)
    for b, (v, H, R, P, _, inside) in enumerate(problems):
        sets = _brute_force(v, H, R, P, inside, gates, every_prefix=False)
        _check_best(got[b], sets, v, H, R, P)


@pytest.mark.parametrize("n", [3, 5])
@pytest.mark.parametrize("d", [1, 2])
def test_incremental_joint_d2_equals_the_stacked_one(n, d):
    """The search's joint d² (sequential Schur-complement blocks) against numpy's stacked
    yᵀ S⁻¹ y, to 1e-12 relative, through JCBB's choice: each reading has one compatible
    landmark, and the joint gate of the whole set is the stacked d² times 1 ± 1e-12."""
    rng = np.random.default_rng(40 + 10 * n + d)
    for m in range(1, 5):
        for _ in range(5):
            v, H, R, P, d2, _ = _problem(rng, m, m, n, d)
            inside = np.eye(m, dtype=bool)
            q = _joint_d2([(i, i) for i in range(m)], v, H, R, P)
            for factor, expect in ((1 + 1e-12, m), (1 - 1e-12, m - 1)):
                gates = np.full(m + 1, INF)
                gates[m] = q * factor
                got = _core.jcbb(
                    v[None], H[None], R[None], P[None], d2[None], inside[None], gates, 10**9
                )
                assert np.count_nonzero(got >= 0) == expect


def test_jcbb_node_limit():
    """A node is counted at each visit: the first leaf (each reading paired with its free
    compatible landmark of least d²) is the (m + 1)-th node; any limit returns a reachable set."""
    rng = np.random.default_rng(9)
    gates = chi2.ppf(0.95, 2 * np.arange(8))
    gates[0] = 0.0
    # the first leaf by hand: three readings, each inside the gate of every landmark
    m = 3
    v, H, R, P, d2, _ = _problem(rng, m, 4, 3, 2, spread=0.01)
    inside = np.ones((m, 4), bool)
    first, taken = [], set()
    for i in range(m):
        first.append(next(lm for lm in np.argsort(d2[i], kind="stable") if lm not in taken))
        taken.add(first[-1])
    assert _reachable(list(enumerate(first)), v, H, R, P, gates)
    args = (v[None], H[None], R[None], P[None], d2[None], inside[None], gates)
    assert _core.jcbb(*args, m + 1).tolist() == [first]
    assert _core.jcbb(*args, m).tolist() == [[-1] * m]
    assert _core.jcbb(*args, 0).tolist() == [[-1] * m]
    # random problems, tiny limits: a one-to-one set of compatible pairs that the search reaches
    for seed in range(20):
        rng = np.random.default_rng(seed)
        v, H, R, P, d2, inside = _problem(rng, 4, 4, 3, 1 + seed % 2)
        for limit in (1, 2, 3, 5, 8, 13):
            got = _core.jcbb(
                v[None], H[None], R[None], P[None], d2[None], inside[None], gates, limit
            )[0]
            used = got[got >= 0]
            assert len(set(used.tolist())) == len(used)
            assert all(inside[i, lm] for i, lm in enumerate(got) if lm >= 0)
            pairs = [(i, int(lm)) for i, lm in enumerate(got) if lm >= 0]
            assert _reachable(pairs, v, H, R, P, gates)


def test_jcbb_never_pairs_a_landmark_whose_S_is_not_positive_definite():
    rng = np.random.default_rng(5)
    v, H, R, P, d2, _ = _problem(rng, 2, 2, 3, 2)
    H[1] = 0.0
    R[1] = -np.eye(2)  # S = H P Hᵀ + R = -I for landmark 1
    d2[:, 1] = 0.0  # tried first by each reading
    inside = np.ones((2, 2), bool)
    gates = np.array([0.0])  # every joint gate +inf
    got = _core.jcbb(v[None], H[None], R[None], P[None], d2[None], inside[None], gates, 1000)
    assert got.tolist() == [[0, -1]]
    # nothing compatible: nothing paired
    none = np.zeros((1, 2, 2), bool)
    assert _core.jcbb(v[None], H[None], R[None], P[None], d2[None], none, gates, 1000).tolist() == [
        [-1, -1]
    ]


def test_jcbb_checks_shapes():
    rng = np.random.default_rng(6)
    v, H, R, P, d2, inside = (x[None] for x in _problem(rng, 3, 2, 3, 2))
    gates = np.array([0.0, 5.0])
    ok = _core.jcbb(v, H, R, P, d2, inside, gates, 100)
    assert ok.shape == (1, 3)
    bad = {
        "H": (v, H[:, :, :1], R, P, d2, inside),
        "R": (v, H, R[:, :1], P, d2, inside),
        "P": (v, H, R, P[:, :, :2], d2, inside),
        "d2": (v, H, R, P, d2[:, :2], inside),
        "inside": (v, H, R, P, d2, inside[:, :, :1]),
        "v": (v[0], H, R, P, d2, inside),
    }
    for name, args in bad.items():
        with pytest.raises(ValueError, match=name):
            _core.jcbb(*args, gates, 100)
    with pytest.raises(ValueError, match="max_nodes"):
        _core.jcbb(v, H, R, P, d2, inside, gates, -1)


@settings(max_examples=25)
@given(
    st.integers(0, 2**32 - 1),
    st.integers(1, 4),
    st.integers(1, 4),
    st.sampled_from([1, 2]),
    st.floats(0.5, 0.999),
)
def test_jcbb_property(seed, m, L, d, alpha):
    """Any problem size and χ² level: JCBB's set is a largest reachable one of least joint d²."""
    rng = np.random.default_rng(seed)
    gates = chi2.ppf(alpha, d * np.arange(m + 1))
    gates[0] = 0.0
    v, H, R, P, d2, inside = _problem(rng, m, L, 3, d)
    got = _run([(v, H, R, P, d2, inside)], gates)[0]
    _check_best(got, _brute_force(v, H, R, P, inside, gates), v, H, R, P)
