"""The scripts in examples/ run as a user runs them (a fresh Python, ``--out`` a temporary
folder), exit 0 and print the figures they promise.

Each script runs once per session; the figures below were measured on the default drive
(seed 0, 100 frames) and over seeds 0-5:

* own_drive.py: ekf-invariant ATE 0.086 m (seed 0), the same to the printed digit in the run's
  metrics.json and in ``vislam score``'s score.json;
* smoother_graph.py: the example's own graph and vislam's smoother on the same graph (same start,
  no gyro bias, one round) 0.5-2.1 micrometres apart at most over seeds 0-5, the tolerance here
  100 micrometres; ATE 0.060 m (seed 0);
* custom_filter.py: its forty-line filter through ``vislam bench`` (aligned ATE 0.378 m, pose
  NEES 9.18 on the 100-frame drive) and ``vislam nees`` (pose ANEES 5.54 over 8 runs, bounds
  [3.84, 8.63]), then the regression test's assertion.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
SCRIPTS = sorted(p.name for p in EXAMPLES.glob("*.py"))
NUMBER = r"([-+0-9.e]+)"


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    """``ran(script)``: (exit code, stdout, stderr, its --out folder), the script run once."""
    done: dict[str, tuple] = {}

    def run(script: str):
        if script not in done:
            out = tmp_path_factory.mktemp(Path(script).stem) / "out"
            proc = subprocess.run([sys.executable, str(EXAMPLES / script), "--out", str(out)],
                                  capture_output=True, text=True, timeout=300)
            done[script] = (proc.returncode, proc.stdout, proc.stderr, out)
        return done[script]

    return run


def _figure(pattern: str, text: str) -> tuple[float, ...]:
    match = re.search(pattern, text)
    assert match, f"no line matching {pattern!r} in:\n{text}"
    return tuple(float(g) for g in match.groups())


def test_there_are_examples():
    assert {"own_drive.py", "smoother_graph.py", "custom_filter.py"} <= set(SCRIPTS)


@pytest.mark.parametrize("script", SCRIPTS)
def test_example_runs(ran, script):
    rc, stdout, stderr, _ = ran(script)
    assert rc == 0, f"{script} exited {rc}\n{stdout}\n{stderr}"


def test_own_drive_scores_against_its_ground_truth(ran):
    rc, stdout, stderr, out = ran("own_drive.py")
    assert rc == 0, stderr
    line = r"ATE {0} m \(se3-aligned {0} m\) over (\d+) frames, pose NEES {0}".format(NUMBER)
    run = _figure(r"vislam run, metrics.json: " + line, stdout)
    score = _figure(r"vislam score, score.json: " + line, stdout)
    assert run == score  # the run's own figures and the score of the trajectory it wrote
    ate, ate_aligned, frames, nees = run
    assert frames == 100
    assert ate < 0.2 and ate_aligned <= ate
    assert 0 < nees < 20
    for path in ["data/mydrive.npz", "data/groundtruth/mydrive.txt", "run/trajectory.tum",
                 "run/metrics.json", "score/score.json"]:
        assert (out / path).is_file(), path
    assert "$ vislam inspect" in stdout and "ground truth: " in stdout


def test_smoother_graph_is_vislams_smoother(ran):
    rc, stdout, stderr, out = ran("smoother_graph.py")
    assert rc == 0, stderr
    (ate,) = _figure(rf"ATE this graph: {NUMBER} m", stdout)
    (ate_vislam,) = _figure(rf"ATE vislam smoother, same graph: {NUMBER} m", stdout)
    (ate_default,) = _figure(rf"ATE vislam smoother, its defaults: {NUMBER} m", stdout)
    (apart,) = _figure(rf"largest position difference, [^:]*: {NUMBER} m", stdout)
    assert apart < 1e-4
    assert abs(ate - ate_vislam) <= 1e-4
    assert ate < 0.1 and ate_default < 0.1
    assert (out / "trajectories.npz").is_file()


def test_custom_filter_goes_through_bench_nees_and_a_nees_test(ran):
    rc, stdout, stderr, out = ran("custom_filter.py")
    assert rc == 0, stderr
    names = re.findall(r"^bench: (\S+)", stdout, flags=re.M)
    assert names == ["ekf-invariant", "smoother", "custom_filter.py:FirstSightMapper"] or \
        sorted(names) == sorted(["ekf-invariant", "smoother", "custom_filter.py:FirstSightMapper"])
    anees, = _figure(r"pose ANEES " + NUMBER, stdout)
    lo, hi = _figure(r"bounds \[" + NUMBER + ", " + NUMBER + r"\]", stdout)
    assert lo <= anees <= hi
    assert "regression test: pose ANEES inside the 95 % bounds" in stdout
    assert (out / "bench" / "results.json").is_file() and (out / "nees" / "nees.json").is_file()
