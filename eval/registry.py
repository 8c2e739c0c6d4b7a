"""The estimator protocols, and estimators by name: vislam's own and a user's, alike.

**Per-frame filters.** A class implementing :class:`vislam.ekf.filter.Filter` (initialise,
predict, update, marginalise and read-outs of pose, covariance and landmarks) is run by the one
per-frame loop, :func:`vislam.ekf.driver.run_filter`, exactly as vislam's EKFs are: a new instance
per drive, ``settings.filter`` its FilterConfig.

**Whole-drive estimators** (smoothers, systems run elsewhere). A callable
``estimate(seq, settings) -> Estimate`` (:class:`Estimator`):

- ``seq`` a :class:`vislam.ekf.sequence.Sequence` (timestamps, body velocities, stereo
  observations, camera model and ``cam_T_imu``);
- ``settings`` an :class:`EstimatorSettings`: ``filter`` (the noise model every estimator shares:
  :class:`vislam.ekf.config.FilterConfig`), ``smoother`` (GTSAM settings), ``initial`` (another
  estimator's result to start from, or None) and ``progress`` (call it with the number of frames
  done, or ignore it);
- it returns a :class:`vislam.ekf.estimate.Estimate` with one pose per frame of ``seq``:
  ``timestamps`` equal to ``seq.timestamps``, ``poses`` (T, 4, 4) ``world_T_imu`` with the world
  frame the IMU frame at the first frame, ``pose_cov`` (T, 6, 6) the covariance of the right
  perturbation ``world_T_imu_true = world_T_imu_est @ se3_exp(xi)``, ``xi`` translation first
  (m, rad), symmetric positive semi-definite; ``landmarks`` (M, 3) world positions per track of
  ``seq`` and ``landmark_cov`` (M, 3, 3), NaN where a track got no landmark (M may be 0);
  ``step_time_s``, ``n_updates``, ``n_rejected``, ``n_initialised`` (T,) counters (zeros are
  fine). ``Estimate.empty(name, seq.timestamps, n_tracks)`` gives the right shapes to fill in.

Every estimate is checked against this contract (:func:`check_contract`) before anything is
scored or written.

**Where estimators come from.** A name is looked up, in order:

1. ``MODULE:CLASS`` or ``MODULE:FUNCTION`` (a dotted module importable from ``sys.path`` or the
   current folder, or a ``path/to/file.py``): a user's filter class or estimator, without
   installing anything;
2. the entry points of the group ``vislam.estimators`` of every installed package. vislam's own
   are registered there by its ``pyproject.toml`` (the one list of their names:
   :mod:`vislam.ekf.estimators`); a user's package adds its own in the same way::

       [project.entry-points."vislam.estimators"]
       my-ekf = "my_package.filter:MyFilter"

A user's estimator gets everything a built-in one gets (tables, plots, vs-smoother scores, Monte
Carlo NEES). A user's estimator that cannot be found, raises, or returns an Estimate that breaks
the contract is bad input: :class:`UserEstimatorError` (an InputError, exit code 2), one line.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import importlib
import importlib.util
import logging
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Protocol

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.estimate import Estimate
from vislam.ekf.filter import is_filter_class
from vislam.ekf.estimators import (DISTRIBUTION, ENTRY_POINT_GROUP, INERTIAL_ENTRY_POINT_GROUP,
                                   SMOOTHER_INITIALISERS, builtin_entry_points, filter_names)
from vislam.ekf.runner import COVARIANCE_RTOL, covariance_defects
from vislam.graph.settings import SmootherSettings

log = logging.getLogger(__name__)

#: vislam's own entry points, as pyproject.toml registers them (:mod:`vislam.ekf.estimators`).
BUILTIN_ENTRY_POINTS: dict[str, str] = builtin_entry_points()

#: vislam's own estimators, in the order tables and plots list them.
ESTIMATOR_NAMES: tuple[str, ...] = tuple(BUILTIN_ENTRY_POINTS)

#: What ``vislam bench`` runs unless told otherwise: every estimator but the fixed-lag smoother
#: (iSAM2 is in since it runs within twice the batch smoother's time: 0034 7 s against 11 s).
DEFAULT_BENCH: tuple[str, ...] = tuple(n for n in ESTIMATOR_NAMES if n != "smoother-fixed-lag")

#: vislam's own estimators of raw-IMU drives (:class:`ekf.inertial.InertialDrive`), in table
#: order: a second entry-point group, so that every list above stays that of velocity drives.
INERTIAL_ENTRY_POINTS: dict[str, str] = builtin_entry_points(INERTIAL_ENTRY_POINT_GROUP)
INERTIAL_ESTIMATOR_NAMES: tuple[str, ...] = tuple(INERTIAL_ENTRY_POINTS)
#: What ``vislam bench`` runs on a raw-IMU drive unless told otherwise.
DEFAULT_BENCH_INERTIAL: tuple[str, ...] = INERTIAL_ESTIMATOR_NAMES
#: The reference smoothers of raw-IMU drives.
INERTIAL_SMOOTHERS: tuple[str, ...] = tuple(n for n in INERTIAL_ESTIMATOR_NAMES if n.startswith("smoother"))
#: Drive kinds: a velocity drive (:class:`ekf.sequence.Sequence`) or a raw-IMU drive.
DRIVE_KINDS = ("velocity", "raw-imu")

#: The EKFs whose estimate the batch smoother starts from, first available wins.
SMOOTHER_INITIAL_FROM: tuple[str, ...] = SMOOTHER_INITIALISERS

#: Names of the smoothers (the references the EKFs are cross-validated against): vislam's own
#: estimators that are whole-drive callables, not per-frame filters.
SMOOTHERS: tuple[str, ...] = tuple(n for n in ESTIMATOR_NAMES if n not in filter_names())


@dataclass(frozen=True)
class EstimatorSettings:
    """What every estimator is given besides the drive (see the module docstring)."""

    filter: FilterConfig = dataclasses.field(default_factory=FilterConfig)
    smoother: SmootherSettings = dataclasses.field(default_factory=SmootherSettings)
    initial: Any = None  # an Estimate to start from, or None
    progress: Callable[[int], None] | None = None


class Estimator(Protocol):
    """A whole-drive estimator: ``estimate(seq, settings) -> Estimate`` (module docstring)."""

    def __call__(self, seq, settings: EstimatorSettings) -> Estimate: ...


class UserEstimatorError(InputError):
    """A user's estimator cannot be loaded, raised, or broke the Estimate contract."""


def is_user_spec(name: str) -> bool:
    """``MODULE:CLASS`` or ``MODULE:FUNCTION`` names a user's estimator; a plain name is looked
    up in the entry points."""
    return ":" in name


def display_name(name) -> str:
    """The name under which an estimator appears in tables, files and results.json: its name,
    or ``module:function`` for a callable."""
    if isinstance(name, str):
        return name
    return f"{getattr(name, '__module__', '?')}:{getattr(name, '__qualname__', repr(name))}"


def file_stem(name: str) -> str:
    """``name`` as a file name: a user's ``pkg.mod:estimate`` becomes ``pkg.mod-estimate``."""
    return re.sub(r"[^A-Za-z0-9._+-]", "-", name)


def entry_points() -> dict[str, str]:
    """Estimator name -> ``module:function``: vislam's own, then every installed package's
    entry points of :data:`ENTRY_POINT_GROUP` (a plugin cannot take a built-in's name)."""
    from importlib.metadata import entry_points as installed

    found = dict(BUILTIN_ENTRY_POINTS)
    for ep in installed(group=ENTRY_POINT_GROUP):
        if ep.dist is not None and ep.dist.name == DISTRIBUTION:
            continue  # vislam's own: BUILTIN_ENTRY_POINTS (its installed copy may be stale)
        if ep.name in BUILTIN_ENTRY_POINTS:
            if ep.value != BUILTIN_ENTRY_POINTS[ep.name]:
                log.warning("ignoring entry point %s = %s: %r is vislam's own estimator",
                            ep.name, ep.value, ep.name)
            continue
        found.setdefault(ep.name, ep.value)
    return found


def known_names() -> list[str]:
    """Every estimator name: vislam's own of velocity drives (table order), installed plug-ins,
    then vislam's own of raw-IMU drives."""
    names = list(entry_points())
    return names + [n for n in INERTIAL_ESTIMATOR_NAMES if n not in names]


def drive_kind(seq) -> str:
    """``"raw-imu"`` for a raw-IMU drive (:class:`ekf.inertial.InertialDrive`), else
    ``"velocity"``."""
    from vislam.ekf.inertial import InertialDrive

    return "raw-imu" if isinstance(seq, InertialDrive) else "velocity"


def estimator_kind(name) -> str:
    """The kind of drive estimator ``name`` runs on: vislam's raw-IMU estimators and a user's
    callable with ``drive_kind = "raw-imu"`` take raw-IMU drives; every other estimator takes
    velocity drives."""
    if isinstance(name, str) and name in INERTIAL_ENTRY_POINTS:
        return "raw-imu"
    if isinstance(name, str) and name in BUILTIN_ENTRY_POINTS:
        return "velocity"
    return getattr(resolve(name), "drive_kind", "velocity")


def applicable(estimators, seq) -> list:
    """The estimators of ``estimators`` that run on ``seq``'s kind of drive, in order."""
    kind = drive_kind(seq)
    return [n for n in estimators if estimator_kind(n) == kind]


def _valid_names() -> str:
    return ", ".join(known_names()) + ", or MODULE:CLASS / MODULE:FUNCTION"


def filter_estimator(cls: type, name: str | None = None) -> Estimator:
    """The whole-drive estimator of filter class ``cls``: a new ``cls()`` per drive through
    :func:`vislam.ekf.driver.run_filter`, its Estimate named ``name`` (default: the class's
    ``name``, else ``module:Class``)."""
    from vislam.ekf.driver import run_filter

    label = name or getattr(cls, "name", None) or display_name(cls)

    def estimate(seq, settings: EstimatorSettings) -> Estimate:
        return run_filter(cls(), seq, settings.filter, settings.progress, name=label)

    estimate.__module__, estimate.__qualname__ = cls.__module__, cls.__qualname__
    estimate.__name__, estimate.__doc__ = cls.__name__, cls.__doc__
    estimate.filter_class = cls
    return estimate


@functools.lru_cache(maxsize=None)
def _load(spec: str, user: bool) -> Callable:
    """``module:attribute`` (``module`` dotted or a path to a .py file) -> the estimator: the
    callable, or a filter class wrapped by :func:`filter_estimator`."""
    module_name, _, attr = spec.rpartition(":")
    if not module_name or not attr:
        raise UserEstimatorError(f"estimator {spec!r}: expected MODULE:CLASS or MODULE:FUNCTION")
    try:
        if module_name.endswith(".py"):
            path = Path(module_name)
            if not path.is_file():
                raise UserEstimatorError(f"estimator {spec!r}: no file {module_name}")
            mod_spec = importlib.util.spec_from_file_location(f"_vislam_user_{path.stem}", path)
            module = importlib.util.module_from_spec(mod_spec)
            mod_spec.loader.exec_module(module)
        else:
            module = _import_module(module_name)
    except UserEstimatorError:
        raise
    except ModuleNotFoundError as exc:
        where = "" if not user else " (on sys.path or in the current folder)"
        raise UserEstimatorError(f"estimator {spec!r}: no module {exc.name!r}{where}") from None
    except Exception as exc:  # the user's module fails on import
        raise UserEstimatorError(
            f"estimator {spec!r}: importing {module_name} raised {type(exc).__name__}: {exc}"
        ) from None
    fn = module
    for part in attr.split("."):
        fn = getattr(fn, part, None)
        if fn is None:
            raise UserEstimatorError(f"estimator {spec!r}: {module_name} has no {attr!r}")
    if is_filter_class(fn):
        return filter_estimator(fn)
    if not callable(fn) or isinstance(fn, type):
        what = f"class {fn.__name__}" if isinstance(fn, type) else f"a {type(fn).__name__}"
        raise UserEstimatorError(f"estimator {spec!r}: {attr!r} is {what}, neither a Filter class "
                                 "(vislam.filters.Filter) nor a callable (seq, settings) -> Estimate")
    return fn


def _import_module(name: str):
    """Import ``name``; like ``python -m``, the current folder is searched too (for this import
    only: sys.path is left as it was)."""
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        cwd = os.getcwd()
        if exc.name != name.split(".")[0] or cwd in sys.path:
            raise
    sys.path.insert(0, cwd)
    try:
        return importlib.import_module(name)
    finally:
        with contextlib.suppress(ValueError):
            sys.path.remove(cwd)


def resolve(name) -> Callable:
    """The protocol callable of estimator ``name`` (a name, ``MODULE:CLASS``, ``MODULE:FUNCTION``,
    a filter class or a callable); an unknown name is an InputError listing the valid ones."""
    if is_filter_class(name):
        return filter_estimator(name)
    if callable(name):
        return name
    if is_user_spec(name):
        return _load(name, True)
    spec = entry_points().get(name) or INERTIAL_ENTRY_POINTS.get(name)
    if spec is None:
        raise InputError(f"unknown estimator {name!r}; valid names: {_valid_names()}")
    return _load(spec, name not in BUILTIN_ENTRY_POINTS and name not in INERTIAL_ENTRY_POINTS)


def get_estimator(name) -> Callable:
    """The callable running estimator ``name`` as the benchmark calls it:
    ``run(seq, config, progress=None, initial=None, smoother=None) -> Estimate``. Its Estimate
    is checked against the contract (:func:`check_contract`), so no NaN and no wrong shape
    reaches a result. A user's estimator that raises or breaks the contract gets a
    :class:`UserEstimatorError`; vislam's own raise as they always did."""
    fn = resolve(name)
    label = display_name(name)
    user = not (isinstance(name, str) and (name in BUILTIN_ENTRY_POINTS
                                           or name in INERTIAL_ENTRY_POINTS))

    def checked(seq, config, progress=None, initial=None, smoother=None):
        settings = EstimatorSettings(
            filter=config if config is not None else FilterConfig(),
            smoother=smoother if smoother is not None else SmootherSettings(),
            initial=initial, progress=progress)
        if not user:
            est = fn(seq, settings)
            check_contract(est, seq, label)
            return est
        try:
            est = fn(seq, settings)
        except (KeyboardInterrupt, SystemExit):
            raise
        except Exception as exc:
            raise UserEstimatorError(
                f"estimator {label!r} raised {type(exc).__name__}: {' '.join(str(exc).split())}"
            ) from exc
        try:
            check_contract(est, seq, label)
        except (EstimationError, InputError) as exc:
            raise UserEstimatorError(str(exc)) from None
        return est

    return checked


def check_contract(est, seq, name: str) -> None:
    """EstimationError naming estimator ``name`` and the fault when ``est`` is not an Estimate
    of ``seq`` as the protocol defines it (type, lengths, timestamps, shapes, finite poses that
    are rigid transforms, symmetric positive semi-definite covariances)."""
    from vislam.ekf.estimate import Estimate

    def fail(what: str):
        raise EstimationError(f"estimator {name!r} returned {what}")

    if not isinstance(est, Estimate):
        fail(f"a {type(est).__name__}, not a vislam.ekf.estimate.Estimate")
    T = seq.n_frames
    shapes = {"timestamps": (T,), "poses": (T, 4, 4), "pose_cov": (T, 6, 6),
              "step_time_s": (T,), "n_updates": (T,), "n_rejected": (T,), "n_initialised": (T,)}
    for key, shape in shapes.items():
        got = np.shape(getattr(est, key))
        if got != shape:
            fail(f"{key} of shape {got}; the sequence has {T} frames, expected {shape}")
    M = np.shape(est.landmarks)[0] if np.ndim(est.landmarks) == 2 else -1
    if np.shape(est.landmarks) != (M, 3) or np.shape(est.landmark_cov) != (M, 3, 3):
        fail(f"landmarks of shape {np.shape(est.landmarks)} and landmark_cov of shape "
             f"{np.shape(est.landmark_cov)}; expected (M, 3) and (M, 3, 3)")
    if not np.array_equal(np.asarray(est.timestamps, dtype=float), seq.timestamps):
        k = int(np.flatnonzero(np.asarray(est.timestamps, dtype=float) != seq.timestamps)[0])
        fail(f"timestamp {est.timestamps[k]!r} at frame {k}; the sequence's is {seq.timestamps[k]!r}")
    try:
        est.check_finite()
    except EstimationError as exc:
        if est.estimator == name:
            raise
        fail(f"an Estimate with {str(exc).removeprefix(f'{est.estimator}: ')}")
    poses = np.asarray(est.poses, dtype=float)
    R = poses[:, :3, :3]
    err = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
    bottom = np.abs(poses[:, 3, :] - [0, 0, 0, 1]).max(axis=1)
    bad = np.flatnonzero((err > 1e-6) | (np.linalg.det(R) < 0) | (bottom > 0))
    if bad.size:
        fail(f"a pose at frame {int(bad[0])} that is not a rigid transform (rotation error "
             f"{err[bad[0]]:.1e})")
    cov = np.asarray(est.pose_cov, dtype=float)
    if np.isfinite(cov).all():
        _check_covariances(cov, "pose covariance at frame", fail)
    lcov = np.asarray(est.landmark_cov, dtype=float)[est.has_landmark]
    if lcov.size and np.isfinite(lcov).all():
        rows = np.flatnonzero(est.has_landmark)
        _check_covariances(lcov, "landmark covariance of track", fail, rows)


# COVARIANCE_RTOL (vislam.ekf.runner), the relative tolerance of the covariance checks (of the
# largest entry): a filter's own rounding (the invariant EKF's landmark conversions reach 7e-8
# on hostile drives) passes, a wrong entry or a negative variance does not. The EKFs drop a
# landmark whose covariance fails it (vislam.ekf.runner.covariance_usable).


def _check_covariances(cov: np.ndarray, what: str, fail, index=None) -> None:
    asym, low = covariance_defects(cov)
    bad = np.flatnonzero(asym > COVARIANCE_RTOL)
    if bad.size:
        k = int(bad[0] if index is None else index[bad[0]])
        fail(f"a {what} {k} that is not symmetric (relative asymmetry {asym[bad[0]]:.1e})")
    bad = np.flatnonzero(low < -COVARIANCE_RTOL)
    if bad.size:
        k = int(bad[0] if index is None else index[bad[0]])
        fail(f"a {what} {k} that is not positive semi-definite (smallest eigenvalue "
             f"{low[bad[0]]:.1e} of its largest entry)")


def parse_estimator_list(text: str | None, default: tuple[str, ...]) -> list[str]:
    """Comma-separated names (``all`` for every installed estimator) -> validated list: vislam's
    own in table order, then installed plug-ins and ``MODULE:FUNCTION`` estimators in the order
    given. A user's module is imported here, so a missing one is reported before any work."""
    if text is None or not text.strip():  # absent or empty: the default list
        return list(default)
    names = list(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    if not names:
        raise InputError(f"--estimators {text!r} names no estimator; valid names: "
                         f"{_valid_names()} (or 'all')")
    known = known_names()
    if names == ["all"]:
        return known
    unknown = [n for n in names if n not in known and not is_user_spec(n)]
    if unknown:
        raise InputError(f"unknown estimator(s) {', '.join(map(repr, unknown))}; "
                         f"valid names: {_valid_names()}")
    for n in names:
        if is_user_spec(n):
            resolve(n)
    return [n for n in known if n in names] + [n for n in names if n not in known]


def estimators_from_flag(text: str | None, default: tuple[str, ...]) -> list[str]:
    """``--estimators``: as :func:`parse_estimator_list`, but an empty value is an error (on
    the command line it is a mistake; the API's empty string means the default)."""
    if text is not None and not text.strip():
        raise InputError("--estimators: empty; name estimators, or leave the flag out for the "
                         "default list")
    return parse_estimator_list(text, default)


def uses_initial(name: str, smoother: SmootherSettings | None = None) -> bool:
    """Whether estimator ``name`` starts from another estimator's result (the batch smoother,
    when it is initialised from the EKF)."""
    return name == "smoother" and (smoother is None or smoother.init == "ekf")
