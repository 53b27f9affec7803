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
