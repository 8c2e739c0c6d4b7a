"""`vislam config [--out FILE]`: a commented settings file holding every default.

The ``[filter]`` table (ekf.config.FilterConfig), the ``[smoother]`` table
(graph.settings.SmootherSettings) and a commented-out ``[model]`` example (ekf.model), each
setting with its meaning and what it may be (eval.config_reference). ``--config`` reads the file
unchanged and gets exactly the defaults. Printed on stdout, or written to ``--out``, which must
not exist (an existing file is never replaced: exit code 2).
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

from vislam.ekf.errors import InputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", "-o", metavar="FILE",
                        help="write the settings file here instead of printing it (a new file: "
                             "an existing one is never replaced)")


def run(args: argparse.Namespace) -> int:
    from vislam.eval.config_reference import default_settings_toml

    text = default_settings_toml()
    if args.out is None:
        sys.stdout.write(text)
        return 0
    out = Path(args.out)
    _write_new(out, text)
    print(f"wrote {out}", file=sys.stderr)
    return 0


def _write_new(out: Path, text: str) -> None:
    """Write ``text`` to ``out``, which must not exist (created exclusively, so a file that
    appears meanwhile is not replaced either); a partly written file is removed."""
    if out.is_dir():
        raise InputError(f"--out {out}: is a folder; give a file name such as settings.toml")
    if out.exists() or out.is_symlink():
        raise InputError(f"--out {out}: exists; vislam config never replaces a file "
                         "(choose another name or remove it)")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"--out {out}: folder {parent} does not exist")
    try:
        fh = out.open("x", encoding="utf-8")
    except FileExistsError:
        raise InputError(f"--out {out}: exists; vislam config never replaces a file") from None
    try:
        with fh:
            fh.write(text)
    except BaseException:
        with contextlib.suppress(OSError):
            out.unlink()
        raise
