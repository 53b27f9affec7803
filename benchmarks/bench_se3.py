"""SE(3) compounding and reversal with covariance: relmap vs GTSAM's Pose3, on the same inputs.

1. N random pairs of uncertain 3-D poses (AT3s and the GTSAM Pose3s built before timing),
   compounded with first-order covariance:
   - relmap: one batched ``a @ b``;
   - GTSAM, per pair, as a Python user writes it: ``Pose3.compose(other, H1, H2)`` into 6×6
     Fortran-order Jacobians (allocated once and reused), then ``H1 Σa H1ᵀ + H2 Σb H2ᵀ`` in numpy.
     GTSAM works in its own chart (body perturbation, rotation first): the input covariances are
     given to it in that chart before timing, so it pays no conversion;
   - GTSAM compose with Jacobians only, no covariance products: GTSAM's floor in a Python loop.
2. N reversals with covariance: ``a.reverse()`` vs ``Pose3.inverse(H)`` and ``H Σ Hᵀ``.
3. Chains: B independent chains of L steps (B·L compounds), every intermediate kept: relmap
   compounds the B chains one step at a time (L batched calls of width B), and all prefixes in
   one call (``rm.compound_chain``) on the steps as stored, (B, L), and stored
   step-major, (L, B) (the order its kernel reads; (B, L) is first copied into it); GTSAM
   loops over all.
4. One pair per call (no batch): relmap's fixed overhead against GTSAM's, for a compound and
   for a reversal.

relmap compounds and reverses in its compiled core (``src/core/se3.cpp``), one implementation
for one pair and for any batch; nothing is compiled at run time.

A memory-bandwidth floor is printed with the pairs: one numpy pass that reads exactly the bytes
a compound reads (two poses, two covariances) and writes the bytes it writes (a pose, a
covariance), ``Ta + Tb`` and ``Ca + Cb`` on contiguous entry-major arrays. No implementation that
reads its inputs from memory once can beat it.

Before timing, GTSAM's results on a subsample are converted back to relmap's chart
(``AT3.from_body``) and compared; the largest differences are printed. Contenders are timed in
the same rounds, interleaved, so that a slow spell of the (shared, noisy) machine hits all alike;
relmap, being fast, runs several times per round. Times are medians (min in brackets); the
ratios are of medians from the same rounds.
Run: ``python benchmarks/bench_se3.py [--n 100000] [--chains 1000 --length 100]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable, Sequence

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small dense blocks: threads only cost

import gtsam
import numpy as np

import relmap as rm

Timing = tuple[float, float]


def timings(*fns: Callable[[], object], repeat: int, inner: Sequence[int] = ()) -> list[Timing]:
    """(median, min) wall time (s) of each function over ``repeat`` rounds, calls interleaved so
    that a slow spell of this noisy machine hits all contenders alike; ``inner[i]`` runs of
    function i per round (default 1), each one recorded."""
    counts = list(inner) + [1] * (len(fns) - len(inner))
    times: list[list[float]] = [[] for _ in fns]
    for _ in range(repeat):
        for fn, count, record in zip(fns, counts, times, strict=True):
            for _ in range(count):
                t0 = time.perf_counter()
                fn()
                record.append(time.perf_counter() - t0)
    return [(statistics.median(t), min(t)) for t in times]


def random_at3s(
    rng: np.random.Generator, n: int, *, spread: float = 3.0, sigma: float = 0.1
) -> rm.AT3:
    """Uniform rotations, Gaussian translations, dense random covariances."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    L = rng.normal(0, sigma, (n, 6, 6))
    return rm.AT3(rng.normal(0, spread, (n, 3)), q, L @ np.swapaxes(L, -1, -2) + 1e-6 * np.eye(6))


def to_gtsam(at: rm.AT3) -> tuple[list[gtsam.Pose3], np.ndarray]:
    """Pose3s and covariances in GTSAM's chart (what a GTSAM user would already hold)."""
    return [gtsam.Pose3(T) for T in at.mean], np.ascontiguousarray(at.to_body())


def gtsam_compose(pa: list, Sa: np.ndarray, pb: list, Sb: np.ndarray, *, cov: bool = True):
    n = len(pa)
    poses, covs = [None] * n, np.empty((n, 6, 6))
    H1, H2 = np.zeros((6, 6), order="F"), np.zeros((6, 6), order="F")
    for i in range(n):
        poses[i] = pa[i].compose(pb[i], H1, H2)
        if cov:
            covs[i] = H1 @ Sa[i] @ H1.T + H2 @ Sb[i] @ H2.T
    return poses, covs


def gtsam_inverse(pa: list, Sa: np.ndarray):
    n = len(pa)
    poses, covs = [None] * n, np.empty((n, 6, 6))
    H = np.zeros((6, 6), order="F")
    for i in range(n):
        poses[i] = pa[i].inverse(H)
        covs[i] = H @ Sa[i] @ H.T
    return poses, covs


def gtsam_chains(steps: list[list], covs: np.ndarray):
    """``steps[b][k]`` Pose3, ``covs[b, k]`` body covariance; every prefix of every chain kept."""
    B, L = covs.shape[:2]
    out_poses, out_covs = [[None] * L for _ in range(B)], np.empty((B, L, 6, 6))
    H1, H2 = np.zeros((6, 6), order="F"), np.zeros((6, 6), order="F")
    for b in range(B):
        pose, cov, chain, C = steps[b][0], covs[b, 0], out_poses[b], out_covs[b]
        chain[0], C[0] = pose, cov
        for k in range(1, L):
            pose = pose.compose(steps[b][k], H1, H2)
            cov = H1 @ cov @ H1.T + H2 @ covs[b, k] @ H2.T
            chain[k], C[k] = pose, cov
    return out_poses, out_covs


def relmap_chains(steps: rm.AT3) -> list[rm.AT3]:
    """``steps`` (B, L): the L prefixes of B chains, one batched compound per step."""
    acc = steps[:, 0]
    out = [acc]
    for k in range(1, steps.batch_shape[1]):
        acc = acc @ steps[:, k]
        out.append(acc)
    return out


def back_to_relmap(poses: list, covs: np.ndarray) -> rm.AT3:
    return rm.AT3.from_body(np.stack([p.matrix() for p in poses]), covs)


def rel_err(a: np.ndarray, b: np.ndarray) -> float:
    return float((np.linalg.norm(a - b, axis=(-2, -1)) / np.linalg.norm(b, axis=(-2, -1))).max())


def agreement(label: str, ours: rm.AT3, theirs: rm.AT3) -> None:
    """Largest differences of the means (4×4 matrices) and covariances (relmap's chart)."""
    mo, co = ours.mean.reshape(-1, 4, 4), ours.cov.reshape(-1, 6, 6)
    mt, ct = theirs.mean.reshape(-1, 4, 4), theirs.cov.reshape(-1, 6, 6)
    dm = float(np.abs(mo - mt).max())
    dc = float(np.abs(co - ct).max())
    rc = rel_err(co, ct)
    print(f"  check {label:<22} max |ΔT| {dm:8.1e}   max |ΔC| {dc:8.1e}   max rel ‖ΔC‖ {rc:8.1e}")
    assert dm < 1e-9 and rc < 1e-9, f"{label}: relmap and GTSAM disagree"


def row(label: str, t: tuple[float, float], n: int, unit: str) -> None:
    med, best = t
    print(f"  {label:<34}{med * 1e3:9.2f} ms  [{best * 1e3:8.2f}]  {med / n * 1e9:8.1f} ns/{unit}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--n", type=int, default=100_000, help="pairs and reversals (default 100000)"
    )
    parser.add_argument(
        "--chains", type=int, default=1000, help="independent chains (default 1000)"
    )
    parser.add_argument("--length", type=int, default=100, help="steps per chain (default 100)")
    parser.add_argument("--check", type=int, default=2000, help="subsample checked against GTSAM")
    parser.add_argument("--repeat", type=int, default=15, help="runs of each relmap timing")
    parser.add_argument("--gtsam-repeat", type=int, default=3, help="repeats of the GTSAM timings")
    args = parser.parse_args()
    n, m = args.n, min(args.check, args.n)
    rng = np.random.default_rng(0)
    a, b = random_at3s(rng, n), random_at3s(rng, n)
    pa, Sa = to_gtsam(a)
    pb, Sb = to_gtsam(b)

    # --- 1. pairs: check on a subsample, then time
    print(f"compound {n:,} SE(3) pairs with covariance")
    gp, gc = gtsam_compose(pa[:m], Sa[:m], pb[:m], Sb[:m])
    agreement(f"(first {m:,} pairs)", a[:m] @ b[:m], back_to_relmap(gp, gc))
    inner = max(1, args.repeat // args.gtsam_repeat)  # relmap runs per round
    # the floor's operands: contiguous (4, 4, n) and (6, 6, n), whatever relmap's storage
    Ta, Tb, Ca, Cb = (
        np.ascontiguousarray(np.moveaxis(x, 0, -1)) for x in (a.mean, b.mean, a.cov, b.cov)
    )
    To, Co = np.empty_like(Ta), np.empty_like(Ca)

    def floor() -> None:
        np.add(Ta, Tb, out=To)
        np.add(Ca, Cb, out=Co)

    t_rel, t_floor, t_gc, t_gj = timings(
        lambda: a @ b,
        floor,
        lambda: gtsam_compose(pa, Sa, pb, Sb),
        lambda: gtsam_compose(pa, Sa, pb, Sb, cov=False),
        repeat=args.gtsam_repeat,
        inner=(inner, inner),
    )
    row("relmap  a @ b (batched)", t_rel, n, "pair")
    row("memory floor (read + write once)", t_floor, n, "pair")
    row("GTSAM compose(H1, H2) + H Σ Hᵀ", t_gc, n, "pair")
    row("GTSAM compose(H1, H2) only", t_gj, n, "pair")
    print(f"  relmap vs GTSAM with covariance: {t_gc[0] / t_rel[0]:6.1f}x faster   (target >= 50x)")
    print(f"  relmap vs GTSAM Jacobians only:  {t_gj[0] / t_rel[0]:6.1f}x faster")
    print(f"  relmap / memory floor:           {t_rel[0] / t_floor[0]:6.1f}x the time")
    nbytes = (2 * 16 + 2 * 36 + 16 + 36) * 8
    print(
        f"  ({nbytes} bytes per pair moved: {nbytes / t_floor[0] * n / 1e9:.1f} GB/s at the floor)"
    )

    # --- 2. reversal
    print(f"\nreverse {n:,} SE(3) poses with covariance")
    gp, gc = gtsam_inverse(pa[:m], Sa[:m])
    agreement(f"(first {m:,} poses)", a[:m].reverse(), back_to_relmap(gp, gc))
    t_rrev, t_grev = timings(
        a.reverse, lambda: gtsam_inverse(pa, Sa), repeat=args.gtsam_repeat, inner=(inner,)
    )
    row("relmap  a.reverse() (batched)", t_rrev, n, "pose")
    row("GTSAM inverse(H) + H Σ Hᵀ", t_grev, n, "pose")
    print(f"  relmap vs GTSAM: {t_grev[0] / t_rrev[0]:6.1f}x faster")

    # --- 3. chains, every prefix kept
    B, L = args.chains, args.length
    g = np.random.default_rng(1)
    flat = random_at3s(g, B * L, spread=0.3, sigma=0.02)
    steps = rm.AT3.from_matrix(flat.mean.reshape(B, L, 4, 4), flat.cov.reshape(B, L, 6, 6))
    g_steps = [[gtsam.Pose3(T) for T in chain] for chain in steps.mean]
    g_covs = np.ascontiguousarray(steps.to_body())
    k = max(1, min(B, m // L))  # chains in the check
    ours = relmap_chains(steps[:k])
    gp, gc = gtsam_chains(g_steps[:k], g_covs[:k])
    theirs = back_to_relmap([p for chain in gp for p in chain], gc.reshape(-1, 6, 6))
    ours_all = rm.AT3.stack(ours, axis=1)  # (k, L), chain-major like GTSAM's
    print(f"\n{B:,} chains of {L} SE(3) steps ({B * L:,} compounds), every prefix kept")
    agreement(f"(first {k} chains)", ours_all, theirs)
    agreement("compound_chain", rm.compound_chain(steps[:k], axis=1), theirs)
    # the same steps stored step-major, (L, B): the chain axis first, as the kernel reads them
    steps_lb = rm.AT3.from_matrix(np.swapaxes(steps.mean, 0, 1), np.swapaxes(steps.cov, 0, 1))
    ours_lb = rm.compound_chain(steps_lb[:, :k], axis=0)
    agreement("compound_chain (L, B)", rm.AT3(*(np.swapaxes(x, 0, 1) for x in (
        ours_lb.translation, ours_lb.rotation, ours_lb.cov))), theirs)  # fmt: skip
    t_rch, t_rcc, t_rlb, t_gch = timings(
        lambda: relmap_chains(steps),
        lambda: rm.compound_chain(steps, axis=1),
        lambda: rm.compound_chain(steps_lb, axis=0),
        lambda: gtsam_chains(g_steps, g_covs),
        repeat=args.gtsam_repeat,
        inner=(inner, inner, inner),
    )
    row(f"relmap  {L} batched a @ b of {B}", t_rch, B * L, "step")
    row("relmap  compound_chain on (B, L)", t_rcc, B * L, "step")
    row("relmap  compound_chain on (L, B)", t_rlb, B * L, "step")
    row("GTSAM loop", t_gch, B * L, "step")
    print(f"  relmap vs GTSAM, step by step:        {t_gch[0] / t_rch[0]:6.1f}x faster")
    print(f"  relmap vs GTSAM, one call, (B, L):    {t_gch[0] / t_rcc[0]:6.1f}x faster")
    print(f"  relmap vs GTSAM, one call, (L, B):    {t_gch[0] / t_rlb[0]:6.1f}x faster")

    # --- 4. one pair per call
    reps = 2000
    a0, b0 = a[0], b[0]
    pa0, pb0, Sa0, Sb0 = pa[0], pb[0], Sa[0], Sb[0]
    H1, H2 = np.zeros((6, 6), order="F"), np.zeros((6, 6), order="F")
    a0 @ b0, a0.reverse()  # warm-up (first calls: allocator, caches)

    def relmap_single() -> None:
        for _ in range(reps):
            a0 @ b0

    def gtsam_single() -> None:
        for _ in range(reps):
            pa0.compose(pb0, H1, H2)
            H1 @ Sa0 @ H1.T + H2 @ Sb0 @ H2.T

    def relmap_single_reverse() -> None:
        for _ in range(reps):
            a0.reverse()

    def gtsam_single_reverse() -> None:
        for _ in range(reps):
            pa0.inverse(H1)
            H1 @ Sa0 @ H1.T

    t_r1, t_g1, t_rr1, t_gr1 = timings(
        relmap_single, gtsam_single, relmap_single_reverse, gtsam_single_reverse, repeat=args.repeat
    )
    print("\none pair per call (no batch axis): fixed overhead")
    row("relmap  a @ b", t_r1, reps, "call")
    row("GTSAM compose(H1, H2) + H Σ Hᵀ", t_g1, reps, "call")
    print(f"  relmap / GTSAM: {t_r1[0] / t_g1[0]:5.1f}x the time")
    row("relmap  a.reverse()", t_rr1, reps, "call")
    row("GTSAM inverse(H) + H Σ Hᵀ", t_gr1, reps, "call")
    print(f"  relmap / GTSAM: {t_rr1[0] / t_gr1[0]:5.1f}x the time")


if __name__ == "__main__":
    main()
