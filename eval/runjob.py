"""Former home of the estimator runner, the settings flags and ``vislam run``'s outputs, kept
only for the callers outside this change; remove it once they import from the new homes:
:func:`eval.study.run_estimator` and :class:`eval.study.JobResult` (the library), the flags in
:mod:`eval.commands.options` (the command line).

Importers left: eval/commands/calibrate.py, eval/commands/inspect.py (the flags),
vislam/__init__.py and benchmarks/nees_floor.py (run_estimator), notebooks/analysis.ipynb
(JobResult).
"""

from vislam.eval.commands.options import (  # noqa: F401
    add_filter_arguments,
    filter_config_from_args,
    model_from_args,
    smoother_settings_from_args,
)
from vislam.eval.study import JobResult, run_estimator  # noqa: F401
