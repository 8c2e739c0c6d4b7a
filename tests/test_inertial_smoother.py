"""The raw-IMU smoother (graph.inertial_*): conventions both ways, preintegration against exact
integration, the rest detector, and a tiny synthetic drive recovered within its sigmas."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vislam.ekf.conventions import estimate_cov_to_gtsam, gtsam_cov_to_estimate
from vislam.ekf.errors import EstimationError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import se3_exp, se3_inv
from vislam.ekf.inertial import ImuNoise, InertialCalibration, InertialDrive
from vislam.ekf.sequence import Observations
from vislam.eval.metrics import pose_errors
from vislam.graph.inertial_conventions import (
    from_gtsam_bias,
    from_nav_state,
    gtsam_bias_cov_to_vislam,
    nav_cov_to_vislam,
    nav_state,
    to_gtsam_bias,
    vislam_bias_cov_to_gtsam,
    vislam_cov_to_nav,
)
from vislam.graph.inertial_factors import interval_pieces, preintegrate, preintegration_params
from vislam.graph.inertial_init import (
    RestDetector,
    detect_rest,
    gravity_aligned_rotation,
    to_gravity_world,
)
from vislam.graph.inertial_smoother import InertialSmootherSettings, build_problem, smooth

G = 9.81


def _pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return se3_exp(rng.normal(size=6))


def _spd(n: int, seed: int) -> np.ndarray:
    A = np.random.default_rng(seed).normal(size=(n, n))
    return A @ A.T + n * np.eye(n)


# --- conventions ---------------------------------------------------------------------------
def test_nav_state_both_ways():
    T, v = _pose(1), np.array([0.3, -1.2, 2.0])
    state = nav_state(T, v)
    np.testing.assert_allclose(state.pose().matrix(), T, atol=1e-12)
    np.testing.assert_allclose(state.velocity(), v)
    T2, v2 = from_nav_state(state)
    np.testing.assert_allclose(T2, T, atol=1e-12)
    np.testing.assert_allclose(v2, v)


def test_nav_tangent_map_matches_gtsam_retract_to_first_order():
    T, v = _pose(2), np.array([1.0, 2.0, -0.5])
    state = nav_state(T, v)
    d = 1e-6 * np.random.default_rng(3).normal(size=9)  # [dphi; dp; dv], GTSAM's NavState tangent
    T_new, v_new = from_nav_state(state.retract(d))
    xi = pose_errors(T[None], T_new[None])[0]  # [rho; phi]: T_new = T exp(xi)
    P = np.diag(np.arange(1.0, 10.0))
    J = nav_cov_to_vislam(T, np.eye(9))  # J J^T; recover J from the map itself:
    from vislam.graph.inertial_conventions import nav_tangent_to_vislam

    mapped = nav_tangent_to_vislam(T) @ d
    np.testing.assert_allclose(mapped[:6], xi, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(mapped[6:], v_new - v, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(vislam_cov_to_nav(T, nav_cov_to_vislam(T, P)), P, atol=1e-12)
    np.testing.assert_allclose(J, J.T, atol=1e-12)


def test_bias_both_ways_gyro_first():
    b = np.array([0.01, -0.02, 0.03, 0.1, 0.2, -0.3])  # [gyro; accel]
    g = to_gtsam_bias(b)
    np.testing.assert_allclose(g.gyroscope(), b[:3])
    np.testing.assert_allclose(g.accelerometer(), b[3:])
    np.testing.assert_allclose(from_gtsam_bias(g), b)
    P = _spd(6, 4)
    np.testing.assert_allclose(vislam_bias_cov_to_gtsam(gtsam_bias_cov_to_vislam(P)), P)
    # GTSAM's bias vector is [accel; gyro]: its covariance's gyro block lands first in vislam's
    np.testing.assert_allclose(gtsam_bias_cov_to_vislam(P)[:3, :3], P[3:, 3:])


def test_pose_covariance_both_ways():
    P = _spd(6, 5)
    np.testing.assert_allclose(gtsam_cov_to_estimate(estimate_cov_to_gtsam(P)), P)


# --- preintegration against exact integration ----------------------------------------------
def _exact_case(omega_z: float, a_z: float, v0: np.ndarray, yaw0: float, t0: float, t1: float):
    """Rotation about world z at a constant rate with a constant vertical acceleration: the body
    z axis stays vertical, so the specific force [0, 0, g + a_z] and the rate [0, 0, w] are
    constant in the IMU frame, and the motion is known exactly."""
    t = np.arange(0.0, 2.0, 0.005)
    imu = ImuSamples(t, np.tile([0.0, 0.0, G + a_z], (t.size, 1)), np.tile([0.0, 0.0, omega_z], (t.size, 1)))
    R0 = Rotation.from_rotvec([0, 0, yaw0]).as_matrix()
    dt = t1 - t0
    R1 = Rotation.from_rotvec([0, 0, yaw0 + omega_z * dt]).as_matrix()
    p1 = v0 * dt + 0.5 * np.array([0, 0, a_z]) * dt ** 2
    v1 = v0 + np.array([0, 0, a_z]) * dt
    return imu, R0, R1, p1, v1


@pytest.mark.parametrize("t0,t1", [(0.1, 0.15), (0.1013, 0.2527), (0.0, 1.0)])
def test_preintegration_reproduces_exact_motion(t0, t1):
    v0 = np.array([0.4, -0.2, 0.1])
    imu, R0, R1, p1, v1 = _exact_case(0.7, 1.3, v0, 0.4, t0, t1)
    noise = ImuNoise(1e-4, 1e-5, 1e-3, 1e-3)
    pim = preintegrate(imu, t0, t1, preintegration_params(noise, G), gtsam.imuBias.ConstantBias())
    assert pim.deltaTij() == pytest.approx(t1 - t0, abs=1e-12)
    start = gtsam.NavState(gtsam.Rot3(R0), np.zeros(3), v0)
    end = pim.predict(start, gtsam.imuBias.ConstantBias())
    np.testing.assert_allclose(end.attitude().matrix(), R1, atol=1e-9)
    np.testing.assert_allclose(end.position(), p1, atol=1e-9)
    np.testing.assert_allclose(end.velocity(), v1, atol=1e-9)


def test_interval_pieces_hold_each_sample_until_the_next_as_the_strapdown_does():
    t = np.array([0.0, 0.1, 0.2, 0.3])
    gyro = np.array([[0, 0, 0.0], [0, 0, 1.0], [0, 0, 2.0], [0, 0, 3.0]])
    imu = ImuSamples(t, np.zeros((4, 3)), gyro)
    _, w, dt = interval_pieces(imu, 0.05, 0.25)
    np.testing.assert_allclose(dt, [0.05, 0.1, 0.05])
    np.testing.assert_allclose(w[:, 2], [0.0, 1.0, 2.0])  # the sample at or before each piece
    _, w, dt = interval_pieces(imu, 0.1, 0.3)  # interval ends on samples
    np.testing.assert_allclose(dt, [0.1, 0.1])
    np.testing.assert_allclose(w[:, 2], [1.0, 2.0])
    _, w, dt = interval_pieces(imu, 0.25, 0.4)  # past the last sample: it is held
    np.testing.assert_allclose(dt, [0.05, 0.1])
    np.testing.assert_allclose(w[:, 2], [2.0, 3.0])
    with pytest.raises(EstimationError, match="no IMU sample at or before"):
        interval_pieces(imu, -0.1, 0.1)


def test_preintegration_and_strapdown_agree_on_a_simulated_drive():
    """The smoother's preintegrated interval and the filters' strapdown integrate the same
    signal (one rule for the samples): the same state at the next frame to 1e-9."""
    from vislam.ekf.strapdown import NavState, integrate
    from vislam.eval.imu_sim import simulate_imu
    from vislam.eval.imu_sim_config import ImuSimConfig

    drive, truth = simulate_imu(ImuSimConfig(n_frames=81, seed=4))
    k0, k1 = 50, 51
    t0, t1 = drive.timestamps[k0], drive.timestamps[k1]
    R0, p0 = truth.frame_poses[k0][:3, :3], truth.frame_poses[k0][:3, 3]
    v0 = truth.frame_velocity[k0]
    g = drive.calibration.gravity
    pim = preintegrate(drive.imu, t0, t1, preintegration_params(drive.calibration.noise, g),
                       gtsam.imuBias.ConstantBias())
    end = pim.predict(gtsam.NavState(gtsam.Rot3(R0), p0, v0), gtsam.imuBias.ConstantBias())
    mine, _ = integrate(NavState(R0, v0, p0, np.zeros(3), np.zeros(3)), None, drive.imu, t0, t1,
                        np.array([0.0, 0.0, -g]))
    np.testing.assert_allclose(end.attitude().matrix(), mine.R, atol=1e-9)
    np.testing.assert_allclose(end.velocity(), mine.v, atol=1e-9)
    np.testing.assert_allclose(end.position(), mine.p, atol=1e-9)


def test_preintegration_noise_is_the_continuous_density_squared():
    noise = ImuNoise(2e-4, 3e-5, 4e-3, 5e-3)
    p = preintegration_params(noise, G, inflation=2.0)
    np.testing.assert_allclose(p.getGyroscopeCovariance(), (2 * 2e-4) ** 2 * np.eye(3))
    np.testing.assert_allclose(p.getAccelerometerCovariance(), (2 * 4e-3) ** 2 * np.eye(3))
    np.testing.assert_allclose(p.getBiasOmegaCovariance(), (2 * 3e-5) ** 2 * np.eye(3))
    np.testing.assert_allclose(p.getBiasAccCovariance(), (2 * 5e-3) ** 2 * np.eye(3))


# --- initialisation ------------------------------------------------------------------------
def _rest_then_turn(rest_s: float, seed: int = 0, vibration: float = 0.5) -> ImuSamples:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, rest_s + 2.0, 0.005)
    up = np.array([0.3, 0.1, 0.95])
    up /= np.linalg.norm(up)
    accel = G * up + vibration * rng.normal(size=(t.size, 3))
    gyro = np.array([0.002, -0.003, 0.001]) + 0.002 * rng.normal(size=(t.size, 3))
    moving = t > rest_s
    gyro[moving, 2] += 0.5
    accel[moving, 0] += 1.0
    return ImuSamples(t, accel, gyro)


def test_rest_detector_finds_the_rest_despite_vibration():
    rest = detect_rest(_rest_then_turn(1.5), RestDetector(margin_blocks=0))
    assert rest is not None
    assert rest.t_start == 0.0 and 1.35 <= rest.t_end <= 1.5
    margin = detect_rest(_rest_then_turn(1.5))  # the last 0.4 s of the run left out
    assert margin.t_start == 0.0 and 0.95 <= margin.t_end <= 1.1
    np.testing.assert_allclose(margin.gyro_mean, [0.002, -0.003, 0.001], atol=5e-4)
    np.testing.assert_allclose(rest.gyro_mean, [0.002, -0.003, 0.001], atol=5e-4)
    np.testing.assert_allclose(rest.up, np.array([0.3, 0.1, 0.95]) / np.linalg.norm([0.3, 0.1, 0.95]), atol=1e-2)


def test_a_slow_start_is_not_taken_for_rest():
    """A simulated car eases away at 2.0 s: its 0.1 s means stay inside the tolerances until
    about 2.4 s, when it already moves at 0.04-0.05 m/s; the margin ends the rest before the car
    moves (zero velocity there would be wrong)."""
    from vislam.eval.imu_sim import simulate_imu
    from vislam.eval.imu_sim_config import ImuSimConfig

    for seed in (3, 4):
        drive, truth = simulate_imu(ImuSimConfig(scenario="road", n_frames=61, seed=seed))
        assert detect_rest(drive.imu, RestDetector(margin_blocks=0)).t_end > truth.motion_start_s + 0.2
        assert detect_rest(drive.imu).t_end <= truth.motion_start_s


def test_no_rest_means_no_initialisation():
    assert detect_rest(_rest_then_turn(0.2)) is None
    assert detect_rest(_rest_then_turn(1.5), RestDetector(min_rest_s=3.0)) is None


def test_gravity_aligned_rotation_takes_up_to_z_by_the_least_rotation():
    up = np.array([0.9, 0.1, -0.4])
    R = gravity_aligned_rotation(up)
    np.testing.assert_allclose(R @ (up / np.linalg.norm(up)), [0, 0, 1], atol=1e-12)
    axis = Rotation.from_matrix(R).as_rotvec()
    assert abs(axis @ up) < 1e-12 and abs(axis[2]) < 1e-12  # about an axis normal to both
    np.testing.assert_allclose(gravity_aligned_rotation([0, 0, 2.0]), np.eye(3))
    np.testing.assert_allclose(gravity_aligned_rotation([0, 0, -1.0]) @ [0, 0, -1.0], [0, 0, 1], atol=1e-12)


def test_to_gravity_world_keeps_gravity_and_starts_at_the_origin():
    yaw = Rotation.from_rotvec([0, 0, 1.1]).as_matrix()
    tilt = Rotation.from_rotvec([0.2, -0.1, 0]).as_matrix()
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, :3, :3] = yaw @ tilt
    poses[:, :3, 3] = [[5, 6, 7], [5, 6, 8], [6, 6, 8]]
    out = to_gravity_world(poses)
    np.testing.assert_allclose(out[0, :3, 3], 0, atol=1e-12)
    np.testing.assert_allclose(out[1, :3, 3], [0, 0, 1], atol=1e-12)  # height stays height
    up_imu = out[0, :3, :3].T @ [0, 0, 1]
    np.testing.assert_allclose(up_imu, (yaw @ tilt).T @ [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(out[0, :3, :3], gravity_aligned_rotation(up_imu), atol=1e-12)


# --- a tiny synthetic drive ----------------------------------------------------------------
def _smooth_step(t, start):
    """``(b, b', b'')`` of ``b = (1 - cos(s))^2 / 4``, ``s = t - start`` (0 before): C^2, zero at rest."""
    s = np.clip(t - start, 0.0, None)
    on = t > start
    b = (1 - np.cos(s)) ** 2 / 4
    db = np.where(on, (1 - np.cos(s)) * np.sin(s) / 2, 0.0)
    ddb = np.where(on, (np.sin(s) ** 2 + (1 - np.cos(s)) * np.cos(s)) / 2, 0.0)
    return b, db, ddb


def synthetic_drive(seed: int = 0, duration: float = 4.0, rest_s: float = 1.0, n_lm: int = 300
                    ) -> tuple[InertialDrive, np.ndarray]:
    """A rig at rest for ``rest_s``, then turning about the vertical and moving on a smooth
    curve in a ring of landmarks: 200 Hz IMU with white noise, 20 Hz monocular tracks with
    0.5 px noise. Returns the drive and the true ``world_T_imu`` at its frames."""
    rng = np.random.default_rng(seed)
    noise = ImuNoise(2e-4, 2e-5, 2e-3, 3e-3)
    tilt = Rotation.from_rotvec([0.05, -0.03, 0.0]).as_matrix()
    amp = np.array([1.0, 0.6, 0.3])
    yaw_amp = 1.2

    def state(t):
        b, db, ddb = _smooth_step(t, rest_s)
        p = b[:, None] * amp
        a = ddb[:, None] * amp
        yaw, yaw_rate = yaw_amp * b, yaw_amp * db
        R = Rotation.from_rotvec(np.outer(yaw, [0, 0, 1])).as_matrix() @ tilt
        return R, p, a, yaw_rate

    t_imu = np.arange(0.0, duration + 1e-9, 0.005)
    R, p, a, yaw_rate = state(t_imu)
    f_world = a + np.array([0, 0, G])
    accel = np.einsum("nji,nj->ni", R, f_world)  # R^T f
    gyro = (tilt.T @ np.array([0, 0, 1.0]))[None] * yaw_rate[:, None]
    accel += noise.accel_noise_density / np.sqrt(0.005) * rng.normal(size=accel.shape)
    gyro += noise.gyro_noise_density / np.sqrt(0.005) * rng.normal(size=gyro.shape)
    frames = np.arange(0.0, duration + 1e-9, 0.05)
    Rf, pf, _, _ = state(frames)
    poses = np.tile(np.eye(4), (frames.size, 1, 1))
    poses[:, :3, :3], poses[:, :3, 3] = Rf, pf
    # camera looking along the IMU's x axis
    cam_R_imu = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0.0]])
    cam_T_imu = np.eye(4)
    cam_T_imu[:3, :3], cam_T_imu[:3, 3] = cam_R_imu, [0.02, -0.01, 0.03]
    K = np.array([[400.0, 0, 320], [0, 400, 240], [0, 0, 1]])
    angle = rng.uniform(-np.pi, np.pi, n_lm)
    landmarks = np.stack([4 * np.cos(angle), 4 * np.sin(angle), rng.uniform(-1.5, 1.5, n_lm)], axis=1)
    rows_f, rows_j, rows_z = [], [], []
    for k, T in enumerate(poses):
        cam_T_world = cam_T_imu @ se3_inv(T)
        q = landmarks @ cam_T_world[:3, :3].T + cam_T_world[:3, 3]
        uv = (q[:, :2] / q[:, 2:3]) * 400 + [320, 240]
        seen = (q[:, 2] > 0.2) & (uv[:, 0] > 0) & (uv[:, 0] < 640) & (uv[:, 1] > 0) & (uv[:, 1] < 480)
        for j in np.flatnonzero(seen):
            rows_f.append(k)
            rows_j.append(j)
            rows_z.append(uv[j] + 0.5 * rng.normal(size=2))
    frame, track, z = np.array(rows_f), np.array(rows_j), np.array(rows_z)
    order = np.lexsort((track, frame))
    ptr = np.zeros(frames.size + 1, dtype=np.int64)
    np.cumsum(np.bincount(frame, minlength=frames.size), out=ptr[1:])
    obs = Observations(ptr, track[order].astype(np.int64), z[order])
    calib = InertialCalibration(K, cam_T_imu, noise, gravity=G)
    drive = InertialDrive("synthetic", frames, ImuSamples(t_imu, accel, gyro), obs, n_lm, calib)
    return drive, poses


@pytest.fixture(scope="module")
def synthetic_result():
    drive, truth = synthetic_drive(duration=3.0, n_lm=150)
    return drive, to_gravity_world(truth), smooth(drive)


def test_smoother_recovers_a_synthetic_drive_within_its_sigmas(synthetic_result):
    drive, truth, result = synthetic_result
    est = result.estimate
    assert est.poses.shape == (drive.n_frames, 4, 4)
    err = pose_errors(est.poses, truth)
    sigma = np.sqrt(np.diagonal(est.pose_cov, axis1=1, axis2=2))
    assert np.all(np.isfinite(sigma))
    z = np.abs(err) / sigma
    assert np.mean(z < 3.0) > 0.95, np.max(z, axis=0)
    assert np.linalg.norm(err[:, :3], axis=1).max() < 0.05
    assert result.info["n_landmarks"] > 30


def test_smoother_states_velocity_and_bias(synthetic_result):
    drive, truth, result = synthetic_result
    s = result.states
    assert s.velocity.shape == (drive.n_frames, 3) and s.bias.shape == (drive.n_frames, 6)
    np.testing.assert_allclose(s.velocity[:10], 0.0, atol=0.02)  # the rest
    assert np.all(np.isfinite(s.velocity_cov)) and np.all(np.isfinite(s.bias_cov))
    assert np.all(np.abs(s.bias[:, :3]) < 5 * np.sqrt(np.diagonal(s.bias_cov, axis1=1, axis2=2))[:, :3] + 1e-3)


def test_a_drive_without_rest_cannot_be_initialised():
    drive, _ = synthetic_drive(duration=3.0, rest_s=0.1)
    with pytest.raises(EstimationError, match="cannot be initialised"):
        build_problem(drive)


def test_one_pass_marginals_equal_gtsam_marginals():
    """graph.inertial_marginals against gtsam.Marginals key by key on a short drive."""
    import gtsam
    from gtsam.symbol_shorthand import B, L, V, X

    from vislam.graph.inertial_marginals import frame_marginals
    from vislam.graph.inertial_smoother import _graph, batch_solve, incremental_solve

    drive, _ = synthetic_drive(seed=1, duration=2.0, n_lm=60)
    problem = build_problem(drive, InertialSmootherSettings(pixel_sigma=0.5))
    sol = batch_solve(problem, incremental_solve(problem))
    graph = _graph(problem, sol.rows, sol.anchors, robust=False)
    fm = frame_marginals(graph, sol.values, drive.n_frames, sol.tracks)
    P, Pl = fm.P, fm.Pl
    m = gtsam.Marginals(graph, sol.values)
    for k in range(0, drive.n_frames - 1, 7):
        keys = gtsam.KeyVector([X(k), V(k), B(k), X(k + 1), V(k + 1), B(k + 1)])
        ref = m.jointMarginalCovariance(keys).fullMatrix()
        # two factorisations of one information matrix: they agree to rounding, which is
        # about 1e-12 of the block's largest entry (3.7e-15 against 2.5e-3 in one CI run)
        tol = 1e-10 * np.abs(ref).max()
        np.testing.assert_allclose(P[k], ref[:15, :15], rtol=1e-6, atol=tol)
        np.testing.assert_allclose(fm.P_next[k], ref[:15, 15:], rtol=1e-6, atol=tol)
    for i in range(0, sol.tracks.size, 5):
        ref = m.marginalCovariance(L(int(sol.tracks[i])))
        np.testing.assert_allclose(Pl[i], ref, rtol=1e-6, atol=1e-12)


def test_one_pass_marginals_do_not_depend_on_the_border_pieces():
    """The dense border computed in pieces of landmark columns and frames (to bound its memory
    on long drives) gives the blocks of the border solved at once to 1e-9, and the landmarks'
    blocks are gtsam.Marginals' (a 4 s simulated room drive: 162 landmarks)."""
    import gtsam
    from gtsam.symbol_shorthand import L

    from vislam.eval.imu_sim import simulate_imu
    from vislam.eval.imu_sim_config import ImuSimConfig
    from vislam.graph.inertial_marginals import frame_marginals
    from vislam.graph.inertial_smoother import _graph, batch_solve, incremental_solve

    drive, _ = simulate_imu(ImuSimConfig(n_frames=81))
    problem = build_problem(drive, InertialSmootherSettings(pixel_sigma=1.0))
    sol = batch_solve(problem, incremental_solve(problem))
    graph = _graph(problem, sol.rows, sol.anchors, robust=False)
    whole = frame_marginals(graph, sol.values, drive.n_frames, sol.tracks, 10 ** 6, 10 ** 6)
    pieces = frame_marginals(graph, sol.values, drive.n_frames, sol.tracks, 7, 3)
    assert whole.Pl.shape[0] > 100
    for a, b in ((whole.P, pieces.P), (whole.P_next, pieces.P_next), (whole.Pl, pieces.Pl)):
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-9 * np.abs(a).max())
    m = gtsam.Marginals(graph, sol.values)
    for i in range(0, sol.tracks.size, 40):
        np.testing.assert_allclose(pieces.Pl[i], m.marginalCovariance(L(int(sol.tracks[i]))),
                                   rtol=1e-6, atol=1e-12)


def test_pixel_sigma_identified_from_the_residuals(synthetic_result):
    """The synthetic tracks carry 0.5 px noise per axis; the smoother's identified sigma (its
    default) finds it within the sampling spread of a few thousand residuals."""
    _, _, result = synthetic_result
    assert result.info["pixel_sigma_identified"]
    assert 0.45 < result.info["pixel_sigma"] < 0.56, result.info["pixel_sigma"]
    # the IMU's white noise is simulated at its data-sheet density, its biases constant:
    # EM's scale on the IMU covariance comes out near 1, below it (no random walk)
    assert 0.3 < result.info["imu_noise_em_scale"] < 1.3, result.info


def test_identify_pixel_sigma_counts_the_parameters():
    from vislam.graph.inertial_smoother import identify_pixel_sigma

    r = np.full(100, np.sqrt(2.0))  # |r|^2 = 2: one px^2 per axis
    assert identify_pixel_sigma(r, 0, 0) == pytest.approx(1.0)
    assert identify_pixel_sigma(r, 10, 5) == pytest.approx(np.sqrt(200 / (200 - 30 - 30)))
    with pytest.raises(EstimationError, match="cannot identify"):
        identify_pixel_sigma(r, 50, 10)


def test_in_estimate_gauge_matches_yaw_and_position_at_frame_0():
    from vislam.graph.inertial_init import in_estimate_gauge

    rng = np.random.default_rng(3)
    truth = np.stack([se3_exp(rng.normal(size=6)) for _ in range(5)])
    move = np.eye(4)
    move[:3, :3] = Rotation.from_rotvec([0, 0, 0.7]).as_matrix()
    move[:3, 3] = [1.0, -2.0, 0.5]
    est = move @ truth
    np.testing.assert_allclose(in_estimate_gauge(truth, est), est, atol=1e-9)
    # a tilt difference at frame 0 stays: only yaw and position are matched
    tilted = est.copy()
    tilted[0, :3, :3] = Rotation.from_rotvec([0.01, 0, 0]).as_matrix() @ est[0, :3, :3]
    w = Rotation.from_matrix(in_estimate_gauge(truth, tilted)[0, :3, :3] @ tilted[0, :3, :3].T).as_rotvec()
    assert abs(w[2]) < 1e-6 and abs(w[0]) == pytest.approx(0.01, rel=1e-3)


def test_an_indeterminate_cholesky_pass_is_run_again_with_qr(monkeypatch, synthetic_result):
    """GTSAM's Cholesky stopped every 201-frame simulated car drive (four seeds) with an
    indeterminate system; the incremental pass is then repeated with QR, and says so."""
    import vislam.graph.inertial_smoother as ism

    drive, _ = synthetic_drive(duration=3.0, n_lm=150)
    solve = ism.incremental_solve
    used = []

    def flaky(problem):
        used.append(problem.settings.isam_factorization)
        if problem.settings.isam_factorization == "cholesky":
            raise EstimationError("smoother-imu failed while adding frame 9 (iSAM2) near pose "
                                  "x3: the linear system is indeterminate (an under-constrained "
                                  "or degenerate variable)")
        return solve(problem)

    monkeypatch.setattr(ism, "incremental_solve", flaky)
    result = smooth(drive)
    assert used == ["cholesky", "qr"]
    assert result.estimate.info["isam_factorization"].startswith("qr (cholesky failed: ")
    assert synthetic_result[2].estimate.info["isam_factorization"] == "cholesky"
    # another failure is not retried
    monkeypatch.setattr(ism, "incremental_solve",
                        lambda problem: (_ for _ in ()).throw(EstimationError("something else")))
    with pytest.raises(EstimationError, match="something else"):
        smooth(drive)


def test_stereo_tracks_give_stereo_factors_and_a_consistent_estimate():
    """A stereo drive: a GenericStereoFactor3D per observation ([uL, uR, v], v the rows' mean,
    sigma / sqrt(2) on it), landmarks triangulated from the left pixels, the pixel sigma
    identified over 3 dimensions; the estimate within its sigmas."""
    import vislam.graph.inertial_smoother as ism
    from vislam.eval.groundtruth import GroundTruth
    from vislam.eval.imu_sim import simulate_imu
    from vislam.eval.imu_sim_config import ImuSimConfig
    from vislam.eval.inertial_truth import frame0_gauge
    from vislam.eval.metrics import nees

    drive, truth = simulate_imu(ImuSimConfig(camera="stereo", n_frames=71, seed=1))
    problem = build_problem(drive)
    assert problem.stereo is not None and problem.stereo.baseline() == pytest.approx(drive.calibration.baseline)
    z = drive.obs.z[0]
    factor = problem.projection(z, 0, int(drive.obs.track[0]), robust=False)
    assert isinstance(factor, gtsam.GenericStereoFactor3D)
    measured = factor.measured()
    np.testing.assert_allclose([measured.uL(), measured.uR(), measured.v()],
                               [z[0], z[2], 0.5 * (z[1] + z[3])])
    np.testing.assert_allclose(problem.pixel_noise.sigmas(), problem.pixel_sigma * np.array([1, 1, np.sqrt(0.5)]))
    with pytest.raises(EstimationError, match="cannot identify"):
        ism.identify_pixel_sigma(np.ones(10), 10, 1, dims=3)  # 30 - 30 - 6 < 0
    result = smooth(drive)
    est = result.estimate
    assert result.info["n_landmarks"] > 50
    assert 0.8 < result.info["pixel_sigma"] < 1.2  # simulated at 1 px
    gt = frame0_gauge(GroundTruth(np.arange(drive.n_frames), truth.frame_poses, source="sim"), est.poses[0])
    err = pose_errors(est.poses, gt.poses)[1:]
    assert np.mean(nees(err, est.pose_cov[1:])) < 14.45  # one drive's 95 % band
    assert np.linalg.norm(err[:, :3], axis=1).max() < 0.02
