#!/usr/bin/env python3
"""Strip a notebook's outputs before committing: outputs, execution counts and run metadata.

    python tools/strip_notebook.py notebooks/analysis.ipynb [more.ipynb ...]
    python tools/strip_notebook.py --check notebooks/analysis.ipynb   # exit 1 if not stripped

The notebooks are executed by the tests (tests/test_notebook.py), so their committed form
carries code and text only.
"""

from __future__ import annotations

import argparse
import sys

import nbformat

#: Cell metadata written by running a notebook, not by editing it.
RUN_METADATA = ("execution", "collapsed", "scrolled", "ExecuteTime")


def strip(nb: nbformat.NotebookNode) -> bool:
    """Remove outputs, execution counts and run metadata in place; True if anything changed."""
    changed = False
    for cell in nb.cells:
        for key in RUN_METADATA:
            if key in cell.metadata:
                del cell.metadata[key]
                changed = True
        if cell.cell_type != "code":
            continue
        if cell.outputs:
            cell.outputs = []
            changed = True
        if cell.execution_count is not None:
            cell.execution_count = None
            changed = True
    for key in ("widgets", "papermill"):
        if key in nb.metadata:
            del nb.metadata[key]
            changed = True
    return changed


def is_stripped(nb: nbformat.NotebookNode) -> bool:
    return not strip(nbformat.from_dict(nb))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="+", metavar="NOTEBOOK")
    parser.add_argument("--check", action="store_true", help="only report notebooks with outputs")
    args = parser.parse_args(argv)
    rc = 0
    for path in args.paths:
        nb = nbformat.read(path, as_version=nbformat.NO_CONVERT)
        if args.check:
            if not is_stripped(nb):
                print(f"{path}: has outputs or execution counts; run tools/strip_notebook.py", file=sys.stderr)
                rc = 1
            continue
        if strip(nb):
            nbformat.validate(nb)
            nbformat.write(nb, path)
            print(f"stripped {path}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
