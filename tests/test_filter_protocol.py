"""The per-frame filter protocol (ekf/filter.py) and its one driver (ekf/driver.py): a user's filter
of a few lines runs through ``run_filter`` and through the registry as ``MODULE:CLASS``, exactly
as vislam's own; the driver's contract (predict T-1 times, update once per frame, marginalise
each track once, at its last frame)."""

from __future__ import annotations

import numpy as np
import pytest

from vislam.eval import registry
from vislam.eval.simulate import SimConfig, simulate
from vislam.filters import (Estimate, FilterConfig, FrameObservations, Landmarks, MotionInput,
                            StereoModel, UpdateCounts, ekf_cov_to_estimate, is_filter_class,
                            run_filter, se3_exp, se3_inv)


class PoseAndFirstSight:
    """Dead reckoning (paper eq. 4, covariance growing by dt^2 W) and each landmark triangulated
    once, at its first sight, from the pose then: a filter of about forty lines."""

    name = "pose-and-first-sight"

    def initialise(self, seq, config, guard):
        self.model = StereoModel.from_config(seq.calibration, config)
        self.W, self.U, self.Sigma = config.velocity_cov, np.eye(4), config.initial_pose_cov
        self.mean = np.full((seq.n_tracks, 3), np.nan)
        self.cov = np.full((seq.n_tracks, 3, 3), np.nan)
        self.active = np.zeros(seq.n_tracks, dtype=bool)
        self.calls = []

    def predict(self, motion: MotionInput):
        self.calls.append(("predict", motion.frame, motion.dt))
        self.U = se3_exp(-motion.dt * motion.twist) @ self.U
        self.Sigma = self.Sigma + motion.dt**2 * self.W

    def update(self, frame: FrameObservations) -> UpdateCounts:
        self.calls.append(("update", frame.frame, frame.tracks.size))
        new = ~self.active[frame.tracks] & np.isnan(self.mean[frame.tracks, 0])
        new &= self.model.valid_observations(frame.z)
        tr = frame.tracks[new]
        if tr.size:
            m, J_d, Cz = self.model.initialise_with_cov(self.U, frame.z[new])
            self.mean[tr], self.cov[tr] = m, Cz + J_d @ self.Sigma @ np.swapaxes(J_d, 1, 2)
            self.active[tr] = True
        return UpdateCounts(0, int(frame.tracks.size - tr.size), int(tr.size))

    def marginalise(self, tracks):
        self.calls.append(("marginalise", tracks.copy()))
        self.active[tracks] = False

    def pose(self):
        return se3_inv(self.U)

    def pose_cov(self):
        return ekf_cov_to_estimate(self.Sigma)

    def active_landmarks(self):
        tr = np.flatnonzero(self.active)
        return Landmarks(tr, self.mean[tr], self.cov[tr])

    def landmark_map(self):
        ended = ~self.active[:, None]
        return np.where(ended, self.mean, np.nan), np.where(ended[:, :, None], self.cov, np.nan)

    def info(self):
        return {"first_sight": True}


@pytest.fixture(scope="module")
def drive():
    return simulate(SimConfig(seed=3, n_frames=40)).sequence


def test_the_driver_calls_each_verb_as_the_protocol_says(drive):
    config = FilterConfig(clean_tracks=False)
    filt = PoseAndFirstSight()
    est = run_filter(filt, drive, config)
    T = drive.n_frames
    predicts = [c for c in filt.calls if c[0] == "predict"]
    updates = [c for c in filt.calls if c[0] == "update"]
    ended = [c[1] for c in filt.calls if c[0] == "marginalise"]
    assert [c[1] for c in predicts] == list(range(1, T))
    np.testing.assert_array_equal([c[2] for c in predicts], drive.dt)
    assert [c[1] for c in updates] == list(range(T)) and len(ended) == T
    assert [c[0] for c in filt.calls[:3]] == ["update", "marginalise", "predict"]
    last = drive.track_last_frame()
    for t, tracks in enumerate(ended):  # each track once, sorted, at its last observation
        np.testing.assert_array_equal(tracks, np.sort(np.flatnonzero(last == t)))
    assert isinstance(est, Estimate) and est.estimator == "pose-and-first-sight"
    assert est.info["first_sight"] and est.info["numerical_rejections"] == 0
    assert est.n_initialised.sum() == est.has_landmark.sum() > 0.9 * drive.n_tracks


def test_a_users_filter_runs_through_the_registry_as_module_colon_class(drive):
    assert is_filter_class(PoseAndFirstSight)
    spec = f"{__file__}:PoseAndFirstSight"
    assert registry.parse_estimator_list(spec, registry.DEFAULT_BENCH) == [spec]
    est = registry.get_estimator(spec)(drive, FilterConfig())
    ref = run_filter(PoseAndFirstSight(), drive, FilterConfig())
    assert est.estimator == ref.estimator
    for key in ("poses", "pose_cov", "landmarks", "landmark_cov", "n_initialised"):
        np.testing.assert_array_equal(getattr(est, key), getattr(ref, key))
    # its dead reckoning is vislam's (paper eq. 4), to rounding
    dr = registry.get_estimator("dead-reckoning")(drive, FilterConfig())
    np.testing.assert_allclose(est.poses, dr.poses, atol=1e-9)


def test_a_builtin_through_the_registry_is_its_run_function(drive):
    from vislam.ekf.joint import JointEKF, run_joint

    est = registry.get_estimator("ekf-joint")(drive, FilterConfig())
    assert registry.resolve("ekf-joint").filter_class is JointEKF
    ref = run_joint(drive, FilterConfig())
    np.testing.assert_array_equal(est.poses, ref.poses)
    np.testing.assert_array_equal(est.landmark_cov, ref.landmark_cov)


def test_bench_and_nees_run_a_users_filter_class(tmp_path):
    import json

    from vislam.eval.cli import main

    spec = f"{__file__}:PoseAndFirstSight"
    assert main(["bench", "--frames", "40", "--model", "as-given", "-e", spec, "-j", "1",
                 "--out", str(tmp_path / "bench"), "-q"]) == 0
    (seq,) = json.loads((tmp_path / "bench" / "results.json").read_text())["sequences"]
    assert [r["name"] for r in seq["estimators"]] == [spec] and seq["estimators"][0]["error"] is None
    assert main(["nees", "--runs", "2", "--frames", "30", "-e", spec, "-j", "1",
                 "--out", str(tmp_path / "nees"), "-q"]) == 0
    row = json.loads((tmp_path / "nees" / "nees.json").read_text())["estimators"][spec]
    assert row["runs_failed"] == 0 and row["anees_pose"] is not None
