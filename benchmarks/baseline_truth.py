"""Which stereo baseline a drive's ground truth and its pixels agree on, beside the file's.

    .venv/bin/python benchmarks/baseline_truth.py [FILE.npz ...]

Default: the three editions of KITTI 0027 (../shared/data/kitti-pr3, kitti-pr3-2019 and
kitti-utias). For each drive with ground truth it prints, per depth band, the observations used
and the median of the measured disparities over the ones the file's baseline predicts at the
ground truth's depths (eval.baseline_truth: each track triangulated from its left-image rays
alone, seen from the ground truth's camera poses), and the baseline the near bands imply. A
ratio of 1.012 means the pixels' disparities are 1.2 % larger than the file's baseline allows:
vision's translations come out 1.2 % short of the truth's.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from vislam.eval.baseline_truth import baseline_from_truth
from vislam.eval.datasets import data_dir_2019, drive_path
from vislam.eval.groundtruth import find_ground_truth
from vislam.eval.loader import load_sequence


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path)
    args = parser.parse_args()
    files = args.files or [drive_path("0027"), data_dir_2019() / "0027.npz",
                           drive_path("0027").parents[1] / "kitti-utias" / "0027.npz"]
    for path in files:
        seq = load_sequence(path)
        gt = find_ground_truth(path)
        if gt is None or gt.camera_poses is None:
            print(f"{path}: no ground truth, skipped")
            continue
        o = seq.obs
        fit = baseline_from_truth(gt.camera_poses, o.frame_index, o.track, o.z,
                                  seq.calibration.K, seq.calibration.baseline)
        print(f"{path} ({seq.n_frames} frames, {fit.n_tracks} tracks triangulated)")
        print("  depth (m)   observations   measured / predicted disparity")
        for band in fit.bands:
            print(f"  {band.near:4.0f}-{band.far:<4.0f}   {band.n_observations:12d}   {band.ratio:.4f}")
        print(f"  nearer than {fit.near_limit:.0f} m: {fit.ratio:.4f}; the file's baseline "
              f"{fit.baseline:.4f} m, the pixels' {fit.pixels_baseline:.4f} m")


if __name__ == "__main__":
    main()
