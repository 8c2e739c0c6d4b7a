"""Split-half cross-validation of the smoother's heading: are its yaw errors the tracks' own?

    .venv/bin/python benchmarks/split_half.py [FILE.npz ...] [--windows 6] [--frames N]

For each drive (default: the simulator's default drive, which has exact truth) the script
solves the smoother three times under the model `vislam bench` identifies (cached): on every
track, on the even tracks only and on the odd tracks only, each time started from ekf-joint on
the same observations, as bench does. Per stretch of the drive it prints each solution's yaw
error against ground truth at the stretch's end, the two halves' yaw difference, and the
standard deviation that difference would have if the halves' errors were independent
(``sqrt(var_even + var_odd)``; an upper bound, since both halves use the same velocities).

How to read it. Errors that belong to the tracks (a tracker's noise, even when it drifts along
each track) are independent between the halves: the halves then disagree with each other about
as much as either disagrees with the truth. An error common to every track (the images'
calibration, the ground truth) moves both halves together: they agree with each other within
their standard deviation while both leave the truth by several. The residuals show such an
error only where it leaves a pattern across the image, as the radial lens term does
(:mod:`graph.radial`); where every track agrees with it, they cannot.

Issue 13 (the smoother's NEES on shared 0027 is 21 against at most 12): from 76 s on, both
halves are 0.039-0.058 rad off the truth in yaw (2.1-3.7 of their own standard deviations, 0.014-
0.019 rad; the even half -0.050, -0.058, -0.055 and the odd half -0.045, -0.047, -0.039 at 76,
95 and 114 s), while they differ from each other by at most 0.016 rad at any stretch's end
(sd 0.013-0.026): the drift is common to the tracks. The 2019 edition's independent tracker
leans the same way where its clean gyro lets it (-0.013 rad at 57 s, 1.6 sd).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

HALVES = ("all", "even", "odd")


def split_tracks(seq, parity: int):
    """``seq`` (ekf.sequence.Sequence) with only the observations of tracks whose index has
    ``parity`` (0 even, 1 odd)."""
    from vislam.ekf.sequence import Observations

    obs = seq.obs
    frame = np.repeat(np.arange(seq.n_frames), np.diff(obs.frame_ptr))
    keep = obs.track % 2 == parity
    return dataclasses.replace(seq, obs=Observations.from_rows(
        frame[keep], obs.track[keep], obs.z[keep], seq.n_frames))


def solve_halves(seq, config) -> dict:
    """The smoother's Estimate on every track and on each half, each started from ekf-joint on
    the same observations (as `vislam bench` starts it)."""
    from vislam.eval.registry import get_estimator
    from vislam.graph.settings import SmootherSettings

    ekf, smoother, settings = get_estimator("ekf-joint"), get_estimator("smoother"), SmootherSettings()
    drives = {"all": seq, "even": split_tracks(seq, 0), "odd": split_tracks(seq, 1)}
    out = {}
    for name, drive in drives.items():
        initial = ekf(drive, config, progress=None, initial=None, smoother=settings)
        out[name] = smoother(drive, config, progress=None, initial=initial, smoother=settings)
    return out


def yaw_of(R: np.ndarray) -> np.ndarray:
    """The z component of ``Log(R)`` for rotations (T, 3, 3)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()[:, 2]


def compare(ests: dict, gt, n_windows: int) -> list[dict]:
    """Per stretch: the time at its end, each solution's yaw error against ``gt`` there
    (``Log(R_est^T R_true)``, body z, rad) and its standard deviation, the halves' yaw
    difference (``Log(R_even^T R_odd)``) and its sd were they independent."""
    first = ests["all"]
    keep = gt.frames < first.n_frames
    frames, truth = gt.frames[keep], gt.poses[keep]
    rows = []
    for part in np.array_split(np.arange(1, frames.size), n_windows):
        k = frames[part[-1]]
        R_true = truth[part[-1], :3, :3]
        row = {"to_s": float(first.timestamps[k] - first.timestamps[0])}
        for name in HALVES:
            R = ests[name].poses[k, :3, :3]
            row[f"{name}_error"] = float(yaw_of((R.T @ R_true)[None])[0])
            row[f"{name}_sd"] = float(np.sqrt(ests[name].pose_cov[k, 5, 5]))
        row["difference"] = float(yaw_of((ests["even"].poses[k, :3, :3].T
                                          @ ests["odd"].poses[k, :3, :3])[None])[0])
        row["difference_sd"] = float(np.hypot(row["even_sd"], row["odd_sd"]))
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="*", type=Path)
    parser.add_argument("--windows", type=int, default=6, help="stretches per drive")
    parser.add_argument("--frames", type=int, default=None,
                        help="length of the default simulated drive (no files given)")
    args = parser.parse_args(argv)

    from vislam.ekf.config import FilterConfig
    from vislam.eval.drives import identify_models, load_bench_sequence, simulated_sequence
    from vislam.graph.settings import SmootherSettings

    drives = ([load_bench_sequence(p) for p in args.files] if args.files
              else [simulated_sequence(0, args.frames)])
    for bs in identify_models(drives, FilterConfig(), SmootherSettings()):
        where = bs.path or bs.name
        if bs.gt is None:
            print(f"{where}: no ground truth, nothing to compare")
            continue
        rows = compare(solve_halves(bs.sequence, bs.config or FilterConfig()), bs.gt, args.windows)
        print(f"\n{where}: yaw error against ground truth at each stretch's end (rad, its sd)")
        print("   to (s)   all               even              odd               even - odd (sd if independent)")
        for r in rows:
            cells = "  ".join(f"{r[f'{n}_error']:+.4f} ({r[f'{n}_sd']:.4f})" for n in HALVES)
            print(f"  {r['to_s']:6.0f}   {cells}  {r['difference']:+.4f} ({r['difference_sd']:.4f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
