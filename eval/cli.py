"""The ``vislam`` command line: one subcommand per module of :mod:`eval.commands`.

Library code raises :class:`ekf.InputError` / :class:`ekf.EstimationError`; here they become
one line on stderr and exit code 2, with no traceback and nothing written.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from ekf.errors import EstimationError, InputError

#: subcommand -> (module under eval.commands, one-line help)
COMMANDS = {
    "simulate": ("simulate", "write a simulated KITTI-like drive with ground truth"),
    "inspect": ("inspect", "summarise a data file before estimating"),
    "run": ("run", "run one estimator on one sequence"),
    "bench": ("bench", "run every estimator on every sequence and compare"),
    "nees": ("nees", "Monte Carlo consistency (NEES) on the simulator"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vislam",
        description="Visual-inertial SLAM: EKF variants cross-validated against a GTSAM smoother.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        mod = importlib.import_module(f"eval.commands.{module}")
        p = sub.add_parser(name, help=help_text, description=help_text)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return int(args._run(args) or 0)
    except (InputError, EstimationError) as exc:
        print(f"vislam {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"vislam {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
