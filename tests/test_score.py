"""`vislam score`: a trajectory made elsewhere, scored with the benchmark's definitions."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from vislam.ekf.errors import InputError
from vislam.ekf.estimate import Estimate
from vislam.eval.cli import main
from vislam.eval.covariance_files import read_pose_covariances, write_covariances_text
from vislam.eval.export import (
    read_euroc,
    write_euroc,
    write_kitti,
    write_tum,
)
from vislam.eval.score import associate, match_times, read_trajectory

FIGURES = ("ate_m", "ate_aligned_m", "rpe_trans_pct", "rpe_rot_deg_per_100m", "nees_pose_mean")
VS_FIGURES = ("ate_m", "ate_aligned_m", "nees_pose_mean", "inside_95_fraction")
BENCH_ESTIMATORS = "dead-reckoning,ekf-invariant,smoother"


def _close(a, b, rel=1e-9) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return math.isclose(a, b, rel_tol=rel, abs_tol=1e-300)


def _simulate(root: Path, frames: int, seed: int) -> Path:
    assert main(["simulate", "--out", str(root), "--frames", str(frames), "--seed", str(seed)]) == 0
    return root / f"sim-seed{seed}.npz"


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """A 150-frame simulated drive (about 130 m: long enough for the KITTI drift) and its
    benchmark (as given): (data path, drive folder in the results, results.json's rows)."""
    root = tmp_path_factory.mktemp("score")
    data = _simulate(root / "data", 150, 5)
    out = root / "bench"
    assert main(["bench", str(data), "-e", BENCH_ESTIMATORS, "--model", "as-given", "-j", "1",
                 "-q", "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    (seq,) = results["sequences"]
    rows = {r["name"]: r for r in seq["estimators"]}
    return data, out / seq["name"], rows


def _score(argv, capsys=None) -> dict:
    """Run `vislam score` with --out into a fresh folder next to the trajectory; score.json."""
    traj = Path(argv[0])
    out = traj.parent / f"score-{len(list(traj.parent.glob('score-*')))}"
    assert main(["score", *argv, "--out", str(out), "-q"]) == 0
    assert (out / "score.md").is_file()
    return json.loads((out / "score.json").read_text())


def _fails(argv, capsys, *fragments, out=None) -> str:
    capsys.readouterr()  # what earlier commands wrote
    try:
        code = main(["score", *argv, *(["--out", str(out)] if out else []), "-q"])
    except SystemExit as exc:  # argparse's usage errors: one line too (eval.cli)
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for f in fragments:
        assert f in lines[0], lines[0]
    if out is not None:
        assert not Path(out).exists()
    return lines[0]


# --- reproducing the benchmark ---------------------------------------------------------------


@pytest.mark.parametrize("estimator", ["ekf-invariant", "dead-reckoning"])
def test_score_reproduces_the_benchmark(bench, estimator, capsys):
    data, folder, rows = bench
    result = _score([str(folder / f"{estimator}.tum"), "--data", str(data), "--cov",
                     str(folder / f"{estimator}.estimate.npz"), "--model", "as-given"])
    row, got = rows[estimator], result["scores"]
    assert row["rpe_trans_pct"] is not None and row["vs_smoother"]["ate_m"] is not None
    for k in FIGURES:
        assert _close(got[k], row[k]), (k, got[k], row[k])
    for k in VS_FIGURES:
        assert _close(got["vs_smoother"][k], row["vs_smoother"][k]), k
    assert result["association"]["associated_frames"] == 150
    assert result["covariance"]["frames_with_covariance"] == 150
    assert result["nees"] is None and result["reference"]["error"] is None
    # the reference's own row is the benchmark's smoother row
    (ref,) = [r for r in result["sequence"]["estimators"] if r["name"] == "smoother"]
    for k in FIGURES:
        assert _close(ref[k], rows["smoother"][k]), k


def test_score_prints_the_table_and_says_why_nees_is_null(bench, capsys):
    data, folder, _ = bench
    assert main(["score", str(folder / "ekf-invariant.tum"), "--data", str(data),
                 "--model", "as-given", "--no-reference"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("# vislam score") and "| ekf-invariant.tum |" in out
    assert "no --cov given" in out


@pytest.mark.regression
def test_score_with_the_identified_model_reproduces_the_benchmark(tmp_path):
    data = _simulate(tmp_path / "data", 60, 2)
    out = tmp_path / "bench"
    assert main(["bench", str(data), "-e", "ekf-invariant,smoother", "-j", "1", "-q",
                 "--out", str(out)]) == 0
    (seq,) = json.loads((out / "results.json").read_text())["sequences"]
    assert seq["model"]["mode"] == "identified"
    row = seq["estimators"][0]
    folder = out / seq["name"]
    result = _score([str(folder / "ekf-invariant.tum"), "--data", str(data), "--cov",
                     str(folder / "ekf-invariant.estimate.npz")])
    assert result["model"]["mode"] == "identified"
    assert result["model"]["model"] == seq["model"]["model"]
    for k in FIGURES:
        assert _close(result["scores"][k], row[k]), k
    for k in VS_FIGURES:
        assert _close(result["scores"]["vs_smoother"][k], row["vs_smoother"][k]), k


def test_own_tum_reads_back_within_1e_12(bench):
    _, folder, _ = bench
    est = Estimate.load_npz(folder / "ekf-invariant.estimate.npz")
    traj = read_trajectory(folder / "ekf-invariant.tum")
    np.testing.assert_array_equal(traj.times, est.timestamps)
    assert np.max(np.abs(traj.poses - est.poses)) < 1e-12


# --- other tools' files ----------------------------------------------------------------------


def _plain_scores(traj: str, data, *extra) -> dict:
    return _score([traj, "--data", str(data), "--model", "as-given", "--no-reference", *extra])


def test_evo_files_read_back_and_score_the_same(bench, tmp_path):
    from evo.core.trajectory import PosePath3D, PoseTrajectory3D
    from evo.tools import file_interface

    data, folder, _ = bench
    est = Estimate.load_npz(folder / "ekf-invariant.estimate.npz")
    tum, kitti = tmp_path / "evo.tum", tmp_path / "evo.kitti"
    file_interface.write_tum_trajectory_file(
        str(tum), PoseTrajectory3D(poses_se3=list(est.poses), timestamps=est.timestamps))
    file_interface.write_kitti_poses_file(str(kitti), PosePath3D(poses_se3=list(est.poses)))
    t = read_trajectory(tum)
    np.testing.assert_array_equal(t.times, est.timestamps)
    assert np.max(np.abs(t.poses - est.poses)) < 1e-12
    k = read_trajectory(kitti)
    assert k.times is None and np.max(np.abs(k.poses - est.poses)) < 1e-12
    want = _plain_scores(str(folder / "ekf-invariant.tum"), data)["scores"]
    for path in (tum, kitti):
        got = _plain_scores(str(path), data)["scores"]
        for key in ("ate_m", "ate_aligned_m", "rpe_trans_pct", "rpe_rot_deg_per_100m"):
            assert _close(got[key], want[key]), (path.name, key)
        assert got["nees_pose_mean"] is None
    # a KITTI file under another extension, with --format
    other = tmp_path / "poses.txt"
    other.write_bytes(kitti.read_bytes())
    got = _plain_scores(str(other), data, "--format", "kitti")["scores"]
    assert _close(got["ate_m"], want["ate_m"])


def test_euroc_round_trip_and_score(bench, tmp_path):
    data, folder, rows = bench
    est = Estimate.load_npz(folder / "ekf-invariant.estimate.npz")
    path = write_euroc(tmp_path / "traj.csv", est.timestamps, est.poses)
    assert path.read_text().startswith("#timestamp [ns]")
    times, poses, lines = read_euroc(path)
    assert np.max(np.abs(times - est.timestamps)) < 1e-9
    assert np.max(np.abs(poses - est.poses)) < 1e-12 and lines[0] == 2
    # OpenVINS-style extra columns are ignored
    extra = tmp_path / "extra.csv"
    extra.write_text("".join(line + ",0.1,0.2,0.3\n" if not line.startswith("#") else line + "\n"
                             for line in path.read_text().splitlines()))
    np.testing.assert_array_equal(read_euroc(extra)[1], poses)
    result = _score([str(path), "--data", str(data), "--model", "as-given", "--cov",
                     str(folder / "ekf-invariant.estimate.npz")])
    for k in FIGURES:
        assert _close(result["scores"][k], rows["ekf-invariant"][k], rel=1e-7), k


def test_covariance_files_of_each_kind_agree(bench, tmp_path):
    data, folder, rows = bench
    est = Estimate.load_npz(folder / "ekf-invariant.estimate.npz")
    npy, txt = tmp_path / "cov.npy", tmp_path / "cov.txt"
    np.save(npy, est.pose_cov)
    write_covariances_text(txt, est.timestamps, est.pose_cov)
    for path, kind in ((npy, "npy"), (txt, "text")):
        c = read_pose_covariances(path)
        assert c.kind == kind
        np.testing.assert_array_equal(c.cov, est.pose_cov)
        got = _plain_scores(str(folder / "ekf-invariant.tum"), data, "--cov", str(path))
        assert _close(got["scores"]["nees_pose_mean"], rows["ekf-invariant"]["nees_pose_mean"])


# --- association -----------------------------------------------------------------------------


def test_time_offset_jitter_and_max_diff(bench, tmp_path, capsys):
    data, folder, _ = bench
    est = Estimate.load_npz(folder / "ekf-invariant.estimate.npz")
    want = _plain_scores(str(folder / "ekf-invariant.tum"), data)["scores"]
    shifted = write_tum(tmp_path / "shifted.tum", est.timestamps + 1000.0, est.poses)
    _fails([str(shifted), "--data", str(data), "--model", "as-given", "--no-reference"], capsys,
           "0 of its 150 poses", "--t-max-diff 0.01", "--t-offset -1000")
    got = _plain_scores(str(shifted), data, "--t-offset", "-1000")
    assert got["association"]["associated_frames"] == 150
    for k in ("ate_m", "ate_aligned_m", "rpe_trans_pct"):
        assert _close(got["scores"][k], want[k]), k
    jitter = np.random.default_rng(0).uniform(-0.008, 0.008, est.n_frames)
    jittered = write_tum(tmp_path / "jittered.tum", est.timestamps + jitter, est.poses)
    got = _plain_scores(str(jittered), data)
    assert got["association"]["associated_frames"] == 150
    assert got["association"]["max_abs_diff_s"] <= 0.008 + 1e-9
    assert _close(got["scores"]["ate_aligned_m"], want["ate_aligned_m"])
    late = write_tum(tmp_path / "late.tum", est.timestamps + 0.02, est.poses)
    _fails([str(late), "--data", str(data), "--model", "as-given"], capsys,
           str(late), "--t-max-diff 0.01")
    got = _plain_scores(str(late), data, "--t-max-diff", "0.03")
    assert got["association"]["associated_frames"] == 150


def test_a_subsampled_trajectory_scores_on_its_frames(bench, tmp_path):
    from vislam.eval.consistency import ate_or_none
    from vislam.eval.drives import load_bench_sequence
    from vislam.eval.metrics import kitti_drift, nees, pose_errors

    data, folder, _ = bench
    est = Estimate.load_npz(folder / "ekf-invariant.estimate.npz")
    every = slice(0, None, 2)
    sub = write_tum(tmp_path / "half.tum", est.timestamps[every], est.poses[every])
    np.save(tmp_path / "half.npy", est.pose_cov[every])
    result = _score([str(sub), "--data", str(data), "--model", "as-given",
                     "--cov", str(tmp_path / "half.npy")])
    a = result["association"]
    assert a["associated_frames"] == 75 and a["first_frame"] == 0 and a["last_frame"] == 148
    # the benchmark's definitions on frames 0, 2, 4, ...
    gt = load_bench_sequence(Path(data)).gt
    g = np.asarray(gt.poses)[every]
    e = est.poses[every]
    got = result["scores"]
    assert _close(got["ate_m"], ate_or_none(e, g, None))
    assert _close(got["ate_aligned_m"], ate_or_none(e, g, "se3"))
    assert _close(got["rpe_trans_pct"], kitti_drift(e, g)["t_rel_pct"])
    values = nees(pose_errors(e, g), est.pose_cov[every])[1:]  # step 0 left out, as the benchmark does
    assert _close(got["nees_pose_mean"], float(np.mean(values)))
    assert got["vs_smoother"]["ate_aligned_m"] is not None


def test_match_times_keeps_the_nearest_pose_per_frame():
    frames = np.array([0.0, 0.1, 0.2, 0.3])
    f, r, _, dup = match_times(np.array([0.004, 0.099, 0.101, 0.5]), frames, 0.01)
    assert f.tolist() == [0, 1] and r.tolist() == [0, 1] and dup == 1
    f, r, _, _ = match_times(np.array([10.0, 10.2]), frames, 0.01, t_offset=-10.0)
    assert f.tolist() == [0, 2] and r.tolist() == [0, 1]


def test_kitti_needs_one_pose_per_frame(bench, tmp_path):
    _, folder, _ = bench
    est = Estimate.load_npz(folder / "ekf-invariant.estimate.npz")
    path = write_kitti(tmp_path / "short.kitti", est.poses[:-1])
    traj = read_trajectory(path)
    with pytest.raises(InputError, match="149 poses for the 150 frames"):
        associate(traj, est.timestamps)


# --- hostile input ---------------------------------------------------------------------------

_GOOD = "0.0 0 0 0 0 0 0 1\n"


def _hostile_cases():
    def tum(text):
        return ("traj.tum", text)

    return [
        ("missing file", None, ["does not exist"]),
        ("unparseable", tum(_GOOD + "0.1 0 0 0 0 0 zero 1\n"), ["line 2", "not a number", "'zero'"]),
        ("columns", tum(_GOOD + "0.1 0 0 0 0 0 1\n"), ["line 2 has 7 columns", "expected 8"]),
        ("zero quaternion", tum(_GOOD + "0.1 0 0 0 0 0 0 0\n"), ["line 2", "zero quaternion"]),
        ("non-unit quaternion", tum(_GOOD + "0.1 0 0 0 0 0 0 2\n"), ["line 2", "norm 2"]),
        ("not increasing", tum(_GOOD + "0.1 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 0 1\n"),
         ["line 3", "duplicates the one on line 2", "strictly increasing"]),
        ("nan", tum(_GOOD + "nan 0 0 0 0 0 0 1\n"), ["line 2", "not a finite number"]),
        ("empty", tum("# nothing\n"), ["no pose lines"]),
        ("kitti in a .txt", ("traj.txt", "1 0 0 0 0 1 0 0 0 0 1 0\n"), ["12 columns", "--format kitti"]),
        ("unknown extension", ("traj.dat", _GOOD), ["extension", "--format"]),
        ("not rigid", ("traj.kitti", "2 0 0 0 0 1 0 0 0 0 1 0\n"), ["line 1", "orthonormal"]),
        ("euroc columns", ("traj.csv", "#timestamp [ns],x\n1000,1,2,3\n"),
         ["line 2 has 4 columns", "at least 8"]),
        ("binary", ("traj.tum", b"\xff\xfe\x00binary"), ["not UTF-8"]),
        ("nothing associates", tum("1000.0 0 0 0 0 0 0 1\n1000.1 0 0 0 0 0 0 1\n"),
         ["0 of its 2 poses", "--t-max-diff"]),
    ]


@pytest.mark.parametrize("name, file, fragments", _hostile_cases(), ids=[c[0] for c in _hostile_cases()])
def test_hostile_trajectories_exit_2_with_one_line(bench, tmp_path, capsys, name, file, fragments):
    data, _, _ = bench
    if file is None:
        path = tmp_path / "absent.tum"
    else:
        path = tmp_path / file[0]
        content = file[1]
        (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
    _fails([str(path), "--data", str(data), "--model", "as-given"], capsys, *fragments,
           out=tmp_path / "out")


def _cov_cases(n):
    eye = np.tile(np.eye(6) * 1e-4, (n, 1, 1))
    asym = eye.copy()
    asym[3, 0, 1] = 1e-5
    neg = eye.copy()
    neg[4, 2, 2] = -1e-4
    nan = eye.copy()
    nan[5, 1, 1] = np.nan
    return [
        ("asymmetric", asym, ["entry 3", "not symmetric"]),
        ("not positive definite", neg, ["entry 4", "not positive definite"]),
        ("nan", nan, ["entry 5", "NaN"]),
        ("wrong shape", np.zeros((n, 3, 3)), ["(N, 6, 6)"]),
        ("wrong count", eye[:-1], [f"{n - 1} covariances for the {n} poses"]),
    ]


@pytest.mark.parametrize("case", range(5), ids=[c[0] for c in _cov_cases(10)])
def test_hostile_covariances_exit_2_with_one_line(bench, tmp_path, capsys, case):
    data, folder, _ = bench
    _, cov, fragments = _cov_cases(150)[case]
    path = tmp_path / "cov.npy"
    np.save(path, cov)
    _fails([str(folder / "ekf-invariant.tum"), "--data", str(data), "--cov", str(path),
            "--model", "as-given"], capsys, str(path), *fragments, out=tmp_path / "out")


def test_hostile_covariance_text_names_the_line(bench, tmp_path, capsys):
    data, folder, _ = bench
    path = tmp_path / "cov.txt"
    path.write_text("# t and 36 numbers\n0.0 " + " ".join(["1"] * 36) + "\n")
    _fails([str(folder / "ekf-invariant.tum"), "--data", str(data), "--cov", str(path)],
           capsys, "line 2", "not positive definite")
    path.write_text("0.0 1 2 3\n")
    _fails([str(folder / "ekf-invariant.tum"), "--data", str(data), "--cov", str(path)],
           capsys, "line 1 has 4 columns", "expected 37")
    path = tmp_path / "other.npz"
    np.savez(path, something=np.zeros(3))
    _fails([str(folder / "ekf-invariant.tum"), "--data", str(data), "--cov", str(path)],
           capsys, "pose_cov", "estimate file")


def test_bad_options_and_data_exit_2_with_one_line(bench, tmp_path, capsys):
    data, folder, _ = bench
    traj = str(folder / "ekf-invariant.tum")
    _fails([traj], capsys, "--data", "required")
    _fails([traj, "--data", str(tmp_path / "absent.npz")], capsys, "absent.npz")
    _fails([traj, "--data", str(tmp_path)], capsys, "is a folder")
    _fails([traj, "--data", str(data), "--t-max-diff", "-1"], capsys, "--t-max-diff")
    _fails([traj, "--data", str(data), "--t-offset", "nan"], capsys, "--t-offset")
    _fails([traj, "--data", str(data), "--format", "xyz"], capsys, "--format")


def test_out_never_replaces_a_users_files(bench, tmp_path, capsys):
    data, folder, _ = bench
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep")
    code = main(["score", str(folder / "ekf-invariant.tum"), "--data", str(data),
                 "--model", "as-given", "--out", str(out), "-q"])
    assert code == 2 and len(capsys.readouterr().err.strip().splitlines()) == 1
    assert [p.name for p in out.iterdir()] == ["notes.txt"]
