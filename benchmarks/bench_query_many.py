"""Solve once, query many: a map keeps its joint solve, so further queries reuse it.

On city10000 (``../shared/data/posegraph2d``): load the map, the first query 0 → 9999 (one
joint solve), then ten more pairs in the same part of the network (no solve), timed one by one;
and ``query_many`` of ten pairs on a fresh map, counting the solves.

Run: ``python benchmarks/bench_query_many.py [--graph city10000.g2o]``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from relmap.io import load_map
from relmap.network import optimal

DATA = Path(os.environ.get("RELMAP_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
PAIRS = [(10, 5000), (123, 9876), (0, 9999), (5, 6), (7000, 20), (1, 2), (300, 301),
         (9998, 9999), (4000, 4500), (2, 9000)]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", default="city10000.g2o")
    args = parser.parse_args()
    path = DATA / "posegraph2d" / args.graph
    t0 = time.perf_counter()
    g = load_map(path)
    t1 = time.perf_counter()
    first = g.query(0, 9999)
    t2 = time.perf_counter()
    times = []
    for a, b in PAIRS:
        s = time.perf_counter()
        g.query(a, b)
        times.append(time.perf_counter() - s)
    ms = 1e3 * np.array(times)
    print(f"{args.graph}: load {t1 - t0:.2f} s, first query {t2 - t1:.2f} s "
          f"({first.iterations} iterations, converged {first.converged})")  # fmt: skip
    print(f"  next {len(PAIRS)} queries: min {ms.min():.2f} ms, median {np.median(ms):.2f} ms, "
          f"max {ms.max():.2f} ms")  # fmt: skip
    solves = []
    real = optimal.optimize
    optimal.optimize = lambda *a, **k: solves.append(1) or real(*a, **k)
    try:
        fresh = load_map(path)
        s = time.perf_counter()
        fresh.query_many(PAIRS)
        total = time.perf_counter() - s
    finally:
        optimal.optimize = real
    print(
        f"  query_many of {len(PAIRS)} pairs on a fresh map: {len(solves)} solve(s), {total:.2f} s"
    )


if __name__ == "__main__":
    main()
