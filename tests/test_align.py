"""Trajectory alignment before the aligned ATE: SE(3), Sim(3), yaw-only (4-dof) and none, in
eval.metrics and through every command that aligns (``--align``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vislam.ekf.errors import InputError
from vislam.ekf.estimate import Estimate
from vislam.ekf.geometry import se3_exp, so3_exp
from vislam.eval.cli import main
from vislam.eval.metrics import (
    ALIGN_MODES,
    align_trajectory,
    alignment_transform,
    ate_rmse,
    check_align_mode,
    umeyama,
    yaw_fit,
)
from tests.test_metrics import _random_drive


def _drive(rng, n=200, dt=0.1):
    """A smooth random 3-D drive (T, 4, 4): it climbs and banks a little, so its positions
    are not planar."""
    return _random_drive(rng, n, dt, vertical=0.5)


def _noisy(rng, gt, sigma_t=0.3, sigma_r=0.01):
    noise = np.concatenate([rng.normal(0, sigma_t, (gt.shape[0], 3)),
                            rng.normal(0, sigma_r, (gt.shape[0], 3))], axis=1)
    return gt @ se3_exp(np.cumsum(noise, axis=0) / np.sqrt(gt.shape[0]))


def _transform(R, t, s=1.0):
    """The 4x4 that maps world_T_imu poses: rotation R and translation t, positions scaled by s."""
    G = np.eye(4)
    G[:3, :3], G[:3, 3] = R, t
    return G, s


def _apply_inverse(G, s, gt):
    """An estimate ``est`` such that the alignment of ``est`` onto ``gt`` is (G, s):
    ``gt_pos = s R est_pos + t`` and ``gt_rot = R est_rot``."""
    R, t = G[:3, :3], G[:3, 3]
    est = gt.copy()
    est[:, :3, :3] = R.T @ gt[:, :3, :3]
    est[:, :3, 3] = (gt[:, :3, 3] - t) @ R / s
    return est


def _rz(theta):
    return so3_exp(np.array([0.0, 0.0, theta]))


# --- yaw alignment ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed,yaw", [(0, 0.7), (1, -2.9), (2, np.pi - 1e-9), (3, 0.0), (4, 1e-7)])
def test_yaw_alignment_recovers_a_known_yaw_and_translation_exactly(seed, yaw):
    rng = np.random.default_rng(seed)
    gt = _drive(rng)
    t = rng.normal(0, 50, 3)
    est = _apply_inverse(*_transform(_rz(yaw), t), gt)
    assert ate_rmse(est, gt) > 1.0 or yaw == 0.0
    theta, t_hat = yaw_fit(est[:, :3, 3], gt[:, :3, 3])
    assert np.angle(np.exp(1j * (theta - yaw))) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(t_hat, t, atol=1e-9)
    R, t2, s = alignment_transform(est, gt, "yaw")
    np.testing.assert_allclose(R, _rz(yaw), atol=1e-12)
    assert s == 1.0 and np.allclose(t2, t, atol=1e-9)
    assert ate_rmse(est, gt, align="yaw") < 1e-9
    np.testing.assert_allclose(align_trajectory(est, gt, "yaw"), gt, atol=1e-9)


def test_yaw_fit_is_the_least_squares_yaw():
    """The closed form against a brute-force search of the cost over the yaw."""
    rng = np.random.default_rng(11)
    gt = _drive(rng)
    est = _apply_inverse(*_transform(_rz(1.1) @ so3_exp(np.array([0.02, -0.03, 0.0])),
                                     np.array([3.0, -4.0, 2.0])), _noisy(rng, gt, sigma_t=2.0))
    src, dst = est[:, :3, 3], gt[:, :3, 3]
    theta, t = yaw_fit(src, dst)

    def cost(th):
        R = _rz(th)
        tt = dst.mean(axis=0) - R @ src.mean(axis=0)
        return np.sum((dst - src @ R.T - tt) ** 2)

    best = cost(theta)
    np.testing.assert_allclose(t, dst.mean(axis=0) - _rz(theta) @ src.mean(axis=0), atol=1e-12)
    grid = np.linspace(-np.pi, np.pi, 3601)
    assert best <= min(cost(th) for th in grid) + 1e-9
    for d in (1e-4, -1e-4):
        assert best < cost(theta + d)
    # rpg_trajectory_evaluation's get_best_yaw (C = data^T model, centred), modulo 2 pi.
    C = (src - src.mean(axis=0)).T @ (dst - dst.mean(axis=0))
    rpg = np.pi / 2 - np.arctan2(C[0, 0] + C[1, 1], C[0, 1] - C[1, 0])
    assert np.angle(np.exp(1j * (theta - rpg))) == pytest.approx(0.0, abs=1e-12)


def test_roll_and_pitch_are_not_removed_by_yaw_alignment_but_are_by_se3():
    rng = np.random.default_rng(3)
    gt = _drive(rng)
    tilt = so3_exp(np.array([0.08, -0.05, 0.0]))  # about 5 and 3 degrees: not about gravity
    est = _apply_inverse(*_transform(_rz(0.4) @ tilt, np.array([10.0, -5.0, 1.0])), gt)
    se3 = ate_rmse(est, gt, align="se3")
    yaw = ate_rmse(est, gt, align="yaw")
    assert se3 < 1e-9
    assert yaw > 1.0 and yaw > 1e6 * se3


@pytest.mark.parametrize("seed", range(6))
def test_yaw_is_never_better_than_se3_and_sim3_never_worse_than_se3(seed):
    rng = np.random.default_rng(seed)
    gt = _drive(rng)
    R = so3_exp(rng.normal(0, 0.5, 3))
    est = _apply_inverse(*_transform(R, rng.normal(0, 20, 3)), _noisy(rng, gt))
    none, yaw = ate_rmse(est, gt, align="none"), ate_rmse(est, gt, align="yaw")
    se3, sim3 = ate_rmse(est, gt, align="se3"), ate_rmse(est, gt, align="sim3")
    assert sim3 <= se3 + 1e-12 and se3 <= yaw + 1e-12 and yaw <= none + 1e-12


def test_yaw_equals_se3_when_the_misalignment_is_a_yaw():
    rng = np.random.default_rng(8)
    gt = _drive(rng)
    est = _apply_inverse(*_transform(_rz(-1.3), np.array([5.0, 7.0, -2.0])), gt)
    R_se3, t_se3, _ = alignment_transform(est, gt, "se3")
    R_yaw, t_yaw, _ = alignment_transform(est, gt, "yaw")
    np.testing.assert_allclose(R_se3, R_yaw, atol=1e-10)
    np.testing.assert_allclose(t_se3, t_yaw, atol=1e-8)
    np.testing.assert_allclose(align_trajectory(est, gt, "se3"), align_trajectory(est, gt, "yaw"),
                               atol=1e-8)
    assert ate_rmse(est, gt, align="yaw") == pytest.approx(ate_rmse(est, gt, align="se3"), abs=1e-9)


def test_yaw_alignment_of_degenerate_trajectories_is_defined():
    rng = np.random.default_rng(2)
    gt = _drive(rng, n=20)
    est = _apply_inverse(*_transform(_rz(0.5), np.array([1.0, 2.0, 3.0])), gt)
    # One pose: the translation alone fits it; the yaw is 0 (any yaw fits equally).
    theta, t = yaw_fit(est[:1, :3, 3], gt[:1, :3, 3])
    assert theta == 0.0 and np.all(np.isfinite(t))
    assert ate_rmse(est[:1], gt[:1], align="yaw") == pytest.approx(0.0, abs=1e-12)
    # All positions equal (a vehicle standing still): finite, the yaw 0, the error the spread.
    still = np.broadcast_to(est[:1], est.shape).copy()
    assert yaw_fit(still[:, :3, 3], gt[:, :3, 3])[0] == 0.0
    centred = gt[:, :3, 3] - gt[:, :3, 3].mean(axis=0)
    expected = np.sqrt(np.mean(np.sum(centred**2, axis=1)))
    assert ate_rmse(still, gt, align="yaw") == pytest.approx(expected, rel=1e-12)
    # Moving straight up only (no horizontal spread): the yaw is 0, no NaN.
    up = est.copy()
    up[:, :3, 3] = np.outer(np.arange(20.0), [0.0, 0.0, 1.0])
    assert np.isfinite(ate_rmse(up, gt, align="yaw"))
    # A straight line: collinear, so SE(3) is undetermined (an error), the yaw is not.
    line = gt.copy()
    line[:, :3, 3] = np.outer(np.arange(20.0), [3.0, 4.0, 0.0])
    moved = _apply_inverse(*_transform(_rz(0.9), np.array([1.0, -1.0, 0.5])), line)
    with pytest.raises(InputError, match="degenerate"):
        ate_rmse(moved, line, align="se3")
    assert ate_rmse(moved, line, align="yaw") < 1e-9
    # No poses, or non-finite ones: a clear error, never NaN.
    with pytest.raises(InputError, match="at least 1"):
        align_trajectory(est[:0], gt[:0], "yaw")
    bad = est.copy()
    bad[3, 0, 3] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        ate_rmse(bad, gt, align="yaw")


# --- sim3, none, se3 unchanged, invalid modes ------------------------------------------------


def test_sim3_recovers_scale_rotation_and_translation():
    rng = np.random.default_rng(4)
    gt = _drive(rng)
    R, t = so3_exp(np.array([0.3, -0.2, 1.0])), np.array([4.0, 5.0, -6.0])
    est = _apply_inverse(*_transform(R, t, s=1.7), gt)
    R_hat, t_hat, s_hat = alignment_transform(est, gt, "sim3")
    assert s_hat == pytest.approx(1.7, rel=1e-12)
    np.testing.assert_allclose(R_hat, R, atol=1e-12)
    np.testing.assert_allclose(t_hat, t, atol=1e-9)
    assert ate_rmse(est, gt, align="sim3") < 1e-9 < ate_rmse(est, gt, align="se3")


def test_none_is_the_identity():
    rng = np.random.default_rng(5)
    gt = _drive(rng)
    est = _noisy(rng, gt) @ se3_exp(np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]))
    out = align_trajectory(est, gt, "none")
    assert np.array_equal(out, est) and out is not est
    R, t, s = alignment_transform(est, gt, "none")
    assert np.array_equal(R, np.eye(3)) and not t.any() and s == 1.0
    assert ate_rmse(est, gt, align="none") == ate_rmse(est, gt)


def test_se3_and_sim3_are_unchanged():
    """The aligned poses are bit for bit what the Umeyama fit applied before the yaw mode."""
    rng = np.random.default_rng(6)
    gt = _drive(rng)
    est = _noisy(rng, gt) @ se3_exp(np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]))
    for mode in ("se3", "sim3"):
        R, t, s = umeyama(est[:, :3, 3], gt[:, :3, 3], with_scale=mode == "sim3")
        ref = est.copy()
        ref[:, :3, :3] = R @ est[:, :3, :3]
        ref[:, :3, 3] = s * est[:, :3, 3] @ R.T + t
        assert np.array_equal(align_trajectory(est, gt, mode), ref)


def test_se3_alignment_matches_evo():
    import evo.core.trajectory as evo_traj

    rng = np.random.default_rng(7)
    gt = _drive(rng)
    est = _noisy(rng, gt) @ se3_exp(np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]))
    traj = evo_traj.PosePath3D(poses_se3=list(est))
    traj.align(evo_traj.PosePath3D(poses_se3=list(gt)))
    np.testing.assert_allclose(align_trajectory(est, gt, "se3"), np.array(traj.poses_se3),
                               atol=1e-9)


def test_an_unknown_mode_is_an_input_error_naming_it_and_the_valid_ones():
    from vislam.eval.consistency import ate_or_none, versus_smoother
    from vislam.eval.bench_scores import trajectory_scores

    assert ALIGN_MODES == ("se3", "sim3", "yaw", "none")
    assert check_align_mode("yaw") == "yaw"
    rng = np.random.default_rng(1)
    gt = _drive(rng, n=20)
    e = Estimate.empty("test", np.arange(20) * 0.1, n_tracks=0)
    e.poses[:] = gt
    for call in (lambda: align_trajectory(gt, gt, "4dof"),
                 lambda: alignment_transform(gt, gt, "4dof"),
                 lambda: ate_rmse(gt, gt, align="4dof"),
                 lambda: ate_or_none(gt, gt, align="4dof"),  # not swallowed as "no value"
                 lambda: versus_smoother(e, e, align="4dof"),
                 lambda: trajectory_scores(e, None, align="4dof")):
        with pytest.raises(InputError, match=r"se3, sim3, yaw, none, got '4dof'"):
            call()


# --- through the scores and the commands -----------------------------------------------------


def test_scores_and_versus_smoother_use_the_alignment():
    from vislam.eval.drives import KnownTruth
    from vislam.eval.consistency import versus_smoother
    from vislam.eval.bench_scores import trajectory_scores

    rng = np.random.default_rng(9)
    gt = _drive(rng, n=60)
    e = Estimate.empty("test", np.arange(60) * 0.1, n_tracks=0)
    e.poses[:] = _apply_inverse(*_transform(_rz(0.3) @ so3_exp(np.array([0.05, 0.0, 0.0])),
                                            np.array([1.0, 2.0, 0.0])), _noisy(rng, gt))
    truth = KnownTruth(np.arange(60), gt)
    ref = Estimate.empty("ref", np.arange(60) * 0.1, n_tracks=0)
    ref.poses[:] = gt
    default = trajectory_scores(e, truth)
    assert default["alignment"] == "se3"
    assert default["ate_aligned_m"] == ate_rmse(e.poses, gt, align="se3")
    assert versus_smoother(e, ref)["ate_aligned_m"] == default["ate_aligned_m"]
    for mode in ALIGN_MODES:
        s = trajectory_scores(e, truth, align=mode)
        assert s["alignment"] == mode
        assert s["ate_aligned_m"] == pytest.approx(ate_rmse(e.poses, gt, align=mode), rel=1e-12)
        v = versus_smoother(e, ref, align=mode)
        assert v["ate_aligned_m"] == pytest.approx(s["ate_aligned_m"], rel=1e-12)
    assert trajectory_scores(e, truth, align="none")["ate_aligned_m"] == default["ate_m"]
    assert (trajectory_scores(e, truth, align="yaw")["ate_aligned_m"]
            > default["ate_aligned_m"])
    assert trajectory_scores(e, None, align="yaw")["alignment"] == "yaw"


def test_bench_align_yaw_records_the_alignment(tmp_path):
    from vislam.eval.drives import simulated_sequence
    from vislam.eval.bench_scores import trajectory_scores

    out = tmp_path / "bench"
    names = ["dead-reckoning", "ekf-invariant"]
    assert main(["bench", "--frames", "60", "-q", "-j", "1", "-e", ",".join(names),
                 "--align", "yaw", "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["alignment"] == "yaw" and "yaw" in results["alignment_definition"]
    assert json.loads((out / "settings.json").read_text())["alignment"] == "yaw"
    summary = (out / "summary.md").read_text()
    assert "ATE al.: the ATE after yaw-only 4-dof alignment" in summary
    assert "SE(3)" not in summary
    (seq,) = results["sequences"]
    bs = simulated_sequence(seed=0, frames=60)
    for r in seq["estimators"]:
        assert r["error"] is None and r["ate_aligned_m"] is not None
        est = Estimate.load_npz(out / seq["name"] / f"{r['name']}.estimate.npz")
        assert r["ate_aligned_m"] == pytest.approx(
            trajectory_scores(est, bs.gt, align="yaw")["ate_aligned_m"], rel=1e-9)
        assert r["ate_aligned_m"] >= trajectory_scores(est, bs.gt)["ate_aligned_m"] - 1e-12
        assert r["ate_aligned_m"] <= r["ate_m"] + 1e-12


def test_bench_rejects_an_unknown_alignment(tmp_path, capsys):
    out = tmp_path / "o"
    with pytest.raises(SystemExit) as info:
        main(["bench", "--frames", "60", "-q", "-e", "dead-reckoning", "--align", "4dof",
              "--out", str(out)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "--align" in err and "yaw" in err and not out.exists()


@pytest.fixture(scope="module")
def sim_file(tmp_path_factory):
    from vislam.eval.simulate import SimConfig, simulate, write_simulation

    folder = tmp_path_factory.mktemp("sim")
    paths = write_simulation(simulate(SimConfig(seed=4, n_frames=60, name="short")), folder)
    return paths["data"]


def test_run_align_none_gives_the_raw_ate(sim_file, tmp_path, capsys):
    out = tmp_path / "none"
    assert main(["run", str(sim_file), "-e", "dead-reckoning", "--align", "none", "--out",
                 str(out), "-q", "--no-plots"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["alignment"] == "none" and m["ate_m"] is not None
    assert m["ate_aligned_m"] == m["ate_m"]
    assert json.loads((out / "settings.json").read_text())["alignment"] == "none"
    assert "aligned, none" in capsys.readouterr().out
    default = tmp_path / "default"
    assert main(["run", str(sim_file), "-e", "dead-reckoning", "--out", str(default), "-q",
                 "--no-plots"]) == 0
    d = json.loads((default / "metrics.json").read_text())
    assert d["alignment"] == "se3" and d["ate_aligned_m"] < d["ate_m"]
