"""The sparse Cholesky of relmap's core on real normal matrices: process time per call.

For city10000 (2-D) and sphere2500 (3-D), at the optimum found by ``solve_graph``: the symbolic
analysis (ordering + ``relmap._core.SparseCholesky``), one numerical factorization, one solve,
and the marginal covariance of every frame (Takahashi's selected inversion, factorization
included). Process time (``time.process_time``, one thread), min and median of ``--repeat``:
on a machine shared with other work, wall time mostly measures the other work.

Run: ``python benchmarks/bench_sparse.py [--repeat 9]``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from relmap.io import read_graph, solve_graph
from relmap.network.sparse import SymmetricFactor

DATA = Path(os.environ.get("RELMAP_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
GRAPHS = {"city10000": "posegraph2d", "sphere2500": "posegraph3d"}


def _cpu(fn, repeat: int) -> str:
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return f"{min(times) * 1e3:6.1f} ms (median {np.median(times) * 1e3:6.1f})"


def report(name: str, folder: str, repeat: int) -> None:
    sol = solve_graph(read_graph(DATA / folder / f"{name}.g2o"))
    f, data = sol.factor, sol._data
    assert f is not None and data is not None
    rhs = np.ones(f.pattern.size)
    print(
        f"{name}: {f.pattern.size} parameters, {f.core.supernodes} supernodes,"
        f" {f.nnz_L} entries stored in L"
    )
    print(f"  symbolic analysis {_cpu(lambda: SymmetricFactor(f.pattern).core, 3)}")
    print(f"  factorization     {_cpu(lambda: f.factorize(data), repeat)}")
    print(f"  solve             {_cpu(lambda: f.solve(rhs), repeat)}")
    print(f"  every marginal    {_cpu(sol.marginals, 3)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=9)
    args = parser.parse_args()
    for name, folder in GRAPHS.items():
        report(name, folder, args.repeat)


if __name__ == "__main__":
    main()
