"""graph/marginals.py on drives of every shape: a chain of short tracks, a loop whose landmarks
of the start are seen again at the end, a room whose ~20 landmarks are seen in every frame.
Every block EM and the outputs need (poses, consecutive pose pairs, landmarks, another
variable's) equals ``gtsam.Marginals`` and the dense inverse of ``H``; the solves equal a dense
solve; the long-lived landmarks go to the border and the band stays that of the short tracks.
The graphs come from benchmarks/marginals_scaling.py (which times them up to 4,541 frames)."""

import gtsam
import numpy as np
import pytest

from vislam.ekf.errors import EstimationError
from vislam.graph.marginals import (
    _schur_marginals,
    border_landmarks,
    eliminate_landmarks,
    gtsam_marginals,
    information_solver,
    linearise,
    pose_chain_covariances,
    schur_marginals,
    whitened_system,
)
from vislam.graph.pose_conversions import L, X

RTOL = 1e-9


@pytest.fixture(scope="module")
def shapes(benchmark_script):
    build = benchmark_script("marginals_scaling").build
    return {"chain": build("chain", 80, seed=1), "loop": build("loop", 150, seed=2),
            "room": build("room", 90, seed=3)}


def _dense(g):
    system, reduced = linearise(g.graph, g.values, g.n_frames, "test")
    H = (system.A.T @ system.A).toarray()
    return system, reduced, H, np.linalg.inv(H)


def _close(got, want):
    """Equal to ``RTOL`` of the block's largest entry (cross terms can be near zero)."""
    np.testing.assert_allclose(got, want, rtol=0, atol=RTOL * np.abs(want).max())


def test_the_border_takes_the_long_landmarks_only(shapes):
    """The chain's short tracks stay in the band; the loop's landmarks seen at the start and
    the end and the room's landmarks go to the border; the band is then a few poses wide."""
    chain, loop, room = (linearise(g.graph, g.values, g.n_frames, "test")[1]
                         for g in (shapes["chain"], shapes["loop"], shapes["room"]))
    assert chain.border is None
    assert loop.border is not None and 0 < len(loop.border.tracks) < len(loop.tracks) // 4
    assert room.border is not None and len(room.border.tracks) >= 15
    assert (loop.w + 1) // 6 < 40 and (room.w + 1) // 6 <= 2


def test_border_rule_keeps_short_tracks_and_takes_drive_long_ones():
    first = np.arange(1000)
    assert not border_landmarks(first, first + 8, 1, 1000).any()  # KITTI-like: all in the band
    last = first + 8
    last[:5] = 999  # five landmarks seen from their start to the end of the drive
    assert np.array_equal(np.flatnonzero(border_landmarks(first, last, 1, 1000)), np.arange(5))


@pytest.mark.parametrize("shape", ["chain", "loop", "room"])
def test_every_block_equals_the_dense_inverse(shapes, shape):
    g = shapes[shape]
    system, reduced, H, Hi = _dense(g)
    T = g.n_frames
    pose_cov, landmark_cov, pair_cov, log_det = _schur_marginals(reduced, T, g.n_tracks, pairs=True)
    for k in range(T):
        o = system.offsets[X(k)]
        _close(pose_cov[k], Hi[o:o + 6, o:o + 6])
        if k + 1 < T:
            o1 = system.offsets[X(k + 1)]
            _close(pair_cov[k], Hi[o:o + 6, o1:o1 + 6])
    for j in g.tracks:
        o = system.offsets[L(int(j))]
        _close(landmark_cov[j], Hi[o:o + 3, o:o + 3])
    assert np.isnan(landmark_cov[np.setdiff1d(np.arange(g.n_tracks), g.tracks)]).all()
    assert log_det == pytest.approx(np.linalg.slogdet(H)[1], rel=RTOL)
    chain_cov, chain_pairs, chain_log_det = pose_chain_covariances(reduced, T, with_log_det=True)
    np.testing.assert_array_equal(chain_cov, pose_cov)
    np.testing.assert_array_equal(chain_pairs, pair_cov)
    assert chain_log_det == log_det


@pytest.mark.parametrize("shape", ["loop", "room"])
def test_marginals_equal_gtsam_marginals(shapes, shape):
    g = shapes[shape]
    fast = schur_marginals(g.graph, g.values, g.n_frames, g.tracks, g.n_tracks)
    ref = gtsam_marginals(g.graph, g.values, g.n_frames, g.tracks, g.n_tracks)
    for a, b in zip(fast, ref):
        assert np.array_equal(np.isfinite(a), np.isfinite(b))
        ok = np.isfinite(b)
        for got, want in zip(a[ok.all(axis=(1, 2))], b[ok.all(axis=(1, 2))]):
            _close(got, want)


@pytest.mark.parametrize("shape", ["chain", "loop", "room"])
def test_solves_equal_a_dense_solve(shapes, shape):
    g = shapes[shape]
    system, reduced, H, Hi = _dense(g)
    B = np.random.default_rng(0).standard_normal((H.shape[0], 4))
    want = np.linalg.solve(H, B)
    _close(reduced.solve(B), want)
    _close(reduced.solve(B[:, 0]), want[:, 0])
    n_p = 6 * g.n_frames  # the poses are H's last columns
    B_p = np.zeros_like(B)
    B_p[-n_p:] = B[-n_p:]
    _close(reduced.pose_solve(B[-n_p:]), np.linalg.solve(H, B_p)[-n_p:])


def test_a_forced_border_gives_the_same_numbers_as_the_band(shapes):
    """The same room graph with its landmarks all in the band, and with a border chosen by hand
    (some long landmarks in it, others left in the band)."""
    g = shapes["room"]
    system, _ = linearise(g.graph, g.values, g.n_frames, "test")
    H = (system.A.T @ system.A).tocsr()
    n_l = 3 * len(g.tracks)
    runs = [_schur_marginals(eliminate_landmarks(H, n_l, g.n_frames, g.tracks, long_tracks=lt),
                             g.n_frames, g.n_tracks, pairs=True)
            for lt in (np.array([], dtype=int), g.tracks[::3])]
    assert eliminate_landmarks(H, n_l, g.n_frames, g.tracks, long_tracks=[]).border is None
    for a, b in zip(runs[0][:3], runs[1][:3]):
        ok = np.isfinite(a).all(axis=(1, 2))
        for got, want in zip(b[ok], a[ok]):
            _close(got, want)
    assert runs[1][3] == pytest.approx(runs[0][3], rel=RTOL)


def test_another_variable_joins_the_border(shapes):
    """A variable that is neither a pose nor a landmark (here a Point3 ``b0`` observed from
    every pose, as the gyro bias touches every motion factor): solves and its covariance equal
    the dense ones and gtsam.Marginals'."""
    g = shapes["room"]
    graph, values = gtsam.NonlinearFactorGraph(g.graph), gtsam.Values(g.values)
    bias = gtsam.symbol("b", 0)
    point = np.array([0.3, 4.0, 0.2])
    pixel = gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
    K = gtsam.Cal3_S2Stereo(500.0, 500.0, 0.0, 320.0, 240.0, 0.5)
    for k in range(g.n_frames):
        pose = values.atPose3(X(k))
        z = gtsam.StereoCamera(pose, K).project(point)
        graph.add(gtsam.GenericStereoFactor3D(z, pixel, X(k), bias, K))
    values.insert(bias, point + 0.01)
    system = linearise(graph, values, g.n_frames, "test")[0]
    reduced = information_solver(system.A, system.keys, g.n_frames)
    assert reduced.border.other_keys == [bias]
    H = (system.A.T @ system.A).toarray()
    Hi = np.linalg.inv(H)
    o = system.offsets[bias]
    _close(reduced.other_covariance(bias), Hi[o:o + 3, o:o + 3])
    _close(reduced.other_covariance(bias), gtsam.Marginals(graph, values).marginalCovariance(bias))
    B = np.random.default_rng(1).standard_normal((H.shape[0], 3))
    _close(reduced.solve(B), Hi @ B)
    pose_cov, landmark_cov, pair_cov, log_det = _schur_marginals(reduced, g.n_frames, g.n_tracks,
                                                                 pairs=True)
    for k in (0, g.n_frames // 2, g.n_frames - 1):
        p = system.offsets[X(k)]
        _close(pose_cov[k], Hi[p:p + 6, p:p + 6])
    for j in g.tracks:
        p = system.offsets[L(int(j))]
        _close(landmark_cov[j], Hi[p:p + 3, p:p + 3])
    assert log_det == pytest.approx(np.linalg.slogdet(H)[1], rel=RTOL)
    with pytest.raises(EstimationError, match="not a variable"):
        reduced.other_covariance(gtsam.symbol("b", 1))


def test_an_undetermined_border_variable_is_refused(shapes):
    """Two other variables tied only to each other: the border's Schur complement is
    singular, and the solver says so instead of returning numbers."""
    g = shapes["room"]
    graph, values = gtsam.NonlinearFactorGraph(g.graph), gtsam.Values(g.values)
    b0, b1 = gtsam.symbol("b", 0), gtsam.symbol("b", 1)
    values.insert(b0, np.zeros(3))
    values.insert(b1, np.ones(3))
    graph.add(gtsam.BetweenFactorPoint3(b0, b1, gtsam.Point3(1, 1, 1),
                                        gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
    system = whitened_system(graph, values, "test")
    with pytest.raises(EstimationError, match="not positive definite near .*b1"):
        information_solver(system.A, system.keys, g.n_frames)
