"""Compounding speed: relmap vs GTSAM vs a hand-fused numpy closed form, on the same inputs.

1. N random pairs of uncertain SE(2) poses (ATs built before timing), compounded with covariance:
   - relmap: one batched ``a @ b``;
   - GTSAM, per pair: build the two Pose2, convert both covariances to GTSAM's body chart,
     compose with Jacobians, propagate, convert the result back to the paper's chart;
   - hand-fused numpy: the closed form of Eqs. (1)-(4) written out elementwise, nothing else.
2. Dead reckoning over N steps keeping every intermediate covariance:
   - relmap: ``compound_chain`` (a parallel scan);
   - GTSAM: a Python loop of ``Pose2.compose`` with Jacobians and the covariance update.

All three compute the same numbers; the script checks that before it prints timings.
Run: ``python benchmarks/bench_compound.py [--n 100000]``.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small dense blocks: threads only cost

import gtsam
import numpy as np

import relmap as rm
from relmap.lie import se2


def best_of(*fns: Callable[[], object], repeat: int) -> list[float]:
    """Smallest wall time (s) of each function over ``repeat`` rounds, calls interleaved so that
    a slow spell of this noisy machine hits all contenders alike."""
    times: list[list[float]] = [[] for _ in fns]
    for _ in range(repeat):
        for fn, record in zip(fns, times, strict=True):
            t0 = time.perf_counter()
            fn()
            record.append(time.perf_counter() - t0)
    return [min(t) for t in times]


def random_ats(rng: np.random.Generator, n: int) -> rm.AT:
    mean = np.column_stack(
        [rng.normal(0, 3, n), rng.normal(0, 3, n), rng.uniform(-np.pi, np.pi, n)]
    )
    L = rng.normal(0, 0.1, (n, 3, 3))
    return rm.AT(mean, L @ np.swapaxes(L, -1, -2) + 1e-6 * np.eye(3))


def fused_numpy(ma: np.ndarray, Ca: np.ndarray, mb: np.ndarray, Cb: np.ndarray):
    """Eqs. (1)-(4) by hand, elementwise: the fastest plain-numpy form we know."""
    c, s = np.cos(ma[:, 2]), np.sin(ma[:, 2])
    dx = c * mb[:, 0] - s * mb[:, 1]
    dy = s * mb[:, 0] + c * mb[:, 1]
    mean = np.empty_like(ma)
    mean[:, 0] = ma[:, 0] + dx
    mean[:, 1] = ma[:, 1] + dy
    mean[:, 2] = np.mod(ma[:, 2] + mb[:, 2] + np.pi, 2 * np.pi) - np.pi
    p00, p01, p02, p11, p12, p22 = (
        Ca[:, i, j] for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    )
    q00, q01, q02, q11, q12, q22 = (
        Cb[:, i, j] for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    )
    r0 = p02 - dy * p22
    r1 = p12 + dx * p22
    cc, ss, cs = c * c, s * s, c * s
    out = np.empty_like(Ca)
    out[:, 0, 0] = p00 - dy * (p02 + r0) + cc * q00 - 2 * cs * q01 + ss * q11
    out[:, 0, 1] = out[:, 1, 0] = p01 - dy * p12 + dx * r0 + cs * (q00 - q11) + (cc - ss) * q01
    out[:, 0, 2] = out[:, 2, 0] = r0 + c * q02 - s * q12
    out[:, 1, 1] = p11 + dx * (p12 + r1) + ss * q00 + 2 * cs * q01 + cc * q11
    out[:, 1, 2] = out[:, 2, 1] = r1 + s * q02 + c * q12
    out[:, 2, 2] = p22 + q22
    return mean, out


def gtsam_pairs(a: rm.AT, b: rm.AT) -> tuple[np.ndarray, np.ndarray]:
    """Per pair, as a GTSAM user would: Pose2s, body covariances, compose with Jacobians."""
    n = a.batch_shape[0]
    means, covs = np.empty((n, 3)), np.empty((n, 3, 3))
    am, ac, bm, bc = a.mean, a.cov, b.mean, b.cov
    for i in range(n):
        pa, pb = gtsam.Pose2(*am[i]), gtsam.Pose2(*bm[i])
        Ma, Mb = pa.rotation().matrix(), pb.rotation().matrix()
        Sa, Sb = ac[i].copy(), bc[i].copy()
        Sa[:2, :] = Ma.T @ Sa[:2, :]  # M⁻¹ Σ M⁻ᵀ with M = blkdiag(R, 1)
        Sa[:, :2] = Sa[:, :2] @ Ma
        Sb[:2, :] = Mb.T @ Sb[:2, :]
        Sb[:, :2] = Sb[:, :2] @ Mb
        H1, H2 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        pc = pa.compose(pb, H1, H2)
        S = H1 @ Sa @ H1.T + H2 @ Sb @ H2.T
        Mc = pc.rotation().matrix()
        S[:2, :] = Mc @ S[:2, :]
        S[:, :2] = S[:, :2] @ Mc.T
        means[i] = (pc.x(), pc.y(), pc.theta())
        covs[i] = S
    return means, covs


def gtsam_chain(steps: rm.AT) -> tuple[np.ndarray, np.ndarray]:
    """Dead reckoning in a GTSAM loop, keeping every pose and covariance (body chart)."""
    n = steps.batch_shape[0]
    means, covs = np.empty((n, 3)), np.empty((n, 3, 3))
    body = steps.to_body()
    sm = steps.mean
    pose, cov = gtsam.Pose2(), np.zeros((3, 3))
    for i in range(n):
        H1, H2 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        pose = pose.compose(gtsam.Pose2(*sm[i]), H1, H2)
        cov = H1 @ cov @ H1.T + H2 @ body[i] @ H2.T
        means[i] = (pose.x(), pose.y(), pose.theta())
        covs[i] = cov
    return means, covs


def row(label: str, seconds: float, n: int, unit: str) -> None:
    print(f"  {label:<26}{seconds * 1e3:9.2f} ms   {seconds / n * 1e9:8.1f} ns/{unit}")


def rel_err(a: np.ndarray, b: np.ndarray) -> float:
    return float((np.linalg.norm(a - b, axis=(-2, -1)) / np.linalg.norm(b, axis=(-2, -1))).max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--n", type=int, default=100_000, help="pairs and chain steps (default 100000)"
    )
    parser.add_argument("--repeat", type=int, default=15, help="repeats of the fast timings")
    args = parser.parse_args()
    n = args.n
    rng = np.random.default_rng(0)
    a, b = random_ats(rng, n), random_ats(rng, n)

    # --- 1. pairs
    ours = a @ b
    _, fused_cov = fused_numpy(a.mean, a.cov, b.mean, b.cov)
    t_gtsam = time.perf_counter()
    gt_mean, gt_cov = gtsam_pairs(a, b)
    t_gtsam = time.perf_counter() - t_gtsam
    assert rel_err(ours.cov, fused_cov) < 1e-12 and rel_err(ours.cov, gt_cov) < 1e-9
    assert np.abs(se2.minus(ours.mean, gt_mean)).max() < 1e-9
    t_relmap, t_fused = best_of(
        lambda: a @ b, lambda: fused_numpy(a.mean, a.cov, b.mean, b.cov), repeat=args.repeat
    )
    print(f"compound {n:,} pairs with covariance (same inputs, same results checked)")
    row("relmap  a @ b (batched)", t_relmap, n, "pair")
    row("hand-fused numpy", t_fused, n, "pair")
    row("GTSAM per pair", t_gtsam, n, "pair")
    print(f"  relmap vs GTSAM: {t_gtsam / t_relmap:6.0f}x faster   (target >= 100x)")
    print(f"  relmap / hand-fused: {t_relmap / t_fused:5.2f}   (target <= 1.5)")

    # --- 2. dead reckoning, every intermediate covariance kept
    g = np.random.default_rng(1)
    steps = rm.AT.from_sigmas(
        np.column_stack([g.uniform(0.05, 0.15, n), g.normal(0, 0.005, n), g.normal(0, 0.02, n)]),
        [0.005, 0.002, 0.002],
    )
    chain = rm.compound_chain(steps)
    t_gtsam_chain = time.perf_counter()
    gm, gc = gtsam_chain(steps)
    t_gtsam_chain = time.perf_counter() - t_gtsam_chain
    back = rm.AT.from_body(gm, gc)
    assert rel_err(chain.cov, back.cov) < 1e-9
    assert np.abs(se2.minus(chain.mean, gm)).max() < 1e-8
    (t_chain,) = best_of(lambda: rm.compound_chain(steps), repeat=args.repeat)
    print(f"\ndead reckoning, {n:,} steps, every covariance kept (results checked equal)")
    row("relmap compound_chain", t_chain, n, "step")
    row("GTSAM loop", t_gtsam_chain, n, "step")
    print(f"  relmap vs GTSAM: {t_gtsam_chain / t_chain:6.0f}x faster   (target >= 30x)")


if __name__ == "__main__":
    main()
