"""The ``vislam`` command line: one subcommand per module of :mod:`eval.commands`.

Library code raises :class:`ekf.InputError` / :class:`ekf.EstimationError`; here they become
one line on stderr and exit code 2, with no traceback and nothing written.

Exit codes: 0 done; 2 bad input, an estimator that failed (``run``), or an output that could
not be written (one line on stderr, nothing written); 3 ``bench`` or ``nees`` finished and
wrote their results, but an estimator failed (one line per failure on stderr); 130 Ctrl-C and
143 SIGTERM (workers ended, nothing left behind); 1 a bug (a traceback: please report it).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import signal
import sys

from vislam.ekf.errors import EstimationError, InputError
from vislam.eval.signals import Terminated, raise_terminated

#: subcommand -> (module under eval.commands, one-line help)
COMMANDS = {
    "simulate": ("simulate", "write a simulated KITTI-like drive with ground truth"),
    "convert": ("convert", "write an ASL folder, an eqvio csv or a course drive as vislam's file form"),
    "inspect": ("inspect", "summarise a data file before estimating"),
    "run": ("run", "run one estimator on one sequence"),
    "bench": ("bench", "run every estimator on every sequence and compare"),
    "nees": ("nees", "Monte Carlo consistency (NEES) on the simulator"),
    "calibrate": ("calibrate", "identify the noise model of a drive from the data (no ground truth)"),
    "score": ("score", "score a trajectory made elsewhere against ground truth and the smoother"),
    "compare": ("compare", "compare result folders (bench or nees) side by side"),
    "config": ("config", "print a commented settings file with every default (for --config)"),
}


class OneLineParser(argparse.ArgumentParser):
    """argparse's usage errors as one line (the usage is one ``--help`` away), exit code 2."""

    def error(self, message: str):
        message = " ".join(message.split())
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="vislam",
        description="Visual-inertial SLAM: EKF variants cross-validated against a GTSAM smoother.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=OneLineParser)
    for name, (module, help_text) in COMMANDS.items():
        mod = importlib.import_module(f"vislam.eval.commands.{module}")
        p = sub.add_parser(name, help=help_text, description=help_text)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    previous = _terminate_raises()  # first: a SIGTERM during start-up is handled too
    os.environ["MPLBACKEND"] = "Agg"  # figures go to files; a bad MPLBACKEND must not matter
    for stream in (sys.stdout, sys.stderr):  # a path in a message never fails to print
        with contextlib.suppress(AttributeError, ValueError):
            stream.reconfigure(errors="backslashreplace")
    command, out = "vislam", None
    try:
        parser = build_parser()  # imports every command's modules: may be interrupted
        args = parser.parse_args(argv)
        command, out = f"vislam {args.command}", getattr(args, "out", None)
        logging.basicConfig(
            level=logging.INFO if args.verbose else logging.WARNING,
            format="%(levelname)s %(name)s: %(message)s",
        )
        return int(args._run(args) or 0)
    except (InputError, EstimationError) as exc:
        print(f"{command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except OSError as exc:  # the disk filled up, a folder vanished, ...: nothing was written
        where = exc.filename or (f"--out {out}" if out else None)
        where = f" writing {where}:" if where else ""
        print(f"{command}: error:{_one_line(where)} {_one_line(exc.strerror or exc)}; "
              "nothing written", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"{command}: error: out of memory; nothing written", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{command}: interrupted; nothing written", file=sys.stderr)
        return 130
    except Terminated:
        print(f"{command}: terminated; nothing written", file=sys.stderr)
        return 143
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _one_line(text) -> str:
    """A message on one line: newlines (in a path, say) written as \\n."""
    return str(text).replace("\r", "\\r").replace("\n", "\\n")


def _terminate_raises():
    """Install the SIGTERM handler; returns the previous one (None where it cannot be set)."""
    try:
        return signal.signal(signal.SIGTERM, raise_terminated)
    except ValueError:  # not the main thread (e.g. main() called from a test's thread)
        return None


if __name__ == "__main__":
    sys.exit(main())
