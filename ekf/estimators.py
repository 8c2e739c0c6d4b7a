"""vislam's estimators by name: the entry points of pyproject.toml, the one list of names.

``[project.entry-points."vislam.estimators"]`` in pyproject.toml names every estimator vislam
ships, in the order tables and plots list them, and what runs it: a per-frame filter class
(:mod:`ekf.filter`, run by :func:`ekf.driver.run_filter`) under ``vislam.ekf``, or a whole-drive
callable (the smoothers, ``vislam.eval.builtin``). Everything else that lists names reads them
from here (``vislam.eval.registry``, ``ESTIMATORS`` below).

They are read from the checkout's pyproject.toml when vislam runs from one (an editable install:
always the file as it is now, in its order), else from the installed distribution's metadata
(which pip generates from the same table; its order is alphabetical).
"""

from __future__ import annotations

import functools
import importlib
from pathlib import Path
from typing import Callable

from vislam.ekf.config import FilterConfig
from vislam.ekf.driver import run_filter
from vislam.ekf.estimate import Estimate
from vislam.ekf.runner import Progress
from vislam.ekf.sequence import Sequence

#: The entry-point group every estimator of velocity drives, vislam's own and a plug-in's, is
#: registered in.
ENTRY_POINT_GROUP = "vislam.estimators"
#: The group of the estimators of raw-IMU drives (:class:`ekf.inertial.InertialDrive`).
INERTIAL_ENTRY_POINT_GROUP = "vislam.inertial_estimators"

#: The package whose entry points are vislam's own.
DISTRIBUTION = "vislam"

#: Where vislam's per-frame filters live: an entry point into this package names a Filter class.
FILTER_PACKAGE = "vislam.ekf."

#: The EKFs the batch smoother starts from, first that succeeds wins.
SMOOTHER_INITIALISERS: tuple[str, ...] = ("ekf-invariant", "ekf-joint")


def builtin_entry_points(group: str = ENTRY_POINT_GROUP) -> dict[str, str]:
    """vislam's own estimators of ``group``: name -> ``module:attribute``, in pyproject.toml's
    order (a new dict)."""
    return dict(_read_entry_points(group))


@functools.lru_cache(maxsize=None)
def _read_entry_points(group: str = ENTRY_POINT_GROUP) -> dict[str, str]:
    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        tomllib = None
    if tomllib is not None and pyproject.is_file():
        project = tomllib.loads(pyproject.read_text(encoding="utf-8")).get("project", {})
        if project.get("name") == DISTRIBUTION:
            return dict(project.get("entry-points", {}).get(group, {}))
    from importlib.metadata import distribution

    return {ep.name: ep.value for ep in distribution(DISTRIBUTION).entry_points
            if ep.group == group}


def filter_names() -> tuple[str, ...]:
    """vislam's per-frame filters (the EKFs, dead reckoning and mapping), in table order."""
    return tuple(n for n, v in builtin_entry_points().items() if v.startswith(FILTER_PACKAGE))


def load_target(value: str):
    """The object an entry point's ``module:attribute`` names."""
    module, _, attr = value.partition(":")
    obj = importlib.import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


def whole_drive(cls: type, name: str) -> Callable[..., Estimate]:
    """``run(seq, config, progress) -> Estimate``: a new ``cls()`` through
    :func:`ekf.driver.run_filter`, its Estimate named ``name``."""

    def run(seq: Sequence, config: FilterConfig = FilterConfig(), progress: Progress = None) -> Estimate:
        return run_filter(cls(), seq, config, progress, name=name)

    run.__name__ = run.__qualname__ = f"run_{name.replace('-', '_')}"
    run.__doc__ = f"{name}: :class:`{cls.__module__}.{cls.__qualname__}` over a whole drive."
    return run


def __getattr__(name: str):
    """``ESTIMATORS``: the per-frame filters by name, each as a whole-drive
    ``run(seq, config, progress)`` (:func:`whole_drive`); built on first use, so that reading the
    names imports no filter."""
    if name == "ESTIMATORS":
        table = {n: whole_drive(load_target(builtin_entry_points()[n]), n) for n in filter_names()}
        globals()["ESTIMATORS"] = table
        return table
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["ENTRY_POINT_GROUP", "ESTIMATORS", "SMOOTHER_INITIALISERS", "builtin_entry_points",
           "filter_names", "load_target", "whole_drive"]
