"""relmap.filter.segments: the steps of a relative motion between cuts, compounded by prefix
sums, against :func:`relmap.models.dead_reckon` (the paper's compounding, Eqs. 1-4, step by
step through :func:`relmap.compound_chain`) of each segment alone, to 1e-12."""

from __future__ import annotations

import numpy as np
import pytest

from relmap.filter.segments import chains
from relmap.lie import se2
from relmap.models import AlphaNoise, DiffDrive, DistanceNoise, Odometry, WheelNoise, dead_reckon

DRIVE = DiffDrive(0.05, 0.3)

#: name: (model, how to draw its N inputs)
MODELS = {
    "distance-midpoint": (
        Odometry(DistanceNoise(0.01, 0.02, 0.003)),
        lambda rng, n: np.column_stack([rng.uniform(-0.1, 0.4, n), rng.normal(0, 0.2, n)]),
    ),
    "distance-arc": (
        Odometry(DistanceNoise(0.01, 0.02, 0.003), integration="arc"),
        lambda rng, n: np.column_stack([rng.uniform(-0.1, 0.4, n), rng.normal(0, 0.2, n)]),
    ),
    "wheel": (
        Odometry(WheelNoise(sigma=0.02, k=0.001), drive=DRIVE),
        lambda rng, n: rng.normal(3.0, 1.5, (n, 2)),
    ),
    "alpha": (
        Odometry(AlphaNoise(0.01, 0.002, 0.01, 0.001)),
        lambda rng, n: np.column_stack([rng.uniform(0.0, 0.4, n), rng.normal(0, 0.3, n)]),
    ),
}


def dead_reckoned(model: Odometry, u: np.ndarray):
    return dead_reckon(u, model.noise, integration=model.integration, drive=model.drive)


def segment_start(cut: np.ndarray, k: int) -> int:
    """The last cut strictly before time k (time 0 always starts one)."""
    return max([0, *np.flatnonzero(cut[:k])])


def assert_chain(mean, cov, want, what):
    """The composed step equals the dead-reckoned one: position (to 1e-12 of the distance, at
    least a metre) and heading to 1e-12, the covariance to 1e-12 of its size."""
    e = se2.minus(mean, want.mean)
    dm = max(np.abs(e[:2]).max() / max(1.0, np.abs(want.mean[:2]).max()), abs(e[2]))
    dc = np.abs(cov - want.cov).max() / max(np.abs(want.cov).max(), 1e-300)
    assert dm <= 1e-12 and dc <= 1e-12, f"{what}: |Δmean| {dm:.1e}, |ΔP|/|P| {dc:.1e}"


@pytest.mark.parametrize("name", sorted(MODELS))
def test_each_chain_is_its_segment_dead_reckoned(name):
    """Cuts anywhere (at random, at the first and the last time, two in a row): at every time
    k the chain is the dead reckoning of the steps from the last cut before k to k."""
    model, inputs = MODELS[name]
    rng = np.random.default_rng(sum(map(ord, name)))
    N = 300
    u = inputs(rng, N)
    cut = rng.random(N + 1) < 0.05
    cut[[0, 1, 2, 150, N]] = True
    ch = chains(model, u, cut)
    assert ch.mean.shape == (N + 1, 3) and ch.cov.shape == (N + 1, 3, 3)
    np.testing.assert_array_equal(ch.mean[0], 0.0)
    np.testing.assert_array_equal(ch.cov[0], 0.0)
    for k in range(1, N + 1):
        c = segment_start(cut, k)
        want = dead_reckoned(model, u[c:k])[-1]
        assert_chain(ch.mean[k], ch.cov[k], want, f"time {k} (segment from {c})")


def test_no_cut_is_the_whole_run_and_a_cut_everywhere_each_step():
    model, inputs = MODELS["distance-midpoint"]
    rng = np.random.default_rng(1)
    u = inputs(rng, 500)
    whole = chains(model, u, np.zeros(501, bool))
    run = dead_reckoned(model, u)
    for k in (1, 10, 250, 500):
        assert_chain(whole.mean[k], whole.cov[k], run[k], f"time {k}")
    each = chains(model, u, np.ones(501, bool))
    steps = model.increment(u)
    for k in range(1, 501):
        assert_chain(each.mean[k], each.cov[k], steps[k - 1], f"step {k}")


def test_the_chains_ending_at_given_times():
    """``at``: only the chains ending at those times (what a run needs: the reading times)."""
    model, inputs = MODELS["wheel"]
    rng = np.random.default_rng(2)
    u = inputs(rng, 100)
    cut = np.zeros(101, bool)
    cut[[0, 17, 40, 41, 90]] = True
    at = np.array([17, 40, 41, 90, 100])
    every = chains(model, u, cut)
    some = chains(model, u, cut, at)
    np.testing.assert_array_equal(some.mean, every.mean[at])
    # (summed in other pieces: equal to rounding)
    np.testing.assert_allclose(some.cov, every.cov[at], rtol=1e-12, atol=1e-18)
    for j, k in enumerate(at):
        c = segment_start(cut, k)
        assert_chain(some.mean[j], some.cov[j], dead_reckoned(model, u[c:k])[-1], f"time {k}")


def test_batched_parameters_give_each_models_chains():
    """A batch of noise parameters (B,): the covariance (B, N + 1, 3, 3), each filter's what
    its parameters give alone; the mean, which the noise does not move, shared."""
    rng = np.random.default_rng(3)
    N, B = 120, 5
    u = MODELS["distance-midpoint"][1](rng, N)
    cut = rng.random(N + 1) < 0.1
    k_s, k_theta = np.geomspace(1e-4, 1e-1, B), rng.uniform(0.001, 0.05, B)
    model = Odometry(DistanceNoise(k_s, k_theta, 0.003))
    ch = chains(model, u, cut)
    assert ch.mean.shape == (N + 1, 3) and ch.cov.shape == (B, N + 1, 3, 3)
    for b in range(B):
        one = Odometry(DistanceNoise(k_s[b], k_theta[b], 0.003))
        alone = chains(one, u, cut)
        np.testing.assert_array_equal(ch.mean, alone.mean)
        np.testing.assert_allclose(ch.cov[b], alone.cov, rtol=1e-14, atol=1e-20)
        for k in (1, 60, N):
            c = segment_start(cut, k)
            assert_chain(ch.mean[k], ch.cov[b, k], dead_reckoned(one, u[c:k])[-1], f"{b}, {k}")


def test_a_short_chain_after_a_long_segment():
    """A long stretch without readings (3000 steps: 5 minutes of 10 Hz odometry), then
    readings at every step: each chain after it is its own steps dead-reckoned, to 1e-12 —
    not the rounding of the long segment's sums carried into the next."""
    model, inputs = MODELS["distance-midpoint"]
    rng = np.random.default_rng(5)
    L = 3000
    u = inputs(rng, L + 5)
    cut = np.zeros(L + 6, bool)
    cut[[0, L, L + 1, L + 2]] = True
    ch = chains(model, u, cut)
    for k in (L, L + 1, L + 2, L + 3, L + 5):
        c = segment_start(cut, k)
        assert_chain(ch.mean[k], ch.cov[k], dead_reckoned(model, u[c:k])[-1], f"time {k}")
