"""`vislam compare RESULTS_A RESULTS_B [...]`: result folders of ``vislam bench``
(results.json) and ``vislam nees`` (nees.json) side by side. The first folder is the baseline;
every other one is compared with it (A vs B, A vs C, ...).

Per sequence and estimator each figure of every folder, with its change against the baseline
(absolute, relative, better / worse); for Monte Carlo runs "mean, median (min, max)" of the
per-run NEES and whether the change is beyond the run-to-run spread (Welch's t-test at 5 %);
the settings that differ are listed first. Prints the Markdown table (``--format latex``: the
LaTeX) and writes ``compare.md``, ``compare.tex`` and ``compare.png`` into ``--out`` (default
``results/compare-<YYYYmmdd-HHMMSS>``). See :mod:`eval.compare` for the readings, :mod:`eval.results` for what is read.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folders", nargs="*", metavar="RESULTS",
                        help="folders written by vislam bench or vislam nees (or their "
                             "results.json / nees.json); the first is the baseline")
    parser.add_argument("--out", "-o", metavar="DIR",
                        help="output folder for compare.md, compare.tex and compare.png "
                             "(default results/compare-<YYYYmmdd-HHMMSS>); never inside an "
                             "input folder")
    parser.add_argument("--force", action="store_true",
                        help="write into a non-empty folder vislam did not write (its files are "
                             "never replaced)")
    parser.add_argument("--format", choices=("md", "latex"), default="md",
                        help="what is printed: the Markdown tables (default) or the LaTeX")
    parser.add_argument("--quiet", "-q", action="store_true", help="print nothing but errors")


def run(args: argparse.Namespace) -> int:
    import time

    from vislam.eval.atomic import write_text
    from vislam.eval.compare import build_comparison, check_out_dir, input_files, load_folders
    from vislam.eval.compare_text import COMPARE_FILES, to_latex, to_markdown
    from vislam.eval.output_dir import OutputDir
    from vislam.eval.signals import deferred

    folders = load_folders(args.folders)
    comparison = build_comparison(folders)
    out = Path(args.out) if args.out else Path("results") / time.strftime("compare-%Y%m%d-%H%M%S")
    check_out_dir(out, folders)
    markdown, latex = to_markdown(comparison), to_latex(comparison)
    with OutputDir(out, force=args.force, expected=COMPARE_FILES,
                   inputs=input_files(folders)) as tmp:
        from vislam.eval.compare_plots import plot_comparison

        with deferred():  # a signal waits until the files are written
            write_text(tmp / "compare.md", markdown)
            write_text(tmp / "compare.tex", latex)
            plot_comparison(tmp / "compare.png", comparison)
    if not args.quiet:
        print(markdown if args.format == "md" else latex, end="")
    print(f"wrote {out}", file=sys.stderr)
    return 0
