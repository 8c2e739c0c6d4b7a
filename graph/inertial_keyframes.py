"""The raw-IMU smoother's initial values from keyframes: the incremental (iSAM2) pass over every
``stride``-th camera frame, the frames between predicted by the preintegrated IMU.

The batch solve (:func:`graph.inertial_smoother.batch_solve`) needs initial values in the basin
of its minimum, not an estimate: a track's landmark and the states of every frame. The full
incremental pass costs about 30 ms and 3 MB a frame on a room flight (an iSAM2 update per ten
frames, whose cliques hold the separators of the 100-400 landmarks in view, and a Python loop
over every observation), so 5 minutes at 20 Hz would take minutes and 20 GB. Over keyframes
(:func:`keyframe_drive`: the frames ``0, stride, 2 stride, ...`` and the last, their
observations only, one IMU factor preintegrated across each keyframe interval by
:func:`graph.inertial_smoother.build_problem`) the same pass costs ``1 / stride`` of that, and
the frames in between are predicted from the keyframe before them (0.5 s of IMU at the default
stride: millimetres against the batch's minimum). The pass starts a new landmark for a track's
return after a gap (``return_gap``), so that the Bayes tree stays as narrow as odometry's; the
batch closes the returns.
"""

from __future__ import annotations

import dataclasses
import time

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, L, V, X

from vislam.ekf.inertial import InertialDrive
from vislam.ekf.sequence import Observations


def keyframes(n_frames: int, stride: int) -> np.ndarray:
    """The keyframes (K,): every ``stride``-th frame from 0, and the last frame."""
    if stride < 1:
        raise ValueError(f"keyframe stride must be >= 1, got {stride}")
    return np.unique(np.r_[np.arange(0, n_frames, stride), n_frames - 1]).astype(np.int64)


def keyframe_drive(drive: InertialDrive, frames: np.ndarray) -> InertialDrive:
    """``drive`` with the camera frames ``frames`` only (their stamps and observations; the IMU
    and everything else unchanged)."""
    obs = drive.obs
    slot = np.full(drive.n_frames, -1, dtype=np.int64)
    slot[frames] = np.arange(frames.size)
    f = slot[obs.frame_index]
    keep = f >= 0
    sub = Observations.from_rows(f[keep], obs.track[keep], obs.z[keep], int(frames.size))
    return dataclasses.replace(drive, timestamps=np.asarray(drive.timestamps)[frames], obs=sub)


def keyframe_solve(problem, stride: int, return_gap: int | None):
    """A :class:`graph.inertial_smoother.Solution` for every frame of ``problem``'s drive from
    the incremental pass over its keyframes (module docstring): the keyframes' states and
    landmarks as that pass left them, the other frames predicted by ``problem.pims`` from the
    keyframe before. ``return_gap`` in frames of the full drive. Rows and tracks are those of
    the keyframe pass (its graph is not returned: an initial value, not an estimate)."""
    from vislam.graph.inertial_smoother import Solution, _triangulate, build_problem, incremental_solve

    start = time.perf_counter()
    drive = problem.drive
    frames = keyframes(drive.n_frames, stride)
    gap = None if return_gap is None else max(1, int(return_gap) // int(stride))
    sub = dataclasses.replace(build_problem(keyframe_drive(drive, frames), problem.settings), return_gap=gap)
    inc = incremental_solve(sub)
    values = gtsam.Values()
    for i, k in enumerate(frames.tolist()):
        nav = gtsam.NavState(inc.values.atPose3(X(i)), inc.values.atVector(V(i)))
        bias = inc.values.atConstantBias(B(i))
        stop = int(frames[i + 1]) if i + 1 < frames.size else k + 1
        for f in range(k, stop):
            if f > k:
                nav = problem.pims[f - 1].predict(nav, bias)
            values.insert(X(f), nav.pose())
            values.insert(V(f), nav.velocity())
            values.insert(B(f), bias)
    anchors = dict(inc.anchors)
    for j in inc.tracks.tolist():
        values.insert(L(j), inc.values.atPoint3(L(j)))
    # The tracks the incremental pass over every frame would have taken (it triangulates a
    # track from its first observations, then adds all later ones) but the keyframes missed
    # (seen in fewer than min_track_frames keyframes): from all their observations.
    obs, s = drive.obs, problem.settings
    order = np.argsort(obs.track, kind="stable")
    bounds = np.searchsorted(obs.track[order], np.arange(drive.n_tracks + 1))
    all_frames = obs.frame_index
    for j in range(drive.n_tracks):
        rs = order[bounds[j]:bounds[j + 1]]
        if j in anchors or rs.size < s.min_track_frames:
            continue
        found = _triangulate(problem, values, all_frames[rs], obs.z[rs])
        if found is None or found[1].sum() < s.min_track_frames:
            continue
        anchors[j] = found[0]
        values.insert(L(j), found[0])
    tracks = np.array(sorted(anchors), dtype=np.int64)
    return Solution(values, tracks, np.zeros(0, dtype=np.int64), anchors, gtsam.NonlinearFactorGraph(), 0,
                    {"isam2_s": time.perf_counter() - start})
