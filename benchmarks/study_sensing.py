"""A noise sweep of ``forecast_sensing`` with ``relmap.sim.study``, here or on a Dask cluster.

On a real pose graph (default ``manhattanOlson3500``): how much would sensing the relation
between frame 0 and frame ``k`` directly, with a sensor of position σ (and heading σ/10 rad per
metre of σ), shrink the 90% position ellipse of the relation 0 → last? One point per
(k, σ); each point answers two optimal queries. The map is sent to each worker once.

Run: ``python benchmarks/study_sensing.py [--workers 2 | --scheduler tcp://host:8786]``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from relmap.io import load_map
from relmap.sim import study

DATA = Path(os.environ.get("RELMAP_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def forecast(k: int, sigma: float, g, last: int) -> dict[str, float]:
    """One point: the forecast of sensing 0 ↔ k with position σ ``sigma``."""
    cov = np.diag([sigma**2, sigma**2, (sigma / 10) ** 2])
    f = g.forecast_sensing((0, k), cov, (0, last))
    return {"position_shrink": f.position_shrink, "heading_shrink": f.heading_shrink}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    where = ap.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int)
    where.add_argument("--scheduler")
    ap.add_argument("--graph", default="manhattanOlson3500")
    args = ap.parse_args()
    g = load_map(DATA / "posegraph2d" / f"{args.graph}.g2o")
    last = max(g.frames)
    points = study.grid(k=[last // 4, last // 2, last], sigma=[0.01, 0.1, 1.0, 10.0])
    from relmap.sim.distributed import client_for

    with client_for(args.workers, args.scheduler) as client:
        t0 = time.perf_counter()
        table = study.run(forecast, points, shared={"g": g, "last": last}, client=client)
        seconds = time.perf_counter() - t0
    print(table)
    print(f"\n{len(table)} forecasts in {seconds:.1f} s")


if __name__ == "__main__":
    main()
