"""`vislam convert SOURCE --out DIR/NAME.npz [--gt FILE] [--tracks FILE]`: a drive in another
layout as vislam's file form, with its ground truth beside it where every command finds it.

``SOURCE`` is one of

- an **ASL folder** (EuRoC, TUM-VI: ``mav0/imu0/data.csv`` and the ``sensor.yaml`` files;
  :mod:`eval.asl`), with ``--tracks FILE``: a csv of ``timestamp [ns], track id, u, v[, uR, vR]``
  or gtsam's eqvio csv (``--tracks eqvio`` for the one in the gtsam package). Ground truth:
  ``--gt FILE`` or ``mav0/state_groundtruth_estimate0/data.csv``; written as
  ``DIR/groundtruth/NAME.csv`` (ASL/OpenVINS csv, cut to the drive's span);
- the word **eqvio**, or an eqvio csv (:mod:`eval.eqvio`): its IMU, tracks and camera, with the
  EuRoC IMU's data-sheet noise;
- a **course .npz** (a velocity drive, dense or sparse layout): rewritten in the sparse layout;
  its KITTI pose ground truth (``--gt FILE`` or the one beside it) copied to
  ``DIR/groundtruth/NAME.txt``.

Ground truth may be an ASL/OpenVINS csv or TUM text for raw-IMU drives. Nothing is replaced:
an existing ``--out`` or ground-truth file is an error (exit 2) and nothing is written; every
fault in the source is one line naming the file, line and column.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from vislam.ekf.errors import InputError
from vislam.eval.eqvio import is_eqvio_csv

#: Ground truth kept before the first and after the last camera frame, s (an interpolation
#: at the ends needs a neighbour).
GT_MARGIN_S = 0.5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", metavar="SOURCE",
                        help="an ASL folder, a course .npz, or 'eqvio' (the eqvio csv in the gtsam "
                             "package) or the path of an eqvio csv")
    parser.add_argument("--out", required=True, metavar="DIR/NAME.npz",
                        help="the file to write (never replaced); the ground truth goes to "
                             "DIR/groundtruth/NAME.csv (raw IMU) or NAME.txt (course drives)")
    parser.add_argument("--gt", metavar="FILE", default=None,
                        help="ground truth: ASL/OpenVINS csv or TUM text (raw IMU), KITTI poses "
                             "(course drives); default: the source's own where it has one")
    parser.add_argument("--tracks", metavar="FILE", default=None,
                        help="camera tracks for an ASL folder: a csv 'timestamp [ns], track id, u, "
                             "v[, uR, vR]' or an eqvio csv ('eqvio': the one in the gtsam package)")


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.suffix != ".npz":
        raise InputError(f"{out}: --out must name a .npz file (DIR/NAME.npz)")
    source = args.source
    if Path(source).is_dir():
        return _raw_imu(args, out, _asl(source, args.tracks), _asl_truth(source, args.gt))
    if source == "eqvio" or is_eqvio_csv(source):
        if args.tracks is not None:
            raise InputError(f"{source}: --tracks is for an ASL folder; the eqvio csv holds its tracks")
        from vislam.eval.eqvio import read_eqvio_drive

        return _raw_imu(args, out, read_eqvio_drive(source), None if args.gt is None else Path(args.gt))
    if Path(source).suffix == ".npz":
        if args.tracks is not None:
            raise InputError(f"{source}: --tracks is for an ASL folder; a course .npz holds its tracks")
        return _course(Path(source), out, args.gt)
    raise InputError(f"{source}: not an ASL folder, a .npz drive or an eqvio csv (nothing there, or "
                     "a file of another kind)")


def _asl(folder: str, tracks: str | None):
    from vislam.eval.asl import read_asl_folder

    return read_asl_folder(Path(folder), None if tracks is None else (
        tracks if tracks == "eqvio" else Path(tracks)))


def _asl_truth(folder: str, gt: str | None) -> Path | None:
    if gt is not None:
        return Path(gt)
    from vislam.eval.asl import mav_folder

    own = mav_folder(Path(folder)) / "state_groundtruth_estimate0" / "data.csv"
    return own if own.is_file() else None


def _refuse_existing(*paths: Path) -> None:
    for path in paths:
        if path.exists() or path.is_symlink():
            raise InputError(f"{path}: already exists; vislam convert never replaces a file "
                             "(remove it or choose another --out)")


def _raw_imu(args, out: Path, drive, gt_path: Path | None) -> int:
    from vislam.eval.inertial_files import load_inertial_drive, save_inertial_drive
    from vislam.eval.trajectory_files import read_trajectory, write_trajectory

    gt_out = out.parent / "groundtruth" / f"{out.stem}.csv"
    _refuse_existing(out, *([gt_out] if gt_path is not None else []))
    truth = None
    if gt_path is not None:
        full = read_trajectory(gt_path)
        origin = drive.time_origin_ns * 1e-9
        truth = full.between(origin + drive.timestamps[0] - GT_MARGIN_S,
                             origin + drive.timestamps[-1] + GT_MARGIN_S)
        if len(truth) == 0:
            raise InputError(f"{gt_path}: no ground-truth pose within the drive's span "
                             f"({origin + drive.timestamps[0]:.3f} to {origin + drive.timestamps[-1]:.3f} s)")
    save_inertial_drive(out, drive)
    try:
        load_inertial_drive(out)  # what was written reads back, or nothing is left
        if truth is not None:
            write_trajectory(gt_out, truth)
    except BaseException:
        out.unlink(missing_ok=True)
        raise
    kind = "stereo" if drive.stereo else "monocular"
    duration = drive.imu.time[-1] - drive.imu.time[0]
    print(f"wrote {out}: raw IMU, {drive.imu.time.size} samples at {drive.imu_rate:.0f} Hz "
          f"({duration:.1f} s), {drive.n_frames} frames, {drive.n_tracks} {kind} tracks, "
          f"{len(drive.obs)} observations")
    if truth is not None:
        state = "with velocity and biases" if truth.state is not None else "poses only"
        print(f"wrote {gt_out}: {len(truth)} ground-truth poses ({state}) from {truth.source}")
    else:
        print("no ground truth given (--gt FILE)")
    return 0


def _course(source: Path, out: Path, gt: str | None) -> int:
    from vislam.eval.groundtruth import ground_truth_path, read_kitti_poses
    from vislam.eval.loader import load_sequence, save_sequence

    gt_path = Path(gt) if gt is not None else ground_truth_path(source)
    has_truth = gt is not None or gt_path.exists()
    gt_out = out.parent / "groundtruth" / f"{out.stem}.txt"
    _refuse_existing(out, *([gt_out] if has_truth else []))
    seq = load_sequence(source, monocular=True)
    if has_truth:
        read_kitti_poses(gt_path)  # a fault in it is named before anything is written
    save_sequence(out, seq)
    try:
        load_sequence(out, monocular=True)
        if has_truth:
            gt_out.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(gt_path, gt_out)
    except BaseException:
        out.unlink(missing_ok=True)
        raise
    print(f"wrote {out}: velocity drive, {seq.n_frames} frames, {seq.n_tracks} tracks, "
          f"{len(seq.obs)} observations (sparse layout)")
    print(f"wrote {gt_out}: ground truth copied from {gt_path}" if has_truth else "no ground truth")
    return 0
