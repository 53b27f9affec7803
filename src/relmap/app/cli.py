"""The ``relmap`` command. Subcommands import their work lazily, so the command starts fast."""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Sequence

from relmap.errors import RelmapError

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing at start-up
if TYPE_CHECKING:
    from collections.abc import Callable
    from typing import NoReturn

    from relmap.uncertain.at3 import AT3


def _demo(args: argparse.Namespace) -> int:
    from pathlib import Path

    from relmap.app.demo import print_demo, run
    from relmap.app.demo_report import write_report
    from relmap.app.progress import TerminalProgress
    from relmap.errors import ParameterError

    if args.samples < 100:
        raise ParameterError(f"--samples must be at least 100; got {args.samples}")
    if args.data is not None and not Path(args.data, "landmarks", "mrclam6").is_dir():
        raise ParameterError(f"--data {args.data}: no landmarks/mrclam6 folder in it")
    bar = TerminalProgress("relmap demo")
    try:
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
    import contextlib
    import json
    import time

    import numpy as np

    from relmap.app import validate
    from relmap.app.progress import TerminalProgress
    from relmap.errors import ParameterError
    from relmap.io.maps import load_map

    if args.workers is not None and args.workers < 1:
        raise ParameterError(f"--workers must be a positive integer; got {args.workers}")
    g = load_map(args.map)
    src, dst = _frame(g, args.src), _frame(g, args.dst)
    try:
        with contextlib.ExitStack() as stack:
            p = validate.plan(g, src, dst, method=args.method, moments=args.moments)
            client, where, workers = None, "in this process", 1
            if args.workers is not None or args.scheduler is not None:
                from relmap.sim import distributed

                client = stack.enter_context(distributed.client_for(args.workers, args.scheduler))
                where = (
                    f"on the Dask cluster at {args.scheduler}"
                    if args.scheduler is not None
                    else f"on a local Dask cluster of {args.workers} processes"
                )
                workers = distributed.workers_of(client)
            guess = p.expected_seconds(args.n, workers)
            print(
                f"relmap validate: {p.estimate.method} ({p.reason}); {args.n:,} samples "
                f"{where}, about {_duration(guess)}",
                file=sys.stderr,
            )
            bar = TerminalProgress(f"validating {args.src} → {args.dst}")
            stack.callback(bar.close)
            t0 = time.perf_counter()

            def show(k: int, n: int) -> None:
                left = (time.perf_counter() - t0) * (n - k) / max(k, 1)
                bar.update(f"{k:,}/{n:,} samples, about {_duration(left)} left", force=True)

            v = validate.run(p, n=args.n, seed=args.seed, progress=show, client=client)
    except KeyboardInterrupt:
        print("relmap validate: interrupted; the pending chunks were cancelled", file=sys.stderr)
        return 130
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
    print(f"  method: {v.reason}")
    print(f"  sampled ATs: {_summary(', '.join(v.names), args.verbose)}")
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
    print(f"  NEES {s['nees']:.3f} of the {s['nees_expected']}-dof error (expected "
          f"{s['nees_expected']} if the covariance is right; ANEES = NEES/dof = "
          f"{s['nees'] / max(s['nees_expected'], 1):.3f}, 1 if right)")  # fmt: skip
    print(f"  {s['coverage']:.1%} of the samples inside the {s['probability']:.0%} ellipsoid")
    print(
        f"  Mardia skewness {s['mardia_skewness']:.4f}, excess kurtosis "
        f"{s['mardia_excess_kurtosis']:.4f} (0 and 0 for a Gaussian)"
    )
    return 0


def _duration(seconds: float) -> str:
    """``12 s``, ``3.4 min``, ``1.2 h``."""
    if seconds < 90:
        return f"{seconds:.2g} s" if seconds < 10 else f"{seconds:.0f} s"
    return f"{seconds / 60:.1f} min" if seconds < 5400 else f"{seconds / 3600:.1f} h"


def _frame(g, name: str):  # type: ignore[no-untyped-def]
    """The frame whose string form is ``name`` (g2o/TORO ids are integers)."""
    from relmap.errors import UnknownFrameError

    matches = [f for f in g.frames if str(f) == name]
    if not matches:
        raise UnknownFrameError(f"no frame {name!r} in the map")
    if len(matches) > 1:
        raise UnknownFrameError(f"frame name {name!r} is ambiguous: {matches!r}")
    return matches[0]


def _summary(text: str | None, verbose: bool, limit: int = 300) -> str | None:
    """``text`` cut to ``limit`` characters unless ``verbose`` (the full text is in --json)."""
    if text is None or verbose or len(text) <= limit:
        return text
    return f"{text[: limit - 40]}… ({len(text)} characters; --verbose or --json for all)"


def _query(args: argparse.Namespace) -> int:
    import json

    from relmap.app.progress import TerminalProgress
    from relmap.errors import ParameterError
    from relmap.io.maps import load_map

    frames = [args.src, args.dst, *args.more]
    if len(frames) % 2:
        raise ParameterError(
            f"give frames in pairs FROM TO [FROM TO ...]; got {len(frames)} frame names"
        )
    bar = TerminalProgress("reduction")
    try:
        g = load_map(args.map)
        pairs = [(_frame(g, frames[k]), _frame(g, frames[k + 1])) for k in range(0, len(frames), 2)]
        estimates = g.query_many(
            pairs,
            method=args.method,
            on_irreducible=args.on_irreducible,
            progress=lambda done, total: bar.update(f"{done} of {total}"),
        )
    finally:
        bar.close()
    if args.json:
        outs = [_query_json(est) for est in estimates]
        print(json.dumps(outs[0] if len(outs) == 1 else outs))
        return 0
    for k, est in enumerate(estimates):
        if k:
            print()
        _print_estimate(est, args.verbose)
    return 0


def _query_json(est) -> dict:  # type: ignore[no-untyped-def,type-arg]
    from relmap.uncertain.at3 import AT3

    at = est.at
    return {
        "from": est.src,
        "to": est.dst,
        "method": est.method,
        "expression": est.expression,
        "definitions": est.definitions,
        "mean": (at.vector if isinstance(at, AT3) else at.mean).tolist(),
        "cov": at.cov.tolist(),
        "iterations": est.iterations,
        "converged": est.converged,
        "dropped": list(est.dropped),
    }


def _print_estimate(est, verbose: bool) -> None:  # type: ignore[no-untyped-def]
    import numpy as np

    from relmap.uncertain.at3 import AT3

    at, src, dst = est.at, est.src, est.dst
    how = est.method + (f", {est.iterations} iterations" if est.iterations is not None else "")
    if est.converged is False:
        how += ", NOT converged"
    print(f"AT of frame {dst} seen from frame {src} ({how})")
    if est.expression:
        print(f"  expression: {_summary(est.expression, verbose)}")
        shown = list(est.definitions.items())
        for name, meaning in shown if verbose else shown[:6]:
            print(f"    {name}: {_summary(meaning, verbose, 160)}")
        if not verbose and len(shown) > 6:
            print(f"    … and {len(shown) - 6} more (--verbose or --json)")
    if est.dropped:
        print(f"  dropped (best deletion): {_summary(', '.join(est.dropped), verbose)}")
    if isinstance(at, AT3):
        _print_at3(at, src)
        return
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


def _print_at3(at: AT3, src: object) -> None:
    """Text form of a 3-D result: translation, quaternion, Euler angles when defined, σ,
    90% position ellipsoid, covariance."""
    import numpy as np

    from relmap.errors import ParameterError

    x, y, z = at.translation
    print(f"  translation  x = {x:.6g} m   y = {y:.6g} m   z = {z:.6g} m")
    print("  rotation     q = [" + ", ".join(f"{v:.6g}" for v in at.quaternion) + "] (qx qy qz qw)")
    import warnings

    from relmap.uncertain.at3 import PoleWarning

    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", PoleWarning)
            r, p, yaw = np.degrees(at.to_euler()[0][3:])
        print(f"               roll {r:.4g}°, pitch {p:.4g}°, yaw {yaw:.4g}° (R = Rz Ry Rx)")
        if caught:
            print("               (near the pole: roll and yaw poorly determined; use q)")
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

    from relmap.app.progress import TerminalProgress
    from relmap.errors import ParameterError
    from relmap.io.maps import solve_graph
    from relmap.io.posegraph import as_format, read_graph, write_graph

    for out in (args.out, args.out_trajectory):
        if out and not Path(out).resolve().parent.is_dir():
            raise ParameterError(f"cannot write {out}: its folder does not exist")
    t0 = time.perf_counter()
    graph = read_graph(args.graph)
    # written in its own format, or 3-D g2o for the read-only legacy EDGE3 (the information
    # converted before solving, so a covariance with no information matrix fails fast)
    out_graph = as_format(graph) if args.out else graph
    bar = TerminalProgress(f"solving {args.graph}")
    try:
        sol = solve_graph(
            graph,
            progress=lambda k, err: bar.update(f"iteration {k}, error {err:.6g}", force=True),
            max_iterations=args.max_iterations,
            loss=args.loss,
        )
    finally:
        bar.close()
    if args.out:
        write_graph(args.out, out_graph, poses=sol.poses)  # atomically; 3-D: (n, 4, 4) poses
    if args.out_trajectory:
        from relmap.app.trajectory import write_solution

        write_solution(args.out_trajectory, graph, sol.poses, sol.marginals())
    seconds = time.perf_counter() - t0
    summary = {
        "poses": len(graph.vertex_ids),
        "edges": len(graph.edge_from),
        "iterations": sol.iterations,
        "converged": sol.converged,
        "initial_error": sol.initial_error,
        "final_error": sol.final_error,
        "seconds": seconds,
    }
    if args.loss is not None:  # the robust cost Σ ρ(s²), and how many edges it down-weighted
        summary["loss"] = repr(args.loss)
        summary["downweighted"] = int((sol.weights < 1.0).sum())
    if args.json:
        print(json.dumps(summary))
    else:
        print(
            f"{args.graph}: {summary['poses']} poses, {summary['edges']} edges; "
            f"error {sol.initial_error:.6g} → {sol.final_error:.6g} "
            f"in {sol.iterations} iterations"
            + ("" if sol.converged else " (NOT converged: stopped at --max-iterations)")
            + (
                f" under {summary['loss']}, {summary['downweighted']} edges down-weighted"
                if args.loss is not None
                else ""
            )
            + f", {seconds:.2f} s"
            + (f"; written to {args.out}" if args.out else "")
        )
    return 0


def _localize(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    import numpy as np

    from relmap.app.localize import localize
    from relmap.app.progress import TerminalProgress
    from relmap.errors import ParameterError
    from relmap.filter.autocalibration import Calibrated

    for out in (args.plot, args.out):
        if out and not Path(out).resolve().parent.is_dir():
            raise ParameterError(f"cannot write {out}: its folder does not exist")
    if args.calibrate != ["auto"]:
        how, number = [*args.calibrate, ""][:2] if len(args.calibrate) <= 2 else ("", "")
        if how != "from-run" or not number.isdigit():
            raise ParameterError(
                f"--calibrate takes 'auto' or 'from-run N'; got {' '.join(args.calibrate)}"
            )
        args.calibrate_from = int(number)
    stages = (
        "estimating the noise from the run's innovations",
        "searching the odometry's clock offset and turn-rate bias",
        "refining the noise",
        "measuring the innovations' whiteness",
        "running the filter",
        "scoring",
    )
    bar = TerminalProgress(f"localizing {args.dataset}")
    bar.update("reading the logs", force=True)
    try:
        run = localize(
            args.dataset,
            robot=args.robot,
            associate=args.associate,
            calibrate_from=args.calibrate_from,
            progress=lambda k, n: bar.update(stages[min(k, len(stages) - 1)], force=True),
        )
    finally:
        bar.close()
    if args.out:
        from relmap.app.trajectory import write_localization

        write_localization(args.out, run)
    if args.plot:
        from relmap.viz.localization import figure
        from relmap.viz.plot import save_png

        save_png(figure(run), args.plot)
    for warning in run.warnings:
        print(f"relmap localize: warning: {warning}", file=sys.stderr)
    if args.json:
        print(json.dumps(run.summary()))
        return 0
    cal = run.calibration
    m, sn = cal.motion, cal.sensor
    who = "CMU Plaza (second half)" if run.dataset == "plaza" else f"MRCLAM robot {run.robot}"
    span = run.t[-1] - run.t[0]
    ranges_only = run.dataset == "plaza"
    sensor = f"σ range {float(sn.sigma_range):.3g} m"
    if not ranges_only:
        sensor += f", σ bearing {float(sn.sigma_bearing):.3g} rad"
    if np.isfinite(cal.nu):
        sensor += f", Student-t ν {cal.nu:.3g}"
    auto = isinstance(cal, Calibrated)
    if auto:
        source = (
            f"this run's innovations (clock offset {cal.delay:g} s"
            + (f", range scale {cal.scale:g}" if ranges_only else "")
            + (f", turn-rate bias {cal.turn_bias:.3g} rad/s" if cal.turn_bias else "")
            + f"; update σ ×{cal.inflation:.2f} for correlated readings, ρ "
            + f"{cal.correlation[0]:.2f})"
        )
    else:
        source = cal.trained_on + " against its ground truth"
        if cal.range_scale != 1.0:
            sensor += f", range scale {cal.range_scale:.4f}"
    print(f"{who}: {run.steps} filter times over {span:.1f} s, association {run.associate}")
    print(f"  noise from {source}:")
    print(
        f"    odometry k_s={float(m.k_s):.3g} m²/m, k_θ={float(m.k_theta):.3g} rad²/rad, "
        f"k_θs={float(m.k_theta_s):.3g} rad²/m; {sensor}"
    )
    r = run.readings
    print(
        f"  readings: {r['used']} used"
        + (
            f" ({r['ambiguous']} ambiguous: the mixture of the landmarks in their gate)"
            if r.get("ambiguous")
            else ""
        )
        + f", {run.score.rejected} rejected"
        + (f", {r['wrong']} paired with the wrong landmark" if r["wrong"] else "")
        + (f", {r['ignored']} ignored (not landmarks)" if r["ignored"] else "")
        + (
            f"; of {r['not_in_map']} readings of no landmark {r['not_in_map_used']} used"
            + (f" (clutter fitted: {cal.clutter_fraction:.0%} of the readings)" if auto else "")
            if r.get("not_in_map")
            else ""
        )
        + f"; NIS/dof {run.anis:.2f} (1 if consistent"
        + (
            f"; below 1 by design when correlated readings are inflated in the update, "
            f"here σ ×{cal.inflation:.2f})"
            if auto and cal.inflation > 1.05
            else ")"
        )
    )
    print(f"  {'':16s}{'RMSE position':>15s}{'RMSE heading':>15s}{'coverage_90':>13s}{'ANEES':>9s}")
    for name, s in (("EKF", run.score), ("dead reckoning", run.baseline)):
        print(
            f"  {name:16s}{s.rmse_position:13.3f} m{s.rmse_heading:11.3f} rad"
            f"{s.coverage_90:13.2f}{s.anees:9.2f}"
        )
    print(
        "  (ANEES: mean NEES of the 3-dof pose error / 3, 1 if consistent; coverage_90: share "
        "of times the true position is inside the 90% ellipse)"
    )
    if args.plot:
        print(f"  plot written to {args.plot}")
    return 0


# ------------------------------------------------------------------ shared machinery
class _Parser(argparse.ArgumentParser):
    """argparse with relmap's error style: one line ``relmap <command>: error: …``, exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _int_in(lo: int, hi: int | None = None, what: str = "an integer") -> Callable[[str], int]:
    """An argparse type: an integer in ``[lo, hi]`` (no upper bound if ``hi`` is None)."""

    def parse(text: str) -> int:
        try:
            value = int(text.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text[:40]!r}") from None
        if value < lo or (hi is not None and value > hi):
            span = f"at least {lo:,}" if hi is None else f"between {lo:,} and {hi:,}"
            shown = f"{value:,}" if len(text) < 40 else f"a {len(text.strip())}-digit number"
            raise argparse.ArgumentTypeError(f"must be {span}; got {shown}")
        return value

    parse.__name__ = what  # argparse names the type in some messages
    return parse


#: Seeds of numpy's generators: non-negative integers (SeedSequence refuses negative ones).
_seed = _int_in(0, 2**128 - 1, "a seed (a non-negative integer)")
#: Monte Carlo sample counts: large enough to mean something, small enough to fit in memory.
MAX_SAMPLES = 10_000_000


def _output_file(text: str) -> str:
    """An argparse type: a file that can be written (checked before any work)."""
    from relmap.io.atomic import check_writable

    try:
        check_writable(text)
    except RelmapError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _loss(text: str) -> object:
    """An argparse type: a loss of the pose-graph optimizer, ``NAME[:PARAMETERS]``
    (:func:`relmap.network.losses.parse_loss`)."""
    from relmap.network.losses import parse_loss

    try:
        return parse_loss(text)
    except RelmapError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _output_folder(text: str) -> str:
    """An argparse type: a folder that can be made or written into (checked before any work)."""
    from relmap.io.atomic import check_writable_folder

    try:
        check_writable_folder(text)
    except RelmapError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


#: The trajectory commands (:mod:`relmap.app.trajectory`) and their help lines.
TRAJECTORY_COMMANDS = {
    "eval": "score an estimated trajectory against a reference: APE, RPE (as evo) and NEES",
    "traj": "summarize (and plot) trajectory files",
    "convert": "convert a trajectory between formats",
}
#: relmap's commands and their help lines, in the order ``relmap --help`` lists them. Listing
#: them imports nothing; a command's parser is built only when it runs (its choices come from
#: the option enums of the modules it runs, which import numpy).
COMMANDS = {
    "demo": "reproduce the paper: print the key numbers, write an HTML report with figures",
    "validate": "Monte Carlo check of a query on a map file",
    "query": "the AT between two frames of a map (map JSON/YAML, g2o 2-D/3-D or TORO file)",
    "solve": "optimize a pose graph (g2o 2-D/3-D, TORO) from its initial guess",
    "localize": "EKF localization with a known map on an MRCLAM or CMU Plaza folder",
    **TRAJECTORY_COMMANDS,
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser of the ``relmap`` command; of the commands' own parsers only
    ``command``'s is built (all of them for None)."""
    from relmap import __version__

    parser = _Parser(
        prog="relmap",
        description="Spatial uncertainty for robotics (Smith & Cheeseman 1986, and beyond).",
    )
    parser.add_argument("--version", action="version", version=f"relmap {__version__}")
    parser.add_argument(
        "--debug", action="store_true", help="on an error, print the full traceback too"
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, text in COMMANDS.items():  # listed always, built when they run
        command_parser = sub.add_parser(name, help=text)
        if command is None or command == name:
            if name in TRAJECTORY_COMMANDS:
                from relmap.app.trajectory import add_arguments

                add_arguments(name, command_parser)
            else:
                _ARGUMENTS[name](command_parser)

    for command in sub.choices.values():  # --debug after the command too
        command.add_argument(
            "--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS
        )
    return parser


def _demo_arguments(demo: argparse.ArgumentParser) -> None:
    demo.description = (
        "Fig. 1, the Wheatstone bridge (Figs. 3-4), Fig. 5 and §6.3, decisions "
        "ahead of time, and the lecture's examples: numbers printed, and DIR/index.html written "
        "with its figures beside it."
    )
    demo.add_argument(
        "--seed", type=_seed, default=0, help="seed of the Monte Carlo checks (default 0)"
    )
    demo.add_argument(
        "--out",
        metavar="DIR",
        type=_output_folder,
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
        type=_int_in(100, MAX_SAMPLES),
        default=100_000,
        metavar="N",
        help="Monte Carlo samples of Fig. 1 and §6.3 (default 100000)",
    )
    demo.set_defaults(run=_demo)


def _validate_arguments(val: argparse.ArgumentParser) -> None:
    val.description = (
        "Sample every AT that the query FROM → TO depends on, re-estimate on each "
        "sampled map by the query's method, and compare predicted and empirical mean and "
        "covariance (relative errors), NEES and Mardia's Gaussianity statistics. The reduction "
        "is evaluated on blocks of 4096 samples at once; the optimal method solves each sampled "
        "map in turn. --workers or --scheduler spread the blocks over a Dask cluster: the same "
        "seed gives the same numbers. The method, why, and a forecast of the time are printed "
        "on standard error before sampling starts."
    )
    from relmap.network.query import QueryMethod
    from relmap.uncertain.moments import MomentsMethod

    val.add_argument("map", metavar="MAP", help="map file (JSON/YAML) or pose graph")
    val.add_argument("src", metavar="FROM", help="source frame")
    val.add_argument("dst", metavar="TO", help="destination frame")
    val.add_argument(
        "-n",
        type=_int_in(2, MAX_SAMPLES),
        default=10_000,
        help="number of samples (default 10000)",
    )
    val.add_argument("--seed", type=_seed, default=0, help="random seed (default 0)")
    val.add_argument("--method", choices=QueryMethod.choices(), default=QueryMethod.AUTO.value)
    val.add_argument(
        "--moments",
        choices=MomentsMethod.choices(),
        default=MomentsMethod.FIRST_ORDER.value,
        help="how the reduction compounds (SE(2) maps; default first_order)",
    )
    val.add_argument("--json", action="store_true", help="print one JSON object")
    val.add_argument("--verbose", action="store_true", help="list every sampled AT")
    where = val.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="sample on a local Dask cluster of N processes (needs relmap[distributed])",
    )
    where.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="sample on an existing Dask cluster, e.g. tcp://10.0.0.5:8786 (same seed, same "
        "numbers: see the README, 'On a cluster')",
    )
    val.set_defaults(run=_validate)


def _query_arguments(query: argparse.ArgumentParser) -> None:
    query.description = "Estimate where frame TO is, seen from frame FROM, with its covariance."
    from relmap.network.query import QueryMethod
    from relmap.network.reduce import OnIrreducible

    query.add_argument(
        "map", metavar="MAP", help="map file (JSON/YAML) or pose graph (g2o 2-D/3-D, TORO)"
    )
    query.add_argument(
        "src", metavar="FROM", help="source frame (its name; vertex id for pose graphs)"
    )
    query.add_argument("dst", metavar="TO", help="destination frame")
    query.add_argument(
        "more",
        metavar="FROM TO",
        nargs="*",
        help="further pairs of frames: the map is loaded (and solved) once for all",
    )
    query.add_argument("--method", choices=QueryMethod.choices(), default=QueryMethod.AUTO.value)
    query.add_argument(
        "--on-irreducible",
        choices=OnIrreducible.choices(),
        default=OnIrreducible.RAISE.value,
        help="reduce: when Delta-Y cannot reduce a loop, fail (raise) or delete the best AT (drop)",
    )
    query.add_argument(
        "--verbose", action="store_true", help="print long expressions and definitions in full"
    )
    query.add_argument(
        "--json", action="store_true", help="print one JSON object (a list for several pairs)"
    )
    query.set_defaults(run=_query)


def _solve_arguments(solve: argparse.ArgumentParser) -> None:
    solve.description = (
        "Jointly optimize all poses of a pose graph; the anchor (the first FIX "
        "vertex, else the first vertex) stays put."
    )
    solve.add_argument("graph", metavar="GRAPH", help="g2o (2-D or 3-D) or TORO file")
    solve.add_argument(
        "--out",
        metavar="FILE",
        type=_output_file,
        help="write the graph back, vertices at the optimum (legacy EDGE3 graphs as 3-D g2o)",
    )
    solve.add_argument(
        "--out-trajectory",
        metavar="FILE",
        type=_output_file,
        help="write the solved poses with their marginal covariances (relmap trajectory format)",
    )
    solve.add_argument("--json", action="store_true", help="print a JSON summary")
    solve.add_argument("--max-iterations", type=_int_in(1, 1_000_000), default=100)
    solve.add_argument(
        "--loss",
        metavar="NAME[:K]",
        type=_loss,
        help="a robust loss of each edge's normalized residual: huber[:k] (k in σ, default "
        "1.345) or l2 (least squares, the default)",
    )
    solve.set_defaults(run=_solve)


def _localize_arguments(loc: argparse.ArgumentParser) -> None:
    loc.description = (
        "Run an EKF (odometry + landmark readings, lecture Eqs. 13-28) over a "
        "dataset folder (UTIAS MRCLAM or CMU Plaza, recognised by its files) and score it, and "
        "dead reckoning, against the ground truth. The noise comes from the run's own innovations "
        "(no ground truth), or with --calibrate from-run N from another MRCLAM robot's run "
        "against its ground truth; Plaza runs and is scored on the second half of its run."
    )
    from relmap.filter.landmarks import Association

    loc.add_argument("dataset", metavar="DATASET", help="MRCLAM or CMU Plaza dataset folder")
    loc.add_argument(
        "--robot", type=_int_in(1, 5), metavar="N", help="MRCLAM robot 1-5 (default 1)"
    )
    loc.add_argument(
        "--associate",
        choices=Association.choices(),
        default=Association.SIGNATURES.value,
        help="pair readings with landmarks by barcode/beacon id (default), by the nearest "
        "landmark (Mahalanobis or Euclidean distance), or by joint compatibility (JCBB)",
    )
    loc.add_argument(
        "--calibrate",
        nargs="+",
        metavar="HOW",
        default=["auto"],
        help="'auto' (default): the noise from this run's own innovations, no ground truth; "
        "'from-run N' (MRCLAM): from robot N's run against its ground truth",
    )
    loc.add_argument("--json", action="store_true", help="print one JSON object")
    loc.add_argument(
        "--plot",
        metavar="FILE",
        type=_output_file,
        help="write a PNG of truth, estimate and dead reckoning",
    )
    loc.add_argument(
        "--out",
        metavar="FILE",
        type=_output_file,
        help="write the estimate with covariance (for relmap eval)",
    )
    loc.set_defaults(run=_localize, calibrate_from=None)


_ARGUMENTS = {
    "demo": _demo_arguments,
    "validate": _validate_arguments,
    "query": _query_arguments,
    "solve": _solve_arguments,
    "localize": _localize_arguments,
}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``relmap`` console script; returns the exit status.

    Every error is one line ``relmap <command>: error: …`` on stderr: exit status 2 for bad input
    (a :class:`relmap.errors.RelmapError`: a malformed file, an unknown frame, an output that
    cannot be written, …), 1 when the computation fails (:class:`relmap.errors.SolverError`,
    :class:`relmap.errors.NumericalError`, or an unexpected error, which is a bug). ``--debug``
    prints the traceback too. A closed pipe (``relmap … | head``) ends the command quietly.
    """
    words = sys.argv[1:] if argv is None else list(argv)
    command = next((w for w in words if not w.startswith("-")), "")
    args = build_parser(command).parse_args(words)
    prog = f"relmap {args.command}"
    try:
        with warnings.catch_warnings():
            if not args.debug:  # numpy's overflow warnings: relmap's own checks report them
                warnings.simplefilter("ignore", RuntimeWarning)
            status = int(args.run(args))
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return status
    except BrokenPipeError:
        _silence_stdout()
        return 141  # as a command killed by SIGPIPE
    except KeyboardInterrupt:
        print(f"\n{prog}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # the one place that turns errors into a line
        if args.debug:
            import traceback

            traceback.print_exc()
        print(f"{prog}: error: {_describe(exc, getattr(args, 'verbose', False))}", file=sys.stderr)
        return _status(exc)


def _status(exc: BaseException) -> int:
    from relmap.errors import NumericalError, SolverError

    if isinstance(exc, RelmapError) and not isinstance(exc, (SolverError, NumericalError)):
        return 2
    return 1


def _describe(exc: BaseException, verbose: bool = False) -> str:
    """One line for an error: relmap's own message (summarized past 400 characters unless
    ``verbose``); for anything else its type too."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, RelmapError):
        return _summary(text, verbose, 400) or text
    if isinstance(exc, MemoryError):
        return "out of memory (try a smaller problem)"
    if isinstance(exc, OSError) and exc.strerror:
        where = f"{exc.filename}: " if exc.filename else ""
        return f"{where}{exc.strerror}"
    return f"unexpected {type(exc).__name__}: {text} (a bug: please report it; --debug shows where)"


def _silence_stdout() -> None:
    """After a closed pipe: point stdout at /dev/null so that Python's exit flush stays quiet."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


if __name__ == "__main__":
    raise SystemExit(main())
