"""`vislam inspect` of a raw-IMU drive (a file with ``imu_time``: :mod:`eval.inertial_files`):
the IMU stream (rate, span, at-rest stretch at the start, magnitudes, the data sheet's noise),
the camera and its tracks, and the ground truth found."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vislam.eval.inertial_files import load_inertial_drive
from vislam.eval.inertial_truth import RAW_IMU_WORLD, find_inertial_truth, gyro_agreement

#: Still, window by window (:data:`REST_WINDOW_S`) from the start: the window's mean gyro within
#: REST_GYRO (rad/s) of the first window's, its mean accelerometer within REST_ACCEL (m/s^2) of
#: the first window's. Means, not spreads: a drone's running motors shake a still IMU by 1 m/s^2.
REST_WINDOW_S = 0.2
REST_GYRO = 0.02
REST_ACCEL = 0.2


def _mmm(values: np.ndarray, fmt: str) -> str:
    if values.size == 0:
        return "n/a"
    return "min {} / median {} / max {}".format(
        *(fmt.format(v) for v in (values.min(), np.median(values), values.max())))


def still_from_start(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> float:
    """Seconds from the start over which the IMU's windowed means stay those of the first
    window (module constants)."""
    edges = np.arange(t[0], t[-1] + 1e-9, REST_WINDOW_S)
    index = np.searchsorted(t, edges)
    first = None
    for a, b, start in zip(index[:-1], index[1:], edges[:-1]):
        if b <= a:
            continue
        g, f = gyro[a:b].mean(axis=0), accel[a:b].mean(axis=0)
        if first is None:
            first = (g, f)
        elif (np.linalg.norm(g - first[0]) > REST_GYRO or np.linalg.norm(f - first[1]) > REST_ACCEL):
            return float(start - t[0])
    return float(t[-1] - t[0])


def summarise_inertial(path: Path, gt_path: Path | None = None) -> list[str]:
    """The lines ``vislam inspect`` prints for a raw-IMU drive."""
    drive = load_inertial_drive(path)
    cal, imu = drive.calibration, drive.imu
    lines = [f"file: {path}", "drive: raw IMU"]
    span = float(imu.time[-1] - imu.time[0])
    dt = np.diff(imu.time)
    lines.append(f"IMU: {imu.time.size} samples over {span:.2f} s at {drive.imu_rate:.1f} Hz, "
                 f"interval (ms) {_mmm(dt * 1e3, '{:.3f}')}")
    gyro, accel = np.linalg.norm(imu.gyro, axis=1), np.linalg.norm(imu.accel, axis=1)
    lines.append(f"|gyro| (rad/s): {_mmm(gyro, '{:.3g}')}; |accel| (m/s^2): {_mmm(accel, '{:.3g}')} "
                 f"(gravity {cal.gravity:.5g})")
    lines.append(f"still from the start: {still_from_start(imu.time, imu.gyro, imu.accel):.2f} s "
                 f"({REST_WINDOW_S:g} s windows whose mean gyro and accelerometer stay within "
                 f"{REST_GYRO:g} rad/s and {REST_ACCEL:g} m/s^2 of the first window's)")
    n = cal.noise
    lines.append(f"IMU noise (data sheet): gyro {n.gyro_noise_density:.4g} rad/s/sqrt(Hz), walk "
                 f"{n.gyro_random_walk:.4g} rad/s^2/sqrt(Hz); accel {n.accel_noise_density:.4g} "
                 f"m/s^2/sqrt(Hz), walk {n.accel_random_walk:.4g} m/s^3/sqrt(Hz)")
    duration = float(drive.timestamps[-1] - drive.timestamps[0])
    kind = f"stereo, baseline {cal.baseline:.4f} m" if cal.stereo else "monocular"
    lines.append(f"frames: {drive.n_frames} over {duration:.2f} s ({kind}), dt (s) "
                 f"{_mmm(np.diff(drive.timestamps), '{:.4f}')}")
    K = cal.K
    lens = "none (undistorted pixels)" if cal.distortion_model == "none" else \
        f"{cal.distortion_model} {', '.join(f'{c:.4g}' for c in cal.distortion)}"
    lines.append(f"camera: fu {K[0, 0]:.2f} fv {K[1, 1]:.2f} cu {K[0, 2]:.2f} cv {K[1, 2]:.2f} px, "
                 f"distortion {lens}")
    lever = cal.imu_T_cam[:3, 3]
    lines.append(f"camera in the IMU frame: position {np.array2string(lever, precision=4)} m")
    lengths = np.bincount(drive.obs.track, minlength=drive.n_tracks)
    observed = lengths[lengths > 0]
    lines.append(f"tracks: {drive.n_tracks} ({observed.size} observed), observations {len(drive.obs)}; "
                 f"per frame {_mmm(drive.obs.per_frame, '{:.0f}')}; lengths (frames) "
                 f"{_mmm(observed, '{:.0f}')}")
    truth = find_inertial_truth(path, drive, gt_path)
    if truth is None:
        lines.append("ground truth: none found")
    else:
        gt = truth.truth
        length = float(np.sum(np.linalg.norm(np.diff(gt.poses[:, :3, 3], axis=0), axis=1)))
        extra = "with velocity and biases" if truth.velocity is not None else "poses only"
        lines.append(f"ground truth: {gt.source}, covers {gt.covers(drive.n_frames)}, path length "
                     f"{length:.2f} m, {extra}; world {RAW_IMU_WORLD}")
        check = gyro_agreement(drive, truth)
        if check is not None:
            lines.append(f"ground truth against the gyro: {check.words()}")
    return lines
