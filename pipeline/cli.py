"""The ``terrain`` command line: thin wrappers over the Python API."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from meshcore import MeshError

from .errors import PipelineError

__all__ = ["main"]

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2


def _positive_int(text: str) -> int:
    value = int(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="terrain",
        description="Combined triangle/quad terrain meshes and DEMs from point clouds.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    exp = sub.add_parser(
        "experiment",
        help="run the error experiment of the combined-mesh paper (Tables 1-3, Figure 2)",
        description=(
            "Points uniform in the unit disc; convex, saddle and random test functions; "
            "rows S1 (triangulation), S2 (S1 + S2 quads), S3 (triangulation), S4 (S3 + S4 quads); "
            "L2 norms of f - g and grad f - grad g by Gauss quadrature over every face. "
            "Prints the tables and writes PNG figures to --out."
        ),
    )
    exp.add_argument("--points", type=_positive_int, default=500, help="points per trial (default 500)")
    exp.add_argument("--trials", type=_positive_int, default=20, help="point sets per function (default 20)")
    exp.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    exp.add_argument("--out", type=Path, default=Path("experiment-out"), help="folder for the PNG figures")
    exp.add_argument(
        "--merge", choices=("greedy", "optimal"), default="greedy", help="elimination strategy (default greedy)"
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``terrain``; returns the exit code (0 ok, 1 failed, 2 usage or input error)."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "experiment":
            from .experiment import experiment_command

            return experiment_command(
                points=args.points, trials=args.trials, seed=args.seed, out=args.out, merge=args.merge
            )
    except (PipelineError, MeshError) as exc:
        print(f"terrain: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_FAILED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
