"""`relmap localize` on every shared landmark log: the time it takes, the noise the run's own
innovations give, and how the filter scores against the ground truth.

For each MRCLAM robot and association mode (signatures, mahalanobis, jcbb) and for CMU Plaza:
the wall-clock time of :func:`relmap.app.localize.localize_mrclam` (``localize_plaza``) —
autocalibration, the filter, dead reckoning and scoring —, the filter's scores (position RMSE,
coverage of the 90% ellipse, ANEES), and the calibration (:class:`relmap.filter.autocalibration
.Calibrated`): the models' noise parameters, the readings' Student-t dof ν, the clock offset, the
range scale, the turn-rate bias, the whitening factor of the update's σ and the lag-one
correlation of the range innovations before and after, the log-likelihood, and without
signatures the clutter's fraction of the readings and how many readings of no landmark were used.
``--from-run`` adds the filters with the noise of the next robot's run against its ground truth.
The issue-14 targets are printed below the table.

Usage: ``python benchmarks/bench_localize.py [--modes signatures,mahalanobis] [--robots 1,2]
[--no-plaza] [--from-run]`` (all of it takes minutes: ``--modes signatures`` is a check).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

DATA = Path(os.environ.get("RELMAP_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def noise(cal) -> str:
    """The models' noise parameters by name (m, rad)."""
    values = [(k, float(getattr(m, k))) for m in (cal.motion, cal.sensor)
              for k in m.noise_parameters]  # fmt: skip
    return " ".join(f"{k} {v:.3g}" for k, v in values)


def row(name: str, run, seconds: float | None) -> str:
    s, cal = run.score, run.calibration
    head = f"{name:28s} {'' if seconds is None else f'{seconds:6.1f}':>6s} "
    head += f"{s.rmse_position:7.3f} {s.coverage_90:6.2f} {s.anees:7.2f}   "
    if seconds is None:  # the noise of another run against its ground truth
        return head + f"from {cal.trained_on}: {noise(cal)}"
    c0, c1 = cal.correlation
    out = (f"{noise(cal)} ν {cal.nu:.3g}\n{'':58s}delay {cal.delay:+.2f} s  scale "
           f"{cal.scale:.3f}  bias {cal.turn_bias:+.4f} rad/s  σ x{cal.inflation:.2f}  "
           f"ρ {c0:.2f} -> {c1:.2f}  loglik {cal.loglik:.1f}")  # fmt: skip
    r = run.readings
    if r["not_in_map"]:  # readings of no landmark offered: clutter
        out += (f"  clutter {cal.clutter_fraction:.2f} (λ {cal.clutter:.3g}), not in map used "
                f"{r['not_in_map_used']}/{r['not_in_map']}")  # fmt: skip
    return head + out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", default="signatures,mahalanobis,jcbb")
    ap.add_argument("--robots", default="1,2,3,4,5", help="MRCLAM robots")
    ap.add_argument("--no-plaza", action="store_true", help="skip CMU Plaza")
    ap.add_argument("--from-run", action="store_true", help="also the noise of the next robot")
    args = ap.parse_args()
    from relmap.app.localize import calibrate_mrclam, localize_mrclam, localize_plaza
    from relmap.io import read_mrclam, read_plaza

    mrclam = read_mrclam(DATA / "landmarks" / "mrclam6")
    robots = [int(k) for k in args.robots.split(",")]
    print(f"{'run':28s} {'time s':>6s} {'RMSE m':>7s} {'cov90':>6s} {'ANEES':>7s}   calibration")
    rmse: dict[str, list[float]] = {}
    for mode in args.modes.split(","):
        for k in robots:
            t0 = time.perf_counter()
            run = localize_mrclam(mrclam, k, associate=mode)
            dt = time.perf_counter() - t0
            rmse.setdefault(mode, []).append(run.score.rmse_position)
            print(row(f"robot {k} {mode}", run, dt), flush=True)
            if args.from_run and mode == "signatures":
                old = localize_mrclam(mrclam, k, calibration=calibrate_mrclam(mrclam, k % 5 + 1))
                print(row(f"robot {k} {mode} (from-run)", old, None), flush=True)
    if not args.no_plaza:
        plaza_data = read_plaza(DATA / "landmarks" / "plaza2")
        for mode in ("signatures", "mahalanobis"):
            t0 = time.perf_counter()
            plaza = localize_plaza(plaza_data, associate=mode)
            print(row(f"Plaza {mode}", plaza, time.perf_counter() - t0), flush=True)
    for mode, r in rmse.items():
        print(f"mean position RMSE over robots {args.robots}, {mode}: {sum(r) / len(r):.3f} m")
    print(
        "issue 14's targets: signatures coverage_90 0.85-0.95 and ANEES 0.7-1.5 on every robot, "
        "mean RMSE <= 0.20 m; Mahalanobis RMSE <= 1.25x signatures and coverage_90 >= 0.80; "
        "Plaza coverage_90 0.85-0.95, RMSE <= 0.408 m; issue 31: `relmap localize` of one MRCLAM "
        "robot, autocalibration included, <= 10 s as a command (the times above include the "
        "filter, dead reckoning and scoring, not reading the files)"
    )


if __name__ == "__main__":
    main()
