"""An EKF study with ``relmap.sim.study``: MRCLAM robots × association × calibration, here or on a
Dask cluster.

Each point runs ``relmap.app.localize.localize_mrclam`` (its public options only) on the UTIAS
MRCLAM dataset 6 (``../shared/data/landmarks/mrclam6``), read once and sent to each worker once
(``shared=``). Calibration choices: ``"auto"`` (the default of ``localize``: noise from the run's
own innovations, no ground truth), ``"neighbour"`` (robot ``k mod 5 + 1``'s run against its
ground truth) and ``"own"`` (the scored robot's run against its own ground truth: optimistic,
the comparison says how much). The table (one row per
point: RMSE, coverage of the 90% ellipse, ANEES, rejected readings) is printed and written as
CSV.

Run: ``python benchmarks/study_ekf.py [--workers 2 | --scheduler tcp://host:8786]
[--robots 1 2 3 4 5] [--csv ekf_study.csv]``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from relmap.app.localize import ASSOCIATIONS, calibrate_mrclam, localize_mrclam
from relmap.io.datasets import read_mrclam
from relmap.sim import study

DATA = Path(os.environ.get("RELMAP_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def ekf(robot: int, associate: str, calibration: str, data) -> dict[str, object]:
    """One point of the study: one EKF run, scored against the ground truth."""
    trained = {"auto": None, "neighbour": robot % len(data.robots) + 1, "own": robot}[calibration]
    cal = None if trained is None else calibrate_mrclam(data, trained)
    run = localize_mrclam(data, robot, associate=associate, calibration=cal)
    s = run.score
    return {
        "trained_on": run.summary()["calibration"]["trained_on"],
        "rmse_position": s.rmse_position,
        "rmse_heading": s.rmse_heading,
        "coverage_90": s.coverage_90,
        "anees": s.anees,
        "rejected": s.rejected,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    where = ap.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int)
    where.add_argument("--scheduler")
    ap.add_argument("--robots", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--csv", default=None)
    args = ap.parse_args()
    data = read_mrclam(DATA / "landmarks" / "mrclam6")
    points = study.grid(
        robot=args.robots, associate=list(ASSOCIATIONS), calibration=["auto", "neighbour", "own"]
    )
    from relmap.sim.distributed import client_for

    with client_for(args.workers, args.scheduler) as client:
        t0 = time.perf_counter()
        table = study.run(ekf, points, shared={"data": data}, client=client)
        seconds = time.perf_counter() - t0
    print(table)
    print(f"\n{len(table)} EKF runs in {seconds:.1f} s")
    if args.csv:
        table.to_csv(args.csv)
        print(f"written to {args.csv}")


if __name__ == "__main__":
    main()
