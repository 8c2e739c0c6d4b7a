"""Tracks that come back after a gap (issue 36): the filters keep their landmark through the gap
(ekf.driver), at most MAX_CARRIED at once; cleaning splits a return only when its pixels do not
fit; the smoother ties every observation of a track to one landmark."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vislam.ekf.cleaning import clean_sequence, inconsistent_returns
from vislam.ekf.config import FilterConfig
from vislam.ekf.driver import carried_gaps, carry_tracks, run_filter
from vislam.ekf.invariant import InvariantEKF
from vislam.ekf.joint import JointEKF
from vislam.ekf.model import apply_model
from vislam.ekf.sequence import Calibration, Observations, Sequence
from vislam.eval.consistency import pose_nees
from vislam.eval.sim_config import scenario_config
from vislam.eval.simulate import simulate

CAL = Calibration(K=np.array([[700.0, 0, 600], [0, 700, 180], [0, 0, 1]]), baseline=0.5,
                  cam_T_imu=np.eye(4))


def _sequence(tracks_frames: dict[int, list[int]], T: int = 12) -> Sequence:
    rows = [(f, j, [300.0 + j, 100.0 + f, 280.0 + j, 100.0 + f])
            for j, frames in tracks_frames.items() for f in frames]
    f, t, z = zip(*rows)
    obs = Observations.from_rows(np.array(f), np.array(t), np.array(z), T)
    return Sequence("gaps", 0.1 * np.arange(T), np.zeros((T, 3)), np.zeros((T, 3)), obs,
                    max(tracks_frames) + 1, CAL)


def test_every_gap_is_carried_under_the_cap_and_nothing_changes():
    seq = _sequence({0: [0, 1, 5, 6], 1: [0, 2, 3], 2: [1, 2, 3, 4]})
    rows, carried = carried_gaps(seq, max_carried=2)
    assert rows.size == 2 and carried.all()
    same, n = carry_tracks(seq, max_carried=2)
    assert same is seq and n == 0


def test_over_the_cap_the_longest_unseen_is_split_into_a_new_track():
    # Frames 2-4: tracks 0 (last seen 1), 1 (last seen 0) and 2 (last seen 1) are all in gaps.
    seq = _sequence({0: [0, 1, 5, 6], 1: [0, 5, 7], 2: [1, 5], 3: [0, 1, 2, 3, 4, 5]})
    rows, carried = carried_gaps(seq, max_carried=2)
    gap_track = seq.obs.track[rows]
    frames = seq.obs.frame_index[rows]
    assert sorted(zip(gap_track.tolist(), frames.tolist(), carried.tolist())) == [
        (0, 5, True), (1, 5, False), (1, 7, True), (2, 5, True)]
    split, n = carry_tracks(seq, max_carried=2)
    assert n == 1 and split.n_tracks == 5
    assert split.track_origin.tolist() == [0, 1, 2, 3, 1]
    f = split.obs.frame_index
    assert sorted(f[split.obs.track == 1].tolist()) == [0]
    assert sorted(f[split.obs.track == 4].tolist()) == [5, 7]
    assert sorted(f[split.obs.track == 0].tolist()) == [0, 1, 5, 6]


@pytest.fixture(scope="module")
def room():
    result = simulate(scenario_config("room", n_frames=300, seed=0))
    seq, config = apply_model(result.sequence, FilterConfig(), result.model)
    return result, seq, config


class Recording:
    """Wraps a filter: the active tracks and their landmarks after each frame."""

    def __init__(self, inner):
        self.inner, self.name = inner, inner.name
        self.active: list[dict[int, np.ndarray]] = []

    def __getattr__(self, key):
        return getattr(self.inner, key)

    def marginalise(self, tracks):
        self.inner.marginalise(tracks)
        lm = self.inner.active_landmarks()
        self.active.append(dict(zip(lm.tracks.tolist(), lm.mean.copy())))


@pytest.mark.parametrize("make", [JointEKF, InvariantEKF])
def test_a_filter_keeps_a_returning_landmark_through_its_gap(room, make):
    result, seq, config = room
    cleaned, report = clean_sequence(seq, min_disparity=config.min_disparity)
    assert report.n_tracks_split == 0
    rec = Recording(make())
    est = run_filter(rec, seq, config)
    assert est.landmarks.shape[0] == seq.n_tracks and "n_carry_splits" not in est.info
    # a track with a gap of at least a second
    obs = cleaned.obs
    f = obs.frame_index
    order = np.lexsort((f, obs.track))
    t, fs = obs.track[order], f[order]
    i = np.flatnonzero((t[1:] == t[:-1]) & (fs[1:] - fs[:-1] > 10))[0] + 1
    j, left, back = int(t[i]), int(fs[i - 1]), int(fs[i])
    for k in range(left, back):  # in the state, with the same estimate, all through the gap
        assert j in rec.active[k]
    np.testing.assert_allclose(rec.active[back - 1][j], rec.active[left][j], atol=0.2)
    assert not np.array_equal(rec.active[back][j], rec.active[back - 1][j])  # updated on return
    nees = pose_nees(est, np.arange(seq.n_frames), result.poses)
    assert 1.0 < np.nanmean(nees) < 20.0


def test_a_filter_over_the_cap_still_runs_and_maps_the_pieces_back(room):
    result, seq, config = room
    est = run_filter(InvariantEKF(), seq, config, max_carried=3)
    assert est.info["n_carry_splits"] > 0
    origin = np.asarray(est.info["track_origin"])
    assert origin.size == est.landmarks.shape[0] > seq.n_tracks
    assert set(origin.tolist()) == set(range(seq.n_tracks))
    nees = pose_nees(est, np.arange(seq.n_frames), result.poses)
    assert np.nanmean(nees) < 20.0


def test_cleaning_keeps_consistent_returns_and_splits_an_inconsistent_one():
    result = simulate(scenario_config("room", n_frames=600, seed=1))
    seq = result.sequence
    assert not inconsistent_returns(seq).any()
    cleaned, report = clean_sequence(seq)
    assert report.n_tracks_split == 0 and cleaned.n_tracks == seq.n_tracks
    # Move one track's observations after a long gap 150 px to the right: another point.
    obs = seq.obs
    f = obs.frame_index
    order = np.lexsort((f, obs.track))
    t, fs = obs.track[order], f[order]
    gaps = np.flatnonzero((t[1:] == t[:-1]) & (fs[1:] - fs[:-1] > 20)) + 1
    for i in gaps:
        j, back = int(t[i]), int(fs[i])
        z = obs.z.copy()
        later = (obs.track == j) & (f >= back)
        z[later, [0]] += 150.0
        z[later, [2]] += 150.0
        if not np.all(z[later][:, [0, 2]] < 1200):
            continue
        bad = dataclasses.replace(seq, obs=Observations(obs.frame_ptr, obs.track, z))
        cut = inconsistent_returns(bad)
        if not cut.any():
            continue  # not judged there (too few other tracks in both frames)
        assert np.flatnonzero(cut).tolist() == [int(order[i])]
        split, report = clean_sequence(bad)
        assert report.n_tracks_split == 1 and split.n_tracks == seq.n_tracks + 1
        new = split.obs.track[split.obs.frame_index >= back]
        assert split.track_origin[-1] == j
        assert (split.obs.track == j).sum() + (split.obs.track == seq.n_tracks).sum() \
            == (obs.track == j).sum()
        assert seq.n_tracks in new
        return
    pytest.fail("no judged return to corrupt")


def test_the_smoother_ties_every_observation_of_a_track_to_one_landmark():
    gtsam = pytest.importorskip("gtsam")
    from vislam.graph.factors import NoiseModels, usable_rows
    from vislam.graph.pose_conversions import L, X
    from vislam.graph.settings import SmootherSettings
    from vislam.graph.smoother import run_smoother

    short = simulate(scenario_config("room", n_frames=150, seed=0))
    seq, config = apply_model(short.sequence, FilterConfig(), short.model)
    rows, _ = usable_rows(seq, config.min_disparity)
    graph = gtsam.NonlinearFactorGraph()
    motion = np.tile(np.eye(6), (seq.n_frames - 1, 1, 1))
    noise = NoiseModels.create(seq, config, SmootherSettings(), motion)
    noise.add_stereo_factors(graph, rows)
    keys = np.array([[graph.at(i).keys()[0], graph.at(i).keys()[1]] for i in range(graph.size())])
    assert np.array_equal(keys[:, 0], X(0) + rows.frame) and np.array_equal(keys[:, 1], L(0) + rows.track)
    est = run_smoother(seq, config)
    assert est.landmarks.shape[0] == seq.n_tracks
    err = est.landmarks - short.landmarks
    assert np.nanmax(np.linalg.norm(err, axis=1)) < 0.5
    nees = pose_nees(est, np.arange(seq.n_frames), short.poses)
    assert 1.0 < np.nanmean(nees) < 20.0


def test_tracks_return_only_after_a_gap_longer_than_asked():
    from vislam.graph.isam2 import tracks_return

    seq = _sequence({0: [0, 1, 5, 6], 1: [0, 1, 2, 3]})
    assert tracks_return(seq, 3) and not tracks_return(seq, 4)
    assert not tracks_return(_sequence({0: [0, 1, 2], 1: [1, 2, 3]}), 1)


def test_isam2_holds_returning_observations_and_loses_nothing_by_it(room):
    """smoother-isam2 adds the observations of a landmark unseen for more than
    isam2_return_batch frames in batches (graph/isam2.py): every one of them still enters
    (the gate is as loose as frame by frame) and the estimate is as accurate."""
    from vislam.eval.metrics import ate_rmse
    from vislam.graph.isam2 import run_isam2
    from vislam.graph.settings import SmootherSettings

    result, seq, config = room
    runs = {}
    for batch in (1, SmootherSettings().isam2_return_batch):
        est = run_isam2(seq, config, settings=SmootherSettings(isam2_return_batch=batch))
        runs[batch] = (est.info["timing"]["held_observations"], int(est.n_updates.sum()),
                       ate_rmse(est.poses, result.poses, align="se3"),
                       float(np.nanmean(pose_nees(est, np.arange(seq.n_frames), result.poses))))
    (held_1, used_1, ate_1, _), (held_b, used_b, ate_b, nees_b) = runs.values()
    assert held_1 == 0 and held_b > 0, runs
    assert used_b >= 0.99 * used_1, runs
    assert ate_b <= 1.1 * ate_1 and 1.0 < nees_b < 20.0, runs


def test_isam2_on_a_drive_whose_tracks_never_return_is_unchanged():
    """A road's tracks never return: whatever isam2_return_batch is, the same estimate (a gap
    that track cleaning makes is not a return either: graph.isam2.tracks_return reads the drive
    before cleaning)."""
    from vislam.graph.isam2 import run_isam2
    from vislam.graph.settings import SmootherSettings

    road = simulate(scenario_config("road", n_frames=60, seed=1))
    seq, config = apply_model(road.sequence, FilterConfig(), road.model)
    a = run_isam2(seq, config, settings=SmootherSettings(isam2_return_batch=1))
    b = run_isam2(seq, config, settings=SmootherSettings(isam2_return_batch=10))
    assert np.array_equal(a.poses, b.poses) and np.array_equal(a.pose_cov, b.pose_cov)
    assert b.info["timing"]["held_observations"] == 0
