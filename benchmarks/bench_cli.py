"""relmap's commands as processes, start-up included, against a Python process running GTSAM on
the same job.

Each contender is a fresh process, timed from its start to its exit (wall clock):

1. ``relmap query city10000.g2o 0 9999`` (read, optimize, the relative AT of 9999 seen from 0
   with its covariance, printed) against ``python -c`` running GTSAM: import, ``readG2o``, a
   prior on pose 0, Levenberg-Marquardt, ``Marginals`` and the joint marginal of poses 0 and
   9999, the relative pose and its covariance through ``between``'s Jacobians, printed.
2. ``relmap solve sphere2500.g2o --out F`` (read, optimize, write the g2o file) against GTSAM:
   import, ``readG2o`` (3-D), a prior on pose 0, Levenberg-Marquardt, ``writeG2o``.
3. ``relmap --help`` (target <= 0.2 s), beside ``python -c pass`` (the interpreter's own floor).

Contenders run interleaved, round after round, so that a slow spell of the (shared, noisy)
machine hits all alike; wall and CPU time (user + system of the process), min and median over
the rounds, and the ratios of medians, are printed (CPU time is the steadier figure when other
work loads the machine).
The ``relmap`` console script next to this interpreter is the one timed: run it from a regular
install (``pip install .``). An editable install (``pip install -e .``) times scikit-build-core's
redirecting import hook too, which compiles relmap's modules from source at every start (no
bytecode cache): measured 0.13 s more CPU per command here. Data: ``--data`` or ``$RELMAP_DATA`` or ``../shared/data``.

Run: ``python benchmarks/bench_cli.py [--rounds 5] [--data DIR]``.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

GTSAM_QUERY = """
import sys
import numpy as np
import gtsam
graph, initial = gtsam.readG2o(sys.argv[1], False)
a, b = int(sys.argv[2]), int(sys.argv[3])
prior = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))
graph.add(gtsam.PriorFactorPose2(a, initial.atPose2(a), prior))
result = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams()).optimize()
keys = gtsam.KeyVector()
keys.append(a)
keys.append(b)
joint = gtsam.Marginals(graph, result).jointMarginalCovariance(keys).fullMatrix()
H0, H1 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
d = result.atPose2(a).between(result.atPose2(b), H0, H1)
J = np.hstack([H0, H1])
print(d, J @ joint @ J.T)
"""

GTSAM_SOLVE = """
import sys
import numpy as np
import gtsam
graph, initial = gtsam.readG2o(sys.argv[1], True)
prior = gtsam.noiseModel.Diagonal.Variances(np.full(6, 1e-10))
graph.add(gtsam.PriorFactorPose3(0, initial.atPose3(0), prior))
result = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams()).optimize()
gtsam.writeG2o(graph, result, sys.argv[2])
"""


def data_root(given: str | None) -> Path:
    if given:
        return Path(given)
    env = os.environ.get("RELMAP_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "data"


def relmap_command() -> str:
    script = Path(sys.executable).with_name("relmap")
    if not script.is_file():
        sys.exit(f"no relmap console script next to {sys.executable}: pip install . first")
    return str(script)


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run(cmd: list[str]) -> tuple[float, float]:
    """Wall time and CPU time (user + system, s) of one process, from start to exit; fails
    loudly if it fails. CPU time is the steadier figure on a machine loaded by other work."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "1")}
    c0, t0 = _children_cpu(), time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    seconds, cpu = time.perf_counter() - t0, _children_cpu() - c0
    if done.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stderr}")
    return seconds, cpu


Times = dict[str, list[tuple[float, float]]]


def interleaved(commands: dict[str, list[str]], rounds: int) -> Times:
    times: Times = {name: [] for name in commands}
    for _ in range(rounds):
        for name, cmd in commands.items():
            times[name].append(run(cmd))
    return times


def report(times: Times) -> None:
    for name, t in times.items():
        wall, cpu = [w for w, _ in t], [c for _, c in t]
        print(
            f"  {name:<42}{statistics.median(wall):7.3f} s [min {min(wall):6.3f}]   "
            f"CPU {statistics.median(cpu):6.3f} s [min {min(cpu):6.3f}]"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--data", help="the shared data folder")
    args = parser.parse_args()
    data, relmap = data_root(args.data), relmap_command()
    city = data / "posegraph2d" / "city10000.g2o"
    sphere = data / "posegraph3d" / "sphere2500.g2o"
    py = sys.executable
    print(
        f"(interleaved, {args.rounds} rounds; median [min]; shared machine, load "
        f"{os.getloadavg()[0]:.1f} at the start)"
    )
    with tempfile.TemporaryDirectory() as tmp:
        out_r, out_g = str(Path(tmp, "relmap.g2o")), str(Path(tmp, "gtsam.g2o"))
        for cmd in ([relmap, "--help"], [py, "-c", "import gtsam"]):  # warm the file cache
            run(cmd)
        jobs = {
            "query": {
                "relmap query city10000.g2o 0 9999": [relmap, "query", str(city), "0", "9999"],
                "GTSAM process (read, LM, marginals)": [
                    py,
                    "-c",
                    GTSAM_QUERY,
                    str(city),
                    "0",
                    "9999",
                ],
            },
            "solve": {
                "relmap solve sphere2500.g2o --out F": [
                    relmap,
                    "solve",
                    str(sphere),
                    "--out",
                    out_r,
                ],
                "GTSAM process (read, LM, writeG2o)": [py, "-c", GTSAM_SOLVE, str(sphere), out_g],
            },
            "help": {
                "relmap --help": [relmap, "--help"],
                "python -c pass (the interpreter alone)": [py, "-c", "pass"],
            },
        }
        targets = {"query": 2.0, "solve": 1.5}
        for job, commands in jobs.items():
            print(f"\n{job}")
            times = interleaved(commands, args.rounds)
            report(times)
            (ours, ours_cpu), (theirs, theirs_cpu) = (
                (statistics.median(w for w, _ in t), statistics.median(c for _, c in t))
                for t in times.values()
            )
            if job in targets:
                print(
                    f"  GTSAM / relmap: {theirs / ours:5.2f}x wall, {theirs_cpu / ours_cpu:5.2f}x "
                    f"CPU   (target >= {targets[job]}x)"
                )
            else:
                print(
                    f"  relmap --help: {ours:.3f} s wall, {ours_cpu:.3f} s CPU (median; target "
                    f"<= 0.2 s); {ours - theirs:.3f} s wall above the interpreter's start"
                )


if __name__ == "__main__":
    main()
