"""Delta-Y with heading error on the bridge of Figs. 3-4: the table of docs/delta_y.md.

w→u on ``relmap/data/fig3.json`` with every AT's heading σ set to 0.5°, 1°, 3°, 5°, 10° (means
made loop-consistent), σx = σy = 5 cm as in the file and once more with σy = 1 cm: the
first-order-consistent Delta-Y (relmap's default) and the paper's formulas against the optimal
estimate, w→u against the reversed u→w, and each reduction re-run on sampled ATs against its
own prediction (Monte Carlo). Relative Frobenius errors of the 3×3 covariance.

Run: ``python benchmarks/study_delta_y.py [--samples 20000] [--seed 0]``.
"""

from __future__ import annotations

import argparse

from relmap.demo import DELTA_Y_HEADER, delta_y_rows, delta_y_study


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rows = delta_y_rows(delta_y_study(args.seed, args.samples))
    print("| " + " | ".join(DELTA_Y_HEADER) + " |")
    print("|" + "---|" * len(DELTA_Y_HEADER))
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
