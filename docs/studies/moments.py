"""Beyond first order: how far is each moment method from Monte Carlo on a long chain?

Question: for a chain of 20 links of 1 m (σx = σy = 5 cm per link, heading error σθ 1°-10° per
link, straight or turning 9° a link), how far are the end pose's mean and covariance of
first-order compounding (Eqs. 3-4), the unscented transform (one compounding at a time, or the
whole 60-D chain input at once) and the exact moments from the truth?

Answer (10⁶ samples, the table of the README's "Beyond first order"): first order is off by
0.4% at 1°, 4% at 3°, 15% at 6° and 43% at 10° per link; the unscented transform about halves
that one step at a time and does worse as one joint transform (it perturbs one link at a time,
so it never sees two heading errors together); the exact moments agree with the sample within
its own standard error (0.15%) in every case. The distribution is far from Gaussian at large σθ
(Mardia's skewness 5-11), which no Gaussian with the right moments shows. The exact moments of
every prefix cost about as much as first order: a few ms for 10 000 links.

The truth is the sample: links drawn by ``AT.sample``, headings summed without wrapping (the
exact moments are those of the unwrapped heading), in chunks, so 10⁶ samples fit in memory.

Run: ``python docs/studies/moments.py [--samples 1000000] [--seed 0]`` (about a minute).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import relmap as rm
from relmap.sim.montecarlo import SampleSet
from relmap.uncertain.moments import unscented_chain

LINKS, SIGMA_XY, CHUNK = 20, 0.05, 50_000


def chain(turn_deg: float, sigma_deg: float, n: int = LINKS) -> rm.AT:
    mean = np.tile([1.0, 0.0, np.radians(turn_deg)], (n, 1))
    return rm.AT.from_sigmas(mean, np.tile([SIGMA_XY, SIGMA_XY, np.radians(sigma_deg)], (n, 1)))


def end_poses(links: np.ndarray) -> np.ndarray:
    """End poses ``(N, 3)`` of sampled chains ``(N, n, 3)``, headings summed without wrapping."""
    theta = np.cumsum(links[..., 2], axis=-1)
    c = (np.exp(1j * (theta - links[..., 2])) * (links[..., 0] + 1j * links[..., 1])).sum(-1)
    return np.stack([c.real, c.imag, theta[:, -1]], axis=-1)


def monte_carlo(steps: rm.AT, n: int, seed: int, ref: np.ndarray):
    """Mean, covariance and the covariance's relative standard error of ``n`` sampled end
    poses (sums around ``ref``, chunk by chunk), and the first chunk as a SampleSet."""
    rng = np.random.default_rng(seed)
    s1, s2, s4, first, done = np.zeros(3), np.zeros((3, 3)), np.zeros((3, 3)), None, 0
    while done < n:
        k = min(CHUNK, n - done)
        d = end_poses(steps.sample(k, rng)) - ref
        first = d + ref if first is None else first
        dd = d[:, :, None] * d[:, None, :]
        s1, s2, s4, done = s1 + d.sum(0), s2 + dd.sum(0), s4 + (dd * dd).sum(0), done + k
    mean = s1 / n
    cov = (s2 - n * np.outer(mean, mean)) / (n - 1)
    se = np.sqrt(((s4 / n - (s2 / n) ** 2) / n).sum()) / np.linalg.norm(cov)
    return ref + mean, cov, se, SampleSet.of(first)


def errors(est: rm.AT, ref_heading: float, mc_mean, mc_cov) -> tuple[float, float]:
    """Relative Frobenius error of the covariance; largest mean error in sampled σ."""
    m = est.mean.copy()
    m[2] = ref_heading + (m[2] - ref_heading + np.pi) % (2 * np.pi) - np.pi  # unwrapped
    err = m - mc_mean
    cov_rel = np.linalg.norm(est.cov - mc_cov) / np.linalg.norm(mc_cov)
    return float(cov_rel), float(np.abs(err / np.sqrt(np.diag(mc_cov))).max())


def accuracy(n: int, seed: int) -> None:
    print(f"{LINKS} links of 1 m, σxy {SIGMA_XY} m per link; Monte Carlo N = {n:,}")
    print("| chain | σθ/link | cov. error: first order | unscented | UT, joint | exact |"
          " MC std. err. | mean error/σ: first order | unscented | UT, joint | exact |"
          " skewness |")  # fmt: skip
    print("|---" * 12 + "|")
    for name, turn in (("straight", 0.0), ("curved, 9°/link", 9.0)):
        for sd in (1.0, 3.0, 6.0, 10.0):
            steps = chain(turn, sd)
            estimates = [
                rm.compound_chain(steps, axis=0)[-1],
                rm.compound_chain(steps, axis=0, moments="unscented")[-1],
                rm.AT(*unscented_chain(steps.mean, steps.cov, axis=0, scheme="joint"))[-1],
                rm.compound_chain(steps, axis=0, moments="exact")[-1],
            ]
            ref = estimates[-1].mean.copy()
            ref[2] = steps.mean[:, 2].sum()  # the unwrapped heading
            mc_mean, mc_cov, se, sample = monte_carlo(steps, n, seed, ref)
            rows = [errors(e, ref[2], mc_mean, mc_cov) for e in estimates]
            skew = float(sample.compare(estimates[-1]).skewness)
            cov_cols = " | ".join(f"{100 * r[0]:.2f}%" for r in rows)
            mean_cols = " | ".join(f"{r[1]:.3f}" for r in rows)
            print(f"| {name} | {sd:g}° | {cov_cols} | {100 * se:.2f}% | {mean_cols} | {skew:.2f} |")


def best_of(fn, repeat: int = 5) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def cost() -> None:
    print("\nmoments of every prefix of one chain, best of 5: exact / first order")
    for n in (100, 1000, 10_000):
        steps = chain(9.0, 3.0, n)
        t_ex = best_of(lambda s=steps: rm.compound_chain(s, moments="exact"))
        t_fo = best_of(lambda s=steps: rm.compound_chain(s))
        print(f"  {n:6,} links: {1e3 * t_ex:6.2f} ms / {1e3 * t_fo:6.2f} ms")
    batch = rm.AT.from_sigmas(
        np.tile([1.0, 0.0, 0.1], (1000, 100, 1)), np.tile([0.05, 0.05, 0.05], (1000, 100, 1))
    )
    t_ex = best_of(lambda: rm.compound_chain(batch, moments="exact"), repeat=3)
    t_fo = best_of(lambda: rm.compound_chain(batch), repeat=3)
    print(f"  1 000 chains of 100 links: {1e3 * t_ex:.1f} ms / {1e3 * t_fo:.1f} ms")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    accuracy(args.samples, args.seed)
    cost()
