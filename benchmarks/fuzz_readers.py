"""A longer fuzz run of every reader than the test suite's (tests/test_fuzz_readers.py): valid
inputs mutated at random (tests/fuzzing.py) must be read or refused with a RelmapError.

Prints, per reader, how many mutated inputs were read, refused, and raised anything else (the
last column must be 0), and the first traceback of each unexpected type.
Run: ``python benchmarks/fuzz_readers.py [--count 2000] [--seed 1]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tests/fuzzing.py

from relmap.io import load_map, read_graph
from relmap.io.datasets import read_mrclam, read_plaza
from tests import fuzzing


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=2000, help="inputs per text reader")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    runs = [
        ("g2o 2-D", lambda n, s: fuzzing.fuzz_text_reader(read_graph, fuzzing.G2O_2D, ".g2o", n, s)),
        ("TORO 2-D", lambda n, s: fuzzing.fuzz_text_reader(read_graph, fuzzing.TORO_2D, ".graph", n, s)),
        ("g2o 3-D", lambda n, s: fuzzing.fuzz_text_reader(read_graph, fuzzing.G2O_3D, ".g2o", n, s)),
        ("TORO 3-D", lambda n, s: fuzzing.fuzz_text_reader(read_graph, fuzzing.TORO_3D, ".graph", n, s)),
        ("map YAML", lambda n, s: fuzzing.fuzz_text_reader(load_map, fuzzing.MAP_YAML, ".yaml", n, s)),
        ("map JSON", lambda n, s: fuzzing.fuzz_text_reader(load_map, fuzzing.MAP_JSON, ".json", n, s)),
        ("MRCLAM", lambda n, s: fuzzing.fuzz_folder_reader(read_mrclam, fuzzing.mrclam_folder, n // 4, s)),
        ("Plaza", lambda n, s: fuzzing.fuzz_folder_reader(read_plaza, fuzzing.plaza_folder, n // 4, s)),
    ]  # fmt: skip
    total_unexpected = 0
    print(f"{'reader':10s}{'inputs':>8s}{'read':>8s}{'refused':>9s}{'unexpected':>12s}{'s':>7s}")
    for name, fuzz in runs:
        t0 = time.perf_counter()
        outcome = fuzz(args.count, args.seed)
        seconds = time.perf_counter() - t0
        n = sum(outcome.values())
        total_unexpected += outcome.unexpected
        print(
            f"{name:10s}{n:8d}{outcome['read']:8d}{outcome['refused']:9d}"
            f"{outcome.unexpected:12d}{seconds:7.1f}"
        )
        for kind, example in outcome.examples.items():
            print(f"  {kind} ({outcome[kind]}×), first:\n{example}")
    print(f"unexpected exception types in all: {total_unexpected}")
    return 1 if total_unexpected else 0


if __name__ == "__main__":
    raise SystemExit(main())
