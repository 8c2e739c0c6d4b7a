"""vislam: visual-inertial SLAM with EKFs, cross-validated against a GTSAM factor-graph smoother.

The package installs as ``vislam.ekf`` (the filters, numpy and scipy only), ``vislam.graph`` (the
GTSAM smoothers) and ``vislam.eval`` (data, simulation, metrics, consistency, benchmark, command
line). What a user needs is re-exported here, imported on first use (``import vislam`` stays
cheap and never imports GTSAM):

- data: :func:`load_sequence`, :func:`simulate`, :class:`SimConfig`, :class:`Sequence`,
  :func:`find_ground_truth`;
- estimation: :func:`run_estimator`, :class:`FilterConfig`, :class:`Estimate`;
- scoring: :func:`trajectory_metrics`, :func:`pose_nees`, :func:`landmark_nees`,
  :func:`match_landmarks`, :func:`position_deviation`, :func:`reference_honesty`,
  :func:`monte_carlo_nees`, :func:`chi2_bounds`;
- results folders: :func:`load_results` (``vislam bench`` and ``vislam nees`` folders as
  :class:`Results`: :class:`BenchResults` with :class:`DriveResult` and
  :class:`EstimatorResult` per drive and estimator, :class:`NeesResults` with
  :class:`NeesEstimatorResult`), :class:`DriveData`, :func:`read_tum` (a TUM trajectory), and
  :data:`COLOURS` (each estimator's colour in vislam's figures);
- a filter author's toolkit (the per-frame protocol, its driver, SE(3), the stereo camera):
  :mod:`vislam.filters`;
- pytest helpers: :mod:`vislam.testing`.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: public name -> module that defines it
_EXPORTS = {
    "Sequence": "vislam.ekf.sequence",
    "Estimate": "vislam.ekf.estimate",
    "FilterConfig": "vislam.ekf.config",
    "InputError": "vislam.ekf.errors",
    "EstimationError": "vislam.ekf.errors",
    "load_sequence": "vislam.eval.loader",
    "find_ground_truth": "vislam.eval.groundtruth",
    "simulate": "vislam.eval.simulate",
    "SimConfig": "vislam.eval.simulate",
    "run_estimator": "vislam.eval.study",
    "trajectory_metrics": "vislam.eval.metrics",
    "pose_nees": "vislam.eval.consistency",
    "chi2_bounds": "vislam.eval.consistency",
    "landmark_nees": "vislam.eval.consistency",
    "match_landmarks": "vislam.eval.consistency",
    "position_deviation": "vislam.eval.consistency",
    "reference_honesty": "vislam.eval.consistency",
    "monte_carlo_nees": "vislam.eval.montecarlo",
    "load_results": "vislam.eval.results",
    "Results": "vislam.eval.results",
    "BenchResults": "vislam.eval.results",
    "DriveResult": "vislam.eval.results",
    "EstimatorResult": "vislam.eval.results",
    "NeesResults": "vislam.eval.results",
    "NeesEstimatorResult": "vislam.eval.results",
    "DriveData": "vislam.eval.drive_data",
    "read_tum": "vislam.eval.export",
    "COLOURS": "vislam.eval.plots",
}

#: public submodules, imported on first use
_MODULES = ("filters", "testing")

__all__ = sorted(_EXPORTS) + list(_MODULES)


def __getattr__(name: str):
    if name in _MODULES:
        return importlib.import_module(f"vislam.{name}")
    try:
        module = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'vislam' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return __all__
