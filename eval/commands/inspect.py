"""`vislam inspect FILE [--gt FILE]`: summarise a data file before estimating.

Prints frames and timing, tracks and observations, the invalid observations the loader dropped
(partial or negative pixel coordinates, :mod:`eval.loader`), the repeated-observation events
and bad disparities that the cleaning step repairs (:mod:`ekf.cleaning`), far points, velocity
statistics, and whether ground truth was found.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ekf.cleaning import clean_sequence, find_repeat_events
from eval.groundtruth import find_ground_truth
from eval.loader import load_sequence_with_report

#: Depth (m) beyond which a point counts as far; its disparity is fsu * b / FAR_DEPTH px.
FAR_DEPTH = 80.0
#: Disparities (px) below this are "tiny" (depth sigma of tens of metres).
TINY_DISPARITY = 1.0
#: Event frames listed in full up to this many.
MAX_FRAMES_LISTED = 40


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="drive in the data format (.npz)")
    parser.add_argument(
        "--gt", type=Path, default=None,
        help="ground-truth pose file (KITTI format); default DIR/groundtruth/NAME.txt",
    )


def _mmm(values: np.ndarray, fmt: str = "{:.3g}") -> str:
    if values.size == 0:
        return "n/a"
    return "min {} / median {} / max {}".format(
        *(fmt.format(v) for v in (values.min(), np.median(values), values.max()))
    )


def _frames_text(frames: list[int]) -> str:
    if len(frames) <= MAX_FRAMES_LISTED:
        return " ".join(str(f) for f in frames)
    head = " ".join(str(f) for f in frames[:MAX_FRAMES_LISTED])
    return f"{head} ... ({len(frames) - MAX_FRAMES_LISTED} more)"


def summarise(path: Path, gt_path: Path | None = None) -> list[str]:
    """The lines ``vislam inspect`` prints."""
    seq, load_report = load_sequence_with_report(path)
    cal = seq.calibration
    lines = [f"file: {path}"]
    T = seq.n_frames
    dt = seq.dt
    duration = float(seq.timestamps[-1] - seq.timestamps[0])
    lines.append(f"frames: {T}, duration {duration:.2f} s")
    lines.append(f"dt (s): {_mmm(dt, '{:.4f}')}" if dt.size else "dt (s): n/a (one frame)")
    lines.append(
        f"calibration: fsu {cal.fsu:.2f} fsv {cal.fsv:.2f} cu {cal.cu:.2f} cv {cal.cv:.2f} "
        f"px, baseline {cal.baseline:.4f} m"
    )

    lengths = seq.track_lengths()
    observed = lengths[lengths > 0]
    lines.append(
        f"tracks: {seq.n_tracks} ({observed.size} observed), observations {len(seq.obs)}"
    )
    if load_report.n_invalid:
        j, t = load_report.first_invalid
        lines.append(
            f"invalid observations: {load_report.n_invalid} dropped as unobserved "
            f"({load_report.n_partial} partial: one to three of uL, vL, uR, vR are -1; "
            f"{load_report.n_negative} with another negative coordinate), first at track {j}, "
            f"frame {t}"
        )
    else:
        lines.append("invalid observations: none (no partial or negative pixel coordinates)")
    lines.append(f"observations per frame: {_mmm(seq.obs.per_frame, '{:.0f}')}")
    lines.append(
        f"track lengths (frames): {_mmm(observed, '{:.0f}')}, "
        f"{int(np.sum(observed == 1))} of length 1"
    )

    events = find_repeat_events(seq)
    _, report = clean_sequence(seq, min_disparity=TINY_DISPARITY)
    n_event_repeats = sum(e.n_repeats for e in events)
    lines.append(
        f"repeated-observation events: {len(events)} frames, {n_event_repeats} repeats "
        f"(tracks repeating their previous observation exactly; {report.n_isolated_repeats} "
        "more outside events)"
    )
    if events:
        lines.append(f"  event frames: {_frames_text([e.frame for e in events])}")
        lines.append(
            f"  repeats per event: {_mmm(np.array([e.n_repeats for e in events]), '{:.0f}')}; "
            f"new tracks per event: {_mmm(np.array([e.n_new for e in events]), '{:.0f}')}"
        )
    lines.append(
        f"  cleaning splits {report.n_tracks_split} tracks into {report.n_new_tracks} new ones, "
        f"dropping {report.n_repeats_found} repeated observations"
    )

    d = seq.obs.z[:, 0] - seq.obs.z[:, 2]
    far_disp = cal.fsu * cal.baseline / FAR_DEPTH
    n_nonpos = int(np.sum(d <= 0))
    n_tiny = int(np.sum((d > 0) & (d < TINY_DISPARITY)))
    n_far = int(np.sum((d >= TINY_DISPARITY) & (d < far_disp)))
    lines.append(
        f"bad disparities: {n_nonpos} non-positive (min {d.min():.1f} px), {n_tiny} tiny "
        f"(0 < d < {TINY_DISPARITY:g} px)" if d.size else "bad disparities: n/a"
    )
    lines.append(
        f"far points: {n_far} observations with disparity {TINY_DISPARITY:g}-{far_disp:.2f} px "
        f"(depth > {FAR_DEPTH:g} m)"
    )

    v = seq.linear_velocity
    w = seq.angular_velocity
    nv = np.linalg.norm(v, axis=1)
    nw = np.linalg.norm(w, axis=1)
    lines.append(
        f"|v| (m/s): mean {nv.mean():.3f} std {nv.std():.3f} max {nv.max():.3f}; "
        f"per-axis mean {np.array2string(v.mean(axis=0), precision=3)}"
    )
    lines.append(
        f"|w| (rad/s): mean {nw.mean():.4f} std {nw.std():.4f} max {nw.max():.4f}; "
        f"per-axis mean {np.array2string(w.mean(axis=0), precision=4)}"
    )

    gt = find_ground_truth(path, override=gt_path, calibration=cal, n_frames=T)
    if gt is None:
        lines.append("ground truth: none found")
    else:
        length = float(np.sum(np.linalg.norm(np.diff(gt.poses[:, :3, 3], axis=0), axis=1)))
        lines.append(
            f"ground truth: {gt.source}, covers {gt.covers(T)}, path length {length:.1f} m"
        )
    return lines


def run(args: argparse.Namespace) -> int:
    for line in summarise(args.file, args.gt):
        print(line)
    return 0
