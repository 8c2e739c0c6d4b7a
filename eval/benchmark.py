"""Former home of the benchmark and the Monte Carlo study, cut at its seams; kept only for the
callers outside this change; remove it once they import from the new homes:

- the library: :mod:`eval.drives` (the drives and their models), :mod:`eval.study` (jobs and
  their scheduling), :mod:`eval.bench_scores` (results.json's figures), :mod:`eval.montecarlo`
  (the one Monte Carlo engine, nees.json);
- the application: :mod:`eval.bench_output` (`vislam bench`'s folder), :mod:`eval.readings`
  (summary.md's text), :mod:`eval.drive_figures` (a drive's figures), :mod:`eval.report`.

Importers left: eval/compare.py (SCHEMA), vislam/__init__.py (monte_carlo_nees),
notebooks/analysis.ipynb and benchmarks/*.py (the rest).
"""

from vislam.eval.bench_output import run_benchmark  # noqa: F401
from vislam.eval.bench_scores import SCHEMA, reference_smoother  # noqa: F401
from vislam.eval.drives import (  # noqa: F401
    BenchSequence,
    KnownTruth,
    collect_sequences,
    identify_models,
    load_bench_sequence,
    simulated_sequence,
)
from vislam.eval.montecarlo import (  # noqa: F401
    DEFAULT_NEES_FRAMES,
    monte_carlo_drives,
    monte_carlo_nees,
    nees_sim_config,
)
from vislam.eval.study import run_jobs  # noqa: F401
