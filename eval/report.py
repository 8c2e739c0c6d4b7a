"""``report.html``: one self-contained page per results folder of `vislam bench`.

The page holds what ``summary.md`` holds (per drive: the model line, the readings in words, among
them which segment lengths the RPE used, the table of figures and the RPE per segment length)
and every figure of the drive, embedded as a data URI so that the single file can be
mailed or archived. A small script marks ``<body data-images="loaded/total">`` once the page has
loaded, so a headless browser can check that every image decoded (tests/test_report.py).
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

from vislam.eval.readings import model_line, readings, rpe_length_table, sequence_table

#: The order figures appear in on the page (others follow, by name).
FIGURE_ORDER = ("trajectories.png", "error_over_distance.png", "nees.png", "vs_smoother.png", "map.png")

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: right; }
th:first-child, td:first-child { text-align: left; }
th { background: #eee; }
caption { caption-side: top; text-align: left; color: #444; padding-bottom: 0.3em; }
figure { margin: 1.5em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { color: #555; font-size: 0.9em; }
.model { color: #444; }
"""

_IMAGES_LOADED = """
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  document.body.setAttribute("data-images", ok + "/" + imgs.length);
});
"""


def _figures(folder: Path) -> list[Path]:
    pngs = {p.name: p for p in folder.glob("*.png")} if folder.is_dir() else {}
    first = [pngs.pop(n) for n in FIGURE_ORDER if n in pngs]
    return first + [pngs[n] for n in sorted(pngs)]


def _img(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f'<figure><img alt="{html.escape(path.stem)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(path.name)}</figcaption></figure>")


def _table(caption: str, header: list[str], rows: list[list[str]]) -> list[str]:
    """A captioned table's lines."""
    return (["<table>", f"<caption>{html.escape(caption)}</caption>",
             "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"]
            + ["<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>"
               for row in rows] + ["</table>"])


def report_html(results: dict, folder: Path) -> str:
    """The page for ``results`` (results.json's content) whose drive folders (with their PNG
    figures) are in ``folder``."""
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             "<title>vislam benchmark</title>", f"<style>{_STYLE}</style>",
             f"<script>{_IMAGES_LOADED}</script></head><body>", "<h1>vislam benchmark</h1>",
             f"<p>t_rel, r_rel: {html.escape(results['rpe_definition'])}.</p>"]
    if results.get("rpe_drive_definition"):
        parts.append(f"<p>RPE: {html.escape(results['rpe_drive_definition'])}.</p>")
    if results.get("alignment_definition"):
        parts.append(f"<p>{html.escape(results['alignment_definition'])}.</p>")
    for s in results["sequences"]:
        gt = "ground truth" if s["has_ground_truth"] else "no ground truth"
        parts.append(f"<h2>{html.escape(s['name'])} ({s['frames']} frames, {gt})</h2>")
        model = model_line(s.get("model"))
        if model:
            parts.append(f'<p class="model">{html.escape(model)}</p>')
        said = readings(s)
        if said:
            parts.append("<ul>" + "".join(f"<li>{html.escape(x)}</li>" for x in said) + "</ul>")
        header, rows = sequence_table(s)
        parts.append("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>")
        parts += ["<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows]
        parts.append("</table>")
        per_length = rpe_length_table(s)
        if per_length is not None:
            parts += _table(*per_length)
        parts += [_img(p) for p in _figures(folder / s["name"])]
    parts.append("</body></html>")
    return "\n".join(parts)
