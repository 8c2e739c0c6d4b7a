"""pytest helpers: your own estimator's consistency and accuracy regression tests, with vislam's
machinery (the implementation and the full description: :mod:`vislam.eval.testing`).

An estimator is vislam's name (``"ekf-invariant"``), a ``"MODULE:FUNCTION"`` string or a
module-level callable ``(seq, settings) -> Estimate`` (:mod:`vislam.eval.registry`)::

    from vislam.testing import NEAR_FIELD, assert_agrees_with_smoother, assert_nees_consistent, monte_carlo

    study = monte_carlo(["my_pkg.filter:estimate"], runs=8, frames=80, sim=NEAR_FIELD)
    assert_nees_consistent(study)       # pose and landmark ANEES inside the 95 % chi-square bounds
    assert_agrees_with_smoother(study)  # the smoother inside its 3-sigma as often as chi2 predicts

- :func:`monte_carlo` ``(estimators, runs=10, frames=None, seed=None, config=None, sim=None,
  jobs=1, reference="smoother", smoother=None) -> MonteCarloStudy``: the estimators and the
  smoother on ``runs`` noise draws of one simulated drive: the default drive (seed 0, 120
  frames) with ``sim``'s changes (a dict of SimConfig fields, e.g. :data:`NEAR_FIELD`), or
  ``sim`` a SimConfig as it is;
- :func:`assert_nees_consistent` ``(study_or_estimator, name=None, *, what=("pose", "landmark"),
  probability=0.95, max_failed_runs=0, **monte_carlo_kwargs)``;
- :func:`assert_agrees_with_smoother` ``(study_or_estimator, name=None, *, sigma=3.0,
  allowance=0.01, max_failed_runs=0, **monte_carlo_kwargs)``;
- :func:`run_drive` ``(estimators, drive, *, config=None, model="as-given", smoother=None,
  jobs=1, align="se3") -> DriveStudy``: the estimators on one drive (a .npz path with its
  ground truth beside it, a SimConfig or a SimResult), scored against its ground truth;
- :func:`assert_accuracy` ``(study_or_estimator, drive=None, *, name=None, ate_max=None,
  ate_aligned_max=None, t_rel_max=None, **run_drive_kwargs)``;
- :func:`assert_folder_consistent` ``(folder, name=None, *, what=("pose", "landmark"),
  max_failed_runs=0)``: a saved ``vislam nees`` folder (read with ``vislam.load_results``) held
  to the same bounds, so a test can pin a study run once; :func:`folder_checks` its checks.

Every check is a :class:`Check` (``study.consistency(name, what)``, ``study.agreement(name)``,
``drive_study.accuracy(name, ...)``), whose ``message`` states the figure, the bounds and the
verdict, e.g. ``my_pkg.filter:estimate: pose ANEES 29.84 over 8 runs x 79 steps, 95 % bounds
[3.84, 8.63]: above (overconfident)``; the assertions raise ``AssertionError`` with it.
"""

from vislam.eval.testing import (
    NEAR_FIELD,
    THREE_SIGMA,
    Check,
    DriveStudy,
    MonteCarloStudy,
    assert_accuracy,
    assert_agrees_with_smoother,
    assert_nees_consistent,
    monte_carlo,
    run_drive,
)
from vislam.eval.folder_checks import assert_folder_consistent, folder_checks

__all__ = [
    "NEAR_FIELD",
    "THREE_SIGMA",
    "Check",
    "DriveStudy",
    "MonteCarloStudy",
    "assert_accuracy",
    "assert_agrees_with_smoother",
    "assert_folder_consistent",
    "assert_nees_consistent",
    "folder_checks",
    "monte_carlo",
    "run_drive",
]
