"""A drive made again from a results folder (:meth:`eval.results.DriveResult.load_drive`): its
measurements and its truth, and the truth each estimate is scored against."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class DriveData:
    """A drive's measurements (``ekf.sequence.Sequence``) and its truth where known: poses
    ``truth_poses`` (n, 4, 4) world_T_imu at steps ``truth_frames`` (n,), and the true landmark
    of each track (n_tracks, 3)."""

    sequence: object
    truth_frames: np.ndarray | None
    truth_poses: np.ndarray | None
    landmark_truth: np.ndarray | None

    def _truth(self):
        from vislam.eval.groundtruth import GroundTruth

        if self.truth_poses is None:
            return None
        return GroundTruth(np.asarray(self.truth_frames), np.asarray(self.truth_poses), "results")

    def truth_for(self, est) -> tuple[np.ndarray, np.ndarray] | None:
        """``(frames, poses)`` of the truth ``est`` is scored against, as ``vislam bench`` scores
        it: a raw-IMU drive's moved into the estimate's own gauge (yaw and position at frame 0,
        :func:`eval.bench_scores.truth_in_gauge`), any other as it is; None without truth."""
        from vislam.eval.bench_scores import truth_in_gauge

        gt = self._truth()
        if gt is None:
            return None
        moved = truth_in_gauge(gt, self.sequence, est)
        return np.asarray(moved.frames), np.asarray(moved.poses)

    def landmarks_for(self, est) -> np.ndarray | None:
        """The true landmarks ``est``'s map is scored against (moved as :meth:`truth_for`)."""
        from vislam.eval.bench_scores import landmark_truth_in_gauge

        gt = self._truth()
        if gt is None:
            return self.landmark_truth
        return landmark_truth_in_gauge(gt, self.sequence, est, self.landmark_truth)


def read_drive_data(path: Path) -> DriveData:
    """The drive of data file ``path`` with the ground truth and true landmarks found beside it,
    as ``vislam bench`` read it before applying its model."""
    from vislam.eval.groundtruth import find_ground_truth
    from vislam.eval.inertial_files import is_inertial_file
    from vislam.eval.loader import load_sequence
    from vislam.eval.safe_reading import read_npz

    if is_inertial_file(Path(path)):  # a raw-IMU drive: read as vislam bench reads it
        from vislam.eval.drives import load_bench_sequence

        bs = load_bench_sequence(Path(path))
        return DriveData(bs.sequence, None if bs.gt is None else np.asarray(bs.gt.frames),
                         None if bs.gt is None else np.asarray(bs.gt.poses), bs.landmark_truth)
    seq = load_sequence(path)
    gt = find_ground_truth(path)
    landmarks = None
    beside = Path(path).with_name(f"{Path(path).stem}_landmarks.npz")
    if beside.is_file():
        held = read_npz(beside, ("landmarks",)).get("landmarks")
        if held is not None and held.shape == (seq.n_tracks, 3):
            landmarks = np.asarray(held, dtype=float)
    return DriveData(seq, None if gt is None else np.asarray(gt.frames),
                     None if gt is None else np.asarray(gt.poses), landmarks)
