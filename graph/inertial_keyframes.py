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
batch closes the returns. This module holds the keyframes and their drive; the pass over them
is :func:`graph.inertial_smoother.keyframe_solve`.
"""

from __future__ import annotations

import numpy as np

from vislam.ekf.inertial import InertialDrive, with_frames


def keyframes(n_frames: int, stride: int) -> np.ndarray:
    """The keyframes (K,): every ``stride``-th frame from 0, and the last frame."""
    if stride < 1:
        raise ValueError(f"keyframe stride must be >= 1, got {stride}")
    return np.unique(np.r_[np.arange(0, n_frames, stride), n_frames - 1]).astype(np.int64)


def keyframe_drive(drive: InertialDrive, frames: np.ndarray) -> InertialDrive:
    """``drive`` with the camera frames ``frames`` only (their stamps and observations; the IMU
    and everything else unchanged)."""
    return with_frames(drive, frames)
