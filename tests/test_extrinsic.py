"""Issue 12: the camera-IMU extrinsic identified as a parameter of the stereo factors
(graph.extrinsic): its theta Jacobian and lever-arm covariance against finite differences,
its convention against the simulator's file-extrinsic offset, and its recovery by
identify_model on simulated drives with a wrong extrinsic in the file (known truth)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from vislam.ekf.config import FilterConfig
from vislam.ekf.geometry import se3_inv, so3_exp, so3_log
from vislam.ekf.model import EXTRINSIC_COMPONENTS
from vislam.eval.simulate import KITTI_CAM_T_IMU, SimConfig, simulate
from vislam.graph.extrinsic import (
    PRIOR_SIGMA,
    UNDETERMINED_SIGMA,
    extrinsic_step,
    lever_arm,
    lever_arm_covariance,
    linear_system,
    perturb_cam_T_imu,
    rotation_excitation_sigma,
    theta_between,
)
from vislam.graph.factors import stereo_residuals
from vislam.graph.identification import identify_model
from vislam.graph.settings import SmootherSettings
from vislam.graph.smoother import solve_smoother
from tests.numdiff import numeric_jacobian

#: A wrong extrinsic in the file: several cm and several mrad off the true one.
OFFSET = (0.05, -0.04, 0.03, 0.004, -0.003, 0.005)
SETTINGS = SmootherSettings(compute_marginals=False)
#: Robust weights 1 (Huber threshold far above every residual) and plain between-factors, so
#: that GTSAM's whitened linearisation is the plain derivative of the whitened residuals.
PLAIN = SmootherSettings(compute_marginals=False, huber_k=1e6, gyro_bias="off")


def true_theta(identified: np.ndarray, true: np.ndarray) -> np.ndarray:
    """theta = [dt; r] with ``true = perturb_cam_T_imu(identified, theta)``, written out here
    (not graph.extrinsic.theta_between) so that the check does not rest on the code it checks."""
    dt = true[:3, 3] - identified[:3, 3]
    r = so3_log(true[:3, :3] @ identified[:3, :3].T)
    return np.r_[dt, r]


def random_rigid(rng, translation=1.5) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = so3_exp(rng.uniform(-np.pi, np.pi, 3) / np.sqrt(3.0))
    T[:3, 3] = rng.uniform(-translation, translation, 3)
    return T


# --- the parameter's convention ------------------------------------------------------------
def test_perturbation_round_trips_and_composes_on_the_left():
    rng = np.random.default_rng(0)
    for C in (KITTI_CAM_T_IMU, random_rigid(rng)):
        np.testing.assert_array_equal(perturb_cam_T_imu(C, np.zeros(6)), C)
        tol = 1e-12 if C is not KITTI_CAM_T_IMU else 1e-6  # KITTI's: orthonormal to ~1e-7
        for _ in range(5):
            theta = np.r_[rng.normal(0.0, 0.3, 3), rng.normal(0.0, 0.3, 3)]
            P = perturb_cam_T_imu(C, theta)
            # rigid, translation moved by dt, rotation turned by exp(r) on the left
            # (KITTI's matrix is orthonormal to about 1e-7 only: the turn keeps its Gram matrix)
            np.testing.assert_allclose(P[:3, :3].T @ P[:3, :3], C[:3, :3].T @ C[:3, :3], atol=1e-12)
            np.testing.assert_array_equal(P[3], [0.0, 0.0, 0.0, 1.0])
            np.testing.assert_allclose(P[:3, 3], C[:3, 3] + theta[:3], atol=1e-15)
            np.testing.assert_allclose(P[:3, :3], so3_exp(theta[3:]) @ C[:3, :3], atol=1e-14)
            np.testing.assert_allclose(true_theta(C, P), theta, atol=tol)
            np.testing.assert_allclose(theta_between(C, P), theta, atol=tol)
            np.testing.assert_allclose(perturb_cam_T_imu(P, -theta), C, atol=1e-12)


@pytest.mark.parametrize("fault", ["none", "kitti"])
def test_simulator_file_offset_is_a_perturbation_of_the_true_extrinsic(fault):
    offset = np.array(OFFSET)
    drive = simulate(SimConfig(seed=1, n_frames=3, file_extrinsic_fault=fault,
                               file_extrinsic_offset=tuple(offset)))
    true = drive.cam_T_imu
    np.testing.assert_array_equal(true, KITTI_CAM_T_IMU)
    faulted = true.copy()
    if fault == "kitti":  # imu_T_cam's translation where cam_T_imu's belongs
        faulted[:3, 3] = se3_inv(true)[:3, 3]
        np.testing.assert_allclose(faulted[:3, 3], lever_arm(true), atol=1e-15)
    file_T = drive.sequence.calibration.cam_T_imu
    np.testing.assert_allclose(file_T, perturb_cam_T_imu(faulted, offset), atol=1e-15)
    # so the truth, in theta coordinates around the file's, is known exactly
    np.testing.assert_allclose(true_theta(file_T, faulted), -offset, atol=1e-12)
    # and a file without an offset or fault holds the true extrinsic
    clean = simulate(SimConfig(seed=1, n_frames=3))
    np.testing.assert_array_equal(clean.sequence.calibration.cam_T_imu, clean.cam_T_imu)


# --- the lever arm ---------------------------------------------------------------------------
def _lever_arm_jacobian(C):
    return numeric_jacobian(lambda th: lever_arm(perturb_cam_T_imu(C, th)), np.zeros(6))


@pytest.mark.parametrize("which", ["kitti", "kitti-fault", "random"])
def test_lever_arm_covariance_is_the_first_order_propagation(which):
    rng = np.random.default_rng({"kitti": 1, "kitti-fault": 2, "random": 3}[which])
    C = KITTI_CAM_T_IMU.copy()
    if which == "kitti-fault":
        C[:3, 3] = lever_arm(KITTI_CAM_T_IMU)
    elif which == "random":
        C = random_rigid(rng, translation=3.0)
    np.testing.assert_allclose(lever_arm(C), -C[:3, :3].T @ C[:3, 3], atol=1e-14)
    np.testing.assert_allclose(lever_arm(C), np.linalg.inv(C)[:3, 3], atol=1e-6)
    G = _lever_arm_jacobian(C)
    for _ in range(3):
        M = rng.normal(size=(6, 6)) * np.r_[0.05, 0.05, 0.05, 0.003, 0.003, 0.003][:, None]
        cov = M @ M.T
        expected = G @ cov @ G.T
        np.testing.assert_allclose(lever_arm_covariance(C, cov), expected,
                                   rtol=0.0, atol=1e-6 * np.abs(expected).max())
    # Monte Carlo: small perturbations (cm, mrad) scatter the lever arm as predicted.
    L = np.linalg.cholesky(np.diag(np.r_[0.02, 0.01, 0.03, 0.002, 0.004, 0.001] ** 2))
    cov = L @ L.T
    samples = (L @ rng.standard_normal((6, 20000))).T
    arms = np.array([lever_arm(perturb_cam_T_imu(C, th)) for th in samples])
    predicted = lever_arm_covariance(C, cov)
    Lp = np.linalg.cholesky(predicted)
    white = np.linalg.solve(Lp, np.linalg.solve(Lp, np.cov(arms.T)).T)  # Lp^-1 S Lp^-T
    np.testing.assert_allclose(white, np.eye(3), atol=0.05)
    np.testing.assert_allclose(arms.mean(axis=0), lever_arm(C), atol=5e-3)


def _excitation_by_rows(rates, velocity_sigma, C):
    """The translation's covariance the hard way: one least-squares row block per interval,
    the camera moving by ``[w dt]x l`` beyond the measured point (``dt`` cancels against the
    velocity noise's ``sigma dt``), mapped to theta by finite differences of the lever arm."""
    J = np.vstack([np.cross(w, np.eye(3)).T / velocity_sigma[:, None] for w in rates])
    info = J.T @ J + np.diag(1.0 / PRIOR_SIGMA[:3] ** 2)
    G = _lever_arm_jacobian(C)[:, :3]  # d lever arm / d theta translation
    Gi = np.linalg.inv(G)
    return Gi @ np.linalg.inv(info) @ Gi.T


@pytest.mark.parametrize("which", ["kitti", "random"])
def test_rotation_excitation_is_the_lever_arms_least_squares_information(which):
    """Noise-free rates, no noise margin: the bound equals the least-squares covariance of
    the lever arm from rows [w]x l, taken to theta's translation (camera frame)."""
    rng = np.random.default_rng(7)
    C = KITTI_CAM_T_IMU.copy() if which == "kitti" else random_rigid(rng, translation=2.0)
    rates = rng.normal(size=(200, 3)) * np.array([0.02, 0.05, 0.3])
    sv = np.array([0.1, 0.05, 0.2])
    expected = np.sqrt(np.diag(_excitation_by_rows(rates, sv, C)))
    got = rotation_excitation_sigma(rates, 0.0, sv, C, z=0.0)
    np.testing.assert_allclose(got, expected, rtol=1e-6)


def test_a_drive_that_only_yaws_cannot_place_its_lever_arm_along_the_yaw_axis():
    """Rates about x and y that are the gyro's noise (a planar drive): the lever arm along z
    has no information beyond the weak prior, whatever the noise happens to give; the other
    two are placed to a decimetre. Real roll and pitch rates (twice the noise) place it."""
    rng = np.random.default_rng(3)
    n, sg, sv = 1500, 0.03, 0.15
    yaw = 0.5 * np.sin(np.linspace(0.0, 40.0, n))
    C = KITTI_CAM_T_IMU  # camera y is the IMU's -z
    for seed in range(5):
        noise = np.random.default_rng(seed).normal(scale=sg, size=(n, 3))
        planar = np.column_stack([np.zeros(n), np.zeros(n), yaw]) + noise
        sd = rotation_excitation_sigma(planar, sg, sv, C)
        assert sd[1] > UNDETERMINED_SIGMA[1] and sd[1] == pytest.approx(PRIOR_SIGMA[1], rel=1e-3), sd
        assert np.all(sd[[0, 2]] < 0.15), sd
    # without the noise margin the noise's own energy counts as rotation: the bound would
    # then place the vertical lever arm, as the profile at the estimate did
    assert rotation_excitation_sigma(planar, 0.0, sv, C)[1] < UNDETERMINED_SIGMA[1]
    tilting = planar + np.column_stack([2 * sg * rng.standard_normal((n, 2)), np.zeros(n)])
    assert np.all(rotation_excitation_sigma(tilting, sg, sv, C) < 0.15)


# --- the theta Jacobian and the profile covariance, on a short drive ---------------------------
@pytest.fixture(scope="module")
def short_solution():
    drive = simulate(SimConfig(seed=3, n_frames=60, file_extrinsic_offset=OFFSET))
    config = FilterConfig()
    solution = solve_smoother(drive.sequence, config, PLAIN)
    return drive, config, solution


def _whitening(config):
    return np.array([1.0, 1.0, np.sqrt(2.0)]) / config.pixel_sigma


def test_theta_jacobian_matches_finite_differences_of_the_whitened_stereo_residuals(short_solution):
    drive, config, solution = short_solution
    C = np.array(solution.calibration.cam_T_imu)
    np.testing.assert_array_equal(C, drive.sequence.calibration.cam_T_imu)  # the file's
    assert not np.allclose(C, drive.cam_T_imu)  # ... which is wrong
    system = linear_system(solution, C)
    rows, w = solution.problem.rows, _whitening(config)
    N = len(rows)
    assert N > 1000
    assert system.A_t.shape == (3 * N, 6)
    assert system.stereo.stop - system.stereo.start == 3 * N

    def whitened(theta):
        calib = dataclasses.replace(solution.calibration, cam_T_imu=perturb_cam_T_imu(C, theta))
        res, _ = stereo_residuals(solution.poses, solution.landmarks, calib, rows)
        return (res * w).ravel()

    # b of the stereo rows is the whitened residual (measured - predicted) / sigma ...
    b = system.b[system.stereo]
    np.testing.assert_allclose(b, whitened(np.zeros(6)), atol=1e-4)
    assert np.abs(b).max() > 1.0  # real residuals, not a trivial zero
    # ... so d b / d theta = -A_t.
    J = numeric_jacobian(whitened, np.zeros(6), eps=1e-6)
    scale = np.abs(system.A_t).max()
    assert scale > 100.0
    diff = np.abs(-J - system.A_t)
    assert diff.max() < 1e-5 * scale, (diff.max(), scale)
    for i in range(6):  # every column, also the small translation ones
        col = np.linalg.norm(system.A_t[:, i])
        assert col > 1.0
        assert np.linalg.norm(-J[:, i] - system.A_t[:, i]) < 1e-5 * col, EXTRINSIC_COMPONENTS[i]


def test_profile_covariance_is_the_theta_block_of_the_joint_inverse(short_solution):
    _, _, solution = short_solution
    C = np.array(solution.calibration.cam_T_imu)
    system = linear_system(solution, C)
    step = extrinsic_step(solution, C, None)
    A_theta = np.zeros((system.A.shape[0], 6))
    A_theta[system.stereo] = system.A_t
    J = sp.hstack([system.A, sp.csr_matrix(A_theta)]).tocsr()  # [A_x A_theta], every factor
    H = (J.T @ J).toarray()
    H[-6:, -6:] += np.diag(1.0 / PRIOR_SIGMA ** 2)
    block = np.linalg.solve(H, np.eye(H.shape[0])[:, -6:])[-6:]
    s = np.sqrt(np.diag(block))  # compared as correlations: the dense inverse is ill-conditioned
    np.testing.assert_allclose(step.sigma, s, rtol=1e-6)
    np.testing.assert_allclose(step.covariance / np.outer(s, s), block / np.outer(s, s), atol=1e-5)
    np.testing.assert_allclose(step.covariance, step.covariance.T, atol=0.0)
    assert np.all(np.linalg.eigvalsh(step.information) > -1e-6 * np.abs(step.information).max())
    np.testing.assert_array_equal(step.determined, step.sigma <= UNDETERMINED_SIGMA)
    assert np.all(step.step[~step.determined] == 0.0)


# --- recovery on simulated drives with known truth (the "Done when") --------------------
def identified(seed, velocity_sigma, gyro_sigma, frames=450, fault="none", offset=OFFSET,
               pairing="next", pairings=("next",), **kwargs):
    drive = simulate(SimConfig(seed=seed, n_frames=frames, velocity_sigma=velocity_sigma,
                               gyro_sigma=gyro_sigma, velocity_pairing=pairing,
                               file_extrinsic_fault=fault, file_extrinsic_offset=offset))
    fit = identify_model(drive.sequence, FilterConfig(), SETTINGS, pairings=pairings, **kwargs)
    return drive, fit


def check_recovered(drive, fit, max_rotation_mrad=None, max_horizontal_cm=None):
    """The true extrinsic within 3 reported sigmas on every determined component; the
    undetermined ones named, with sigma inf, at the file's value; optionally the rotation error
    and the horizontal (IMU x, y) lever-arm error bounded."""
    true, file_T, C = drive.cam_T_imu, drive.sequence.calibration.cam_T_imu, fit.cam_T_imu
    np.testing.assert_array_equal(fit.file_cam_T_imu, file_T)
    assert fit.cam_T_imu_cov is not None and fit.cam_T_imu_cov.shape == (6, 6)
    # turned on the left from the file's: the same Gram matrix (KITTI's is orthonormal to 1e-7)
    np.testing.assert_allclose(C[:3, :3].T @ C[:3, :3], file_T[:3, :3].T @ file_T[:3, :3],
                               atol=1e-9)
    sigma = fit.cam_T_imu_sigma
    undetermined = fit.cam_T_imu_undetermined
    assert set(undetermined) <= set(EXTRINSIC_COMPONENTS)
    und = np.array([n in undetermined for n in EXTRINSIC_COMPONENTS])
    np.testing.assert_array_equal(np.isinf(sigma), und)
    assert np.all(sigma[~und] <= UNDETERMINED_SIGMA[~und])
    assert (~und).any()
    # the file's value kept for the undetermined components
    kept = true_theta(file_T, C)
    for i in np.flatnonzero(und):
        assert abs(kept[i]) <= (0.0 if i < 3 else 1e-4), (EXTRINSIC_COMPONENTS[i], kept[i])
    if und[:3].any():
        np.testing.assert_array_equal(C[:3, 3][und[:3]], file_T[:3, 3][und[:3]])
    # the truth within 3 sigma on the determined ones
    theta = true_theta(C, true)
    z = theta / sigma
    report = {n: round(float(v), 2) for n, v, d in zip(EXTRINSIC_COMPONENTS, z, ~und) if d}
    assert np.all(np.abs(z[~und]) <= 3.0), f"true extrinsic in sigmas: {report}"
    if max_rotation_mrad is not None:
        rotation = 1e3 * np.linalg.norm(theta[3:])
        assert rotation <= max_rotation_mrad, f"rotation error {rotation:.2f} mrad, z {report}"
    if max_horizontal_cm is not None:
        horizontal = 100.0 * np.linalg.norm((lever_arm(C) - lever_arm(true))[:2])
        assert horizontal <= max_horizontal_cm, f"horizontal lever-arm error {horizontal:.2f} cm"
    # the model written carries the same
    model = fit.to_model("test")
    np.testing.assert_array_equal(model.cam_T_imu, C)
    np.testing.assert_array_equal(model.file["cam_T_imu"], file_T)
    assert set(model.cam_T_imu_undetermined) == set(undetermined)
    np.testing.assert_array_equal(model.extrinsic_sigmas(), sigma)


# 450 frames (45 s of driving): on 300, the rotation about the optical axis (rz) is known to
# only 2-8 mrad at 0.05 m/s (a true-noise sweep of seeds 1-20), short of the 5 mrad figure
# for reasons of information, not of the estimator.
@pytest.mark.regression
@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_wrong_file_extrinsic_recovered_at_five_centimetres_per_second(seed):
    drive, fit = identified(seed, 0.05, 0.005)
    # several cm and mrad are far outside what this drive allows: the file's is refuted
    assert fit.extrinsic_test["decision"].startswith("identified"), fit.extrinsic_test
    check_recovered(drive, fit, max_rotation_mrad=5.0, max_horizontal_cm=10.0)


@pytest.mark.regression
@pytest.mark.slow
def test_kitti_lever_arm_mix_up_recovered_with_the_pairing_identified():
    # The shared data's fault, imu_T_cam's translation (2 m off) stored as cam_T_imu's, plus
    # the offset; the velocity pairing is left to the data as well (FilterConfig's "mean" first).
    drive, fit = identified(3, 0.05, 0.005, fault="kitti", pairings=("current", "next", "mean"))
    assert fit.pairing == "next", fit.pairing_scores
    assert fit.extrinsic_test["decision"].startswith("identified"), fit.extrinsic_test
    check_recovered(drive, fit, max_rotation_mrad=5.0, max_horizontal_cm=10.0)


@pytest.mark.regression
@pytest.mark.slow
@pytest.mark.parametrize("seed, fault", [(1, "none"), (2, "kitti")])
def test_true_extrinsic_within_three_sigma_at_half_a_metre_per_second(seed, fault):
    drive, fit = identified(seed, 0.5, 0.05, fault=fault)
    check_recovered(drive, fit)


def test_without_the_extrinsic_the_files_is_kept():
    drive, fit = identified(1, 0.5, 0.05, frames=80, extrinsic=False)
    np.testing.assert_array_equal(fit.cam_T_imu, drive.sequence.calibration.cam_T_imu)
    np.testing.assert_array_equal(fit.file_cam_T_imu, drive.sequence.calibration.cam_T_imu)
    assert fit.cam_T_imu_cov is None
    assert fit.cam_T_imu_sigma is None
    assert fit.cam_T_imu_undetermined == ()
    assert fit.extrinsic_test == {}
    model = fit.to_model("test")
    assert model.cam_T_imu_sigma is None
    np.testing.assert_array_equal(model.cam_T_imu, drive.sequence.calibration.cam_T_imu)


@pytest.mark.regression
@pytest.mark.slow
@pytest.mark.parametrize("frames, seed", [(80, 0), (150, 3), (300, 1)])
def test_short_default_drives_keep_their_true_extrinsic(frames, seed):
    """The three drives of a 12-drive sweep (80, 150, 300 frames; seeds 0-3) on which the 99 %
    chi-square refuted the file's true extrinsic (Wald 26.9, 16.7, 25.9): vislam bench then ran
    every estimator 3 sigma off the truth (pose NEES ~6000 at 80 frames). BIC keeps it."""
    from vislam.eval.drives import collect_sequences, identify_models

    (bs,) = collect_sequences([], frames=frames, seed=seed)
    (out,) = identify_models([bs], FilterConfig(), SmootherSettings())
    test = out.model["identification"]["extrinsic_test"]
    assert test["decision"].startswith("file's kept"), test
    assert test["statistic"] > test["chi2_threshold"]  # what the chi-square test refuted
    np.testing.assert_array_equal(out.sequence.calibration.cam_T_imu,
                                  bs.sequence.calibration.cam_T_imu)


def test_calibrate_says_when_the_drives_rotation_is_why_a_lever_arm_is_undetermined():
    """The report's extrinsic line names the components the drive's rotation cannot place
    (graph.extrinsic.rotation_excitation_sigma) and says why; nothing is added where the
    rotation is not the reason, or where it was not checked."""
    from types import SimpleNamespace

    from vislam.eval.commands.calibrate import _rotation_reason

    planar = SimpleNamespace(cam_T_imu_undetermined=("ty",), extrinsic_test={
        "translation_sigma_from_rotation": [0.09, 10.0, 0.08]})
    text = _rotation_reason(planar)
    assert "ty within 10 m" in text and "tx" not in text and "rotation" in text
    by_vision = SimpleNamespace(cam_T_imu_undetermined=("ty",), extrinsic_test={
        "translation_sigma_from_rotation": [0.09, 0.02, 0.08]})
    assert _rotation_reason(by_vision) == ""
    unchecked = SimpleNamespace(cam_T_imu_undetermined=("ty",), extrinsic_test={})
    assert _rotation_reason(unchecked) == ""
