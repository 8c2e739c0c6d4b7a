"""The study engine: one estimator on one drive (:func:`run_estimator`), and every estimator on
every drive (:func:`run_jobs`).

Jobs are (sequence, estimator) pairs run in worker processes (``jobs``): a local process pool,
or a Dask cluster (``executor="dask"``, :mod:`eval.executors`), with the same results to the
last digit. The batch smoother starts from an EKF's estimate
(:data:`eval.registry.SMOOTHER_INITIAL_FROM`): its job is submitted when that EKF's job on the
same sequence has finished, so the EKF never runs twice. A user's estimator that raises or
breaks the Estimate contract stops the run (bad input); :func:`run_groups` runs each user's
estimator apart, so that one stops only its own jobs.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import EstimationError
from vislam.ekf.estimate import Estimate
from vislam.ekf.sequence import Sequence
from vislam.eval import registry
from vislam.eval.executors import JobLost, open_executor
from vislam.eval.progress import Progress
from vislam.eval.registry import (
    BUILTIN_ENTRY_POINTS,
    SMOOTHER_INITIAL_FROM,
    UserEstimatorError,
    display_name,
    resolve,
    uses_initial,
)
from vislam.eval.signals import deferred
from vislam.graph.settings import SmootherSettings

log = logging.getLogger(__name__)


@dataclass
class JobResult:
    """One estimator's estimate on one sequence, with its wall time."""

    sequence: str
    estimator: str
    estimate: Estimate
    wall_s: float


def run_estimator(
    seq, name, config: FilterConfig, progress=None, initial: Estimate | None = None,
    smoother: SmootherSettings | None = None,
) -> JobResult:
    """Run estimator ``name`` (a name, ``MODULE:FUNCTION`` or a callable: eval.registry) on
    ``seq`` and time it (wall clock, seconds); ``smoother`` the smoothers' settings (defaults
    when None; the EKFs ignore them). The Estimate is checked against the protocol's contract."""
    fn = registry.get_estimator(name)  # looked up at each call: tests replace it
    t0 = time.perf_counter()
    est = fn(seq, config, progress=progress, initial=initial, smoother=smoother)
    return JobResult(seq.name, display_name(name), est, time.perf_counter() - t0)


@dataclass
class JobFailure:
    """An estimator that failed on a sequence (EstimationError, its module is missing, or it
    crashed: logged with its traceback, recorded in results.json as ``error``)."""

    sequence: str
    estimator: str
    error: str
    wall_s: float = float("nan")
    #: a user's estimator failed or broke the Estimate contract (registry.UserEstimatorError):
    #: bad input, which stops the whole run (exit code 2), not one failed row
    user_fault: bool = False


def _job(seq: Sequence, key: str, name, config: FilterConfig, initial: Estimate | None,
         smoother: SmootherSettings | None = None):
    """Worker: one estimator (a name, ``MODULE:FUNCTION`` or a module-level callable) on one
    sequence (module-level so worker processes can pickle it)."""
    t0 = time.perf_counter()
    try:
        result = run_estimator(seq, name, config, progress=None, initial=initial, smoother=smoother)
    except UserEstimatorError as exc:
        return JobFailure(key, display_name(name), str(exc), time.perf_counter() - t0,
                          user_fault=True)
    except (EstimationError, ImportError) as exc:
        return JobFailure(key, display_name(name), f"{type(exc).__name__}: {exc}",
                          time.perf_counter() - t0)
    except Exception as exc:  # a crash of one estimator must not lose the whole benchmark
        log.debug("%s on %s crashed", name, key, exc_info=True)  # the traceback with -v
        return JobFailure(key, display_name(name), f"{type(exc).__name__}: {exc}",
                          time.perf_counter() - t0)
    result.sequence = key
    result.estimate = _c_ordered(result.estimate)
    return result


def _c_ordered(est: Estimate) -> Estimate:
    """``est`` with every array C-ordered, as it comes back from a worker process (pickling
    copies a strided array into C order): the figures computed from it (NEES, ATE) are then the
    same to the last digit whether the job ran in this process (``--jobs 1``), in the local pool
    or on Dask (the smoother's poses are strided, and a strided reduction can round
    differently)."""
    if dataclasses.is_dataclass(est):
        for f in dataclasses.fields(est):
            value = getattr(est, f.name)
            if isinstance(value, np.ndarray) and not value.flags.c_contiguous:
                setattr(est, f.name, np.ascontiguousarray(value))
    return est


def progress_words(labels: dict, pending: set, running: set | None = None) -> str:
    """The progress bar's words: the jobs running now (not the ones that just finished);
    ``running`` the futures the executor knows to run (default: those whose ``running()``)."""
    running = [labels[f] for f in pending if (f in running if running is not None else f.running())]
    if not running:
        return "waiting" if pending else "finishing"
    return "running " + ", ".join(sorted(running)[:2]) + (f" and {len(running) - 2} more" if len(running) > 2 else "")


def _initialiser(estimators: list[str]) -> str | None:
    return next((n for n in SMOOTHER_INITIAL_FROM if n in estimators), None)


def run_jobs(
    sequences: dict[str, Sequence],
    estimators: list[str],
    config: "FilterConfig | dict[str, FilterConfig]",
    jobs: int = 1,
    show_progress: bool = True,
    on_result: Callable[[JobResult | JobFailure], None] | None = None,
    smoother: SmootherSettings | None = None,
    executor: str = "local",
    scheduler: str | None = None,
) -> dict[tuple[str, str], JobResult | JobFailure]:
    """Run every estimator on every sequence of its kind (velocity or raw-IMU drives:
    :func:`eval.registry.applicable`); returns {(sequence key, estimator): result}.

    The smoother waits for its initialiser EKF on the same sequence (if that EKF is among
    ``estimators`` and ``smoother.init`` is ``"ekf"``) and starts from its estimate.
    ``config`` is one FilterConfig for every sequence, or one per sequence key. ``executor``
    runs the jobs (:mod:`eval.executors`): "local", ``jobs`` worker processes (none with
    ``jobs`` 1: in this process), or "dask", an embedded cluster of ``jobs`` workers or the
    cluster at ``scheduler``. The results do not depend on either: every job is the same
    function of its drive and settings.
    """
    configs = config if isinstance(config, dict) else {k: config for k in sequences}
    init_name = _initialiser(estimators)
    waiting = {n for n in estimators if uses_initial(n, smoother) and init_name is not None}
    # The initialiser first, so the smoother can start as early as possible; the smoother last.
    order = sorted(
        (n for n in estimators if n not in waiting),
        key=lambda n: (n != init_name, estimators.index(n)),
    )
    # each drive runs the estimators of its kind (velocity or raw IMU: registry.applicable)
    runs = {k: set(registry.applicable(estimators, seq)) for k, seq in sequences.items()}
    results: dict[tuple[str, str], JobResult | JobFailure] = {}
    total = sum(len(r) for r in runs.values())
    bar = Progress("bench", total=total, enabled=show_progress)

    def record(res) -> list[tuple[str, str, Estimate | None]]:
        if isinstance(res, JobFailure) and res.user_fault:
            raise UserEstimatorError(res.error)  # the user's code: stop, write nothing
        results[(res.sequence, res.estimator)] = res
        bar.update(1)
        if on_result is not None:
            on_result(res)
        follow = []
        if res.estimator == init_name:
            initial = res.estimate if isinstance(res, JobResult) else None
            if initial is not None and not np.all(np.isfinite(initial.poses)):
                initial = None  # a diverged EKF: let the smoother initialise itself
            follow = [(res.sequence, n, initial) for n in estimators
                      if n in waiting and n in runs[res.sequence]]
        return follow

    try:
        if jobs <= 1 and executor == "local":
            queue = [(k, n, None) for k in sequences for n in order if n in runs[k]]
            while queue:
                key, name, initial = queue.pop(0)
                bar.set_description(f"running {display_name(name)} on {key}")
                queue.extend(record(_job(sequences[key], key, name, configs[key], initial, smoother)))
            return results
        # Signals are deferred while the workers are managed (an exception inside the pool's or
        # the client's locks would break them) and acted on between waits, within a tenth of a
        # second. Which job runs when is decided here, the same for every executor: every job
        # submitted at once (local) or a few per worker (dask), the smoother when its EKF is done.
        with deferred() as signals:
            pool = open_executor(executor, jobs, scheduler)
            try:
                labels: dict = {}  # future -> "estimator on sequence", while it is pending
                jobs_of: dict = {}  # future -> (sequence key, estimator)
                queue = collections.deque((k, n, None) for k in sequences for n in order
                                          if n in runs[k])
                pending: set = set()

                def submit() -> None:
                    while queue and (pool.capacity() is None or len(pending) < pool.capacity()):
                        key, name, initial = queue.popleft()
                        fut = pool.submit(_job, sequences[key], key, name, configs[key], initial,
                                          smoother)
                        labels[fut] = f"{display_name(name)} on {key}"
                        jobs_of[fut] = (key, name)
                        pending.add(fut)

                submit()
                while pending:
                    signals.check()
                    done, _ = pool.wait(pending, 0.1)
                    for fut in done:
                        pending.discard(fut)
                        key, name = jobs_of.pop(fut)
                        del labels[fut]  # no reference left: a Dask result is freed
                        try:
                            res = pool.outcome(fut, signals)
                        except JobLost as exc:
                            res = JobFailure(key, display_name(name), str(exc))
                        # a smoother waiting for this EKF goes first: its drive and the EKF's
                        # estimate are freed the sooner
                        queue.extendleft(reversed(record(res)))
                    submit()
                    bar.set_description(progress_words(labels, pending, pool.running(pending)))
                signals.check()
            except BaseException:
                pool.abort()  # Ctrl-C, SIGTERM, an error: end the workers now
                raise
            pool.close()
        return results
    finally:
        bar.close()


def estimator_groups(specs: Iterable) -> list[list]:
    """Run groups: vislam's own estimators together (the smoother starts from the EKF), each
    user's estimator apart (one that raises stops only its own runs)."""
    own, user, seen = [], [], set()
    for spec in specs:
        key = display_name(spec)
        if key in seen:
            continue
        seen.add(key)
        if isinstance(spec, str) and spec in BUILTIN_ENTRY_POINTS:
            own.append(spec)
        else:
            user.append([spec])
    return ([own] if own else []) + user


def run_groups(sequences: dict[str, Sequence], specs, config, jobs: int = 1,
               smoother: SmootherSettings | None = None,
               on_result: Callable[[JobResult | JobFailure], None] | None = None,
               on_user_error: Callable[[str, str], None] | None = None, *,
               show_progress: bool = False, executor: str = "local",
               scheduler: str | None = None) -> None:
    """:func:`run_jobs` of the estimators ``specs``, the results to ``on_result`` only (none is
    kept). With ``on_user_error``, group by group (:func:`estimator_groups`), and
    ``on_user_error(display name, message)`` when a user's estimator stopped its runs; without,
    one :func:`run_jobs` of them all, which raises it."""
    groups = estimator_groups(specs) if on_user_error is not None else [list(specs)]
    for group in groups:
        try:
            outcomes = run_jobs(sequences, group, config, jobs=jobs, show_progress=show_progress,
                                on_result=on_result, smoother=smoother, executor=executor,
                                scheduler=scheduler)
        except UserEstimatorError as exc:
            if len(group) != 1 or on_user_error is None:
                raise
            on_user_error(display_name(group[0]), str(exc))
            continue
        outcomes.clear()


def labelled_estimators(estimators) -> dict[str, Any]:
    """{label: estimator} from one estimator, a list of them or a dict label -> estimator; every
    estimator resolved (an unknown name or a module that cannot be imported is an error now),
    each shown under :func:`eval.registry.display_name` unless the dict labels it."""
    if isinstance(estimators, Mapping):
        items = [(str(k), v) for k, v in estimators.items()]
    else:
        if isinstance(estimators, str) or callable(estimators):
            estimators = [estimators]
        items = [(display_name(e), e) for e in estimators]
    out: dict[str, Any] = {}
    for label, spec in items:
        if not (isinstance(spec, str) or callable(spec)):
            raise TypeError(f"estimator {label!r}: expected a name, 'MODULE:FUNCTION' or a "
                            f"callable (seq, settings) -> Estimate, got {type(spec).__name__}")
        if label in out and display_name(out[label]) != display_name(spec):
            raise ValueError(f"two estimators are shown as {label!r}: pass a dict "
                             "{label: estimator} to tell them apart")
        resolve(spec)  # an unknown name or a user's module that cannot be imported: say so now
        out[label] = spec
    if not out:
        raise ValueError("no estimator given")
    return out
