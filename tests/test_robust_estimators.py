"""Estimators on odd but finite input (issue 11, item 2): every estimator either returns a
finite :class:`~ekf.estimate.Estimate` (rejecting the updates it cannot compute, and counting
them in ``info["numerical_rejections"]``) or raises :class:`~ekf.errors.EstimationError` /
:class:`~ekf.errors.InputError` with a one-line message naming the estimator. Never a numpy,
scipy or GTSAM traceback, never NaN in a pose or a pose covariance.

The property tests draw small simulated drives and corrupt them (velocity spikes, pixel shifts,
duplicated or swapped features, tiny or huge disparities, observations at the image border,
time steps of 1e-6 s or 100 s). Their example counts are bounded for CI; a larger sweep:
``VISLAM_ROBUST_EXAMPLES=3000 .venv/bin/python -m pytest tests/test_robust_estimators.py -k property``.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.estimate import Estimate
from vislam.ekf.sequence import Observations, Sequence
from vislam.ekf.estimators import filter_names
from vislam.eval.registry import ESTIMATOR_NAMES, SMOOTHERS, get_estimator
from vislam.eval.simulate import SimConfig, simulate

EKFS = filter_names()  # the per-frame filters: the EKFs, dead reckoning and mapping
assert set(EKFS + SMOOTHERS) == set(ESTIMATOR_NAMES)

#: Examples per property test; the environment variable scales them for a long local sweep.
_SCALE = int(os.environ.get("VISLAM_ROBUST_EXAMPLES", "0"))


def _examples(ci: int) -> int:
    return max(ci, _SCALE) if _SCALE else ci


# --------------------------------------------------------------------------------------
# Drives and corruptions
# --------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=None)
def base_drive(seed: int, n_frames: int = 40) -> Sequence:
    """A small simulated drive (cached: the tests only ever derive new sequences from it)."""
    return simulate(SimConfig(seed=seed, n_frames=n_frames, name=f"sim{seed}")).sequence


def truncate(seq: Sequence, n: int) -> Sequence:
    """The first ``n`` frames of ``seq``."""
    o = seq.obs
    b = int(o.frame_ptr[n])
    obs = Observations(o.frame_ptr[: n + 1].copy(), o.track[:b].copy(), o.z[:b].copy())
    return dataclasses.replace(
        seq,
        timestamps=seq.timestamps[:n].copy(),
        linear_velocity=seq.linear_velocity[:n].copy(),
        angular_velocity=seq.angular_velocity[:n].copy(),
        obs=obs,
    )


def with_rows(seq: Sequence, frame, track, z, n_tracks: int | None = None) -> Sequence:
    """``seq`` with its observations replaced by the rows ``(frame, track, z)``."""
    n_tracks = seq.n_tracks if n_tracks is None else int(n_tracks)
    obs = Observations.from_rows(frame, track, np.asarray(z, dtype=float).reshape(-1, 4), seq.n_frames)
    return dataclasses.replace(seq, obs=obs, n_tracks=n_tracks, track_origin=None)


def gyro_spike(seq: Sequence, frame: int, value: float = 300.0, axis: int = 2) -> Sequence:
    w = seq.angular_velocity.copy()
    w[frame, axis] += value
    return dataclasses.replace(seq, angular_velocity=w)


def velocity_spike(seq: Sequence, frame: int, value: float = 1e6, axis: int = 0) -> Sequence:
    v = seq.linear_velocity.copy()
    v[frame, axis] += value
    return dataclasses.replace(seq, linear_velocity=v)


def shift_pixels(seq: Sequence, shift: float = 1e5, frames=None, columns=(0, 1, 2, 3)) -> Sequence:
    """Add ``shift`` to the pixel ``columns`` of the observations in ``frames`` (None: all)."""
    o = seq.obs
    z = o.z.copy()
    rows = np.ones(len(o), bool) if frames is None else np.isin(o.frame_index, np.atleast_1d(frames))
    for c in columns:
        z[rows, c] += shift
    return dataclasses.replace(seq, obs=Observations(o.frame_ptr, o.track, z))


def no_observations(seq: Sequence) -> Sequence:
    return with_rows(seq, np.zeros(0, int), np.zeros(0, int), np.zeros((0, 4)))


def set_interval(seq: Sequence, k: int, dt: float) -> Sequence:
    """Make interval ``[k, k+1]`` last ``dt`` seconds (later time stamps move with it)."""
    t = seq.timestamps.copy()
    if 0 <= k < t.size - 1:
        t[k + 1 :] += dt - (t[k + 1] - t[k])
    return dataclasses.replace(seq, timestamps=t)


def corrupt(seq: Sequence, kind: str, where: float, value: float, axis: int) -> Sequence:
    """One corruption of ``kind`` at the frame ``where`` (fraction of the drive) of size ``value``."""
    T = seq.n_frames
    f = min(int(where * T), T - 1)
    o = seq.obs
    frame, track, z = o.frame_index, o.track.copy(), o.z.copy()
    at = frame == f
    if kind == "gyro":
        return gyro_spike(seq, f, value, axis % 3)
    if kind == "velocity":
        return velocity_spike(seq, f, value, axis % 3)
    if kind == "shift_frame":
        return shift_pixels(seq, value, f, [(0, 1, 2, 3), (0, 2), (1, 3), (0,), (3,)][axis % 5])
    if kind == "shift_all":
        return shift_pixels(seq, value, None, [(0, 1, 2, 3), (0, 2), (1, 3), (0,), (3,)][axis % 5])
    if kind == "disparity":  # tiny, huge or negative disparities (value px) in one frame or all
        sel = at if axis % 2 else np.ones_like(at)
        z[sel, 2] = z[sel, 0] - value
        return with_rows(seq, frame, track, z)
    if kind == "border":  # observations moved to the image border / corners
        W, H = 1241.0, 376.0
        u = [0.0, W, -0.5, W + 0.5][axis % 4]
        v = [0.0, H, 0.0, H][(axis // 4) % 4]
        d = z[at, 0] - z[at, 2]
        z[at, 0], z[at, 1], z[at, 3] = u, v, v
        z[at, 2] = u - (d if value > 0 else value)
        return with_rows(seq, frame, track, z)
    if kind == "same_pixel":  # every observation of the frame at one pixel
        z[at] = z[at][:1] if at.any() else z[at]
        return with_rows(seq, frame, track, z)
    if kind == "swap":  # data association error: the frame's pixels reversed across tracks
        z[at] = z[at][::-1]
        return with_rows(seq, frame, track, z)
    if kind == "duplicate":  # the frame's observations again, under new track indices
        n = int(at.sum())
        new_tracks = seq.n_tracks + np.arange(n)
        return with_rows(
            seq,
            np.concatenate([frame, frame[at]]),
            np.concatenate([track, new_tracks]),
            np.concatenate([z, z[at] + (value if abs(value) < 1 else 0.0)]),
            seq.n_tracks + n,
        )
    if kind == "copy_track":  # one track's whole history copied to a new track index
        if len(o) == 0:
            return seq
        j = int(track[min(int(where * len(o)), len(o) - 1)])
        sel = track == j
        return with_rows(
            seq,
            np.concatenate([frame, frame[sel]]),
            np.concatenate([track, np.full(int(sel.sum()), seq.n_tracks)]),
            np.concatenate([z, z[sel]]),
            seq.n_tracks + 1,
        )
    if kind == "minus_one":  # one of the four pixel values is -1 (the files' "unobserved")
        z[at, axis % 4] = -1.0
        return with_rows(seq, frame, track, z)
    if kind == "vertical":  # left and right rows disagree
        z[at, 3] += value
        return with_rows(seq, frame, track, z)
    if kind == "dt":  # one interval of value seconds (1e-6 .. 100)
        return set_interval(seq, f, abs(value))
    if kind == "dt_all":
        t = np.arange(T) * abs(value)
        return dataclasses.replace(seq, timestamps=t)
    if kind == "drop_after":  # no observations from the frame on
        keep = frame < f
        return with_rows(seq, frame[keep], track[keep], z[keep])
    if kind == "no_obs":
        return no_observations(seq)
    raise ValueError(kind)


KINDS = (
    "gyro", "velocity", "shift_frame", "shift_all", "disparity", "border", "same_pixel", "swap",
    "duplicate", "copy_track", "minus_one", "vertical", "dt", "dt_all", "drop_after", "no_obs",
)
#: Values a corruption takes (px, m/s, rad/s or s depending on the kind).
VALUES = (
    1e-12, 1e-6, 1e-3, 0.5, 1.0, 1.0000001, 3.0, 30.0, 100.0, 300.0, 1e3, 1e4, 1e5, 1e6, 1e9,
    -1e-6, -1.0, -300.0, -1e5, -1e6,
)


# --------------------------------------------------------------------------------------
# The check every run must pass
# --------------------------------------------------------------------------------------
def run_checked(name: str, seq: Sequence, config: FilterConfig = FilterConfig()) -> Estimate | None:
    """Run ``name``; only InputError/EstimationError may escape (naming the estimator, one
    line), and a returned estimate must pass ``check_finite``. Returns the estimate or None."""
    try:
        est = get_estimator(name)(seq, config)
    except EstimationError as exc:
        msg = str(exc)
        assert name in msg, f"{name}: message does not name the estimator: {msg!r}"
        assert "\n" not in msg, f"{name}: message is not one line: {msg!r}"
        return None
    except InputError as exc:
        assert "\n" not in str(exc), str(exc)
        return None
    est.check_finite()
    assert np.all(np.isfinite(est.poses)), name
    assert np.all(np.isfinite(est.pose_cov)), name
    assert est.poses.shape == (seq.n_frames, 4, 4)
    rej = est.info["numerical_rejections"]
    assert isinstance(rej, int) and rej >= 0
    frames = est.info["numerical_rejection_frames"]
    assert len(frames) == min(rej, 20) and all(0 <= f < seq.n_frames for f in frames)
    return est


@pytest.fixture(autouse=True)
def _quiet_warnings(caplog):
    caplog.set_level(logging.ERROR)


def rejections(est: Estimate | None) -> int:
    return -1 if est is None else int(est.info["numerical_rejections"])


# --------------------------------------------------------------------------------------
# Reproductions (each crashed with a LinAlgError traceback before the fix)
# --------------------------------------------------------------------------------------
#: (frame, axis, rad/s) of one corrupt gyro sample on drive seed 0, and the EKFs that crashed
#: on it with ``LinAlgError: Singular matrix`` (and now reject that frame's update instead).
GYRO_SPIKES = {
    (10, 0, 300.0): ("ekf-invariant",),
    (10, 1, 300.0): ("ekf-joint",),
    (10, 2, -300.0): ("ekf-decoupled",),
    (20, 1, -300.0): ("ekf-joint", "ekf-invariant"),
}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.regression) if n == "smoother-fixed-lag"
                                  else n for n in ESTIMATOR_NAMES])  # fixed-lag: 8-14 s here
def test_one_corrupt_gyro_sample(name, caplog):
    caplog.set_level(logging.WARNING)
    for (frame, axis, value), crashed in GYRO_SPIKES.items():
        seq = gyro_spike(base_drive(0), frame, value, axis)
        est = run_checked(name, seq)  # the defaults (inverse-depth landmarks): no crash either
        if name in EKFS and est is not None:
            assert rejections(est) <= 1
        # The reproductions were made with Euclidean landmarks.
        est = run_checked(name, seq, FilterConfig(landmark_parameterisation="euclidean"))
        if name in crashed:  # recovered: no crash; a rejected update counted and logged
            assert est is not None, (name, frame)
            # Since updates of known landmarks are checked by predicted depth (not by the
            # observation's own), ekf-joint and ekf-decoupled no longer reach a singular system
            # on these spikes, and since the SE(3) left Jacobian is in closed form (the 20-term
            # series it replaced diverged at the spike's 15-30 rad: its noise Jacobian blew the
            # covariance up) neither does ekf-invariant; the rejection path stays covered by the
            # 1e5 px shift below.
            if rejections(est) == 0:
                continue
            assert est.info["numerical_rejection_frames"][0] >= frame
            assert any(name in r.getMessage() and "rejected" in r.getMessage()
                       for r in caplog.records if r.levelno == logging.WARNING)
        elif name in EKFS and est is not None:
            assert rejections(est) <= 1


@pytest.mark.parametrize("name", ESTIMATOR_NAMES)
def test_all_features_shifted_by_1e5_px(name):
    # A depth cut of 100 m (the default until 2026-12-02) takes the EKFs down the numerical
    # rejection path on this drive, which the test covers; with the default 1,000 m
    # ekf-decoupled gets through without one.
    est = run_checked(name, shift_pixels(base_drive(0), 1e5), FilterConfig(max_depth=100.0))
    if name in ("ekf-decoupled", "ekf-joint", "ekf-invariant"):
        assert rejections(est) >= 1  # crashed before (LinAlgError / not positive definite)


@pytest.mark.parametrize("name", ESTIMATOR_NAMES)
def test_one_frame_shifted_by_1e5_px(name):
    run_checked(name, shift_pixels(base_drive(1), 1e5, frames=20))


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.regression) if n == "smoother-fixed-lag"
                                  else n for n in ESTIMATOR_NAMES])  # fixed-lag: 8-14 s here
def test_huge_but_finite_velocity(name):
    for axis in range(3):
        run_checked(name, velocity_spike(base_drive(1), 20, 1e6, axis))


@pytest.mark.parametrize("name", ESTIMATOR_NAMES)
def test_no_observations(name):
    est = run_checked(name, no_observations(base_drive(2)))
    if name != "smoother-isam2":
        assert est is not None and rejections(est) == 0
        assert not est.has_landmark.any()


@pytest.mark.parametrize("n_frames", [1, 2])
@pytest.mark.parametrize("name", ESTIMATOR_NAMES)
def test_tiny_drives(name, n_frames):
    est = run_checked(name, truncate(base_drive(3), n_frames))
    assert est is not None and est.n_frames == n_frames


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # numpy on 1e160 s twists: overflow
@pytest.mark.parametrize("name", ("ekf-joint", "ekf-invariant"))
def test_absurd_time_step_is_one_line_error(name):
    """1e160 s intervals: the twist of an interval overflows; a filter cannot reject a
    prediction, so it names the frame (its time written short) and the quantity (before, a
    ValueError from math.sin escaped). At 1e9 s every estimator either gives an estimate that
    passes the contract or a one-line error (before the closed-form SE(3) left Jacobian, whose
    20-term series overflowed there, the EKFs always failed)."""
    seq = dataclasses.replace(base_drive(1), timestamps=np.arange(40) * 1e160)
    with pytest.raises(EstimationError, match=rf"^{name}: frame 1 \(t=1e\+160 s\): .*not finite"):
        get_estimator(name)(seq, FilterConfig())
    for step in (1e160, 1e9):
        seq = dataclasses.replace(base_drive(1), timestamps=np.arange(40) * step)
        for other in ESTIMATOR_NAMES:
            run_checked(other, seq)


@pytest.mark.parametrize("name", EKFS)
def test_normal_drive_has_no_numerical_rejections(name):
    est = run_checked(name, base_drive(0))
    assert est.info["numerical_rejections"] == 0
    assert est.info["numerical_rejection_frames"] == []


# --------------------------------------------------------------------------------------
# The update itself: rejected updates leave the state untouched
# --------------------------------------------------------------------------------------
def _joint_state_with_landmarks():
    from vislam.ekf.joint import JointState
    from vislam.ekf.stereo_update import StereoModel

    seq = base_drive(0)
    cfg = FilterConfig(landmark_parameterisation="euclidean")  # lm_mean: world points
    model = StereoModel.from_config(seq.calibration, cfg)
    st_ = JointState(cfg, seq.n_tracks)
    tracks, z = seq.frame(0)
    st_.initialise(model, tracks, z, np.zeros(tracks.size, dtype=bool))
    tracks1, z1 = seq.frame(1)
    act = st_.slot[tracks1] >= 0
    return st_, model, tracks1[act], z1[act]


def test_joint_rejected_update_leaves_state_unchanged():
    from vislam.ekf.numerics import UpdateRejected

    st_, model, tracks, z = _joint_state_with_landmarks()
    st_.P[6:, 6:] *= -1.0  # an indefinite covariance: S cannot be factorised
    before = (st_.U.copy(), st_.P.copy(), st_.lm_mean.copy(), st_.bias.copy())
    with pytest.raises(UpdateRejected, match="not positive definite"):
        st_.update(model, tracks, z)
    for a, b in zip(before, (st_.U, st_.P, st_.lm_mean, st_.bias)):
        np.testing.assert_array_equal(a, b)


def test_invariant_rejected_update_leaves_state_unchanged():
    from vislam.ekf.invariant import InvariantState, _update, landmark_offset
    from vislam.ekf.numerics import UpdateRejected

    seq = base_drive(0)
    cfg = FilterConfig()
    cal = seq.calibration
    off = landmark_offset(True)
    st_ = InvariantState(T=np.eye(4), landmarks=np.array([[10.0, 1.0, 0.5], [15.0, -2.0, 1.0]]),
                 tracks=np.array([0, 1]), P=-np.eye(off + 6), bias=np.zeros(3))
    q = (st_.landmarks @ cal.cam_T_imu[:3, :3].T + cal.cam_T_imu[:3, 3])
    z = np.stack([cal.M @ np.append(p / p[2], 1 / p[2]) for p in q])
    before = (st_.T.copy(), st_.P.copy(), st_.landmarks.copy(), st_.bias.copy())
    with pytest.raises(UpdateRejected):
        _update(st_, np.array([0, 1]), z, cal.M, cal.cam_T_imu, cfg.pixel_cov,
                np.linalg.inv(cfg.pixel_cov), None, cfg, off)
    for a, b in zip(before, (st_.T, st_.P, st_.landmarks, st_.bias)):
        np.testing.assert_array_equal(a, b)


def test_decoupled_rejected_update_raises_before_changing_anything():
    from vislam.ekf.decoupled import pose_update_checked
    from vislam.ekf.numerics import UpdateRejected

    st_, model, _, _ = _joint_state_with_landmarks()
    tracks, z = base_drive(0).frame(0)  # the observations the landmarks came from
    m = st_.lm_mean[st_.slot[tracks]]
    U, Sigma, acc, _ = pose_update_checked(model, np.eye(4), 1e-4 * np.eye(6), m, z)
    assert acc.all()
    with pytest.raises(UpdateRejected):
        pose_update_checked(model, np.eye(4), np.zeros((6, 6)), m, z)  # singular prior


def test_singular_innovation_rows_are_gated_out():
    from vislam.ekf.stereo_update import StereoModel

    seq = base_drive(0)
    model = StereoModel.from_config(seq.calibration, FilterConfig())
    q = np.array([[1.0, 0.5, 10.0, 1.0], [0.5, 0.2, 20.0, 1.0]])
    z = model.predicted_pixels(q)
    S3 = np.stack([np.eye(3), np.full((3, 3), np.nan)])
    acc, n_bad = model.gate_check(z, q, S3)
    assert acc.tolist() == [True, False] and n_bad == 1


# --------------------------------------------------------------------------------------
# Estimate.check_finite and save_npz
# --------------------------------------------------------------------------------------
def _estimate(n=5, m=3) -> Estimate:
    est = Estimate.empty("ekf-test", np.arange(n) * 0.1, m)
    est.pose_cov = np.tile(np.eye(6), (n, 1, 1))
    est.landmarks[0] = [1.0, 2.0, 3.0]
    est.landmark_cov[0] = np.eye(3)
    return est


def test_check_finite_accepts_landmarks_without_estimate():
    _estimate().check_finite()  # landmarks 1, 2 are NaN by design


@pytest.mark.parametrize(
    "corrupt_it, message",
    [
        (lambda e: e.poses.__setitem__((3, 0, 3), np.nan), r"ekf-test: frame 3 \(t=0.30 s\): pose not finite"),
        (lambda e: e.pose_cov.__setitem__((2, 1, 1), np.inf), r"ekf-test: frame 2 \(t=0.20 s\): pose covariance not finite"),
        (lambda e: e.landmark_cov.__setitem__((0, 0, 0), np.nan), r"ekf-test: landmark 0: covariance not finite"),
        (lambda e: e.landmarks.__setitem__((1, 0), np.inf), r"ekf-test: landmark 1: mean not finite"),
    ],
)
def test_check_finite_names_estimator_and_frame(corrupt_it, message, tmp_path):
    est = _estimate()
    corrupt_it(est)
    with pytest.raises(EstimationError, match=message):
        est.check_finite()
    with pytest.raises(EstimationError, match=message):
        est.save_npz(tmp_path / "out" / "estimate.npz")
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_check_finite_allows_covariances_not_computed(tmp_path):
    est = _estimate()
    est.pose_cov[:] = np.nan
    est.landmark_cov[:] = np.nan
    with pytest.raises(EstimationError):
        est.check_finite()
    est.info["marginals_computed"] = False
    est.check_finite()
    est.save_npz(tmp_path / "e.npz")


# --------------------------------------------------------------------------------------
# The smoothers' own parts
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "case", ["nan_poses", "singular_covs", "huge_motion", "no_intervals"]
)
def test_estimate_bias_degenerate_input(case, caplog):
    from vislam.graph.factors import relative_motions
    from vislam.graph.gyro_bias import GyroBiasModel, estimate_bias
    from vislam.graph.factors import interval_twists as graph_twists

    caplog.set_level(logging.WARNING)
    seq = base_drive(0)
    cfg = FilterConfig()
    deltas, covs = relative_motions(seq, cfg)
    twists, tau = graph_twists(seq, cfg.velocity_pairing)
    D = GyroBiasModel.create(twists, tau, cfg.gyro_bias_sigma).D
    poses = np.tile(np.eye(4), (seq.n_frames, 1, 1))
    if case == "nan_poses":
        poses[5, 0, 3] = np.nan
    elif case == "singular_covs":
        covs = np.zeros_like(covs)
    elif case == "huge_motion":
        poses[:, :3, 3] = np.arange(seq.n_frames)[:, None] * 1e300
    else:
        poses, deltas, D, covs = poses[:1], deltas[:0], D[:0], covs[:0]
    b = estimate_bias(poses, deltas, D, covs, cfg.gyro_bias_sigma)
    assert b.shape == (3,) and np.all(np.isfinite(b))
    if case in ("nan_poses", "singular_covs"):
        np.testing.assert_array_equal(b, 0.0)
        assert any("gyro bias not estimated" in r.getMessage() for r in caplog.records)


def test_smoother_survives_a_failing_ekf_initialisation(monkeypatch):
    import vislam.ekf.estimators as ekf_estimators
    def broken(seq, config, progress=None):
        raise EstimationError("ekf-invariant: frame 3 (t=0.30 s): innovation covariance")

    monkeypatch.setitem(ekf_estimators.ESTIMATORS, "ekf-invariant", broken)
    monkeypatch.setitem(ekf_estimators.ESTIMATORS, "ekf-joint", broken)
    est = run_checked("smoother", truncate(base_drive(0), 20))
    assert est is not None and "dead-reckoning" in est.info["init"]


def test_gtsam_errors_name_the_estimator_and_variable():
    err = None
    try:
        get_estimator("smoother-isam2")(shift_pixels(base_drive(0), 1e5), FilterConfig())
    except EstimationError as exc:
        err = str(exc)
    if err is not None:  # iSAM2 cannot reject a factor it already took: one line naming it
        assert err.startswith("smoother-isam2") and ("landmark l" in err or "pose x" in err)


# --------------------------------------------------------------------------------------
# Property tests: small finite drives, corrupted
# --------------------------------------------------------------------------------------
@st.composite
def corrupted_drives(draw, max_frames: int = 40, max_corruptions: int = 3):
    seed = draw(st.integers(0, 3))
    n = draw(st.integers(1, max_frames))
    seq = truncate(base_drive(seed), n)
    changes = draw(
        st.lists(
            st.tuples(st.sampled_from(KINDS), st.floats(0.0, 1.0), st.sampled_from(VALUES),
                      st.integers(0, 15)),
            max_size=max_corruptions,
        )
    )
    for change in changes:
        seq = corrupt(seq, *change)
    return seq


def ekfs_survive(seq):
    for name in EKFS:
        run_checked(name, seq)


def smoothers_survive(seq):
    for name in SMOOTHERS:
        run_checked(name, seq)


# The fast tier draws a few examples of every corruption; the regression tier sweeps more of
# them (other examples: hypothesis derandomizes each test by its own name). A longer local
# sweep: VISLAM_ROBUST_EXAMPLES.
@settings(max_examples=_examples(25))
@given(seq=corrupted_drives())
def test_property_ekfs_on_corrupted_drives(seq):
    ekfs_survive(seq)


@settings(max_examples=_examples(8))
@given(seq=corrupted_drives(max_frames=15, max_corruptions=2))
def test_property_smoothers_on_corrupted_drives(seq):
    smoothers_survive(seq)


@pytest.mark.regression
@settings(max_examples=_examples(60))
@given(seq=corrupted_drives())
def test_property_ekfs_on_corrupted_drives_sweep(seq):
    ekfs_survive(seq)


@pytest.mark.regression
@settings(max_examples=_examples(20))
@given(seq=corrupted_drives(max_frames=15, max_corruptions=2))
def test_property_smoothers_on_corrupted_drives_sweep(seq):
    smoothers_survive(seq)


def test_landmarks_with_unusable_covariances_leave_the_map(caplog):
    """What an EKF reports passes the estimator contract: a landmark whose covariance rounding
    has left indefinite (or asymmetric, or not finite) is dropped from the map, counted and
    logged; one within the contract's tolerance (a rounding-level negative eigenvalue) stays."""
    from vislam.ekf.numerics import NumericalGuard
    from vislam.ekf.runner import COVARIANCE_RTOL, covariance_usable, finish_estimate

    est = Estimate.empty("ekf-joint", np.arange(3) * 0.1, 5)
    est.pose_cov[:] = np.eye(6)
    est.landmarks[:4] = 1.0
    est.landmark_cov[:4] = np.eye(3)
    est.landmark_cov[1] = np.diag([1.0, 1.0, -0.5])  # indefinite
    est.landmark_cov[2, 0, 1] = 1e-3  # asymmetric
    est.landmark_cov[3] = np.diag([1.0, 1.0, -0.1 * COVARIANCE_RTOL])  # rounding: kept
    assert covariance_usable(est.landmark_cov[:4]).tolist() == [True, False, False, True]
    caplog.set_level(logging.WARNING)
    out = finish_estimate(est, NumericalGuard("ekf-joint", est.timestamps))
    assert out.has_landmark.tolist() == [True, False, False, True, False]
    assert out.info["n_landmarks_dropped"] == 2
    assert any("2 landmarks" in r.getMessage() for r in caplog.records)
    # The smoothers keep them (drop_unusable_cov=False): a fault in their marginals must still
    # fail the estimator contract, not thin the map quietly.
    est.landmark_cov[1] = np.diag([1.0, 1.0, -0.5])
    est.landmarks[1] = 1.0
    kept = finish_estimate(est, NumericalGuard("smoother", est.timestamps), drop_unusable_cov=False)
    assert kept.has_landmark[1] and kept.info["n_landmarks_dropped"] == 0
