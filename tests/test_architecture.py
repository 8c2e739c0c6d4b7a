"""The package's shape, read from its source with ``ast`` (nothing is imported): imports flow one
way (ekf <- graph <- eval), no module imports itself round a cycle (function-local imports
included), eval/'s library half never imports its application half, and no module in eval/
is longer than :data:`MAX_EVAL_LINES` lines. Each failure names the offending module, file and
line, and what it imports."""

from __future__ import annotations

import ast
import functools
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: Source folder -> the package it installs as (pyproject.toml's package-dir).
PACKAGES = {
    "ekf": "vislam.ekf",
    "graph": "vislam.graph",
    "eval": "vislam.eval",
    "eval/commands": "vislam.eval.commands",
    "vislam": "vislam",
}

#: The application half of eval/: the command line and what only it does (output folders, the
#: report, figures, the compare text, printing). Every other module of eval/ is library: it may
#: read files but neither prints nor makes output folders, and it never imports these. A module
#: listed here as a package (``vislam.eval.commands``) stands for every module in it.
APPLICATION = frozenset({
    "vislam.eval.cli",  # the command line
    "vislam.eval.commands",  # one module per command
    "vislam.eval.output_dir",  # output folders: staged, checked, never over a user's files
    "vislam.eval.report",  # report.html
    "vislam.eval.plots",  # the benchmark's figures
    "vislam.eval.plots_top_view",  # the top views: trajectories and map
    "vislam.eval.compare_plots",  # compare.png
    "vislam.eval.compare_text",  # compare.md and compare.tex
    "vislam.eval.bench_output",  # vislam bench's folder
    "vislam.eval.readings",  # summary.md's readings and tables
    "vislam.eval.drive_figures",  # a drive's figures
    "vislam.eval.config_reference",  # docs/configuration.md and vislam config's text
})

#: Modules allowed to break a rule here while other work cuts them at their seams: their
#: failures are reported but do not fail the tests. Empty: every module keeps every rule.
KNOWN_PENDING_SPLITS: frozenset[str] = frozenset()

#: Longest module allowed in eval/ (lines).
MAX_EVAL_LINES = 500

#: Layers, lowest first: a module may import its own layer and those below it only.
LAYERS = ("vislam.ekf", "vislam.graph", "vislam.eval")


@dataclass(frozen=True)
class Edge:
    """``source`` imports ``target`` at ``path:line``."""

    source: str
    target: str
    path: Path
    line: int

    def __str__(self) -> str:
        return (f"{self.source} imports {self.target} "
                f"({self.path.relative_to(REPO)}:{self.line})")


@functools.lru_cache(maxsize=None)
def modules() -> dict[str, Path]:
    """Every module of the package: dotted name -> file."""
    out = {}
    for folder, package in PACKAGES.items():
        for path in sorted((REPO / folder).glob("*.py")):
            out[package if path.stem == "__init__" else f"{package}.{path.stem}"] = path
    return out


def _resolve(name: str, known: dict[str, Path]) -> str | None:
    """The module of the package that importing ``name`` names (its longest known prefix)."""
    while name:
        if name in known:
            return name
        name = name.rpartition(".")[0]
    return None


def _imported_names(node: ast.AST, module: str, is_package: bool, known) -> list[str]:
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if not isinstance(node, ast.ImportFrom):
        return []
    if node.level:  # relative: from the module's own package upwards
        base = module if is_package else module.rpartition(".")[0]
        for _ in range(node.level - 1):
            base = base.rpartition(".")[0]
        stem = f"{base}.{node.module}" if node.module else base
    else:
        stem = node.module or ""
    # "from vislam.eval import plots" imports the module vislam.eval.plots
    return [f"{stem}.{a.name}" if f"{stem}.{a.name}" in known else stem for a in node.names]


@functools.lru_cache(maxsize=None)
def import_edges() -> tuple[Edge, ...]:
    """Every import of one of the package's modules by another, module-level and
    function-local alike (``ast.walk`` sees every statement)."""
    known = modules()
    edges: dict[tuple[str, str], Edge] = {}
    for module, path in known.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            for name in _imported_names(node, module, path.stem == "__init__", known):
                target = _resolve(name, known) if name.startswith("vislam") else None
                if target is not None and target != module:
                    edges.setdefault((module, target), Edge(module, target, path, node.lineno))
    return tuple(sorted(edges.values(), key=lambda e: (e.source, e.target)))


def is_application(module: str) -> bool:
    return any(module == a or module.startswith(a + ".") for a in APPLICATION)


def layer(module: str) -> int | None:
    for i, prefix in enumerate(LAYERS):
        if module == prefix or module.startswith(prefix + "."):
            return i
    return None


def cycles(edges: list[Edge]) -> list[list[Edge]]:
    """One cycle (its edges in order) per strongly connected component of the import graph
    that has one (Tarjan's algorithm, then a path round the component)."""
    graph: dict[str, list[Edge]] = {}
    for e in edges:
        graph.setdefault(e.source, []).append(e)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[set[str]] = []

    def visit(v: str) -> None:  # recursion depth is bounded by the number of modules
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for e in graph.get(v, []):
            if e.target not in index:
                visit(e.target)
                low[v] = min(low[v], low[e.target])
            elif e.target in on_stack:
                low[v] = min(low[v], index[e.target])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                components.append(component)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    out = []
    for component in components:
        start = min(component)
        # breadth-first from start back to start, inside the component: a shortest cycle
        paths = {start: []}
        frontier = [start]
        found = None
        while frontier and found is None:
            nxt = []
            for v in frontier:
                for e in graph.get(v, []):
                    if e.target not in component:
                        continue
                    if e.target == start:
                        found = paths[v] + [e]
                        break
                    if e.target not in paths:
                        paths[e.target] = paths[v] + [e]
                        nxt.append(e.target)
                if found:
                    break
            frontier = nxt
        out.append(found)
    return out


def _split(failures: list[tuple[str, str]]) -> tuple[list[str], list[str]]:
    """(failing, pending): messages of failures, those of :data:`KNOWN_PENDING_SPLITS` apart."""
    failing = [m for module, m in failures if module not in KNOWN_PENDING_SPLITS]
    pending = [m for module, m in failures if module in KNOWN_PENDING_SPLITS]
    return failing, pending


def _check(failures: list[tuple[str, str]], what: str) -> None:
    failing, pending = _split(failures)
    for m in pending:
        print(f"known pending ({what}): {m}")
    assert not failing, f"{len(failing)} {what}:\n  " + "\n  ".join(failing)


# --- the tests -------------------------------------------------------------------------------


def test_the_walk_sees_the_package():
    known = modules()
    assert {"vislam.ekf.sequence", "vislam.graph.smoother", "vislam.eval.loader",
            "vislam.eval.cli", "vislam.eval.commands.bench", "vislam"} <= set(known)
    edges = import_edges()
    assert any(e.source == "vislam.eval.cli" for e in edges)
    # function-local imports are walked too
    local = [e for e in edges if e.source == "vislam.eval.commands.compare"]
    assert {"vislam.eval.compare", "vislam.eval.compare_text"} <= {e.target for e in local}
    listed = {m for m in APPLICATION if m in known}
    assert listed == set(APPLICATION), f"not modules of the package: {set(APPLICATION) - listed}"


def test_no_import_cycles():
    failures = []
    for cycle in cycles(import_edges()):
        path = " -> ".join([cycle[0].source] + [e.target for e in cycle])
        where = "; ".join(str(e) for e in cycle)
        # a cycle through a pending module is pending
        pending = next((e.source for e in cycle if e.source in KNOWN_PENDING_SPLITS), None)
        failures.append((pending or cycle[0].source, f"cycle {path}: {where}"))
    _check(failures, "import cycles")


def test_imports_flow_one_way_ekf_graph_eval():
    failures = []
    for e in import_edges():
        a, b = layer(e.source), layer(e.target)
        if a is not None and b is not None and b > a:
            failures.append((e.source, f"{e} ({LAYERS[a]} may not import {LAYERS[b]})"))
    _check(failures, "imports against the flow ekf <- graph <- eval")


def test_library_never_imports_the_application_half():
    failures = []
    for e in import_edges():
        if (e.source.startswith("vislam.eval") and not is_application(e.source)
                and is_application(e.target)):
            failures.append((e.source, f"{e}: a library module imports the application half"))
    _check(failures, "library modules importing the application half")


def test_no_module_in_eval_is_too_long():
    failures = []
    for module, path in modules().items():
        if not module.startswith("vislam.eval"):
            continue
        n = len(path.read_text(encoding="utf-8").splitlines())
        if n > MAX_EVAL_LINES:
            failures.append((module, f"{path.relative_to(REPO)}: {n} lines "
                                     f"(at most {MAX_EVAL_LINES}; cut it at its seams)"))
    _check(failures, "modules over the length limit")


def test_the_checks_catch_what_they_are_for():
    """The walk on a made-up graph: a cycle is found and named edge by edge."""
    p = REPO / "eval" / "x.py"
    edges = [Edge("a", "b", p, 1), Edge("b", "c", p, 2), Edge("c", "a", p, 3),
             Edge("c", "d", p, 4)]
    (cycle,) = cycles(edges)
    assert [(e.source, e.target) for e in cycle] == [("a", "b"), ("b", "c"), ("c", "a")]
    assert "eval/x.py:3" in str(cycle[2])
    assert cycles(edges[:2] + edges[3:]) == []
    assert is_application("vislam.eval.commands.bench") and not is_application("vislam.eval.loader")
    assert layer("vislam.graph.smoother") == 1 and layer("vislam.testing") is None
