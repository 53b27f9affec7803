"""Monte Carlo validation of an optimal query, one process against a local Dask cluster.

On ``manhattanOlson3500`` (``../shared/data/posegraph2d``), the query 0 → 3499 by the optimal
method: every sample re-solves the 5 598-AT pose graph. In one run, interleaved and repeated:

1. ``relmap.app.validate.run(plan, n=N)`` in this process;
2. the same on a ``LocalCluster`` of ``--workers`` processes (one thread each), started once
   and warmed (each worker loads relmap and its kernels) before timing; the map is scattered
   to the workers inside every timed run;
3. the two results compared bit for bit (the same seed must give the same numbers);
4. the overhead of distribution: with a draw that does no work, the cost of one block sent,
   scheduled, computed and merged (``relmap.sim.montecarlo.run``), and of scattering the map.

From those figures: T(N workers) ≈ T₁ / N + overhead, so the expected speed-up on N workers.

Run: ``python benchmarks/bench_distributed.py [--samples 64] [--repeat 2] [--workers 2]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np

from relmap.app import validate
from relmap.io import load_map
from relmap.sim import montecarlo
from relmap.sim.distributed import local_client

DATA = Path(os.environ.get("RELMAP_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def _nothing(problem, rng, m):  # a draw that costs (almost) nothing: what is left is overhead
    return np.zeros((m, 3)) + rng.standard_normal((m, 3)) * 1e-3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--graph", default="manhattanOlson3500")
    args = ap.parse_args()

    g = load_map(DATA / "posegraph2d" / f"{args.graph}.g2o")
    last = max(g.frames)
    p = validate.plan(g, 0, last, method="optimal")
    print(
        f"{args.graph}: query 0 → {last} by {p.estimate.method}, {len(p.names)} ATs sampled, "
        f"{args.samples} samples ({-(-args.samples // validate.BLOCK['optimal'])} blocks of "
        f"{validate.BLOCK['optimal']}); one sample (pilot) {p.pilot_seconds:.2f} s; "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    with local_client(args.workers) as client:
        t0 = time.perf_counter()
        validate.run(p, n=validate.BLOCK["optimal"] * args.workers, seed=99, client=client)
        print(f"warm-up on {args.workers} workers: {time.perf_counter() - t0:.1f} s")
        here, there = [], []
        for r in range(args.repeat):
            t0 = time.perf_counter()
            a = validate.run(p, n=args.samples, seed=r)
            here.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            b = validate.run(p, n=args.samples, seed=r, client=client)
            there.append(time.perf_counter() - t0)
            same = all(
                np.array_equal(getattr(a.agreement, f), getattr(b.agreement, f))
                for f in a.agreement._fields
            ) and np.array_equal(a.samples.cov, b.samples.cov)
            print(
                f"run {r}: 1 process {here[-1]:.1f} s, {args.workers} workers {there[-1]:.1f} s "
                f"({here[-1] / there[-1]:.2f}×), {b.blocks} blocks, bitwise equal: {same}"
            )
            assert same, "the same seed must give the same numbers"

        # overhead of distribution: blocks of a draw that does no work
        n_small = 2000
        t0 = time.perf_counter()
        c = montecarlo.run(_nothing, None, p.estimate.at, n=n_small, seed=0, block=1,
                           client=client, chunk_seconds=1e-9)  # fmt: skip
        per_block = (time.perf_counter() - t0) / n_small
        t0 = time.perf_counter()
        montecarlo.run(_nothing, None, p.estimate.at, n=n_small, seed=0, block=1)
        per_block_here = (time.perf_counter() - t0) / n_small
        t0 = time.perf_counter()
        for _ in range(3):
            client.cancel([client.scatter(p.problem, broadcast=True, hash=False)])
        scatter = (time.perf_counter() - t0) / 3
    t1, tn = min(here), min(there)
    print(
        f"\n1 process: min {t1:.1f} s, median {statistics.median(here):.1f} s "
        f"({t1 / args.samples:.2f} s per sample)"
    )
    print(
        f"{args.workers} workers: min {tn:.1f} s, median {statistics.median(there):.1f} s; "
        f"speed-up min/min {t1 / tn:.2f}×, median/median "
        f"{statistics.median(here) / statistics.median(there):.2f}×"
    )
    print(
        f"overhead: one block through the scheduler, 1 thread each: {per_block * 1e3:.2f} ms "
        f"({c.work.chunks} chunks; in process {per_block_here * 1e3:.2f} ms); scattering the map "
        f"({len(p.names)} ATs) to {args.workers} workers: {scatter * 1e3:.0f} ms"
    )
    compute = t1 / args.samples
    for n_workers in (2, 4, 8, 16, 50):
        blocks = -(-args.samples // validate.BLOCK["optimal"])
        waves = -(-blocks // n_workers)  # whole blocks per worker: the tail
        t = waves * validate.BLOCK["optimal"] * compute + scatter + per_block * blocks
        print(
            f"expected on {n_workers:2d} workers ({args.samples} samples): {t:.1f} s, "
            f"{t1 / t:.1f}×; with 10 000 samples: "
            f"{(-(-2500 // n_workers) * 4 * compute + scatter + per_block * 2500) / 60:.1f} min "
            f"vs {10_000 * compute / 60:.0f} min in one process"
        )


if __name__ == "__main__":
    main()
