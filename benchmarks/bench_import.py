"""How long ``import relmap`` takes, against ``import numpy`` alone (relmap's floor).

Run: ``python benchmarks/bench_import.py [--runs 15]``. Each import runs in a fresh interpreter;
the median over the runs is printed, with the heavy modules that ``import relmap`` pulled in
(there should be none: matplotlib, scipy.sparse, scipy.stats, scipy.special, yaml).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time


def median_seconds(code: str, runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15)
    runs = parser.parse_args().runs
    python = median_seconds("pass", runs)
    numpy = median_seconds("import numpy", runs)
    relmap = median_seconds("import relmap", runs)
    probe = (
        "import sys, relmap; print(sorted(m for m in sys.modules if m.split('.')[0] in "
        "('matplotlib', 'yaml') or m.startswith(('scipy.sparse', 'scipy.stats', 'scipy.special'))))"
    )
    heavy = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    print(f"interpreter start        {python * 1e3:7.1f} ms (median of {runs})")
    print(f"import numpy             {(numpy - python) * 1e3:7.1f} ms")
    print(f"import relmap            {(relmap - python) * 1e3:7.1f} ms  (numpy included)")
    print(f"relmap's own share       {(relmap - numpy) * 1e3:7.1f} ms")
    print(f"heavy modules imported   {heavy}")


if __name__ == "__main__":
    main()
