"""``vislam compare``'s text: the comparison (:class:`eval.compare.Comparison`) as Markdown
(``compare.md``, what the command prints) and as LaTeX booktabs tables (``compare.tex``)."""

from __future__ import annotations

import re

from vislam.eval.compare import Comparison, Section
from vislam.eval.compare_readings import ABSENT, NO_VALUE

#: The files ``vislam compare`` writes into its output folder.
COMPARE_FILES = ("compare.md", "compare.tex", "compare.png")

BENCH_NOTE = ("Changes are B − A against the baseline A (relative to |A|). Lower is better for "
              "ATE, t_rel, r_rel, RPE, map RMSE, the vs-smoother ATE and map, and runtime; for NEES "
              "the value closer to its two-sided 95 % chi-square band (shown beside it) is "
              "better. \"same\": within 0.1 %. "
              f"{ABSENT}: not in that folder; {NO_VALUE}: no value.")


def header(section: Section) -> list[str]:
    """The column titles of a section's table: the baseline, then per folder its value, change
    and reading."""
    cols = ["estimator", "figure", f"{section.folders[0].label} (baseline)"]
    for f in section.folders[1:]:
        b = section.folders[0].label
        cols += [f.label, f"{f.label} − {b}", f"{f.label} vs {b}"]
    return cols


def body(section: Section) -> list[list[str]]:
    """The cells of a section's table, one row per figure of each estimator."""
    out = []
    for row in section.rows:
        cells = [row.estimator, row.label, row.cells[0]]
        for cell, ch in zip(row.cells[1:], row.changes[1:]):
            cells += [cell, ch.text() if ch else ABSENT if ABSENT in (cell, row.cells[0]) else "",
                      ch.verdict if ch else ""]
        out.append(cells)
    return out


def md_table(header: list[str], body: list[list[str]]) -> list[str]:
    """The lines of a Markdown table (``|`` and line breaks in cells escaped)."""
    def esc(s: str) -> str:
        return str(s).replace("|", "\\|").replace("\r", "\\r").replace("\n", "\\n")

    lines = ["| " + " | ".join(esc(h) for h in header) + " |",
             "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(esc(c) for c in row) + " |" for row in body]
    return lines


def to_markdown(comp: Comparison) -> str:
    """The comparison as Markdown: folders, settings that differ, one table per section."""
    lines = ["# vislam compare", ""]
    rows = []
    for f in comp.folders:
        label = f.label + (" (baseline)" if f is comp.folders[0] else "")
        rows.append([label, f.shown, ", ".join(f.files), f.command() or ""])
    lines += md_table(["folder", "path", "holds", "command"], rows) + [""]
    for kind, diff in comp.settings.items():
        folders = comp.settings_folders[kind]
        what = "vislam bench: settings.json" if kind == "bench" else "vislam nees: nees.json"
        lines.append(f"## Settings that differ ({what})")
        lines.append("")
        if diff:
            lines += md_table(["setting"] + [f.label for f in folders],
                               [[k] + v for k, v in diff]) + [""]
        else:
            lines += [("None (numbers equal within a relative 1e-3; command line, time and the "
                       "model identification's diagnostics not compared)."), ""]
    for note in comp.notes:
        lines.append(f"Note: {note}.")
    if comp.notes:
        lines.append("")
    for s in comp.sections:
        lines.append(f"## {'Benchmark: ' if s.kind == 'bench' else ''}{s.title}")
        lines.append("")
        lines += md_table(header(s), body(s)) + [""]
        notes = list(s.notes)
        if s.kind == "bench":
            notes.append(BENCH_NOTE)
        else:
            notes.append("ANEES: value [two-sided 95 % bounds] verdict; the change of the "
                         "per-run row is that of the mean.")
        lines += [f"- {n}" for n in notes] + [""]
    return "\n".join(lines).rstrip() + "\n"


_LATEX = {
    "\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
    "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
    "–": "--", "−": "$-$", "°": r"\textdegree{}", "±": r"$\pm$", "<": r"\textless{}",
    ">": r"\textgreater{}", "|": r"\textbar{}", "\n": " ", "\r": " ", "χ": r"$\chi$",
    "²": r"\textsuperscript{2}",
}


def latex_escape(text: str) -> str:
    """Text safe in a LaTeX table cell (special characters and the few non-ASCII ones here)."""
    out = []
    for ch in str(text):
        if ch in _LATEX:
            out.append(_LATEX[ch])
        elif ord(ch) < 128:
            out.append(ch)
        else:
            out.append("?")
    # a leading minus of a number as a math minus (not a hyphen): "-0.5" -> "$-$0.5"
    return re.sub(r"(?<![\w.])-(?=\d)", "$-$", "".join(out))


def to_latex(comp: Comparison) -> str:
    """The comparison as LaTeX: one booktabs longtable per section (needs ``\\usepackage{
    booktabs,longtable,textcomp}``), the differing settings first."""
    e = latex_escape
    lines = ["% vislam compare: needs \\usepackage{booktabs,longtable,textcomp}",
             "% folders: " + "; ".join(f"{f.label} = {e(f.shown)}" for f in comp.folders), ""]

    def table(header, body, caption, footnotes=()):
        spec = "l" * 2 + "r" * (len(header) - 2) if header[0] == "estimator" else \
            "l" * len(header)
        out = [f"\\begin{{longtable}}{{{spec}}}",
               f"\\caption{{{e(caption)}}}\\\\",
               "\\toprule",
               " & ".join(e(h) for h in header) + " \\\\",
               "\\midrule", "\\endfirsthead",
               "\\toprule", " & ".join(e(h) for h in header) + " \\\\", "\\midrule",
               "\\endhead", "\\bottomrule", "\\endlastfoot"]
        last = None
        for row in body:
            if header[0] == "estimator" and last is not None and row[0] != last:
                out.append("\\midrule")
            last = row[0]
            out.append(" & ".join(e(c) for c in row) + " \\\\")
        out.append("\\end{longtable}")
        out += [f"\\noindent\\footnotesize {e(n)}\\par\\normalsize" for n in footnotes]
        return out + [""]

    for kind, diff in comp.settings.items():
        folders = comp.settings_folders[kind]
        if diff:
            lines += table(["setting"] + [f.label for f in folders], [[k] + v for k, v in diff],
                           f"Settings that differ ({'vislam bench' if kind == 'bench' else 'vislam nees'})")
    for s in comp.sections:
        notes = list(s.notes)
        notes.append(BENCH_NOTE if s.kind == "bench" else
                     "ANEES: value [two-sided 95 % bounds] verdict; the change of the per-run "
                     "row is that of the mean.")
        caption = ("Benchmark: " if s.kind == "bench" else "") + s.title + "; " + ", ".join(
            f"{f.label} = {f.shown}" for f in s.folders)
        lines += table(header(s), body(s), caption, notes)
    return "\n".join(lines).rstrip() + "\n"
