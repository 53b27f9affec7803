"""Monte Carlo in blocks: partial moments merged (Chan/Pébay), streams per block, in one process.

The merge is checked against the definition (central moments of the whole sample), Mardia's
statistics against his double sum over sample pairs, and the blocks against their own
definition (``SeedSequence(seed).spawn``); the cluster's side is ``tests/test_distributed.py``.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import relmap as rm
from relmap.app import validate
from relmap.errors import ClusterError, ParameterError
from relmap.lie import se2
from relmap.sim import montecarlo
from relmap.sim.montecarlo import Tally
from tests.app.test_validate import bridge_map


def _skewed(n: int, seed: int, offset: float = 0.0, scale: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = rng.exponential(size=(n, 3)) @ np.array([[1.0, 0.3, 0.0], [0.0, 1.0, 0.5], [0, 0, 0.2]])
    return offset + scale * x


def _central(d: np.ndarray) -> tuple[np.ndarray, ...]:
    e = d - d.mean(axis=0)
    return (
        d.mean(axis=0),
        np.einsum("ni,nj->ij", e, e),
        np.einsum("ni,nj,nk->ijk", e, e, e),
        np.einsum("ni,nj,nk,nl->ijkl", e, e, e, e),
    )


def _fold(parts: list[np.ndarray]) -> Tally:
    tallies = [Tally.of(p, (p**2).sum(-1), 4.0) for p in parts]
    total = tallies[0]
    for t in tallies[1:]:
        total = total.merge(t)
    return total


@pytest.mark.parametrize("cuts", [[1], [7, 8, 500], [300, 301, 302, 900]])
def test_merged_tallies_are_the_moments_of_the_whole_sample(cuts):
    d = _skewed(1000, 1)
    t = _fold(np.split(d, cuts))
    mean, m2, m3, m4 = _central(d)
    assert t.n == 1000
    np.testing.assert_allclose(t.mean, mean, rtol=1e-13)
    np.testing.assert_allclose(t.m2, m2, rtol=1e-12)
    np.testing.assert_allclose(t.m3, m3, rtol=1e-11, atol=1e-11 * np.abs(m3).max())
    np.testing.assert_allclose(t.m4, m4, rtol=1e-11)
    d2 = (d**2).sum(-1)
    assert t.nees == pytest.approx(d2.sum(), rel=1e-13) and t.inside == (d2 <= 4.0).sum()


def test_the_merge_is_stable_far_from_the_origin():
    """A spread of 1e-4 at an offset of 1e6: raw power sums would lose every digit."""
    d = _skewed(4000, 2, offset=1e6, scale=1e-4)
    t = _fold(np.array_split(d, 37))
    e = d - d.mean(axis=0)
    C = np.cov(d.T)  # two-pass, from the same rounded data
    np.testing.assert_allclose(t.m2 / 3999, C, rtol=0, atol=1e-6 * np.abs(C).max())
    m4 = np.einsum("ni,nj,nk,nl->ijkl", e, e, e, e)
    np.testing.assert_allclose(
        t.m4, m4, rtol=0, atol=1e-4 * np.abs(m4).max()
    )  # data rounded at 1e-6


def test_mardia_from_moments_is_mardias_double_sum():
    """b₁ = n⁻² Σ_ij (e_iᵀ S⁻¹ e_j)³ and b₂ = n⁻¹ Σ_i (e_iᵀ S⁻¹ e_i)² (Mardia 1970)."""
    d = _skewed(400, 3)
    t = Tally.of(d, np.zeros(400), 1.0)
    S = t.m2 / 399
    e = d - d.mean(axis=0)
    G = e @ np.linalg.inv(S) @ e.T
    skew, kurt = montecarlo._mardia(t.m3, t.m4, t.n, S)
    assert skew == pytest.approx((G**3).sum() / 400**2, rel=1e-10)
    assert kurt == pytest.approx((np.diag(G) ** 2).mean() - 15, rel=1e-10)


def test_batched_tallies_are_tallies_of_each_element():
    d = np.stack([_skewed(300, 4), _skewed(300, 5)], axis=1)  # (n, 2, 3)
    t = Tally.of(d, np.ones((300, 2)), 2.0)
    one = Tally.of(d[:, 1], np.ones(300), 2.0)
    both = Tally.of(d[:100], np.ones((100, 2)), 2.0).merge(
        Tally.of(d[100:], np.ones((200, 2)), 2.0)
    )
    for field in ("mean", "m2", "m3", "m4"):
        np.testing.assert_allclose(getattr(t, field)[1], getattr(one, field), rtol=1e-12)
        np.testing.assert_allclose(getattr(both, field), getattr(t, field), rtol=1e-10)


def test_block_streams_are_spawned_seed_sequences():
    spawned = np.random.SeedSequence(42).spawn(8)
    for j in (0, 3, 7):
        assert montecarlo.block_seed(42, j).spawn_key == spawned[j].spawn_key
        assert np.array_equal(
            montecarlo.block_rng(42, j).random(4), np.random.default_rng(spawned[j]).random(4)
        )
    fresh = montecarlo.root_seed(None)
    assert isinstance(fresh.entropy, int)
    with pytest.raises(ParameterError):
        montecarlo.root_seed(-1)


def test_how_blocks_are_grouped_into_chunks_changes_no_bit():
    """One task per block, or every block in one task: the same numbers."""
    p = validate.plan(bridge_map(np.radians(2.0)), "w", "u", method="reduce")
    runs = [validate.run(p, n=9000, seed=7, chunk_seconds=s, keep=100) for s in (1e-9, 1e9)]
    a, b = (r.agreement for r in runs)
    for field in a._fields:
        assert np.array_equal(getattr(a, field), getattr(b, field)), field
    assert np.array_equal(runs[0].samples.samples, runs[1].samples.samples)
    assert runs[0].blocks == 3 and runs[0].samples.samples.shape == (100, 3)


def test_the_sample_is_summarized_not_kept():
    v = validate.validate_query(bridge_map(1e-5), "w", "u", method="reduce", n=30_000, keep=50)
    assert v.samples.n == 30_000 and v.samples.samples.shape == (50, 3)
    a = v.agreement
    assert abs(float(a.nees) - 3.0) < 0.1 and abs(float(a.coverage) - 0.9) < 0.01
    assert a.cov_rel_error < 4 * a.cov_rel_standard_error


def test_check_of_a_linear_compounding():
    """Almost no angular error: compounding is linear, the first-order AT is exact."""
    a = rm.AT.from_sigmas([1.0, 0.0, 0.0], [0.05, 0.02, 1e-6])
    b = rm.AT.from_sigmas([2.0, 0.5, 0.0], [0.03, 0.04, 1e-6])
    c = montecarlo.check(se2.compose, a, b, estimate=a @ b, n=200_000, seed=1)
    r = c.agreement
    assert c.blocks == 4 and c.samples.n == 200_000
    assert r.cov_rel_error < 4 * r.cov_rel_standard_error
    assert np.all(np.abs(r.mean_error) < 4 * r.mean_standard_error)
    assert abs(float(r.nees) - 3) < 0.05 and abs(float(r.coverage) - 0.9) < 0.005
    assert abs(float(r.skewness)) < 0.01 and abs(float(r.excess_kurtosis)) < 0.05
    with pytest.raises(ParameterError):
        montecarlo.check(se2.compose, estimate=a)


def test_without_dask_everything_runs_here(monkeypatch):
    """No 'distributed' package: one process works; asking for a cluster says what to install."""
    monkeypatch.setitem(sys.modules, "distributed", None)
    g = bridge_map(np.radians(1.0))
    assert validate.validate_query(g, "w", "u", method="optimal", n=8).samples.n == 8
    with pytest.raises(ClusterError, match=r"relmap\[distributed\]"):
        validate.validate_query(g, "w", "u", n=8, client="tcp://127.0.0.1:8786")


def test_import_relmap_does_not_import_dask():
    code = (
        "import sys, relmap, relmap.app.validate, relmap.sim.montecarlo, relmap.sim.distributed, "
        "relmap.sim.study\n"
        "heavy = [m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed')]\n"
        "assert not heavy, heavy"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
