"""ekf-imu, the error-state EKF on the raw IMU (ekf/imu_ekf.py): consistency and accuracy on
short simulated drives (fast tier), its registration and commands, and its refusals. The
regression tier (tests/regression/test_imu_ekf_regression.py) pins the Monte Carlo and EuRoC."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from vislam.ekf.driver import run_filter
from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_inv, se3_log
from vislam.ekf.imu_ekf import ImuEkf
from vislam.eval.imu_sim import simulate_imu
from vislam.eval.imu_sim_config import ImuSimConfig
from vislam.graph.inertial_init import in_estimate_gauge


def pose_nees_in_gauge(est, truth) -> np.ndarray:
    """Pose NEES (T,) of an estimate against a simulation's truth moved into the estimate's
    frame-0 gauge (yaw and position), as vislam bench scores raw-IMU drives; NaN at frame 0."""
    gt = in_estimate_gauge(truth.frame_poses, est.poses[:1])
    out = np.full(est.n_frames, np.nan)
    for k in range(1, est.n_frames):
        xi = se3_log(se3_inv(est.poses[k]) @ gt[k])
        out[k] = xi @ np.linalg.solve(est.pose_cov[k], xi)
    return out


def aligned_ate(est, truth) -> float:
    from vislam.eval.metrics import ate_rmse

    return float(ate_rmse(est.poses, truth.frame_poses, "yaw"))


def test_stereo_room_drive_is_consistent():
    """Three runs of a 6 s stereo room drive (one scene, the noise redrawn): pose ANEES inside
    the two-sided 95 % bounds of 3 x 6 degrees of freedom, and accurate to a centimetre."""
    runs = 3
    nees, ates = [], []
    for seed in range(runs):
        drive, truth = simulate_imu(ImuSimConfig(camera="stereo", n_frames=121, n_landmarks=150,
                                                 scene_seed=5, seed=seed))
        est = run_filter(ImuEkf(), drive)
        nees.append(np.nanmean(pose_nees_in_gauge(est, truth)))
        ates.append(aligned_ate(est, truth))
    lo, hi = chi2.ppf([0.025, 0.975], 6 * runs) / runs
    assert lo < np.mean(nees) < hi, (nees, lo, hi)
    assert max(ates) < 0.01, ates


def test_mono_room_drive_is_consistent():
    """Three runs of a 6 s monocular room drive: the depth comes from the motion (the
    inverse-depth prior of a first observation covers 1 m to infinity); pose ANEES inside the
    95 % bounds (measured 3.2), accurate to about a centimetre."""
    runs = 3
    nees, ates = [], []
    for seed in range(runs):
        drive, truth = simulate_imu(ImuSimConfig(camera="mono", n_frames=121, n_landmarks=150,
                                                 scene_seed=5, seed=seed))
        est = run_filter(ImuEkf(), drive)
        nees.append(np.nanmean(pose_nees_in_gauge(est, truth)))
        ates.append(aligned_ate(est, truth))
        assert est.info["n_landmarks_started"] > 15
        assert est.info["most_anchor_clones"] > 0
        assert est.info["world_frame"] == "gravity-aligned, z up"
    lo, hi = chi2.ppf([0.025, 0.975], 6 * runs) / runs
    assert lo < np.mean(nees) < hi, (nees, lo, hi)
    assert max(ates) < 0.03, ates


def test_noise_free_drive_is_followed_exactly_enough():
    """Noise-free IMU and pixels: the estimate follows the truth to millimetres (stereo) and a
    couple of centimetres (mono: the depth prior's linearisation)."""
    for camera, bound in (("stereo", 2e-3), ("mono", 0.03)):
        drive, truth = simulate_imu(ImuSimConfig(camera=camera, n_frames=101, n_landmarks=150,
                                                 noise_free=True))
        est = run_filter(ImuEkf(), drive)
        assert aligned_ate(est, truth) < bound, camera


def test_registered_as_a_raw_imu_estimator():
    from vislam.eval.registry import (DEFAULT_BENCH_INERTIAL, INERTIAL_ESTIMATOR_NAMES,
                                      estimator_kind, resolve)

    assert "ekf-imu" in INERTIAL_ESTIMATOR_NAMES and "ekf-imu" in DEFAULT_BENCH_INERTIAL
    assert estimator_kind("ekf-imu") == "raw-imu"
    assert getattr(resolve("ekf-imu"), "filter_class", None) is ImuEkf


def test_vislam_run_on_a_simulated_drive(tmp_path):
    from vislam.eval.cli import main
    from vislam.eval.imu_sim_files import write_imu_simulation

    drive, truth = simulate_imu(ImuSimConfig(camera="mono", n_frames=61, n_landmarks=80,
                                             name="room"))
    path = write_imu_simulation(tmp_path / "drives", drive, truth)
    assert main(["run", "-e", "ekf-imu", "--out", str(tmp_path / "out"), "--quiet",
                 "--no-plots", str(path)]) == 0
    assert (tmp_path / "out" / "estimate.npz").is_file()
    import json
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics, "vislam run wrote no metrics"
    # vislam score takes its trajectory on the raw-IMU drive (yaw alignment, its gauge)
    assert main(["score", str(tmp_path / "out" / "trajectory.tum"), "--data", str(path),
                 "--out", str(tmp_path / "score"), "--quiet", "--no-reference"]) == 0
    scored = json.loads((tmp_path / "score" / "score.json").read_text())
    assert scored["alignment"] == "yaw"
    assert scored["scores"]["ate_aligned_m"] < 0.05


def test_refusals():
    with pytest.raises(InputError, match="linearisation"):
        ImuEkf(linearisation="fej")
    with pytest.raises(InputError, match="mature_ratio"):
        ImuEkf(mature_ratio=-1.0)
    seq = simulate_velocity_drive()  # a velocity drive
    with pytest.raises(InputError, match="raw-IMU drives"):
        run_filter(ImuEkf(), seq)
    import dataclasses

    drive, _ = simulate_imu(ImuSimConfig(n_frames=21, n_landmarks=10))
    distorted = dataclasses.replace(drive, calibration=dataclasses.replace(
        drive.calibration, distortion_model="radtan", distortion=(0.1, 0.0, 0.0, 0.0)))
    with pytest.raises(InputError, match="lens distortion"):
        run_filter(ImuEkf(), distorted)


def simulate_velocity_drive():
    from vislam.eval.sim_config import SimConfig
    from vislam.eval.simulate import simulate

    return simulate(SimConfig(n_frames=5)).sequence


def test_observability_constrained_option():
    """``linearisation="oc"``: every observation's Jacobian is blind to the four directions the
    covariance holds unobservable, and the filter follows a noise-free drive."""
    worst = []

    class Checked(ImuEkf):
        def _observability_constrained(self, rows, Hp, Hl):
            Hp, Hl = super()._observability_constrained(rows, Hp, Hl)
            k = rows.shape[0]
            N = np.concatenate([np.broadcast_to(self.N[0:3], (k, 3, 4)),
                                np.broadcast_to(self.N[6:9], (k, 3, 4)), self.N[rows]], axis=1)
            H = np.concatenate([Hp, Hl], axis=2)
            worst.append(np.abs(H @ N).max() / (np.abs(H).max() * np.abs(N).max()))
            return Hp, Hl

    drive, truth = simulate_imu(ImuSimConfig(camera="stereo", n_frames=81, n_landmarks=150,
                                             noise_free=True))
    est = run_filter(Checked(linearisation="oc"), drive)
    assert aligned_ate(est, truth) < 5e-3
    assert len(worst) > 50 and max(worst) < 1e-9
