"""Which tracks dead reckoning refutes: each track's static point under the velocities' motion.

    .venv/bin/python benchmarks/moving_tracks.py FILE.npz [--level P | --threshold PX] [--write DIR]

By default each track of the cleaned drive (ekf.cleaning, as the estimators clean it) is tested
by ekf.motion_check at the identified model (dead reckoning's covariance from the model's
interval sigmas, the white pixel sigma and its correlation time along a track) and refuted at
``--level`` (default 1e-4); ``--write DIR`` then writes the drive without the refuted tracks'
observations. ``--threshold PX`` instead uses the rms heuristic below (the first measurement
of docs/findings.md, 2026-12-03).

At the drive's identified model (`vislam calibrate`'s, from the cache: its extrinsic, pairing,
gyro bias, lens term and time offsets applied to the data), the poses are the velocities'
alone (graph.factors.dead_reckoning, no vision), and each track of 3 or more observations is
triangulated from all its stereo rows under those poses (one linear solve: left u, v and right
u per observation). A landmark that stands still reprojects within the pixel noise plus what
dead reckoning drifts over the track's span; one on a moving object does not. The script prints
the rms reprojection error (px) of the tracks by the frame where they start (median, 90th
percentile, share above ``--threshold``), and with ``--write DIR`` writes a copy of the drive
without the tracks above the threshold to ``DIR/NAME.npz`` (with the drive's ground truth
copied beside it), for `vislam bench DIR/NAME.npz`. The drive's own folder is never written.

The rms threshold is not a test with a level (on shared 0027 it refutes most tracks), and a
velocity fault (one bad sample) makes every track across it fail in either mode.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import numpy as np

from vislam.ekf.camera import project
from vislam.ekf.config import FilterConfig
from vislam.ekf.geometry import homogeneous
from vislam.ekf.model import model_config, model_sequence
from vislam.ekf.motion_check import linear_point
from vislam.ekf.sequence import track_runs
from vislam.eval.groundtruth import ground_truth_path
from vislam.eval.loader import load_sequence
from vislam.eval.model_cache import identified_model
from vislam.graph.factors import dead_reckoning
from vislam.graph.settings import SmootherSettings


def track_rms(seq, config: FilterConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(track, first_frame, rms)`` of every track of 3 or more observations: the rms
    reprojection error (px, left u, v and right u) of its static point under dead reckoning."""
    calib = seq.calibration
    X, M = np.asarray(calib.cam_T_imu, dtype=float), np.asarray(calib.M, dtype=float)
    U = np.linalg.inv(dead_reckoning(seq, config))  # imu_T_world
    o = seq.obs
    order, starts, ends = track_runs(o.frame_index, o.track)
    frame, track, z = o.frame_index[order], o.track[order], o.z[order]
    out = []
    for a, e in zip(starts, ends):
        if e - a < 3:
            continue
        Uk = U[frame[a:e]]
        p = linear_point(Uk, X, M, z[a:e])
        c = X @ Uk @ homogeneous(p) if np.all(np.isfinite(p)) else None
        if c is None or np.any(c[:, 2] <= 0):
            rms = np.inf
        else:
            r = project(M, c)[:, :3] - z[a:e, :3]  # left u, v and right u
            rms = float(np.sqrt(np.mean(r ** 2)))
        out.append((track[a], frame[a], rms))
    out = np.array(out, dtype=float).reshape(-1, 3)
    return out[:, 0].astype(int), out[:, 1].astype(int), out[:, 2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file", type=Path)
    parser.add_argument("--level", type=float, default=1e-4, help="the test's level (default 1e-4)")
    parser.add_argument("--threshold", type=float, help="px: the rms heuristic instead of the test")
    parser.add_argument("--write", type=Path, help="folder for the drive without those tracks")
    args = parser.parse_args()
    seq = load_sequence(args.file)
    model = identified_model(seq, FilterConfig(), SmootherSettings()).model
    if args.threshold is None:
        return _test(args, parser, seq, model)
    tracks, first, rms = track_rms(model_sequence(seq, model), model_config(FilterConfig(), model))
    n = seq.n_frames
    edges = sorted({0, 10, 20, 40, 100, n} | {min(n, e) for e in (300, 1000)})
    print(f"{args.file}: {tracks.size} tracks of 3 or more observations; rms reprojection (px) "
          "of each one's static point under dead reckoning")
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (first >= lo) & (first < hi)
        if m.any():
            q50, q90 = np.percentile(rms[m], [50, 90])
            print(f"  starting in frames {lo:4d}-{hi - 1:<4d}: {m.sum():5d} tracks, median {q50:6.2f}, "
                  f"90 % {q90:6.2f}, above {args.threshold:g} px {np.mean(rms[m] > args.threshold):5.1%}")
    bad = tracks[rms > args.threshold]
    print(f"  all: {bad.size} of {tracks.size} above {args.threshold:g} px")
    if args.write is not None:
        if args.write.resolve() == args.file.parent.resolve():
            parser.error("--write: give another folder than the drive's own")
        data = dict(np.load(args.file))
        columns = np.asarray(seq.track_origin, dtype=int)[bad]
        data["features"] = np.array(data["features"], copy=True)
        data["features"][:, columns, :] = -1.0
        _write(args, data)


def _test(args, parser, seq, model) -> None:
    """The default: ekf.motion_check's test at ``--level`` on the cleaned drive."""
    from vislam.ekf.cleaning import clean_sequence
    from vislam.ekf.motion_check import track_tests

    config = model_config(FilterConfig(), model)
    cleaned, _ = clean_sequence(model_sequence(seq, model), min_disparity=config.min_disparity)
    t = track_tests(cleaned, config.velocity_cov, config.velocity_pairing, model.pixel_sigma,
                    model.pixel_correlation_time)
    refuted = t.p_value < args.level
    ok = np.isfinite(t.statistic)
    print(f"{args.file}: {t.track.size} cleaned tracks of 3 or more observations tested, "
          f"{int((~ok).sum())} without a point in front of every camera; median statistic / dof "
          f"{np.median(t.statistic[ok] / t.dof[ok]):.3f}")
    n = seq.n_frames
    edges = sorted({0, 10, 20, 40, 100, n} | {min(n, e) for e in (300, 1000)})
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (t.first >= lo) & (t.first < hi)
        if m.any():
            print(f"  starting in frames {lo:4d}-{hi - 1:<4d}: {m.sum():5d} tracks, refuted at "
                  f"{args.level:g}: {int(refuted[m].sum()):4d} ({refuted[m].mean():5.1%})")
    print(f"  all: {int(refuted.sum())} of {t.track.size} refuted")
    if args.write is None:
        return
    if args.write.resolve() == args.file.parent.resolve():
        parser.error("--write: give another folder than the drive's own")
    data = dict(np.load(args.file))
    features = np.array(data["features"], copy=True)
    o = cleaned.obs
    rows = np.isin(o.track, t.track[refuted])
    columns = np.asarray(cleaned.track_origin, dtype=int)[o.track[rows]]
    features[:, columns, o.frame_index[rows]] = -1.0
    data["features"] = features
    _write(args, data)


def _write(args, data) -> None:
    args.write.mkdir(parents=True, exist_ok=True)
    np.savez(args.write / args.file.name, **data)
    gt = ground_truth_path(args.file)
    if gt.is_file():
        (args.write / "groundtruth").mkdir(exist_ok=True)
        shutil.copy(gt, args.write / "groundtruth" / gt.name)
    print(f"  wrote {args.write / args.file.name} without them")


if __name__ == "__main__":
    main()
