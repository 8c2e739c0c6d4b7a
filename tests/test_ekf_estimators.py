"""The EKF estimators end to end on simulated drives (and, when present, on the shared 0027)."""

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.estimators import ESTIMATORS
from vislam.ekf.joint import JointState
from vislam.ekf.stereo_update import StereoModel
from vislam.eval.simulate import SimConfig, simulate

CORE_MODES = ["dead-reckoning", "mapping", "ekf-decoupled", "ekf-joint"]
SLAM_MODES = ["ekf-decoupled", "ekf-joint"]
BASE = FilterConfig(clean_tracks=False, velocity_pairing="mean")


def _ate(est, poses):
    return float(np.sqrt(np.mean(np.sum((est.positions - poses[:, :3, 3]) ** 2, axis=1))))


@pytest.fixture(scope="module")
def clean_sim():
    return simulate(SimConfig(seed=3, n_frames=150, noise_free=True))


@pytest.fixture(scope="module")
def noisy_sim():
    return simulate(SimConfig(seed=4, n_frames=300, gyro_bias=(0.005, -0.005, 0.008)))


@pytest.mark.parametrize("mode", CORE_MODES)
def test_noise_free_recovers_truth(clean_sim, mode):
    seq = clean_sim.sequence
    frames = []
    est = ESTIMATORS[mode](seq, BASE, progress=frames.append)
    assert frames[-1] == seq.n_frames
    assert est.estimator == mode
    assert est.poses.shape == (seq.n_frames, 4, 4)
    assert np.all(np.isfinite(est.pose_cov))
    assert _ate(est, clean_sim.poses) < 0.01
    assert est.step_time_s.shape == (seq.n_frames,) and np.all(est.step_time_s > 0)
    if mode != "dead-reckoning":
        has = est.has_landmark
        assert has.sum() > 0.9 * seq.n_tracks
        err = np.linalg.norm(est.landmarks[has] - clean_sim.landmarks[has], axis=1)
        assert np.max(err) < 0.01
        assert est.n_initialised.sum() == has.sum()
        assert np.all(np.linalg.eigvalsh(est.landmark_cov[has]) > 0)
    if mode in SLAM_MODES:
        assert est.n_updates.sum() > 0
        assert est.n_rejected.sum() == 0  # noise-free: nothing gated away


@pytest.mark.regression
def test_noisy_slam_beats_dead_reckoning(noisy_sim):
    seq = noisy_sim.sequence
    dr = _ate(ESTIMATORS["dead-reckoning"](seq, BASE), noisy_sim.poses)
    dec = _ate(ESTIMATORS["ekf-decoupled"](seq, BASE), noisy_sim.poses)
    from vislam.ekf.decoupled import run_decoupled

    assert _ate(run_decoupled(seq, BASE, as_written=True), noisy_sim.poses) < dr
    joint = _ate(ESTIMATORS["ekf-joint"](seq, BASE), noisy_sim.poses)
    bias = _ate(ESTIMATORS["ekf-joint"](seq, BASE.replace(gyro_bias=True)), noisy_sim.poses)
    assert dec < dr and joint < dr and bias < dr
    assert joint < dec


def test_marginalisation_is_exact(noisy_sim):
    """Deleting ended tracks from the state gives the same poses as keeping them (the kept
    landmarks go on being refined through their correlation with the pose, so only their
    presence is compared)."""
    from vislam.ekf.sequence import Observations, Sequence

    full = noisy_sim.sequence
    n = 60
    a, b = full.obs.frame_ptr[0], full.obs.frame_ptr[n]
    obs = Observations(full.obs.frame_ptr[: n + 1], full.obs.track[a:b], full.obs.z[a:b])
    seq = Sequence(
        name="short",
        timestamps=full.timestamps[:n],
        linear_velocity=full.linear_velocity[:n],
        angular_velocity=full.angular_velocity[:n],
        obs=obs,
        n_tracks=full.n_tracks,
        calibration=full.calibration,
    )
    for param in ("inverse-depth", "euclidean"):
        cfg = BASE.replace(landmark_parameterisation=param)
        marg = ESTIMATORS["ekf-joint"](seq, cfg)
        kept = ESTIMATORS["ekf-joint"](seq, cfg.replace(keep_landmarks=True))
        np.testing.assert_allclose(marg.poses, kept.poses, atol=1e-9)
        np.testing.assert_allclose(marg.pose_cov, kept.pose_cov, atol=1e-12)
        has = marg.has_landmark
        np.testing.assert_array_equal(has, kept.has_landmark)
    # Refinement after a track ends can only shrink a landmark's covariance (in world
    # coordinates only for Euclidean landmarks: an inverse-depth one's world covariance is
    # first order at its latest estimate).
    shrink = np.trace(kept.landmark_cov[has], axis1=1, axis2=2)
    assert np.all(shrink <= np.trace(marg.landmark_cov[has], axis1=1, axis2=2) * (1 + 1e-9))
    assert kept.info["max_state_dim"] > marg.info["max_state_dim"]


def _head(seq, n):
    """The first ``n`` frames of ``seq``."""
    from vislam.ekf.sequence import Observations, Sequence

    a, b = seq.obs.frame_ptr[0], seq.obs.frame_ptr[n]
    obs = Observations(seq.obs.frame_ptr[: n + 1], seq.obs.track[a:b], seq.obs.z[a:b])
    return Sequence(name="short", timestamps=seq.timestamps[:n], linear_velocity=seq.linear_velocity[:n],
                    angular_velocity=seq.angular_velocity[:n], obs=obs, n_tracks=seq.n_tracks,
                    calibration=seq.calibration)


@pytest.mark.parametrize(
    "param, linearisation, bias",
    [("inverse-depth", "oc", True)] + [pytest.param(*p, marks=pytest.mark.regression) for p in (  # ~2.5 s each
     ("inverse-depth", "fej", False), ("inverse-depth", "standard", True),
     ("euclidean", "oc", False), ("euclidean", "fej", True), ("euclidean", "standard", False))],
)
def test_keep_landmarks_equals_the_dense_textbook_update(noisy_sim, param, linearisation, bias):
    """``keep_landmarks`` through :class:`ekf.kept_landmarks.KeptLandmarks` (regressions of the
    retired landmarks on the active state) gives the numbers of the dense joint covariance
    (``textbook=True``) to 1e-9: poses, pose covariances, every landmark's mean and covariance,
    after every track of a 70-frame drive has ended or been refined for tens of frames."""
    from vislam.ekf.joint import run_joint

    seq = _head(noisy_sim.sequence, 70)
    cfg = BASE.replace(keep_landmarks=True, landmark_parameterisation=param,
                       joint_linearisation=linearisation, gyro_bias=bias)
    fast, dense = run_joint(seq, cfg), run_joint(seq, cfg, textbook=True)
    _assert_kept_as_dense(fast, dense, run_joint(seq, cfg.replace(keep_landmarks=False)))
    has = dense.has_landmark
    assert np.abs(fast.landmark_cov[has] - dense.landmark_cov[has]).max() > 0  # two computations
    assert fast.info["max_state_dim"] == dense.info["max_state_dim"]


def assert_same_as_dense(fast, dense, min_landmarks: int) -> np.ndarray:
    """``fast`` (keep_landmarks through retired regressions) equals ``dense`` (its textbook
    form) to 1e-9 with more than ``min_landmarks`` landmarks (a landmark to 1e-9 m plus 1e-10 of
    its range: a far one, whose pixels barely fix its depth, is solved to that relative
    precision along its ray, and the ray's error reaches every coordinate, small ones too: a
    38 m landmark's 4.4 m coordinate differed by 2.9e-9 m on another CPU's BLAS); returns which
    tracks have one."""
    has = dense.has_landmark
    assert has.sum() > min_landmarks and np.array_equal(has, fast.has_landmark)
    np.testing.assert_allclose(fast.poses, dense.poses, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast.pose_cov, dense.pose_cov, rtol=0, atol=1e-12)
    error = np.abs(fast.landmarks[has] - dense.landmarks[has])
    tolerance = 1e-9 + 1e-10 * np.linalg.norm(dense.landmarks[has], axis=1, keepdims=True)
    np.testing.assert_array_less(error, np.broadcast_to(tolerance, error.shape))
    scale = np.abs(dense.landmark_cov[has]).max(axis=(1, 2))[:, None, None]
    np.testing.assert_array_less(np.abs(fast.landmark_cov[has] - dense.landmark_cov[has]) / scale, 1e-9)
    return has


def _assert_kept_as_dense(fast, dense, marg) -> None:
    """:func:`assert_same_as_dense`, and the kept landmarks moved away from ``marg``'s
    (marginalised) estimates: the refinement is real."""
    has = assert_same_as_dense(fast, dense, 300)
    assert np.abs(fast.landmarks[has] - marg.landmarks[has]).max() > 1e-3


@pytest.mark.parametrize("param, bias", [("inverse-depth", True)] + [pytest.param(*p, marks=pytest.mark.regression) for p in (
                                         ("inverse-depth", False), ("euclidean", True), ("euclidean", False))])
def test_invariant_keep_landmarks_equals_the_dense_textbook_update(noisy_sim, param, bias):
    """ekf-invariant's ``keep_landmarks`` through :class:`ekf.kept_landmarks_invariant.InvariantKeptLandmarks`
    (the retired landmarks take the pose's twist noise and the bias coupling, RI-1, and the
    group retraction) gives the numbers of its dense form to 1e-9, as ekf-joint's does."""
    from vislam.ekf.invariant import run_invariant

    seq = _head(noisy_sim.sequence, 70)
    cfg = BASE.replace(keep_landmarks=True, landmark_parameterisation=param, gyro_bias=bias)
    fast, dense = run_invariant(seq, cfg), run_invariant(seq, cfg, textbook=True)
    _assert_kept_as_dense(fast, dense, run_invariant(seq, cfg.replace(keep_landmarks=False)))


@pytest.mark.parametrize("linearisation", ["standard", "fej", "oc"])
def test_joint_update_matches_dense_kalman_reference(noisy_sim, linearisation):
    """The structured stacked update equals the textbook dense Joseph-form update (followed, for
    the constrained linearisations, by the gauge transport of :func:`ekf.joint.gauge_transport`;
    at the first update the first estimates are the current ones, so FEJ's H is the same)."""
    from vislam.ekf.geometry import se3_exp
    from vislam.ekf.joint import gauge_transport

    seq = noisy_sim.sequence
    cfg = BASE.replace(gate_probability=None, joint_linearisation=linearisation, gyro_bias=False,
                       landmark_parameterisation="euclidean")  # inverse depth: test_inverse_depth.py
    model = StereoModel.from_config(seq.calibration, cfg)
    st = JointState(cfg, seq.n_tracks)
    tracks, z = seq.frame(0)
    st.initialise(model, tracks, z, np.zeros(tracks.size, dtype=bool))
    st.predict(0.1, seq.velocities[0] + [0.05, 0.02, 0, 0.001, 0, 0.002], cfg)
    tracks1, z1 = seq.frame(1)
    tracks1 = tracks1[st.slot[tracks1] >= 0][:15]
    z1 = seq.frame(1)[1][np.isin(seq.frame(1)[0], tracks1)]
    U0, m0, P0 = st.U.copy(), st.lm_mean.copy(), st.P.copy()
    # Dense reference with the 4-row model.
    slots = st.slot[tracks1]
    q = model.camera_points(U0, m0[slots])
    Hp, Hm = model.jacobians(U0, m0[slots], q, reduced=False)
    N = P0.shape[0]
    H = np.zeros((4 * slots.size, N))
    for i, s in enumerate(slots):
        H[4 * i : 4 * i + 4, :6] = Hp[i]
        H[4 * i : 4 * i + 4, 6 + 3 * s : 9 + 3 * s] = Hm[i]
    V = np.kron(np.eye(slots.size), model.V)
    S = H @ P0 @ H.T + V
    Kg = P0 @ H.T @ np.linalg.inv(S)
    r = (z1 - model.predicted_pixels(q)).ravel()
    IKH = np.eye(N) - Kg @ H
    P_ref = IKH @ P0 @ IKH.T + Kg @ V @ Kg.T
    dx_ref = Kg @ r
    if linearisation != "standard":
        dm = dx_ref[6:].reshape(-1, 3)
        gauge_transport(P_ref, 6, se3_exp(dx_ref[:6]), U0[:3, :3], dm if linearisation == "oc" else None)
    n_acc, n_rej = st.update(model, tracks1, z1)
    assert (n_acc, n_rej) == (slots.size, 0)
    np.testing.assert_allclose(st.P, P_ref, atol=1e-10, rtol=1e-7)
    np.testing.assert_allclose(st.lm_mean - m0, dx_ref[6:].reshape(-1, 3), atol=1e-9)


@pytest.mark.regression
@pytest.mark.slow
@pytest.mark.realdata
def test_0027_slam_beats_dead_reckoning(study_0027):
    # the session's run of every estimator on 0027 (tests/conftest.py), SE(3)-aligned ATE
    results = {mode: study_0027.scores[mode]["ate_aligned_m"]
               for mode in ["dead-reckoning", "ekf-decoupled", "ekf-joint"]}
    assert results["dead-reckoning"] == pytest.approx(16.4, abs=0.5)
    assert results["ekf-decoupled"] < results["dead-reckoning"]
    assert results["ekf-joint"] < results["dead-reckoning"]


@pytest.mark.regression
@pytest.mark.slow
@pytest.mark.parametrize("landmarks", ["euclidean", "inverse-depth"])
def test_constrained_linearisation_removes_most_spurious_information(landmarks):
    """Monte Carlo pose ANEES of ekf-joint: the standard EKF gains spurious information along
    the unobservable gauge directions (6 is consistent). Euclidean landmarks, 3 x 150 frames:
    standard 135, FEJ 32, oc 22. Inverse depth: standard 17.4, FEJ 18.5 (43, 5.7, 6.4: FEJ's
    first estimates of far points are poor), oc 4.3."""
    from vislam.eval.consistency import pose_nees

    anees = {m: [] for m in ("standard", "fej", "oc")}
    for seed in range(3):
        sim = simulate(SimConfig(seed=seed, n_frames=150))
        for mode in anees:
            cfg = BASE.replace(joint_linearisation=mode, landmark_parameterisation=landmarks)
            est = ESTIMATORS["ekf-joint"](sim.sequence, cfg)
            anees[mode].append(np.nanmean(pose_nees(est, np.arange(150), sim.poses)))
    mean = {m: float(np.mean(v)) for m, v in anees.items()}
    assert mean["oc"] < 0.4 * mean["standard"], mean
    if landmarks == "euclidean":
        assert mean["fej"] < 0.6 * mean["standard"], mean
        assert mean["oc"] < 40, mean
    else:
        assert mean["oc"] < 6 * 1.5, mean


@pytest.mark.parametrize("core", [6, 9])
def test_add_pose_rows_is_the_transport_t_p_tt(core):
    """``numerics.add_pose_rows`` (one in-place GEMM) equals ``T P T^T`` formed densely, for a
    C-ordered covariance and for one BLAS cannot write into (Fortran-ordered)."""
    from vislam.ekf.numerics import add_pose_rows

    rng = np.random.default_rng(core)
    N = core + 3 * 7
    A = rng.standard_normal((N, N))
    P0 = A @ A.T + N * np.eye(N)
    C = rng.standard_normal((N - core, 6))
    T = np.eye(N)
    T[core:, :6] = C
    want = T @ P0 @ T.T
    for P in (P0.copy(), np.asfortranarray(P0)):
        add_pose_rows(P, core, C)
        np.testing.assert_allclose(P, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    P = P0[:core, :core].copy()
    add_pose_rows(P, core, np.zeros((0, 6)))  # no landmark rows: unchanged
    np.testing.assert_array_equal(P, P0[:core, :core])
