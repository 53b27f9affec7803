"""relmap's network commands as processes (start-up included) against a Python process running
GTSAM on the same job, interleaved, best and median of ``--repeat``.

- ``relmap query city10000.g2o 0 9999`` against: import gtsam, ``readG2o``, prior on pose 0,
  ``LevenbergMarquardtOptimizer``, ``Marginals.jointMarginalCovariance(0, 9999)``, print;
- ``relmap solve sphere2500.g2o --out F`` against: import gtsam, ``readG2o(.., True)``, prior,
  LM, ``writeG2o``.

Run: ``python benchmarks/bench_network_commands.py [--repeat 5]``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DATA = Path(os.environ.get("RELMAP_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))

GTSAM_QUERY = """
import sys, numpy as np, gtsam
graph, initial = gtsam.readG2o(sys.argv[1], False)
graph.add(gtsam.PriorFactorPose2(0, initial.atPose2(0),
          gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))))
result = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams()).optimize()
keys = gtsam.KeyVector(); keys.append(0); keys.append(int(sys.argv[2]))
print(result.atPose2(int(sys.argv[2])), gtsam.Marginals(graph, result).jointMarginalCovariance(keys).fullMatrix())
"""

GTSAM_SOLVE = """
import sys, numpy as np, gtsam
graph, initial = gtsam.readG2o(sys.argv[1], True)
graph.add(gtsam.PriorFactorPose3(0, initial.atPose3(0),
          gtsam.noiseModel.Diagonal.Variances(np.full(6, 1e-8))))
result = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams()).optimize()
gtsam.writeG2o(graph, result, sys.argv[2])
"""


def _time(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    py = sys.executable
    out = Path(tempfile.mkdtemp()) / "out.g2o"
    city = str(DATA / "posegraph2d" / "city10000.g2o")
    sphere = str(DATA / "posegraph3d" / "sphere2500.g2o")
    jobs = {
        "relmap query city10000.g2o 0 9999": (
            [py, "-m", "relmap.app.cli", "query", city, "0", "9999"],
            [py, "-c", GTSAM_QUERY, city, "9999"],
            2.0,
        ),
        "relmap solve sphere2500.g2o --out F": (
            [py, "-m", "relmap.app.cli", "solve", sphere, "--out", str(out)],
            [py, "-c", GTSAM_SOLVE, sphere, str(out)],
            1.5,
        ),
    }
    for label, (ours, theirs, target) in jobs.items():
        t_r, t_g = [], []
        for _ in range(args.repeat):  # interleaved: a slow spell hits both
            t_r.append(_time(ours))
            t_g.append(_time(theirs))
        ratio = min(t_g) / min(t_r)
        print(
            f"{label}: relmap {min(t_r):.2f} s (median {np.median(t_r):.2f}), GTSAM process"
            f" {min(t_g):.2f} s (median {np.median(t_g):.2f}): {ratio:.2f}x faster best against"
            f" best, {np.median(t_g) / np.median(t_r):.2f}x median   (target >= {target}x)"
        )


if __name__ == "__main__":
    main()
