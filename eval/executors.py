"""Where the jobs of ``vislam bench`` and ``vislam nees`` run (``--executor``, ``--scheduler``).

:func:`eval.study.run_jobs` decides what to run and in which order (the smoother after its
initialiser EKF); an executor only runs the jobs it is given:

- ``local`` (the default): a process pool of ``--jobs`` workers on this machine
  (``concurrent.futures.ProcessPoolExecutor``); a worker that dies stops the benchmark.
- ``dask``: a Dask cluster (the optional extra ``vislam[dask]``). Without ``--scheduler`` an
  embedded ``distributed.LocalCluster`` is started (``--jobs`` worker processes of one thread
  each, started from the current folder so that a user's ``MODULE:FUNCTION`` module is found
  there too) and closed on exit, Ctrl-C, SIGTERM and errors. With ``--scheduler ADDRESS`` the
  jobs go to a running cluster, which is left running: only our client is closed. A job
  that kills its worker (the scheduler retries it on other workers first) is recorded as
  failed and the cluster goes on.

An executor's interface, as run_jobs uses it: ``submit(fn, *args)`` -> a future,
``wait(pending, timeout)`` -> (done, not done), ``outcome(future)`` (its result; raises
:class:`JobLost` for a job the executor lost but can go on without), ``running(pending)``
(the futures running now, for the progress bar), ``capacity()`` (how many jobs to keep
submitted; None: all at once), ``close()`` (after the last job) and ``abort()`` (on Ctrl-C,
SIGTERM or an error: end the workers now). Both are driven under
:func:`eval.signals.deferred`: a signal is acted on between waits, never inside the pool's or
the client's bookkeeping.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import logging
import os
import signal
import time

from vislam.ekf.errors import EstimationError, InputError

log = logging.getLogger(__name__)

#: The values of ``--executor``.
EXECUTORS = ("local", "dask")
DEFAULT_EXECUTOR = "local"
#: The one-line error when ``--executor dask`` is asked for without the extra installed.
DASK_MISSING = "--executor dask needs the dask extra: pip install 'vislam[dask]'"
#: Seconds to wait for a ``--scheduler`` to answer before giving up (one line, exit code 2).
CONNECT_TIMEOUT_S = 5.0
#: Jobs kept submitted per worker thread of a Dask cluster: enough to keep every worker busy,
#: few enough that the scheduler never holds every drive of a 1000-run study at once.
DASK_JOBS_PER_THREAD = 2
#: Dask settings of the embedded cluster. Its nanny sets MALLOC_TRIM_THRESHOLD_=65536 in the
#: workers' environment by default: glibc then stops adapting its mmap threshold and every
#: array over 128 kB is mapped and unmapped afresh, which made the EKFs about 50 % slower and
#: the smoother 10-20 % (measured on 200-frame drives). BLAS stays at one thread per worker.
EMBEDDED_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}


class JobLost(Exception):
    """A job the executor lost (its worker died, the scheduler gave up on it) while the executor
    itself can go on: recorded as that job's failure."""


def check_executor(kind: str | None, scheduler: str | None) -> str:
    """The executor that ``--executor`` and ``--scheduler`` ask for ("local" or "dask");
    ``--scheduler`` alone means dask. InputError for a bad combination or a missing extra."""
    if kind is None:
        kind = "dask" if scheduler else DEFAULT_EXECUTOR
    if kind not in EXECUTORS:
        raise InputError(f"--executor must be one of {', '.join(EXECUTORS)}, got {kind!r}")
    if scheduler is not None and kind != "dask":
        raise InputError(f"--scheduler {scheduler} needs --executor dask (the local executor "
                         "has no scheduler)")
    if scheduler is not None and not scheduler.strip():
        raise InputError("--scheduler: empty; give the Dask scheduler's address, e.g. "
                         "tcp://host:8786, or leave it out to start a cluster on this machine")
    if kind == "dask":
        _distributed()
    return kind


def add_executor_arguments(parser) -> None:
    """``--executor`` and ``--scheduler``, for ``vislam bench`` and ``vislam nees``."""
    parser.add_argument("--executor", choices=EXECUTORS, default=None,
                        help="where the jobs run: local, worker processes on this machine (the "
                             "default); dask, a Dask cluster: one of --jobs workers started here, "
                             "or the one at --scheduler (needs pip install 'vislam[dask]'). The "
                             "results are the same either way")
    parser.add_argument("--scheduler", metavar="ADDRESS", default=None,
                        help="the address of a running Dask scheduler, e.g. tcp://host:8786 "
                             "(implies --executor dask; --jobs is then the cluster's own; the "
                             "cluster is left running)")


def executor_settings(kind: str, scheduler: str | None, jobs: int) -> dict:
    """How the jobs ran, for settings.json and nees.json: ``kind`` ("local" or "dask"),
    ``scheduler`` (a Dask scheduler's address; null for an embedded cluster or the local
    pool) and ``workers`` (--jobs; null on a cluster given by --scheduler, whose size is its
    own)."""
    return {"kind": kind, "scheduler": scheduler if kind == "dask" else None,
            "workers": None if scheduler else jobs}


def _distributed():
    """The ``distributed`` module, or the one-line InputError saying how to install it."""
    try:
        import distributed
    except ImportError:
        raise InputError(DASK_MISSING) from None
    return distributed


def open_executor(kind: str, jobs: int, scheduler: str | None = None):
    """The executor ``kind`` with ``jobs`` workers (a ``--scheduler`` cluster has its own);
    call it under :func:`eval.signals.deferred`."""
    if kind == "local":
        return LocalExecutor(jobs)
    if kind == "dask":
        return DaskExecutor(jobs, scheduler)
    raise InputError(f"unknown executor {kind!r}; valid: {', '.join(EXECUTORS)}")


# --- local: a process pool -------------------------------------------------------------------


def _worker_signals() -> None:
    """In each worker: Ctrl-C (sent by the terminal to the whole process group) is the main
    process's to handle, and SIGTERM (how the main process ends a worker) ends it at once."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _stop_pool(pool: cf.ProcessPoolExecutor) -> None:
    """Terminate the pool's workers and return without waiting for their jobs to finish."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for p in processes:
        with contextlib.suppress(Exception):
            p.terminate()
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        with contextlib.suppress(Exception):
            p.join(timeout=1.0)


class LocalExecutor:
    """``--executor local``: worker processes on this machine, every job submitted at once."""

    kind = "local"

    def __init__(self, jobs: int) -> None:
        self.pool = cf.ProcessPoolExecutor(max_workers=jobs, initializer=_worker_signals)

    def capacity(self) -> int | None:
        return None

    def submit(self, fn, *args) -> cf.Future:
        return self.pool.submit(fn, *args)

    def wait(self, pending: set, timeout: float) -> tuple[set, set]:
        done, not_done = cf.wait(pending, timeout=timeout, return_when=cf.FIRST_COMPLETED)
        return set(done), set(not_done)

    def outcome(self, fut: cf.Future, signals):
        """A finished job's result; a worker that died (killed, out of memory) is an error,
        unless a signal to the whole process group (Ctrl-C, ``timeout``, a job scheduler)
        killed it: that signal, noted by ``signals`` (eval.signals.Deferred) within a moment,
        takes precedence."""
        try:
            return fut.result()
        except cf.process.BrokenProcessPool as exc:
            deadline = time.monotonic() + 0.5
            while signals.signum is None and time.monotonic() < deadline:
                time.sleep(0.02)
            signals.check()
            raise EstimationError(f"a worker process died ({exc}); the benchmark cannot go on") from None

    def running(self, pending: set) -> set:
        return {f for f in pending if f.running()}

    def close(self) -> None:
        self.pool.shutdown(wait=True)

    def abort(self) -> None:
        _stop_pool(self.pool)  # Ctrl-C, SIGTERM, an error: end the workers now


# --- dask: an embedded LocalCluster or a running cluster -------------------------------------


#: The signals a terminal (Ctrl-C), ``timeout`` or a job scheduler send to the whole process
#: group: the embedded cluster's workers leave them to the main process, which closes it.
_GROUP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


@contextlib.contextmanager
def _group_signals_blocked():
    """SIGINT and SIGTERM blocked in this thread while the block runs: the threads started
    meanwhile (the cluster's event loop, the threads that spawn its workers) and the worker
    processes they start inherit the blocked signals, so a signal to the whole process group
    reaches only this process, which closes the cluster (its workers are then ended with
    SIGKILL, or leave when asked to). A signal during the block stays pending and is
    delivered when it ends."""
    if not hasattr(signal, "pthread_sigmask"):  # Windows
        yield
        return
    # Started first: starting multiprocessing's resource tracker (as the first spawned worker
    # would) unblocks SIGINT and SIGTERM in the thread that starts it.
    from multiprocessing import resource_tracker

    with contextlib.suppress(Exception):
        resource_tracker.ensure_running()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _GROUP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


class DaskExecutor:
    """``--executor dask``: jobs on a Dask cluster, a few per worker thread submitted at once
    (:data:`DASK_JOBS_PER_THREAD`), each carrying its drive (a drive is a few MB at most; a
    scattered one would be lost with its worker)."""

    kind = "dask"

    def __init__(self, jobs: int, scheduler: str | None = None) -> None:
        distributed = _distributed()
        self.scheduler = scheduler
        self.cluster = None
        self.client = None
        self._threads = (0.0, 0)  # (when, worker threads) of the last look
        self._processing = (0.0, frozenset())
        self._environ: dict | None = None
        # Dask's own messages below WARNING only with -v (and its workers' below ERROR: they
        # are about their own bookkeeping, e.g. each job cancelled under them on Ctrl-C).
        verbose = logging.getLogger().isEnabledFor(logging.INFO)  # -v
        quiet = False if verbose else logging.WARNING
        self._logger = logging.getLogger("distributed")
        # put back after the close, but never below WARNING unless -v: the client's and the
        # cluster's threads may still say goodbye (at INFO) as the command ends
        self._log_level = self._logger.level
        if not verbose:
            self._log_level = max(self._log_level, logging.WARNING)
            self._logger.setLevel(logging.WARNING)
        if scheduler is None:
            import dask

            config = dict(EMBEDDED_CONFIG)
            if not verbose:
                config["distributed.nanny.pre-spawn-environ.DASK_LOGGING__DISTRIBUTED"] = "error"
            # The nanny sets its workers' environment in this process's os.environ too: put
            # it back when the cluster is closed.
            self._environ = dict(os.environ)
            with _group_signals_blocked(), dask.config.set(config):
                try:
                    self.cluster = distributed.LocalCluster(
                        n_workers=jobs, threads_per_worker=1, processes=True,
                        # its HTTP server on a free port of this machine: 8787, Dask's
                        # default, may be another cluster's
                        dashboard_address="127.0.0.1:0", memory_limit=0, silence_logs=quiet)
                    self.client = distributed.Client(self.cluster, set_as_default=False)
                except BaseException:
                    self.abort()
                    raise
            log.info("started a Dask LocalCluster of %d workers at %s (dashboard %s)", jobs,
                     self.cluster.scheduler_address, self.cluster.dashboard_link)
            return
        try:
            self.client = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT_S,
                                             set_as_default=False)
        except (OSError, ValueError, TypeError, TimeoutError) as exc:
            self._logger.setLevel(self._log_level)
            why = " ".join(str(exc).split()) or type(exc).__name__
            raise InputError(f"--scheduler {scheduler}: cannot connect to a Dask scheduler "
                             f"({why})") from None
        if not self.client.nthreads():
            log.warning("the Dask cluster at %s has no workers yet; the jobs wait for them",
                        scheduler)

    def capacity(self) -> int:
        when, threads = self._threads
        if time.monotonic() - when > 2.0:  # a cluster may grow or shrink while we run
            with contextlib.suppress(Exception):
                threads = sum(self.client.nthreads().values())
            self._threads = (time.monotonic(), threads)
        return max(DASK_JOBS_PER_THREAD * threads, 2)

    def submit(self, fn, *args):
        return self.client.submit(fn, *args, pure=False)

    def wait(self, pending: set, timeout: float) -> tuple[set, set]:
        import distributed

        with contextlib.suppress(TimeoutError, cf.CancelledError), self.client.as_current():
            distributed.wait(list(pending), timeout=timeout, return_when="FIRST_COMPLETED")
        done = {f for f in pending if f.done()}
        return done, pending - done

    def outcome(self, fut, signals):
        """A finished job's result. A job whose worker died (the scheduler gave up after
        retrying it elsewhere) or that the scheduler cancelled is :class:`JobLost`; a worker
        that cannot even load the job (vislam not installed in its environment) is bad input;
        losing the scheduler stops the benchmark."""
        from distributed.scheduler import KilledWorker

        try:
            while True:  # a result lost with its worker is computed again: wait for it, but
                try:    # act on a signal meanwhile
                    res = fut.result(timeout=0.1)
                    break
                except TimeoutError:
                    signals.check()
        except KilledWorker as exc:
            tries = getattr(exc, "allowed_failures", None)
            tries = f"{tries + 1} workers" if isinstance(tries, int) else "every worker"
            raise JobLost(f"KilledWorker: {tries} died running it (out of memory? a crash in "
                          "native code? see the workers' logs)") from None
        except cf.CancelledError as exc:
            if self.client.status not in ("running", "connecting"):
                raise EstimationError(f"lost the Dask scheduler ({self.scheduler or 'embedded'});"
                                      " the benchmark cannot go on") from None
            raise JobLost(f"cancelled by the Dask scheduler ({_short(exc)})") from None
        except ImportError as exc:  # the job itself catches its estimator's ImportError
            raise InputError(f"the Dask workers cannot load vislam's jobs ({type(exc).__name__}: "
                             f"{_short(exc)}); install vislam in the workers' environment") from None
        except Exception as exc:  # e.g. the job's result could not be sent back
            raise JobLost(f"{type(exc).__name__}: {_short(exc)}") from None
        if (self.scheduler and getattr(res, "user_fault", False)
                and ("no module" in res.error or "no file" in res.error)):
            res.error += (" on a worker of the Dask cluster at " + self.scheduler + "; a "
                          "user's estimator module must be importable on every worker")
        return res

    def running(self, pending: set) -> set:
        when, keys = self._processing
        if time.monotonic() - when > 0.5:  # one call to the scheduler per half second at most
            with contextlib.suppress(Exception):
                keys = frozenset(k for ks in self.client.processing().values() for k in ks)
            self._processing = (time.monotonic(), keys)
        return {f for f in pending if f.key in keys}

    def close(self) -> None:
        self._shut()

    def abort(self) -> None:
        self._shut(abort=True)

    def _shut(self, abort: bool = False) -> None:
        """Our client closed (cancelling what it still has on the cluster) and the embedded
        cluster with its worker processes; a cluster given by --scheduler is left running.
        On abort the embedded cluster goes first, its worker processes ended at once (SIGKILL:
        they do not take SIGTERM, see :func:`_group_signals_blocked`; their nannies told not
        to restart them): a worker closed gracefully in the middle of a job says so, once per
        job, and races its own heartbeats."""
        client, cluster = self.client, self.cluster
        self.client = self.cluster = None
        if abort:  # what the cluster says while it is torn down is noise
            self._logger.setLevel(logging.CRITICAL)
        if abort and cluster is not None:
            for nanny in list(getattr(cluster, "workers", {}).values()):
                with contextlib.suppress(Exception):
                    nanny.close_gracefully()
                    if nanny.pid:
                        os.kill(nanny.pid, signal.SIGKILL)
            with contextlib.suppress(Exception):
                cluster.close(timeout=10)
        if client is not None:
            with contextlib.suppress(Exception):
                client.close(timeout=5)
        if cluster is not None and not abort:
            with contextlib.suppress(Exception):
                cluster.close(timeout=10)
        if self._environ is not None:
            for k in set(os.environ) - set(self._environ):
                os.environ.pop(k, None)
            os.environ.update(self._environ)
            self._environ = None
        self._logger.setLevel(self._log_level)


def _short(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:300] or type(exc).__name__
