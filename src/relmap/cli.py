"""The ``relmap`` command. Subcommands import their work lazily, so the command starts fast."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from relmap import _numba
from relmap.errors import RelmapError

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing at start-up
if TYPE_CHECKING:
    from relmap.at3 import AT3


def _demo(args: argparse.Namespace) -> int:
    from pathlib import Path

    from relmap._progress import TerminalProgress
    from relmap.demo import print_demo, run
    from relmap.demo_report import write_report
    from relmap.errors import ParameterError

    if args.samples < 100:
        raise ParameterError(f"--samples must be at least 100; got {args.samples}")
    if args.data is not None and not Path(args.data, "landmarks", "mrclam6").is_dir():
        raise ParameterError(f"--data {args.data}: no landmarks/mrclam6 folder in it")
    bar = TerminalProgress("relmap demo")
    try:
        with _numba.one_shot():  # small problems, run once: numba's start-up would not pay
            demo = run(
                seed=args.seed,
                samples=args.samples,
                data=args.data,
                progress=lambda text: bar.update(text, force=True),
            )
        index = write_report(demo, args.out, progress=lambda text: bar.update(text, force=True))
    finally:
        bar.close()
    print_demo(demo)
    print(f"\nReport written to {index}")
    return 0


def _validate(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from relmap._progress import TerminalProgress
    from relmap.io import load_map
    from relmap.validate import validate_query

    g = load_map(args.map)
    src, dst = _frame(g, args.src), _frame(g, args.dst)
    bar = TerminalProgress(f"validating {args.src} → {args.dst}")
    try:
        v = validate_query(
            g,
            src,
            dst,
            method=args.method,
            n=args.n,
            seed=args.seed,
            progress=lambda k, n: bar.update(f"sample {k}/{n}"),
            moments=args.moments,
        )
    finally:
        bar.close()
    s = v.summary()
    if args.json:
        print(json.dumps(s))
        return 0
    a = v.agreement
    dof = s["dof"]
    print(
        f"Monte Carlo check of frame {dst} seen from frame {src} ({v.estimate.method}; "
        f"{s['n']:,} sampled maps, seed {args.seed}, {s['seconds']:.2f} s)"
    )
    if v.estimate.expression:
        print(f"  expression: {v.estimate.expression}")
    print(f"  sampled ATs: {', '.join(v.names)}")
    names = ["x", "y", "θ"] if dof == 3 else ["x", "y", "z", "φx", "φy", "φz"]
    pred = np.sqrt(np.diag(np.asarray(s["predicted"]["cov"])))
    emp = np.sqrt(np.diag(np.asarray(s["empirical"]["cov"])))
    print(f"  {'':4s}{'mean error':>14s}{'(σ units)':>11s}{'σ predicted':>14s}{'σ sampled':>12s}")
    for k, nm in enumerate(names):
        print(
            f"  {nm:4s}{a.mean_error[k]:14.4g}{a.mean_error_sigmas[k]:11.3f}"
            f"{pred[k]:14.4g}{emp[k]:12.4g}"
        )
    print(
        f"  covariance relative error {s['cov_rel_error']:.2%} "
        f"(sampling error ±{s['cov_rel_standard_error']:.2%})"
    )
    lin = s["predicted_linearization"]
    if lin is not None:
        print(
            f"  first order vs exact moments (predicted, no sampling): covariance "
            f"{lin['cov_rel_error']:.2%} off, mean {lin['mean_error_sigmas']:.3g}σ off"
            + ("" if s["moments"] == "first_order" else f" (this query: {s['moments']})")
        )
    print(f"  NEES {s['nees']:.3f} (expected {s['nees_expected']} if the covariance is right)")
    print(f"  {s['coverage']:.1%} of the samples inside the {s['probability']:.0%} ellipsoid")
    print(
        f"  Mardia skewness {s['mardia_skewness']:.4f}, excess kurtosis "
        f"{s['mardia_excess_kurtosis']:.4f} (0 and 0 for a Gaussian)"
    )
    return 0


def _frame(g, name: str):  # type: ignore[no-untyped-def]
    """The frame whose string form is ``name`` (g2o/TORO ids are integers)."""
    from relmap.errors import UnknownFrameError

    matches = [f for f in g.frames if str(f) == name]
    if not matches:
        raise UnknownFrameError(f"no frame {name!r} in the map")
    if len(matches) > 1:
        raise UnknownFrameError(f"frame name {name!r} is ambiguous: {matches!r}")
    return matches[0]


def _query(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from relmap.at3 import AT3
    from relmap.io import load_map

    with _numba.one_shot():
        g = load_map(args.map)
        src, dst = _frame(g, args.src), _frame(g, args.dst)
        est = g.query(src, dst, method=args.method, on_irreducible=args.on_irreducible)
    at = est.at
    spatial = isinstance(at, AT3)
    if args.json:
        out = {
            "from": src,
            "to": dst,
            "method": est.method,
            "expression": est.expression,
            "mean": (at.vector if spatial else at.mean).tolist(),
            "cov": at.cov.tolist(),
            "iterations": est.iterations,
            "dropped": list(est.dropped),
        }
        print(json.dumps(out))
        return 0
    how = est.method + (f", {est.iterations} iterations" if est.iterations is not None else "")
    print(f"AT of frame {dst} seen from frame {src} ({how})")
    if est.expression:
        print(f"  expression: {est.expression}")
        for name, meaning in est.definitions.items():
            print(f"    {name}: {meaning}")
    if est.dropped:
        print(f"  dropped (best deletion): {', '.join(est.dropped)}")
    if spatial:
        _print_at3(at, src)
        return 0
    x, y, t = at.mean
    sx, sy, st = at.sigmas
    print(f"  mean   x = {x:.6g} m   y = {y:.6g} m   θ = {t:.6g} rad ({np.degrees(t):.4g}°)")
    print(f"  sigma  x = {sx:.4g} m   y = {sy:.4g} m   θ = {st:.4g} rad ({np.degrees(st):.3g}°)")
    e = at.ellipse(0.9)
    print(
        f"  90% ellipse: half-axes {float(e.semi_major):.4g} m, {float(e.semi_minor):.4g} m, "
        f"major axis at {np.degrees(float(e.angle)):.1f}°"
    )
    print("  covariance on (x, y, θ) in frame " + str(src) + ":")
    for row in at.cov:
        print("   " + " ".join(f"{v: .6e}" for v in row))
    return 0


def _print_at3(at: AT3, src: object) -> None:
    """Text form of a 3-D result: translation, quaternion, Euler angles when defined, σ,
    90% position ellipsoid, covariance."""
    import numpy as np

    from relmap.errors import ParameterError

    x, y, z = at.translation
    print(f"  translation  x = {x:.6g} m   y = {y:.6g} m   z = {z:.6g} m")
    print("  rotation     q = [" + ", ".join(f"{v:.6g}" for v in at.quaternion) + "] (qx qy qz qw)")
    try:
        r, p, yaw = np.degrees(at.to_euler()[0][3:])
        print(f"               roll {r:.4g}°, pitch {p:.4g}°, yaw {yaw:.4g}° (R = Rz Ry Rx)")
    except ParameterError:
        print("               at the Euler pole (pitch ±90°): no roll/yaw")
    s = at.sigmas
    print(f"  sigma        x = {s[0]:.4g} m   y = {s[1]:.4g} m   z = {s[2]:.4g} m")
    print("               φx = {:.3g}°  φy = {:.3g}°  φz = {:.3g}°".format(*np.degrees(s[3:])))
    axes, _ = at.ellipsoid(0.9)
    print("  90% position ellipsoid: half-axes " + ", ".join(f"{a:.4g}" for a in axes[::-1]) + " m")
    print(f"  covariance on (δx, δy, δz, δφx, δφy, δφz) in frame {src} (rotation on the left):")
    for row in at.cov:
        print("   " + " ".join(f"{v: .4e}" for v in row))


def _solve(args: argparse.Namespace) -> int:
    import json
    import time
    from pathlib import Path

    from relmap._progress import TerminalProgress
    from relmap.errors import ParameterError
    from relmap.io import read_graph, solve_graph, write_graph
    from relmap.io.posegraph import file_information
    from relmap.lie import SE3

    if args.out and not Path(args.out).resolve().parent.is_dir():
        raise ParameterError(f"cannot write {args.out}: its folder does not exist")
    t0 = time.perf_counter()
    graph = read_graph(args.graph)
    out_graph = graph
    if args.out and graph.format == "toro" and graph.group is SE3:
        # The legacy EDGE3 format is read only: write 3-D g2o, the information converted (checked
        # before solving, so a covariance with no information matrix fails fast).
        out_graph = graph._replace(
            format="g2o",
            information=file_information(graph.measurements),
            vertex_quaternions=None,
            edge_quaternions=None,
        )
    bar = TerminalProgress(f"solving {args.graph}")
    try:
        with _numba.one_shot():
            sol = solve_graph(
                graph,
                progress=lambda k, err: bar.update(f"iteration {k}, error {err:.6g}", force=True),
                max_iterations=args.max_iterations,
            )
    finally:
        bar.close()
    if args.out:
        write_graph(args.out, out_graph, poses=sol.poses)  # atomically; 3-D: (n, 4, 4) poses
    seconds = time.perf_counter() - t0
    summary = {
        "poses": len(graph.vertex_ids),
        "edges": len(graph.edge_from),
        "iterations": sol.iterations,
        "initial_error": sol.initial_error,
        "final_error": sol.final_error,
        "seconds": seconds,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(
            f"{args.graph}: {summary['poses']} poses, {summary['edges']} edges; "
            f"error {sol.initial_error:.6g} → {sol.final_error:.6g} "
            f"in {sol.iterations} iterations, {seconds:.2f} s"
            + (f"; written to {args.out}" if args.out else "")
        )
    return 0


def _localize(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from relmap._progress import TerminalProgress
    from relmap.errors import ParameterError
    from relmap.localize import localize

    if args.plot and not Path(args.plot).resolve().parent.is_dir():
        raise ParameterError(f"cannot write the plot {args.plot}: its folder does not exist")
    bar = TerminalProgress(f"localizing {args.dataset}")
    bar.update("reading the logs, estimating the noise", force=True)
    try:
        run = localize(
            args.dataset,
            robot=args.robot,
            associate=args.associate,
            progress=lambda k, n: bar.update(f"reading time {k}/{n}"),
        )
    finally:
        bar.close()
    if args.plot:
        from matplotlib.figure import Figure

        from relmap.plot import localization, save_png

        fig = Figure(figsize=(8, 7))
        localization(fig.add_subplot(), run)
        fig.tight_layout()
        save_png(fig, args.plot)
    if args.json:
        print(json.dumps(run.summary()))
        return 0
    cal = run.calibration
    who = "CMU Plaza (second half)" if run.dataset == "plaza" else f"MRCLAM robot {run.robot}"
    span = run.t[-1] - run.t[0]
    sensor = f"σ range {cal.sigma_range:.3g} m"
    if cal.sigma_bearing is not None:
        sensor += f", σ bearing {cal.sigma_bearing:.3g} rad"
    if cal.range_scale != 1.0:
        sensor += f", range scale {cal.range_scale:.4f}"
    n = cal.odometry
    print(f"{who}: {run.steps} filter times over {span:.1f} s, association {run.associate}")
    print(
        f"  noise from {cal.trained_on}: odometry k_s={n.k_s:.3g} m²/m, "
        f"k_θ={n.k_theta:.3g} rad²/rad, k_θs={n.k_theta_s:.3g} rad²/m; {sensor}"
    )
    r = run.readings
    print(
        f"  readings: {r['used']} used, {run.score.rejected} rejected"
        + (f", {r['ignored']} ignored (not landmarks)" if r["ignored"] else "")
    )
    print(f"  {'':16s}{'RMSE position':>15s}{'RMSE heading':>15s}{'coverage_90':>13s}{'ANEES':>9s}")
    for name, s in (("EKF", run.score), ("dead reckoning", run.baseline)):
        print(
            f"  {name:16s}{s.rmse_position:13.3f} m{s.rmse_heading:11.3f} rad"
            f"{s.coverage_90:13.2f}{s.anees:9.2f}"
        )
    if args.plot:
        print(f"  plot written to {args.plot}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``relmap`` command."""
    from relmap import __version__

    parser = argparse.ArgumentParser(
        prog="relmap",
        description="Spatial uncertainty for robotics (Smith & Cheeseman 1986, and beyond).",
    )
    parser.add_argument("--version", action="version", version=f"relmap {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    demo = sub.add_parser(
        "demo",
        help="reproduce the paper: print the key numbers, write an HTML report with figures",
        description="Fig. 1, the Wheatstone bridge (Figs. 3-4), Fig. 5 and §6.3, decisions "
        "ahead of time, and the lecture's examples: numbers printed, and DIR/index.html written "
        "with its figures beside it.",
    )
    demo.add_argument(
        "--seed", type=int, default=0, help="seed of the Monte Carlo checks (default 0)"
    )
    demo.add_argument(
        "--out",
        metavar="DIR",
        default="relmap-report",
        help="folder of the report (default relmap-report/ in the current folder)",
    )
    demo.add_argument(
        "--data",
        metavar="DIR",
        help="the shared data folder (e.g. ../shared/data): adds EKF localization on MRCLAM",
    )
    demo.add_argument(
        "--samples",
        type=int,
        default=100_000,
        metavar="N",
        help="Monte Carlo samples of Fig. 1 and §6.3 (default 100000)",
    )
    demo.set_defaults(run=_demo)

    val = sub.add_parser(
        "validate",
        help="Monte Carlo check of a query on a map file",
        description="Sample every AT that the query FROM → TO depends on, re-estimate on each "
        "sampled map by the query's method, and compare predicted and empirical mean and "
        "covariance (relative errors), NEES and Mardia's Gaussianity statistics. The reduction "
        "is evaluated on all samples at once; the optimal method solves each sample in turn.",
    )
    val.add_argument("map", metavar="MAP", help="map file (JSON/YAML) or pose graph")
    val.add_argument("src", metavar="FROM", help="source frame")
    val.add_argument("dst", metavar="TO", help="destination frame")
    val.add_argument("-n", type=int, default=10_000, help="number of samples (default 10000)")
    val.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    val.add_argument("--method", choices=("auto", "reduce", "optimal"), default="auto")
    val.add_argument(
        "--moments",
        choices=("first_order", "exact", "unscented"),
        default="first_order",
        help="how the reduction compounds (SE(2) maps; default first_order)",
    )
    val.add_argument("--json", action="store_true", help="print one JSON object")
    val.set_defaults(run=_validate)

    query = sub.add_parser(
        "query",
        help="the AT between two frames of a map (map JSON/YAML, g2o 2-D/3-D or TORO file)",
        description="Estimate where frame TO is, seen from frame FROM, with its covariance.",
    )
    query.add_argument(
        "map", metavar="MAP", help="map file (JSON/YAML) or pose graph (g2o 2-D/3-D, TORO)"
    )
    query.add_argument(
        "src", metavar="FROM", help="source frame (its name; vertex id for pose graphs)"
    )
    query.add_argument("dst", metavar="TO", help="destination frame")
    query.add_argument("--method", choices=("auto", "reduce", "optimal"), default="auto")
    query.add_argument(
        "--on-irreducible",
        choices=("raise", "drop"),
        default="raise",
        help="reduce: when Delta-Y cannot reduce a loop, fail (raise) or delete the best AT (drop)",
    )
    query.add_argument("--json", action="store_true", help="print one JSON object")
    query.set_defaults(run=_query)

    solve = sub.add_parser(
        "solve",
        help="optimize a pose graph (g2o 2-D/3-D, TORO) from its initial guess",
        description="Jointly optimize all poses of a pose graph; the anchor (the first FIX "
        "vertex, else the first vertex) stays put.",
    )
    solve.add_argument("graph", metavar="GRAPH", help="g2o (2-D or 3-D) or TORO file")
    solve.add_argument(
        "--out",
        metavar="FILE",
        help="write the graph back, vertices at the optimum (legacy EDGE3 graphs as 3-D g2o)",
    )
    solve.add_argument("--json", action="store_true", help="print a JSON summary")
    solve.add_argument("--max-iterations", type=int, default=100)
    solve.set_defaults(run=_solve)

    loc = sub.add_parser(
        "localize",
        help="EKF localization with a known map on an MRCLAM or CMU Plaza folder",
        description="Run an EKF (odometry + landmark readings, lecture Eqs. 13-28) over a "
        "dataset folder (UTIAS MRCLAM or CMU Plaza, recognised by its files) and score it, and "
        "dead reckoning, against the ground truth. Noise comes from data the run is not scored "
        "on (MRCLAM: the next robot; Plaza: the first half, scored on the second).",
    )
    loc.add_argument("dataset", metavar="DATASET", help="MRCLAM or CMU Plaza dataset folder")
    loc.add_argument("--robot", type=int, metavar="N", help="MRCLAM robot 1-5 (default 1)")
    loc.add_argument(
        "--associate",
        choices=("signatures", "mahalanobis", "euclidean"),
        default="signatures",
        help="pair readings with landmarks by barcode/beacon id (default), or by the nearest "
        "landmark (Mahalanobis or Euclidean distance)",
    )
    loc.add_argument("--json", action="store_true", help="print one JSON object")
    loc.add_argument(
        "--plot", metavar="FILE", help="write a PNG of truth, estimate and dead reckoning"
    )
    loc.set_defaults(run=_localize)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``relmap`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args))
    except RelmapError as exc:
        print(f"relmap: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
