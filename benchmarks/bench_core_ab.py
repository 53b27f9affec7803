"""Two builds of relmap's compiled core side by side: the sparse kernels on the same inputs.

Builds the inputs once with the installed relmap (the normal matrices of city10000,
manhattanOlson3500 and sphere2500 at their optima, the ordering, a right-hand side), then times,
in one fresh process per build and round (rounds interleaved), with each build's
``relmap._core`` loaded from the given ``.so``: the minimum-degree ordering (on every entry's
node pair, and on one pair per node pair), the symbolic analysis (``SparseCholesky``), one
numeric factorization and one solve (also with the caches flushed before each call, as in the
solver's loop) and the selected inversion of every frame's block. Thread CPU time, the minimum
over repeats and rounds (the steadier figure on a shared machine).

Build the other core from another checkout (for example ``git archive <commit> src/core`` and
CMakeLists.txt, then ``cmake -S . -B b -G Ninja && ninja -C b``). Run:
``python benchmarks/bench_core_ab.py OLD.so [NEW.so] [--rounds 2]`` (NEW defaults to the
installed core).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DATA = Path(os.environ.get("RELMAP_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
GRAPHS = {
    "city10000": "posegraph2d",
    "manhattanOlson3500": "posegraph2d",
    "sphere2500": "posegraph3d",
}


def make_inputs(folder: Path) -> None:
    from relmap.io import read_graph, solve_graph

    for name, sub in GRAPHS.items():
        sol = solve_graph(read_graph(DATA / sub / f"{name}.g2o"))
        p = sol.factor.pattern
        _, node = np.unique(p.node, return_inverse=True)
        cols = np.repeat(np.arange(p.size), np.diff(p.indptr))
        a, b = node[p.indices], node[cols]
        off = a != b
        k = int(node.max()) + 1
        pairs = np.unique(np.minimum(a[off], b[off]) * k + np.maximum(a[off], b[off]))
        np.savez(
            folder / f"{name}.npz",
            k=k,
            a=a[off],
            b=b[off],
            a1=pairs // k,
            b1=pairs % k,
            indptr=p.indptr,
            indices=p.indices,
            perm=np.asarray(p.permutation, dtype=np.int64),
            data=sol._data,
            rhs=np.random.default_rng(0).normal(size=(p.size, 1)),
            groups=np.arange(p.size).reshape(-1, sol.group.dof),
        )


def _best(fn, reps: int) -> float:
    times = []
    for _ in range(reps):
        t0 = time.thread_time()
        fn()
        times.append(time.thread_time() - t0)
    return min(times) * 1e3


def _cold(fn, reps: int) -> float:
    """Like :func:`_best`, with the caches flushed before each call (a 64 MB sweep), as in the
    solver's loop, where a linearization runs between two factorizations."""
    sweep = np.zeros(8 << 20)
    times = []
    for _ in range(reps):
        sweep += 1.0
        t0 = time.thread_time()
        fn()
        times.append(time.thread_time() - t0)
    return min(times) * 1e3


def _graph(core, name: str, z: dict) -> dict[str, float]:
    k = int(z["k"].reshape(-1)[0])
    f = core.SparseCholesky(z["indptr"], z["indices"], z["perm"])
    f.factorize(z["data"])
    return {
        f"{name} ordering, every entry": _best(lambda: core.minimum_degree(k, z["a"], z["b"]), 5),
        f"{name} ordering, one pair per node pair": _best(
            lambda: core.minimum_degree(k, z["a1"], z["b1"]), 5
        ),
        f"{name} symbolic analysis": _best(
            lambda: core.SparseCholesky(z["indptr"], z["indices"], z["perm"]), 5
        ),
        f"{name} factorization": _best(lambda: f.factorize(z["data"]), 15),
        f"{name} factorization, caches flushed": _cold(lambda: f.factorize(z["data"]), 15),
        f"{name} solve": _best(lambda: f.solve(z["rhs"]), 15),
        f"{name} solve, caches flushed": _cold(lambda: f.solve(z["rhs"]), 15),
        f"{name} selected inversion": _best(lambda: f.selected_inverse_blocks(z["groups"]), 5),
    }


def measure(core_path: str, folder: Path) -> dict[str, float]:
    if core_path:
        spec = importlib.util.spec_from_file_location("relmap._core", core_path)
        core = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(core)
    else:
        from relmap import _core as core
    out = {}
    for name in GRAPHS:
        z = {key: np.ascontiguousarray(v) for key, v in np.load(folder / f"{name}.npz").items()}
        out.update(_graph(core, name, z))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", help="the other build's _core*.so")
    parser.add_argument("new", nargs="?", default="", help="this build's (default: installed)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--measure", help=argparse.SUPPRESS)  # internal: one process's timings
    args = parser.parse_args()
    if args.measure:
        print(json.dumps(measure(args.new if args.new != "-" else "", Path(args.measure))))
        return
    with tempfile.TemporaryDirectory() as tmp:
        make_inputs(Path(tmp))
        runs: dict[str, list[dict[str, float]]] = {"old": [], "new": []}
        for _ in range(args.rounds):
            for which, path in (("old", args.old), ("new", args.new or "-")):
                cmd = [sys.executable, __file__, args.old, path, "--measure", tmp]
                done = subprocess.run(cmd, check=True, capture_output=True, text=True)
                runs[which].append(json.loads(done.stdout))
    print(
        f"thread CPU time, min over repeats and {args.rounds} rounds (load {os.getloadavg()[0]:.1f})"
    )
    for key in runs["old"][0]:
        old = min(r[key] for r in runs["old"])
        new = min(r[key] for r in runs["new"])
        print(f"  {key:48s} old {old:8.2f} ms   new {new:8.2f} ms   {old / new:5.2f}x")


if __name__ == "__main__":
    main()
