"""The trajectory sub-commands of ``relmap``: ``eval``, ``traj``, ``convert``. :mod:`relmap.app.cli`
lists them (``relmap.app.cli.TRAJECTORY_COMMANDS``) and has :func:`add_arguments` build the parser
of the one that runs only; their work is imported lazily: the command starts fast."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from relmap.errors import ParameterError

__all__ = ["add_arguments", "write_localization", "write_solution"]


def _read(source: Any, topic: str | None, times: str | None = None) -> Any:
    from relmap.io.trajectory import read_trajectory

    return read_trajectory(source, topic=topic, times=times)


def _takes_topic(source: Any) -> bool:
    """Whether an input (read once) is in a format that reads topics (a ROS bag)."""
    from relmap.io import formats

    fmt = formats.recognise(source)
    return fmt is not None and "topic" in fmt.options


def _topics(args: argparse.Namespace, ref: Any, est: Any) -> tuple[str | None, str | None]:
    """``--topic`` given once serves each bag among REF and EST; twice: REF's, then EST's."""
    topics = list(args.topic or [])
    if len(topics) > 2:
        raise ParameterError("--topic is given at most twice (REF's, then EST's)")
    if len(topics) == 2:
        return topics[0], topics[1]
    one = topics[0] if topics else None
    return (one if _takes_topic(ref) else None, one if _takes_topic(est) else None)


def _check_out(path: str | None, what: str) -> None:
    if path and not Path(path).resolve().parent.is_dir():
        raise ParameterError(f"cannot write the {what} {path}: its folder does not exist")


def _eval(args: argparse.Namespace) -> int:
    from relmap.evaluate import evaluate
    from relmap.io.textfile import read_input

    _check_out(args.plot, "plot")
    _check_out(args.report, "report")
    ref_in, est_in = read_input(args.ref), read_input(args.est)  # once each: pipes too
    ref_topic, est_topic = _topics(args, ref_in, est_in)
    ref = _read(ref_in, ref_topic, args.ref_times)
    est = _read(est_in, est_topic, args.est_times)
    chosen = {"relations": tuple(args.relation)} if args.relation else {}  # or evaluate's
    ev = evaluate(
        ref,
        est,
        align_mode=args.align,
        n_align=args.n_align,
        max_diff=args.t_max_diff,
        offset=args.t_offset,
        interpolate_ref=args.interpolate,
        **chosen,  # type: ignore[arg-type]
        rpe_delta=args.delta if args.rpe else None,
        rpe_unit=args.unit,
        all_pairs=args.all_pairs,
        pairs_from_reference=args.pairs_from_reference,
    )
    if args.plot or args.report:
        from relmap.viz.trajectory import evaluation_figure, write_evaluation_report

        if args.plot:
            from relmap.viz.plot import save_png

            save_png(evaluation_figure(ev), args.plot)
        if args.report:
            write_evaluation_report(ev, args.report)
    if args.json:
        print(json.dumps(ev.summary()))
        return 0
    a = ev.alignment
    print(f"{ev.est.source} against {ev.ref.source}: {len(ev.est)} pairs")
    if a.mode != "none":
        print(
            f"  aligned ({a.mode}): scale {a.scale:.6g}, translation "
            + " ".join(f"{v:.4g}" for v in a.translation)
        )
    print(
        f"  {'':16s}"
        + "".join(f"{k:>11s}" for k in ("rmse", "mean", "median", "std", "min", "max"))
    )
    for kind, table in (("APE", ev.ape), ("RPE", ev.rpe)):
        for rel, e in table.items():
            s = e.stats()
            name = f"{kind} {rel} {e.relation.unit}".rstrip()
            print(
                f"  {name:16s}"
                + "".join(f"{s[k]:11.4g}" for k in ("rmse", "mean", "median", "std", "min", "max"))
            )
    if ev.rpe:
        o = ev.rpe_options
        print(
            f"  RPE pairs: delta {o['delta']:g} {o['unit']}, "
            + ("all pairs" if o["all_pairs"] else "consecutive")
        )
    c = ev.consistency
    if c is None:
        print("  consistency: the estimate carries no covariance")
    else:
        print(f"  consistency: {c.verdict}")
        for name, b in c.blocks.items():
            cov = ", ".join(f"{p:.0%}: {v:.0%}" for p, v in b.coverage.items())
            print(
                f"    {name:12s} ANEES {b.anees:8.3g}  "
                f"interval [{b.interval[0]:.3g}, {b.interval[1]:.3g}]  coverage {cov}"
            )
    for what, path in (("plot", args.plot), ("report", args.report)):
        if path:
            print(f"  {what} written to {path}")
    return 0


def _traj(args: argparse.Namespace) -> int:
    _check_out(args.plot, "plot")
    from relmap.io.rosbag import read_bag_topics
    from relmap.io.textfile import read_input

    topics = list(args.topic or [])
    trajs = []
    for k, path in enumerate(args.files):
        source = read_input(path)  # once: a pipe too
        if not _takes_topic(source):
            trajs.append(_read(source, None))
            continue
        if not topics:
            raise ParameterError(f"{path} is a ROS bag: name its topic(s) with --topic")
        if len(args.files) == 1:
            mine = topics  # one bag: every topic, its messages read once
        elif len(topics) == len(args.files):
            mine = [topics[k]]
        else:
            mine = topics[:1]
        trajs.extend(read_bag_topics(source.path, mine))  # a bag's topics, opened once
    if args.plot:
        from relmap.viz.plot import save_png
        from relmap.viz.trajectory import trajectories_figure

        save_png(trajectories_figure(trajs, probability=args.probability), args.plot)
    if args.json:
        print(json.dumps([t.summary() for t in trajs]))
        return 0
    for t in trajs:
        s = t.summary()
        span = f"{s['duration']:.2f} s" if s["stamps"] else "no stamps"
        kind = "planar" if s["planar"] else "3-D"
        frames = f", {t.frame or '?'} → {t.child or '?'}" if (t.frame or t.child) else ""
        print(
            f"{t.source}: {s['poses']} {kind} poses, {span}, path {s['length']:.3f} m, "
            f"covariance {'yes' if s['covariance'] else 'no'}{frames}"
        )
    if args.plot:
        print(f"plot written to {args.plot}")
    return 0


def _convert(args: argparse.Namespace) -> int:
    from relmap.io.trajectory import write_trajectory

    traj = _read(args.input, args.topic, args.times)
    fmt = write_trajectory(args.output, traj, args.format)
    print(f"{traj.source}: {len(traj)} poses written to {args.output} ({fmt})")
    return 0


def write_localization(path: str, run: Any) -> None:
    """``relmap localize --out``: the estimate at the filter's times, with covariance, in
    relmap's planar format. Uses only ``run.t`` and ``run.estimate`` (an AT batch)."""
    from relmap.io.trajectory import write_trajectory
    from relmap.uncertain.trajectory import Trajectory

    e = run.estimate
    write_trajectory(path, Trajectory.planar(e.mean, run.t, e.cov, frame="world", child="robot"))


def write_solution(path: str, graph: Any, poses: Any, covariances: Any = None) -> None:
    """``relmap solve --out-trajectory``: the solved vertex poses in vertex order (the vertex id
    as the stamp), with their marginal covariances when given."""
    import numpy as np

    from relmap.io.trajectory import write_trajectory
    from relmap.uncertain.trajectory import Trajectory

    ids = np.asarray(graph.vertex_ids, dtype=np.float64)
    order = np.argsort(ids, kind="stable")
    if poses.ndim == 2:
        traj = Trajectory.planar(
            poses[order], ids[order], None if covariances is None else covariances[order]
        )
    else:
        traj = Trajectory.from_matrices(
            poses[order], ids[order], None if covariances is None else covariances[order]
        )
    write_trajectory(path, traj)


def add_arguments(command: str, parser: argparse.ArgumentParser) -> None:
    """Build the parser of trajectory command ``command`` (``eval``, ``traj`` or ``convert``),
    registered with its help line by :func:`relmap.app.cli.build_parser`."""
    {"eval": _eval_arguments, "traj": _traj_arguments, "convert": _convert_arguments}[command](
        parser
    )


def _eval_arguments(ev: argparse.ArgumentParser) -> None:
    from relmap.evaluate.alignment import AlignMode
    from relmap.evaluate.metrics import DeltaUnit, Relation

    ev.description = (
        "Associate the estimate with the reference by time stamps, align it, and "
        "report the absolute (APE) and relative (RPE) pose errors with evo's definitions, and, "
        "when the estimate carries a covariance, its consistency (NEES, ANEES, coverage). "
        "Formats are recognised from the files' content: TUM, KITTI, EuRoC CSV, relmap, g2o, "
        "ROS 1/2 bags."
    )
    ev.add_argument("ref", metavar="REF", help="reference (ground truth) trajectory")
    ev.add_argument("est", metavar="EST", help="estimated trajectory")
    ev.add_argument("--align", choices=AlignMode.choices(), default=AlignMode.NONE.value)
    ev.add_argument("--n-align", type=int, metavar="N", help="align on the first N pairs only")
    ev.add_argument("--rpe", action="store_true", help="also the relative pose error")
    ev.add_argument("--delta", type=float, default=1.0, help="RPE pair distance (default 1)")
    ev.add_argument("--unit", choices=DeltaUnit.choices(), default=DeltaUnit.FRAMES.value)
    ev.add_argument(
        "--pairs-from-reference",
        action="store_true",
        help="choose RPE pairs on the reference's poses (default: the estimate's, as evo)",
    )
    ev.add_argument(
        "--all-pairs", action="store_true", help="RPE on all pairs, not consecutive ones"
    )
    ev.add_argument(
        "--relation",
        action="append",
        choices=Relation.choices(),
        help="pose relation(s) to report (default: trans and angle_deg)",
    )
    ev.add_argument(
        "--t-max-diff", type=float, default=0.01, metavar="S", help="association tolerance (s)"
    )
    ev.add_argument(
        "--t-offset", type=float, default=0.0, metavar="S", help="added to EST's stamps (s)"
    )
    ev.add_argument(
        "--interpolate",
        action="store_true",
        help="interpolate REF at EST's stamps instead of taking the nearest stamp",
    )
    ev.add_argument(
        "--topic",
        action="append",
        metavar="T",
        help="bag topic or TF chain /tf:PARENT.CHILD (once for each bag, or REF's then EST's)",
    )
    ev.add_argument("--ref-times", metavar="FILE", help="times file of a KITTI reference")
    ev.add_argument("--est-times", metavar="FILE", help="times file of a KITTI estimate")
    ev.add_argument("--plot", metavar="FILE", help="write a PNG of paths, errors and NEES")
    ev.add_argument("--report", metavar="DIR", help="write an HTML report into DIR")
    ev.add_argument("--json", action="store_true", help="print one JSON object")
    ev.set_defaults(run=_eval)


def _traj_arguments(tr: argparse.ArgumentParser) -> None:
    tr.description = "Poses, duration, path length, covariance present or not."
    tr.add_argument("files", nargs="+", metavar="FILE")
    tr.add_argument(
        "--topic", action="append", metavar="T", help="bag topic(s) or /tf:PARENT.CHILD"
    )
    tr.add_argument("--plot", metavar="FILE", help="write a PNG of the paths with their ellipses")
    tr.add_argument(
        "--probability", type=float, default=0.9, help="ellipse probability (default 0.9)"
    )
    tr.add_argument("--json", action="store_true", help="print a JSON list")
    tr.set_defaults(run=_traj)


def _convert_arguments(cv: argparse.ArgumentParser) -> None:
    cv.description = (
        "Read any trajectory format relmap knows; write TUM, KITTI, "
        "EuRoC or relmap's format (with covariance)."
    )
    cv.add_argument("input", metavar="IN")
    cv.add_argument("output", metavar="OUT")
    from relmap.io import formats

    cv.add_argument(
        "--format",
        choices=[f.name for f in formats.formats(formats.Kind.TRAJECTORY, writable=True)],
        help="default: euroc for .csv, else relmap (TUM when 3-D without covariance)",
    )
    cv.add_argument("--topic", metavar="T", help="bag topic or /tf:PARENT.CHILD")
    cv.add_argument("--times", metavar="FILE", help="times file of KITTI poses")
    cv.set_defaults(run=_convert)
