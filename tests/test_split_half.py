"""benchmarks/split_half.py: the halves it makes and the yaw figures it reports."""

import dataclasses

import numpy as np
from scipy.stats import chi2

from vislam.ekf.config import FilterConfig
from vislam.ekf.estimate import Estimate
from vislam.ekf.geometry import se3_exp
from vislam.eval.groundtruth import GroundTruth
from vislam.eval.simulate import DEFAULT_SIM, simulate

def _rows(seq):
    frame = np.repeat(np.arange(seq.n_frames), np.diff(seq.obs.frame_ptr))
    return {(int(f), int(t)): tuple(z) for f, t, z in zip(frame, seq.obs.track, seq.obs.z)}


def _estimate(poses, yaw_sd):
    T = len(poses)
    cov = np.tile(np.diag([0.1, 0.1, 0.1, 0.01, 0.01, yaw_sd]) ** 2, (T, 1, 1))
    return Estimate(estimator="x", timestamps=0.1 * np.arange(T), poses=poses, pose_cov=cov,
                    landmarks=np.zeros((0, 3)), landmark_cov=np.zeros((0, 3, 3)),
                    step_time_s=np.zeros(T), n_updates=np.zeros(T, int),
                    n_rejected=np.zeros(T, int), n_initialised=np.zeros(T, int))


def test_the_halves_split_the_observations_by_track_parity(benchmark_script):
    seq = simulate(dataclasses.replace(DEFAULT_SIM, n_frames=30)).sequence
    split = benchmark_script("split_half").split_tracks
    even, odd = _rows(split(seq, 0)), _rows(split(seq, 1))
    assert even and odd and not set(even) & set(odd)
    assert {**even, **odd} == _rows(seq)
    assert all(t % 2 == 0 for _, t in even) and all(t % 2 == 1 for _, t in odd)


def test_compare_reports_each_yaw_error_and_the_halves_difference(benchmark_script):
    """Estimates that yaw away from the truth by known amounts: 'all' by 1e-3 rad a frame,
    'even' by 2e-3 and 'odd' by -1e-3; at each stretch's end the errors are those (error =
    Log(R_est^T R_true), so minus the yaw added), the difference even - odd is Log(R_even^T R_odd)
    and its sd the two halves' sds in quadrature."""
    T = 31
    truth = se3_exp(np.c_[np.full((T, 1), 1.0), np.zeros((T, 4)), 0.02 * np.ones((T, 1))]
                    * np.arange(T)[:, None] / 10)
    frames = np.arange(T)

    def yawed(rate):
        return truth @ se3_exp(np.c_[np.zeros((T, 5)), rate * frames])

    ests = {"all": _estimate(yawed(1e-3), 0.01), "even": _estimate(yawed(2e-3), 0.02),
            "odd": _estimate(yawed(-1e-3), 0.03)}
    rows = benchmark_script("split_half").compare(ests, GroundTruth(frames=frames, poses=truth, source="test"), 3)
    assert [r["to_s"] for r in rows] == [1.0, 2.0, 3.0]
    for r in rows:
        k = round(10 * r["to_s"])
        assert np.isclose(r["all_error"], -1e-3 * k) and np.isclose(r["even_error"], -2e-3 * k)
        assert np.isclose(r["odd_error"], 1e-3 * k)
        assert np.isclose(r["difference"], -3e-3 * k)
        assert np.isclose(r["all_sd"], 0.01) and np.isclose(r["difference_sd"], np.hypot(0.02, 0.03))


def test_on_white_simulated_pixels_the_halves_agree_within_their_sd(benchmark_script):
    """The simulator's pixel noise is white and independent between tracks: each half knows its
    heading less well than all tracks together, and the halves' yaw difference, normalised by
    its sd were they independent (an upper bound: they share the velocities), has a mean square
    within the chi-square's 99.9 % point over two drives' stretches."""
    script, z2 = benchmark_script("split_half"), []
    for seed in (0, 1):
        result = simulate(dataclasses.replace(DEFAULT_SIM, n_frames=200, seed=seed))
        gt = GroundTruth(frames=np.arange(result.sequence.n_frames), poses=result.poses,
                         source="sim")
        for r in script.compare(script.solve_halves(result.sequence, FilterConfig()), gt, 3):
            assert r["even_sd"] > 1.2 * r["all_sd"] and r["odd_sd"] > 1.2 * r["all_sd"]
            z2.append((r["difference"] / r["difference_sd"]) ** 2)
    assert np.mean(z2) < chi2.ppf(0.999, len(z2)) / len(z2)
