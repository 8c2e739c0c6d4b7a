"""benchmarks/nees_breakdown.py: its per-stretch figures against what they are defined as."""

import numpy as np

from vislam.ekf.estimate import Estimate
from vislam.ekf.geometry import se3_exp
from vislam.eval.groundtruth import GroundTruth


def test_breakdown_gives_each_stretch_its_nees_z2_and_yaw_drift(benchmark_script):
    """A drive whose estimate yaws away from the truth by 1e-3 rad a frame in its second half
    (covariance diag(sd^2)): the first stretch has no error; the second's NEES is the mean of
    (e / sd)^2 summed over axes, and its rotation increments' error sums to the drift."""
    T, sd = 41, np.array([0.1, 0.1, 0.1, 0.01, 0.01, 0.01])
    truth = se3_exp(np.c_[np.full((T, 1), 1.0), np.zeros((T, 4)), 0.02 * np.ones((T, 1))] *
                    np.arange(T)[:, None] / 10)
    yaw = np.r_[np.zeros(21), 1e-3 * np.arange(1, 21)]  # error grows in the second half
    est_poses = truth @ se3_exp(np.c_[np.zeros((T, 5)), -yaw])
    est = Estimate(estimator="x", timestamps=0.1 * np.arange(T), poses=est_poses,
                   pose_cov=np.tile(np.diag(sd**2), (T, 1, 1)), landmarks=np.zeros((0, 3)),
                   landmark_cov=np.zeros((0, 3, 3)), step_time_s=np.zeros(T),
                   n_updates=np.zeros(T, int), n_rejected=np.zeros(T, int),
                   n_initialised=np.zeros(T, int))
    gt = GroundTruth(frames=np.arange(T), poses=truth, source="test")
    first, second = benchmark_script("nees_breakdown").breakdown(est, gt, 2)
    assert first["nees"] == 0.0 and np.allclose(first["rotation_increment_error"], 0.0)
    e = yaw[21:] / sd[5]
    assert np.isclose(second["nees"], np.mean(e**2))
    assert np.isclose(second["z2"][5], np.mean(e**2)) and np.allclose(second["z2"][:5], 0.0)
    assert np.isclose(second["rotation_increment_error"][2], -yaw[-1], atol=1e-12)
    assert np.isclose(second["rms"][5], np.sqrt(np.mean(yaw[21:] ** 2)))
