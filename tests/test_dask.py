"""``--executor dask`` (eval/executors.py): the Monte Carlo runs and the benchmark on a Dask
cluster give the same numbers as the local process pool, to the last digit; a failed run is
recorded, a user's fault still stops the run; an embedded cluster leaves no process behind (on
exit and on Ctrl-C); a cluster given by --scheduler is left running; a bad address and a
missing extra are one line and exit code 2.

Skipped where dask is not installed, except in CI (``CI=true``): there a missing dask fails
the tests (the ``test`` extra installs it), so CI never passes by skipping them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.eval.cli import main

try:
    import distributed
except ImportError:  # the dask extra is not installed
    distributed = None

VISLAM = Path(sys.executable).with_name("vislam")
NEES_ESTIMATORS = ["ekf-joint", "ekf-invariant", "smoother"]
#: results.json keys that are timings, not figures
TIMING_KEYS = {"runtime_s", "frames_per_s", "wall_s"}


@pytest.fixture(scope="module")
def dask_installed():
    if distributed is None:
        reason = "dask is not installed (pip install 'vislam[dask]')"
        if os.environ.get("CI") == "true":
            pytest.fail(f"{reason}; CI=true: the Dask tests must run, never skip")
        pytest.skip(reason)


@pytest.fixture(scope="module")
def cluster(dask_installed):
    """A running Dask cluster of 2 workers, as a user's ``dask scheduler`` + ``dask worker``
    would be: its address is given with --scheduler, and it must survive every run."""
    import dask
    from vislam.eval.executors import EMBEDDED_CONFIG

    environ = dict(os.environ)  # the nanny writes its workers' environment into ours
    with dask.config.set(EMBEDDED_CONFIG):
        c = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                     dashboard_address="127.0.0.1:0", memory_limit=0)
    try:
        yield c
    finally:
        c.close()
        os.environ.clear()
        os.environ.update(environ)


def _children() -> set[int]:
    """This process's child processes (multiprocessing's resource tracker, which lives as long
    as the process, left out)."""
    import psutil

    out = set()
    for p in psutil.Process().children(recursive=True):
        with contextlib.suppress(psutil.Error):
            if p.status() != psutil.STATUS_ZOMBIE and "resource_tracker" not in " ".join(p.cmdline()):
                out.add(p.pid)
    return out


def _no_new_children(before: set[int], within_s: float = 10.0) -> None:
    deadline = time.monotonic() + within_s
    while (left := _children() - before) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not left, f"processes left behind: {sorted(left)}"


def _figures(results: dict) -> dict:
    """results.json without its timings."""
    out = {k: v for k, v in results.items() if k not in TIMING_KEYS}
    out["sequences"] = [
        {**s, "estimators": [{k: v for k, v in r.items() if k not in TIMING_KEYS}
                             for r in s["estimators"]]}
        for s in results["sequences"]]
    return out


# --- the numbers do not depend on the executor -----------------------------------------------


@pytest.mark.regression
@pytest.mark.slow
def test_monte_carlo_nees_gives_the_same_numbers_locally_and_on_dask(dask_installed):
    from vislam.eval.montecarlo import monte_carlo_nees

    def study(executor: str, jobs: int) -> dict:
        return monte_carlo_nees(6, 3, NEES_ESTIMATORS, FilterConfig(), frames=40, jobs=jobs,
                                show_progress=False, executor=executor)

    before = _children()
    on_dask = study("dask", 2)  # an embedded LocalCluster of 2 workers
    _no_new_children(before)  # closed: its workers are gone
    for local in (study("local", 2), study("local", 1)):  # the pool, and this process alone
        for name in NEES_ESTIMATORS:
            a, b = on_dask["estimators"][name], local["estimators"][name]
            assert a["runs_failed"] == b["runs_failed"] == 0
            for key in ("anees_pose", "anees_landmark", "nees_pose_per_run_mean",
                        "inside_fraction_pose", "inside_fraction_landmark", "landmarks_scored"):
                assert a[key] == b[key], (name, key)  # exactly: same seeds, same arithmetic
            assert np.array_equal(a["nees_pose_over_time"], b["nees_pose_over_time"], equal_nan=True)


@pytest.mark.slow
def test_nees_command_on_an_embedded_dask_cluster(dask_installed, tmp_path, capsys):
    out = tmp_path / "nees"
    before = _children()
    rc = main(["nees", "--runs", "4", "--frames", "40", "--executor", "dask", "-j", "2",
               "--out", str(out), "-q"])
    assert rc == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"wrote {out} in "), err  # no Dask chatter
    data = json.loads((out / "nees.json").read_text())
    assert data["runs"] == 4 and data["frames"] == 40
    assert data["settings"]["executor"] == {"kind": "dask", "scheduler": None, "workers": 2}
    for name in NEES_ESTIMATORS:
        r = data["estimators"][name]
        assert r["runs_failed"] == 0 and r["anees_pose"] > 0 and r["anees_landmark"] > 0
        assert len(r["nees_pose_per_run_mean"]) == 4
    assert (out / "nees.png").is_file()
    _no_new_children(before)


@pytest.mark.regression
@pytest.mark.slow
def test_bench_gives_the_same_figures_on_a_dask_cluster_and_leaves_it_running(cluster, tmp_path):
    args = ["bench", "--frames", "60", "-e", "dead-reckoning,ekf-invariant,smoother",
            "--model", "as-given", "-q"]
    assert main([*args, "-j", "2", "--out", str(tmp_path / "local")]) == 0
    address = cluster.scheduler_address
    assert main([*args, "--executor", "dask", "--scheduler", address,
                 "--out", str(tmp_path / "dask")]) == 0
    local, on_dask = (json.loads((tmp_path / d / "results.json").read_text())
                      for d in ("local", "dask"))
    assert _figures(on_dask) == _figures(local)
    rows = on_dask["sequences"][0]["estimators"]
    assert [r["name"] for r in rows] == ["dead-reckoning", "ekf-invariant", "smoother"]
    assert all(r["error"] is None and r["ate_m"] is not None for r in rows)
    settings = json.loads((tmp_path / "dask" / "settings.json").read_text())
    assert settings["executor"] == {"kind": "dask", "scheduler": address, "workers": None}
    assert json.loads((tmp_path / "local" / "settings.json").read_text())["executor"] == {
        "kind": "local", "scheduler": None, "workers": 2}
    with distributed.Client(address, set_as_default=False) as client:  # not ours: not closed
        assert len(client.nthreads()) == 2


# --- failures ----------------------------------------------------------------------------------


def test_a_failed_run_is_recorded_not_fatal_on_dask(cluster):
    """A drive that makes every estimator fail (a velocity that is not finite) among good ones:
    its jobs are recorded as failures, the others run, the same as with the local pool."""
    from vislam.eval.drives import simulated_sequence
    from vislam.eval.study import JobFailure, JobResult, run_jobs

    good = simulated_sequence(0, 30).sequence
    v = good.linear_velocity.copy()
    v[7, 0] = np.nan
    sequences = {"good": good, "bad": dataclasses.replace(good, linear_velocity=v),
                 "good2": simulated_sequence(1, 30).sequence}
    names = ["dead-reckoning", "ekf-invariant", "smoother"]
    out = {}
    for executor, scheduler in (("dask", cluster.scheduler_address), ("local", None)):
        out[executor] = run_jobs(sequences, names, FilterConfig(), jobs=2, show_progress=False,
                                 executor=executor, scheduler=scheduler)
    on_dask, local = out["dask"], out["local"]
    assert set(on_dask) == set(local) == {(k, n) for k in sequences for n in names}
    for (key, name), res in on_dask.items():
        if key == "bad":
            assert isinstance(res, JobFailure) and "not finite at step 7" in res.error, res
            assert res.error == local[(key, name)].error
        else:
            assert isinstance(res, JobResult), res
            assert np.array_equal(res.estimate.poses, local[(key, name)].estimate.poses)


GOOD = '''
from vislam.eval.builtin import ekf_invariant


def estimate(seq, settings):
    est = ekf_invariant(seq, settings)
    est.estimator = "mine"
    return est
'''

#: A user's estimator that breaks the Estimate contract: the user's fault, which stops the run.
SHORT = '''
from vislam.eval.builtin import dead_reckoning


def estimate(seq, settings):
    est = dead_reckoning(seq, settings)
    est.poses = est.poses[:-1]
    return est
'''


@pytest.fixture
def user_folder(tmp_path, monkeypatch):
    folder = tmp_path / "project"
    folder.mkdir()
    monkeypatch.chdir(folder)
    (folder / "user_dask_good.py").write_text(textwrap.dedent(GOOD))
    (folder / "user_dask_short.py").write_text(textwrap.dedent(SHORT))
    yield folder
    for name in [m for m in sys.modules if m.startswith("user_dask_")]:
        del sys.modules[name]


@pytest.mark.regression
@pytest.mark.slow
def test_a_user_estimator_runs_on_the_embedded_cluster_and_its_fault_stops_the_run(
        dask_installed, user_folder, tmp_path, capsys):
    """The embedded cluster's workers start in the current folder, so a user's MODULE:FUNCTION
    from there runs on them; a user's fault is still exit code 2, one line, nothing written."""
    out = tmp_path / "good"
    assert main(["nees", "--runs", "2", "--frames", "30", "-e", "user_dask_good:estimate",
                 "--executor", "dask", "-j", "2", "--out", str(out), "-q"]) == 0
    row = json.loads((out / "nees.json").read_text())["estimators"]["user_dask_good:estimate"]
    assert row["runs_failed"] == 0 and row["anees_pose"] is not None
    capsys.readouterr()
    out = tmp_path / "short"
    before = _children()
    rc = main(["bench", "--frames", "30", "--model", "as-given", "-e",
               "dead-reckoning,user_dask_short:estimate", "--executor", "dask", "-j", "2",
               "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and "poses of shape" in err[0] and "user_dask_short:estimate" in err[0], err
    assert not out.exists()
    _no_new_children(before)  # an error closes the cluster too


def test_a_user_module_missing_on_the_workers_of_a_given_cluster_is_one_line(
        cluster, user_folder, tmp_path, capsys):
    """The given cluster's workers did not start in the user's folder: the module is not found
    there, which is the user's to fix (one line, exit code 2)."""
    out = tmp_path / "out"
    rc = main(["nees", "--runs", "2", "--frames", "30", "-e", "user_dask_good:estimate",
               "--scheduler", cluster.scheduler_address, "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert "no module 'user_dask_good'" in err[0] and "importable on every worker" in err[0]
    assert not out.exists()


def test_a_bad_scheduler_address_is_one_line_and_exit_2(dask_installed, tmp_path, capsys):
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "out"
    t0 = time.monotonic()
    rc = main(["nees", "--runs", "2", "--frames", "30", "--executor", "dask",
               "--scheduler", f"tcp://127.0.0.1:{port}", "--out", str(out), "-q"])
    assert time.monotonic() - t0 < 20
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith(f"vislam nees: error: --scheduler tcp://127.0.0.1:{port}: "
                             "cannot connect to a Dask scheduler")
    assert not out.exists()


def test_without_dask_the_executor_is_an_input_error(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed fails
    out = tmp_path / "out"
    assert main(["nees", "--runs", "2", "--executor", "dask", "--out", str(out)]) == 2
    assert main(["bench", "--frames", "30", "--scheduler", "tcp://somewhere:8786",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    missing = "error: --executor dask needs the dask extra: pip install 'vislam[dask]'"
    assert err == [f"vislam nees: {missing}", f"vislam bench: {missing}"]
    assert not out.exists()


def test_a_scheduler_needs_the_dask_executor(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["nees", "--runs", "2", "--executor", "local", "--scheduler", "tcp://h:8786",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--scheduler tcp://h:8786 needs --executor dask" in err[0]


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "killpg"), reason="process groups are POSIX")
@pytest.mark.parametrize("signum, rc, line", [
    (signal.SIGINT, 130, "vislam nees: interrupted; nothing written"),
    pytest.param(signal.SIGTERM, 143, "vislam nees: terminated; nothing written",
                 marks=pytest.mark.regression),  # the fast tier has Ctrl-C
], ids=["ctrl-c", "sigterm"])
def test_a_signal_to_the_process_group_closes_the_embedded_cluster(dask_installed, tmp_path,
                                                                    signum, rc, line):
    """The terminal's Ctrl-C (or ``timeout``'s SIGTERM) goes to the whole process group: the
    workers leave it to the main process, which closes the cluster; exit code 130 (143), one
    line, no process left behind."""
    import psutil

    out = tmp_path / "nees"
    proc = subprocess.Popen(
        [str(VISLAM), "nees", "--runs", "20", "--frames", "100", "--executor", "dask", "-j", "2",
         "--out", str(out), "-q"],
        start_new_session=True, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        main_process = psutil.Process(proc.pid)
        deadline = time.monotonic() + 60
        workers: list = []
        while time.monotonic() < deadline and proc.poll() is None:
            workers = [p for p in main_process.children(recursive=True)
                       if "resource_tracker" not in " ".join(p.cmdline())]
            if len(workers) >= 2:
                break
            time.sleep(0.1)
        assert len(workers) >= 2, "the cluster did not start"
        time.sleep(2.0)  # its workers are running jobs
        os.killpg(proc.pid, signum)
        err = proc.communicate(timeout=60)[1]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == rc, err
    assert err.strip().splitlines() == [line]
    time.sleep(0.5)
    left = [p.pid for p in workers if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]
    assert not left, f"worker processes left behind: {left}"
    assert not out.exists()
