"""The ``relmap`` command. Subcommands import their work lazily, so the command starts fast."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from relmap.errors import RelmapError


def _demo(args: argparse.Namespace) -> int:
    from relmap.demo import fig1, print_fig1

    print_fig1(fig1(seed=args.seed))
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

    from relmap.io import load_map

    g = load_map(args.map)
    src, dst = _frame(g, args.src), _frame(g, args.dst)
    est = g.query(src, dst, method=args.method, on_irreducible=args.on_irreducible)
    at = est.at
    if args.json:
        out = {
            "from": src,
            "to": dst,
            "method": est.method,
            "expression": est.expression,
            "mean": at.mean.tolist(),
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


def _solve(args: argparse.Namespace) -> int:
    import json
    import time

    from relmap._progress import TerminalProgress
    from relmap.io import read_graph, solve_graph, write_graph

    t0 = time.perf_counter()
    graph = read_graph(args.graph)
    bar = TerminalProgress(f"solving {args.graph}")
    try:
        sol = solve_graph(
            graph,
            progress=lambda k, err: bar.update(f"iteration {k}, error {err:.6g}", force=True),
            max_iterations=args.max_iterations,
        )
    finally:
        bar.close()
    if args.out:
        write_graph(args.out, graph, poses=sol.poses)
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
        "demo", help="run the paper's Fig. 1 example end to end and print the numbers"
    )
    demo.add_argument(
        "--seed", type=int, default=0, help="seed of the Monte Carlo check (default 0)"
    )
    demo.set_defaults(run=_demo)

    query = sub.add_parser(
        "query",
        help="the AT between two frames of a map (map JSON/YAML, g2o or TORO file)",
        description="Estimate where frame TO is, seen from frame FROM, with its covariance.",
    )
    query.add_argument(
        "map", metavar="MAP", help="map file (JSON/YAML) or 2-D pose graph (g2o, TORO)"
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
        help="optimize a 2-D pose graph (g2o, TORO) from its initial guess",
        description="Jointly optimize all poses of a pose graph; the anchor (the first FIX "
        "vertex, else the first vertex) stays put.",
    )
    solve.add_argument("graph", metavar="GRAPH", help="g2o or TORO file")
    solve.add_argument(
        "--out", metavar="FILE", help="write the graph back, vertices at the optimum"
    )
    solve.add_argument("--json", action="store_true", help="print a JSON summary")
    solve.add_argument("--max-iterations", type=int, default=100)
    solve.set_defaults(run=_solve)
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
