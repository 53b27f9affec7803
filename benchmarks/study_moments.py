"""Beyond first order: first-order, unscented and exact moments of 20-link chains vs Monte Carlo.

Model: a chain of 20 independent links, each 1 m forward with σx = σy = 0.05 m (in the link's
parent frame) and heading error σθ = 1°, 3°, 6°, 10° per link; "straight" links have mean
heading change 0, "curved" ones 9° (the chain turns through a half circle). Every link is
Gaussian in relmap's chart ``(x, y, θ)``.

For each case the end pose's mean and covariance are computed three ways —
``compound_chain(steps)`` (first order, Eqs. 3-4), ``moments="unscented"`` (the unscented
transform one compounding at a time), the unscented transform of the whole 60-D chain input at
once (``relmap.uncertain.moments.unscented_chain(..., scheme="joint")``) and ``moments="exact"`` — and
compared with 10⁶ Monte Carlo
samples (links drawn with ``AT.sample``, headings summed without wrapping, as the exact moments
are those of the unwrapped heading). Columns: relative Frobenius error of the covariance,
``‖C - C_mc‖_F / ‖C_mc‖_F``; the Monte Carlo's own relative standard error in that norm; the
largest mean error over (x, y, θ) in units of the sampled standard deviation (the sampling
error there is 1/√N = 0.001); Mardia's skewness of the first 5·10⁴ draws
(``SampleSet.compare``; 0 for a Gaussian).

Then the cost of the exact chain moments (every prefix) for n = 100, 1000, 10 000 links, with
first-order ``compound_chain`` beside it.

Run: ``python benchmarks/study_moments.py [--samples 1000000] [--seed 0]``.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

import relmap as rm
from relmap.sim.montecarlo import SampleSet
from relmap.uncertain import moments

LINKS = 20
SIGMA_XY = 0.05
CHUNK = 50_000


def chain(turn_deg: float, sigma_deg: float, n: int = LINKS) -> rm.AT:
    mean = np.tile([1.0, 0.0, np.radians(turn_deg)], (n, 1))
    return rm.AT.from_sigmas(mean, np.tile([SIGMA_XY, SIGMA_XY, np.radians(sigma_deg)], (n, 1)))


def end_samples(links: np.ndarray) -> np.ndarray:
    """End poses ``(N, 3)`` of sampled chains ``(N, n, 3)``, heading summed without wrapping."""
    theta = np.cumsum(links[..., 2], axis=-1)
    before = theta - links[..., 2]
    c = (np.exp(1j * before) * (links[..., 0] + 1j * links[..., 1])).sum(axis=-1)
    return np.stack([c.real, c.imag, theta[:, -1]], axis=-1)


def monte_carlo(steps: rm.AT, n: int, seed: int, ref: np.ndarray):
    """Sample mean and covariance of the end pose (accumulated in chunks around ``ref``),
    the per-entry variance of the covariance estimate, and a SampleSet of the first chunk."""
    rng = np.random.default_rng(seed)
    s1 = np.zeros(3)
    s2 = np.zeros((3, 3))
    s4 = np.zeros((3, 3))
    first = None
    done = 0
    while done < n:
        k = min(CHUNK, n - done)
        d = end_samples(steps.sample(k, rng)) - ref
        if first is None:
            first = d + ref
        s1 += d.sum(axis=0)
        dd = d[:, :, None] * d[:, None, :]
        s2 += dd.sum(axis=0)
        s4 += (dd * dd).sum(axis=0)
        done += k
    mean_d = s1 / n
    cov = (s2 - n * np.outer(mean_d, mean_d)) / (n - 1)
    var_cov = (s4 / n - (s2 / n) ** 2) / n  # sampling variance of each covariance entry
    return ref + mean_d, cov, var_cov, SampleSet.of(first)


def compare(est_mean, est_cov, mc_mean, mc_cov):
    err = est_mean - mc_mean
    err[2] = (err[2] + np.pi) % (2 * np.pi) - np.pi
    sig = np.sqrt(np.diag(mc_cov))
    cov_rel = np.linalg.norm(est_cov - mc_cov) / np.linalg.norm(mc_cov)
    return cov_rel, np.abs(err / sig).max()


def accuracy(n_samples: int, seed: int) -> None:
    print(
        f"## {LINKS}-link chains, 1 m links, σxy {SIGMA_XY} m per link, Monte Carlo N = {n_samples:,}"
    )
    print()
    print(
        "| chain | σθ/link | cov err: first order | unscented | UT joint | exact | MC std. err."
        " | mean err/σ: first order | unscented | UT joint | exact | Mardia skewness |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, turn in (("straight", 0.0), ("curved (9°/link)", 9.0)):
        for sd in (1.0, 3.0, 6.0, 10.0):
            steps = chain(turn, sd)
            first = rm.compound_chain(steps, axis=0)[-1]
            uns = rm.compound_chain(steps, axis=0, moments="unscented")[-1]
            joint = rm.AT(
                *moments.unscented_chain(steps.mean, steps.cov, axis=0, scheme="joint")
            )[-1]
            ex = rm.compound_chain(steps, axis=0, moments="exact")[-1]
            ref = ex.mean.copy()
            ref[2] = steps.mean[:, 2].sum()  # the unwrapped heading mean
            mc_mean, mc_cov, var_cov, sample = monte_carlo(steps, n_samples, seed, ref)
            se = np.sqrt(var_cov.sum()) / np.linalg.norm(mc_cov)
            rows = []
            for est in (first, uns, joint, ex):
                m = est.mean.copy()
                m[2] = ref[2] + (m[2] - ref[2] + np.pi) % (2 * np.pi) - np.pi
                rows.append(compare(m, est.cov, mc_mean, mc_cov))
            skew = float(sample.compare(ex).skewness)
            print(
                f"| {name} | {sd:g}° | "
                + " | ".join(f"{100 * r[0]:.2f}%" for r in rows)
                + f" | {100 * se:.2f}% | "
                + " | ".join(f"{r[1]:.3f}" for r in rows)
                + f" | {skew:.3f} |"
            )
    print()


def best_of(fn, repeat: int = 5) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def timing() -> None:
    print("## Cost of the moments of every prefix (one chain, best of 5)")
    print()
    print("| links | exact | first order (`compound_chain`) | exact / link |")
    print("|---|---|---|---|")
    for n in (100, 1000, 10_000):
        steps = chain(9.0, 3.0, n)
        t_ex = best_of(lambda s=steps: rm.compound_chain(s, moments="exact"))
        t_fo = best_of(lambda s=steps: rm.compound_chain(s))
        print(f"| {n:,} | {1e3 * t_ex:.2f} ms | {1e3 * t_fo:.2f} ms | {1e6 * t_ex / n:.2f} µs |")
    batch = rm.AT.from_sigmas(
        np.tile([1.0, 0.0, 0.1], (1000, 100, 1)), np.tile([0.05, 0.05, 0.05], (1000, 100, 1))
    )
    t_b = best_of(lambda: rm.compound_chain(batch, moments="exact"), repeat=3)
    t_bf = best_of(lambda: rm.compound_chain(batch), repeat=3)
    print(
        f"| 1 000 chains × 100 | {1e3 * t_b:.1f} ms | {1e3 * t_bf:.1f} ms |"
        f" {1e6 * t_b / 1e5:.2f} µs |"
    )
    print()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    accuracy(args.samples, args.seed)
    timing()


if __name__ == "__main__":
    main()
