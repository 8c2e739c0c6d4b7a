"""Every benchmark figure is written (Agg, no display) as a non-empty PNG."""

from __future__ import annotations

import numpy as np
import pytest

from ekf.estimate import Estimate
from ekf.geometry import se3_exp
from eval import plots

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _est(name: str, T: int = 80, M: int = 30, noise: float = 0.0, seed: int = 0) -> Estimate:
    rng = np.random.default_rng(seed)
    est = Estimate.empty(name, np.arange(T) * 0.1, M)
    twist = np.array([1.0, 0, 0, 0, 0, 0.02])
    est.poses = se3_exp(np.arange(T)[:, None] * twist + noise * rng.normal(size=(T, 6)))
    est.pose_cov = np.tile(np.diag([0.01, 0.02, 0.005, 1e-4, 1e-4, 1e-4]), (T, 1, 1))
    est.landmarks = rng.uniform(-20, 80, (M, 3))
    est.landmarks[:3] = np.nan
    est.landmark_cov = np.tile(np.eye(3), (M, 1, 1))
    return est


def _check_png(path):
    data = path.read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 5000, path
    assert not list(path.parent.glob(".*.tmp")), "temporary files left behind"


@pytest.fixture
def ests():
    return {
        "dead-reckoning": _est("dead-reckoning", noise=0.05, seed=1),
        "ekf-joint": _est("ekf-joint", noise=0.01, seed=2),
        "smoother": _est("smoother"),
    }


def test_all_figures_are_written(tmp_path, ests):
    truth = ests["smoother"].poses
    gt_pos = truth[:, :3, 3]
    _check_png(plots.plot_trajectories(tmp_path / "traj.png", ests, gt_pos, "test"))
    _check_png(plots.plot_map(tmp_path / "map.png", ests["ekf-joint"], gt_pos, ests["smoother"].landmarks))
    _check_png(plots.plot_error_over_distance(tmp_path / "err.png", ests, np.arange(70), truth[:70]))
    ekfs = {"ekf-joint": ests["ekf-joint"], "ekf-decoupled": _est("ekf-decoupled", noise=0.02)}
    _check_png(plots.plot_vs_smoother(tmp_path / "vs.png", ekfs, ests["smoother"]))
    rng = np.random.default_rng(0)
    series = {"ekf-joint": rng.chisquare(6, 80), "smoother": np.r_[np.nan, rng.chisquare(6, 79)]}
    _check_png(plots.plot_nees(tmp_path / "nees.png", series, dof=6, n_runs=1))
    _check_png(plots.plot_nees(tmp_path / "anees.png", series, dof=6, n_runs=20,
                               times=np.arange(80) * 0.1))


def test_figures_without_ground_truth_or_landmarks(tmp_path, ests):
    bare = _est("dead-reckoning")
    bare.landmarks[:] = np.nan
    _check_png(plots.plot_trajectories(tmp_path / "t.png", {"dead-reckoning": bare}))
    _check_png(plots.plot_map(tmp_path / "m.png", bare))
    _check_png(plots.plot_vs_smoother(tmp_path / "v.png", {}, ests["smoother"]))


def test_distance_travelled():
    p = np.array([[0, 0, 0], [3, 4, 0], [3, 4, 2.0]])
    assert np.allclose(plots.distance_travelled(p), [0, 5, 7])
