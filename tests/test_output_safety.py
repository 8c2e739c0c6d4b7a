"""Issue 11, items 1, 4, 7 and 8: output folders never lose a user's files, every output
problem is found before the estimation, concurrent writers and signals leave a consistent
folder, and the bench reports failed estimators in its exit code."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vislam.ekf.errors import InputError
from vislam.eval import study
from vislam.eval.cli import main
from vislam.eval.output_dir import MARKER, OutputDir


@pytest.fixture(scope="module")
def drive_dir(tmp_path_factory) -> Path:
    """A folder as a user has it: a drive, its ground truth, notes of their own."""
    from vislam.eval.simulate import SimConfig, simulate, write_simulation

    folder = tmp_path_factory.mktemp("data")
    write_simulation(simulate(SimConfig(seed=4, n_frames=40, name="drive")), folder)
    (folder / "notes.txt").write_text("mine\n")
    return folder


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file below ``folder`` with its bytes (hidden ones too)."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*")) if p.is_file() or p.is_symlink()
    }


def no_estimation(monkeypatch):
    """Fail the test if any estimator starts: output checks come first."""
    def boom(*args, **kwargs):
        raise AssertionError("an estimator ran before the output folder was checked")

    monkeypatch.setattr(study, "run_estimator", boom)


def run_cli(argv, capsys) -> tuple[int, str]:
    code = main(argv)
    err = capsys.readouterr().err
    return code, err


# --- item 1: --out never deletes what is there -------------------------------------------------


def test_out_is_the_inputs_folder_is_refused_and_nothing_is_touched(drive_dir, monkeypatch, capsys):
    no_estimation(monkeypatch)
    before = snapshot(drive_dir)
    for force in ([], ["--force"]):
        code, err = run_cli(["run", str(drive_dir / "drive.npz"), "-e", "dead-reckoning",
                             "--out", str(drive_dir), "-q", *force], capsys)
        assert code == 2 and "folder of the input" in err and len(err.splitlines()) == 1
    assert snapshot(drive_dir) == before


def test_a_foreign_non_empty_folder_needs_force_and_is_never_overwritten(drive_dir, tmp_path, capsys,
                                                                        monkeypatch):
    out = tmp_path / "theirs"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work\n")
    (out / "metrics.json").write_text('{"mine": true}\n')
    before = snapshot(out)
    args = ["run", str(drive_dir / "drive.npz"), "-e", "dead-reckoning", "--out", str(out), "-q"]
    with monkeypatch.context() as m:
        no_estimation(m)
        code, err = run_cli(args, capsys)
        assert code == 2 and "vislam did not write" in err and "--force" in err
        # --force writes beside the user's files, never over them: metrics.json clashes
        code, err = run_cli([*args, "--force"], capsys)
        assert code == 2 and "'metrics.json' exists and was not written by vislam" in err
    assert snapshot(out) == before
    (out / "metrics.json").unlink()
    code, _ = run_cli([*args, "--force"], capsys)
    assert code == 0
    after = snapshot(out)
    assert after["thesis.tex"] == b"years of work\n" and "estimate.npz" in after
    owned = json.loads(after[MARKER])["files"]
    assert "thesis.tex" not in owned and "estimate.npz" in owned


def test_an_existing_file_as_out_is_an_error(drive_dir, tmp_path, monkeypatch, capsys):
    no_estimation(monkeypatch)
    target = tmp_path / "result"
    target.write_text("keep\n")
    code, err = run_cli(["run", str(drive_dir / "drive.npz"), "-e", "dead-reckoning",
                         "--out", str(target), "-q", "--force"], capsys)
    assert code == 2 and "is a file" in err and target.read_text() == "keep\n"


def test_rerun_replaces_only_vislams_own_unchanged_files(drive_dir, tmp_path, capsys):
    out = tmp_path / "out"
    args = ["run", str(drive_dir / "drive.npz"), "-e", "dead-reckoning", "--out", str(out), "-q"]
    assert main(args) == 0
    (out / "my-notes.md").write_text("notes\n")  # the user adds a file of their own
    assert main(args) == 0  # vislam's folder: no --force needed
    assert (out / "my-notes.md").read_text() == "notes\n"
    (out / "metrics.json").write_text("edited by hand\n")  # a vislam file the user changed
    capsys.readouterr()
    code, err = run_cli(args, capsys)
    assert code == 2 and "changed since vislam wrote it" in err
    assert (out / "metrics.json").read_text() == "edited by hand\n"


def test_nothing_is_ever_deleted_and_only_unchanged_vislam_files_are_replaced(tmp_path):
    out = tmp_path / "out"
    with OutputDir(out) as tmp:
        (tmp / "a.txt").write_text("a")
        (tmp / "seq1").mkdir()
        (tmp / "seq1" / "x.tum").write_text("x")
    (out / "seq1" / "x.tum").write_text("changed by the user")
    (out / "mine.txt").write_text("mine")
    with OutputDir(out) as tmp:
        (tmp / "a.txt").write_text("a2")
        (tmp / "b.txt").write_text("b")
    files = snapshot(out)
    assert files.keys() == {"a.txt", "b.txt", "mine.txt", "seq1/x.tum", MARKER}
    assert files["a.txt"] == b"a2" and files["seq1/x.tum"] == b"changed by the user"
    # the changed file is no longer listed as vislam's; the earlier run's a.txt was replaced
    assert json.loads(files[MARKER])["files"].keys() == {"a.txt", "b.txt"}


def test_a_marker_placed_by_hand_never_gets_a_users_file_deleted(drive_dir, tmp_path, capsys):
    import hashlib

    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("my notes\n")
    sha = hashlib.sha256(b"my notes\n").hexdigest()
    (out / MARKER).write_text(json.dumps({"files": {"notes.txt": sha}}))
    assert main(["run", str(drive_dir / "drive.npz"), "-e", "dead-reckoning", "--out", str(out),
                 "-q"]) == 0
    assert (out / "notes.txt").read_text() == "my notes\n"


@pytest.mark.parametrize("which", ["groundtruth", "gt", "config"])
def test_the_folder_of_any_input_is_refused(which, drive_dir, tmp_path, monkeypatch, capsys):
    no_estimation(monkeypatch)
    folder = tmp_path / "inputs"
    folder.mkdir()
    argv = ["run", str(drive_dir / "drive.npz"), "-e", "dead-reckoning", "-q", "--force"]
    if which == "groundtruth":  # the ground truth found next to the data
        out = drive_dir / "groundtruth"
    elif which == "gt":
        (folder / "gt.txt").write_bytes((drive_dir / "groundtruth" / "drive.txt").read_bytes())
        argv += ["--gt", str(folder / "gt.txt")]
        out = folder
    else:
        (folder / "s.toml").write_text("[filter]\npixel_sigma = 1.0\n")
        argv += ["--config", str(folder / "s.toml")]
        out = folder
    before = snapshot(out)
    code, err = run_cli([*argv, "--out", str(out)], capsys)
    assert code == 2 and "folder of the input" in err
    assert snapshot(out) == before


def test_a_failed_or_interrupted_run_leaves_no_trace(tmp_path):
    for exc in (RuntimeError("boom"), KeyboardInterrupt()):
        with pytest.raises(type(exc)):
            with OutputDir(tmp_path / "new" / "deeper" / "out") as tmp:
                (tmp / "half.txt").write_text("half")
                raise exc
        assert list(tmp_path.iterdir()) == []  # not even the parents it made
    existing = tmp_path / "kept"
    existing.mkdir()
    with pytest.raises(RuntimeError):
        with OutputDir(existing) as tmp:
            (tmp / "half.txt").write_text("half")
            raise RuntimeError
    assert list(existing.iterdir()) == []


# --- item 4: output problems found before the estimation ---------------------------------------


def test_parent_is_a_file(drive_dir, tmp_path, monkeypatch, capsys):
    no_estimation(monkeypatch)
    (tmp_path / "f").write_text("x")
    code, err = run_cli(["run", str(drive_dir / "drive.npz"), "-e", "dead-reckoning",
                         "--out", str(tmp_path / "f" / "out"), "-q"], capsys)
    assert code == 2 and "is a file" in err and "Traceback" not in err


def test_unwritable_parent_is_found_before_estimating(drive_dir, tmp_path, monkeypatch, capsys):
    import tempfile

    no_estimation(monkeypatch)

    def denied(*args, **kwargs):  # tests run as root, where chmod cannot deny writing
        raise PermissionError(13, "Permission denied", kwargs.get("dir"))

    monkeypatch.setattr(tempfile, "mkdtemp", denied)
    code, err = run_cli(["run", str(drive_dir / "drive.npz"), "-e", "dead-reckoning",
                         "--out", str(tmp_path / "out"), "-q"], capsys)
    assert code == 2 and "cannot write in" in err and "Permission denied" in err
    assert list(tmp_path.iterdir()) == []


def test_out_dot(drive_dir, tmp_path, monkeypatch, capsys):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    args = ["run", str(drive_dir / "drive.npz"), "-e", "dead-reckoning", "--out", ".", "-q"]
    assert main(args) == 0 and (work / "estimate.npz").is_file()
    assert main(args) == 0  # its own folder now
    monkeypatch.chdir(drive_dir)  # the data's folder: refused, nothing touched
    before = snapshot(drive_dir)
    code, err = run_cli(args, capsys)
    assert code == 2 and snapshot(drive_dir) == before


# --- item 7: concurrent writers and signals ----------------------------------------------------


def _writer(out: str, i: int, rounds: int, queue) -> None:
    errors = []
    for r in range(rounds):
        try:
            with OutputDir(out) as tmp:
                for name in ("a.json", "b.json", "sub/c.json"):
                    (tmp / name).parent.mkdir(parents=True, exist_ok=True)
                    (tmp / name).write_text(json.dumps({"writer": i, "round": r}))
                time.sleep(0.001 * (i % 3))
        except Exception as exc:  # noqa: BLE001 - reported to the test
            errors.append(f"{type(exc).__name__}: {exc}")
    queue.put(errors)


def test_eight_concurrent_writers_of_one_folder(tmp_path):
    out = tmp_path / "shared-out"
    ctx = mp.get_context("fork")
    queue = ctx.Queue()
    procs = [ctx.Process(target=_writer, args=(str(out), i, 6, queue)) for i in range(8)]
    for p in procs:
        p.start()
    errors = [e for _ in procs for e in queue.get(timeout=60)]
    for p in procs:
        p.join(timeout=10)
    assert errors == []  # 48 writes, none lost to a rename race
    files = snapshot(out)
    assert files.keys() == {"a.json", "b.json", "sub/c.json", MARKER}
    owned = json.loads(files[MARKER])["files"]
    assert owned.keys() == {"a.json", "b.json", "sub/c.json"}
    import hashlib

    for rel, sha in owned.items():  # the marker describes what is there
        assert hashlib.sha256(files[rel]).hexdigest() == sha
    assert not [p for p in tmp_path.rglob(".*staging*")]


def _vislam(args: list[str], cwd: Path, env: dict | None = None) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "MPLBACKEND": "Agg", **(env or {})}
    return subprocess.Popen(
        [sys.executable, "-c", "import sys; from vislam.eval.cli import main; sys.exit(main())", *args],
        cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True,
    )


def _children(pid: int) -> list[int]:
    import psutil

    try:
        return [c.pid for c in psutil.Process(pid).children(recursive=True)]
    except psutil.NoSuchProcess:
        return []


@pytest.mark.slow
@pytest.mark.parametrize("target", ["process", "group"])  # group: a terminal, timeout, a scheduler
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_during_bench_ends_workers_promptly_and_leaves_nothing(tmp_path, sig, target):
    import psutil

    out = tmp_path / "bench"
    # as-given: straight to the workers (the default identifies the model first, in this process)
    proc = _vislam(["bench", "--frames", "3000", "-e", "ekf-joint,ekf-invariant", "-j", "2",
                    "--model", "as-given", "--out", str(out), "-q"], tmp_path)
    deadline = time.time() + 60
    workers: list[int] = []
    while time.time() < deadline and len(workers) < 2:  # both workers busy estimating
        time.sleep(0.2)
        workers = _children(proc.pid)
        assert proc.poll() is None, proc.communicate()
    time.sleep(1.0)
    assert len(workers) >= 2 and list(tmp_path.glob(".bench.vislam-staging-*"))
    t0 = time.time()
    if target == "group":
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    elapsed = time.time() - t0
    assert elapsed < 2.0, f"took {elapsed:.1f} s to stop"
    assert proc.returncode == (130 if sig == signal.SIGINT else 143), err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert "nothing written" in err, err
    time.sleep(0.2)
    assert not [w for w in workers if psutil.pid_exists(w)
                and psutil.Process(w).status() != psutil.STATUS_ZOMBIE]
    assert list(tmp_path.iterdir()) == []  # no output, no hidden staging folder


# --- item 8 and the bench's exit code ----------------------------------------------------------


def test_estimators_list_naming_nothing_is_an_error(capsys, monkeypatch, tmp_path):
    no_estimation(monkeypatch)
    for text in (",", " , ", ",,"):
        code, err = run_cli(["bench", "--frames", "20", "-e", text, "--out", str(tmp_path / "o")],
                            capsys)
        assert code == 2 and "names no estimator" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["../../x", "a/b", ".hidden", "..", "-rf", "", "x" * 300, "a\nb"])
def test_simulate_name_must_stay_inside_out(name, tmp_path, monkeypatch, capsys):
    work = tmp_path / "deep" / "er"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    code, err = run_cli(["simulate", "--out", "sim", "--frames", "20", f"--name={name}"], capsys)
    assert code == 2 and "--name" in err
    assert snapshot(tmp_path) == {}


def test_simulate_adds_drives_and_never_replaces_a_users_file(tmp_path, capsys):
    data = tmp_path / "data"
    assert main(["simulate", "--out", str(data), "--frames", "20", "--seed", "1"]) == 0
    assert main(["simulate", "--out", str(data), "--frames", "20", "--seed", "2"]) == 0
    assert {"sim-seed1.npz", "sim-seed2.npz"} <= {p.name for p in data.iterdir()}
    (data / "0027.npz").write_bytes(b"the user's real drive")
    capsys.readouterr()
    code, err = run_cli(["simulate", "--out", str(data), "--frames", "20", "--name", "0027"],
                        capsys)
    assert code == 2 and "'0027.npz' exists and was not written by vislam" in err
    assert (data / "0027.npz").read_bytes() == b"the user's real drive"


def test_bench_exits_3_with_one_line_per_failed_estimator(tmp_path, monkeypatch, capsys):
    import vislam.eval.registry as eval_registry
    real = eval_registry.get_estimator

    def failing(name):
        if name == "mapping":
            def crash(*a, **k):
                raise ZeroDivisionError("a bug in mapping")
            return crash
        return real(name)

    monkeypatch.setattr(eval_registry, "get_estimator", failing)
    out = tmp_path / "b"
    code, err = run_cli(["bench", "--frames", "20", "-e", "dead-reckoning,mapping", "-j", "1",
                         "--out", str(out), "-q"], capsys)
    assert code == 3
    lines = [ln for ln in err.splitlines() if ln.startswith("vislam bench: failed:")]
    assert lines == ["vislam bench: failed: sim-seed0 mapping: ZeroDivisionError: a bug in mapping"]
    assert "Traceback" not in err
    results = json.loads((out / "results.json").read_text())
    rows = {r["name"]: r for r in results["sequences"][0]["estimators"]}
    assert rows["mapping"]["error"] and rows["dead-reckoning"]["error"] is None


def test_latest_link_never_replaces_a_users_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results" / "latest").mkdir(parents=True)
    (tmp_path / "results" / "latest" / "keep.txt").write_text("keep")
    assert main(["bench", "--frames", "20", "-e", "dead-reckoning", "-j", "1", "-q"]) == 0
    assert (tmp_path / "results" / "latest" / "keep.txt").read_text() == "keep"


def test_output_dir_checks_name_the_flag(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match=r"^--out .*f: exists and is a file"):
        OutputDir(tmp_path / "f").check()
    os.symlink(tmp_path / "nowhere", tmp_path / "dangling")
    with pytest.raises(InputError, match="broken symbolic link"):
        OutputDir(tmp_path / "dangling").check()


@pytest.mark.slow
def test_eight_vislam_runs_into_one_out_all_succeed(drive_dir, tmp_path):
    """The issue's case end to end: 8 `vislam run` processes, one --out."""
    out = tmp_path / "out"
    procs = [_vislam(["run", str(drive_dir / "drive.npz"), "-e", "dead-reckoning", "--out", str(out),
                      "-q"], tmp_path) for _ in range(8)]
    results = [p.communicate(timeout=120) for p in procs]
    assert [p.returncode for p in procs] == [0] * 8, [err for _, err in results]
    files = snapshot(out)
    owned = json.loads(files[MARKER])["files"]
    assert owned.keys() == set(files) - {MARKER}
    assert not list(tmp_path.glob(".*staging*")) and not list(out.glob(".*staging*"))


@pytest.mark.slow
def test_signal_during_model_identification_leaves_nothing(tmp_path):
    """SIGTERM while bench identifies the drive's model (before any worker): exit 143, one
    line, no output folder, no cache entry half-written."""
    cache = tmp_path / "cache"
    out = tmp_path / "bench"
    proc = _vislam(["bench", "--frames", "3000", "-e", "ekf-joint", "-j", "1", "--out", str(out),
                    "-q"], tmp_path, env={"VISLAM_CACHE_DIR": str(cache)})
    time.sleep(4.0)  # simulating 3000 frames, then EM around the smoother
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert len(err.strip().splitlines()) == 1, err
    assert not out.exists() or not any(out.iterdir())
    assert not cache.exists() or not any(cache.iterdir())
