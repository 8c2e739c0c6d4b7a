"""A saved ``vislam nees`` folder as checks: a regression test can pin a study it ran once
(:func:`eval.results.load_results`), as :func:`eval.testing.assert_nees_consistent` pins one it
runs itself. The figures and bounds are the folder's own (``nees.json``: two-sided 95 %
chi-square bounds); each :class:`eval.testing.Check` states the figure, the bounds and the
verdict."""

from __future__ import annotations

import math
import os

from vislam.eval.consistency import VERDICT_INSIDE, VERDICT_WORDS
from vislam.eval.results import NeesEstimatorResult, load_results
from vislam.eval.testing import Check



def _check(row: NeesEstimatorResult, what: str, max_failed_runs: int) -> Check:
    value = row.anees_pose if what == "pose" else row.anees_landmark
    bounds = row.bounds_pose if what == "pose" else row.bounds_landmark
    verdict = (row.verdict_pose if what == "pose" else row.verdict_landmark) or "missing"
    quantity = f"{what} ANEES"
    if value is None or bounds is None:
        return Check(row.name, quantity, None, (math.nan, math.nan), "missing", False,
                     f"{row.name}: {quantity}: not in the folder")
    lo, hi = bounds
    line = (f"{row.name}: {quantity} {value:.2f} (saved study), 95 % bounds [{lo:.2f}, {hi:.2f}]: "
            f"{VERDICT_WORDS.get(verdict, verdict)}")
    ok = verdict == VERDICT_INSIDE
    if row.runs_failed > max_failed_runs:
        ok, verdict = False, "failed"
        line += f"; {row.runs_failed} runs failed" + (f" ({row.errors[0]})" if row.errors else "")
    return Check(row.name, quantity, float(value), (float(lo), float(hi)), verdict, ok, line)


def folder_checks(folder: str | os.PathLike, name: str | None = None,
                  what: tuple[str, ...] | str = ("pose", "landmark"),
                  max_failed_runs: int = 0) -> list[Check]:
    """The checks of ``name`` (None: the folder's only estimator) in a ``vislam nees`` folder;
    InputError naming the folder when it is not one or has no such estimator."""
    from vislam.ekf.errors import InputError

    nees = load_results(folder).nees
    if nees is None:
        raise InputError(f"{folder}: not a vislam nees folder (no nees.json)")
    if name is None:
        if len(nees.estimators) != 1:
            raise InputError(f"{folder}: {len(nees.estimators)} estimators "
                             f"({', '.join(nees.estimators)}); name one")
        (name,) = nees.estimators
    if name not in nees.estimators:
        raise InputError(f"{folder}: no estimator {name!r} (it has {', '.join(nees.estimators)})")
    whats = (what,) if isinstance(what, str) else tuple(what)
    return [_check(nees.estimators[name], w, max_failed_runs) for w in whats]


def assert_folder_consistent(folder: str | os.PathLike, name: str | None = None, *,
                             what: tuple[str, ...] | str = ("pose", "landmark"),
                             max_failed_runs: int = 0) -> list[Check]:
    """Assert that ``name``'s ANEES in a saved ``vislam nees`` folder is inside its bounds
    (:func:`folder_checks`); fails with one line per failed check."""
    __tracebackhide__ = True
    checks = folder_checks(folder, name, what, max_failed_runs)
    bad = [c for c in checks if not c.ok]
    if bad:
        raise AssertionError("\n".join(c.message for c in bad))
    return checks


__all__ = ["assert_folder_consistent", "folder_checks"]
