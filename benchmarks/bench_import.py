"""How long ``import relmap`` takes, against ``import numpy`` alone.

``import relmap`` imports nothing heavy: its names are imported on first use (PEP 562), so the
first use of ``relmap.AT`` and ``relmap.AT3`` (numpy, relmap's SE(2)/SE(3) layers and its
compiled core) is timed too, against ``import numpy`` (its floor).

Run: ``python benchmarks/bench_import.py [--runs 15]``. Each import runs in a fresh interpreter;
the median over the runs is printed, with the heavy modules that ``import relmap`` and that first
use pulled in (there should be none: matplotlib, scipy.sparse, scipy.stats, scipy.special, yaml).
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
    first_use = median_seconds("import relmap; relmap.AT, relmap.AT3", runs)
    probe = (
        "import sys, relmap; relmap.AT, relmap.AT3; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in "
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
    print(f"import relmap            {(relmap - python) * 1e3:7.1f} ms  (names imported on use)")
    print(f"relmap.AT, relmap.AT3    {(first_use - python) * 1e3:7.1f} ms  (numpy included)")
    print(f"relmap's own share       {(first_use - numpy) * 1e3:7.1f} ms")
    print(f"heavy modules imported   {heavy}")


if __name__ == "__main__":
    main()
