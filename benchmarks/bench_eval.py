"""relmap's trajectory commands against evo's, as commands (start-up included), side by side.

1. APE + RPE on KITTI 00 (ground truth and the ORB-SLAM2 estimate, translation part, no
   alignment, RPE delta 1 frame): ``relmap eval GT EST --rpe --relation trans`` (one process)
   against ``evo_ape kitti GT EST`` + ``evo_rpe kitti GT EST`` (two processes, evo's defaults:
   translation part, delta 1 frame).
2. Reading the ROS 1 bag (3.7 MB, three PoseStamped topics): ``relmap traj BAG --topic …``
   against ``evo_traj bag BAG …`` (both read every message of the three topics and print a
   summary).

The contenders run interleaved, ``--repeat`` times each; min and median wall-clock seconds are
reported and the ratio of the minima. Usage: ``python benchmarks/bench_eval.py [--repeat N]``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

DATA = Path(os.environ.get("RELMAP_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def timed(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def tool(name: str) -> str:
    found = shutil.which(name) or str(Path(sys.executable).parent / name)
    if not Path(found).exists():
        raise SystemExit(f"{name} not found (pip install evo, in the test extra)")
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    d = DATA / "trajectories"
    gt, est, bag = (
        str(d / "KITTI_00_gt.txt"),
        str(d / "KITTI_00_ORB.txt"),
        str(d / "ROS_example.bag"),
    )
    topics = ["groundtruth", "ORB-SLAM", "S-PTAM"]
    relmap = tool("relmap")
    cases = {
        "KITTI 00 APE + RPE": (
            [[relmap, "eval", gt, est, "--rpe", "--relation", "trans"]],
            [[tool("evo_ape"), "kitti", gt, est], [tool("evo_rpe"), "kitti", gt, est]],
        ),
        "ROS 1 bag, 3 topics": (
            [[relmap, "traj", bag, *(a for t in topics for a in ("--topic", t))]],
            [[tool("evo_traj"), "bag", bag, *topics]],
        ),
    }
    print(
        f"python {sys.version.split()[0]}, {os.cpu_count()} cores; {args.repeat} interleaved runs each"
    )
    for name, (mine, theirs) in cases.items():
        a: list[float] = []
        b: list[float] = []
        for _ in range(args.repeat):
            a.append(sum(timed(c) for c in mine))
            b.append(sum(timed(c) for c in theirs))
        a.sort()
        b.sort()
        med = lambda v: v[len(v) // 2]  # noqa: E731
        print(
            f"{name:22s} relmap min {a[0]:.3f} s, median {med(a):.3f} s | evo min {b[0]:.3f} s, "
            f"median {med(b):.3f} s | evo/relmap (min) {b[0] / a[0]:.2f}x, (median) {med(b) / med(a):.2f}x"
        )


if __name__ == "__main__":
    main()
