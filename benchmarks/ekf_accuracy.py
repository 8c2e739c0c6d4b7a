"""Raw and SE(3)-aligned ATE of the EKF estimators on a drive with ground truth (0027).

    .venv/bin/python benchmarks/ekf_accuracy.py [--data DIR] [--drive 0027]
        [--modes dead-reckoning,mapping,ekf-decoupled,ekf-joint] [--set key=value ...]

Ground truth: ``groundtruth/<drive>.txt``, ``T_imu(k) = inv(cam_T_imu) P(k) cam_T_imu``;
only frames with ground truth are scored. Uses ``eval.metrics`` / ``eval.groundtruth`` when
they exist, else the local Umeyama below. Prints one line per mode.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ekf.config import FilterConfig  # noqa: E402
from ekf.sequence import Calibration, Observations, Sequence  # noqa: E402


def default_data_dir() -> Path:
    return Path(os.environ.get("VISLAM_DATA", "/work/shared/data/kitti-pr3"))


def load_sequence(path: Path) -> Sequence:
    """Read a course .npz drive (either key edition) into a Sequence."""
    try:
        from eval.datasets import load_sequence as _load  # type: ignore

        return _load(path)
    except ImportError:
        pass
    with np.load(path) as d:
        ang = d["rotational_velocity"] if "rotational_velocity" in d else d["angular_velocity"]
        if "cam_T_imu" in d:
            cam_T_imu = d["cam_T_imu"]
        else:
            cam_T_imu = np.linalg.inv(d["imu_T_cam"])
        calib = Calibration(K=d["K"], baseline=float(d["b"]), cam_T_imu=cam_T_imu)
        obs = Observations.from_dense(d["features"])
        return Sequence(
            name=path.stem,
            timestamps=d["time_stamps"].ravel().astype(float),
            linear_velocity=d["linear_velocity"].T.astype(float),
            angular_velocity=ang.T.astype(float),
            obs=obs,
            n_tracks=int(d["features"].shape[1]),
            calibration=calib,
            source=str(path),
        )


def load_groundtruth(path: Path, cam_T_imu: np.ndarray) -> np.ndarray:
    """IMU poses (K, 4, 4) in the frame of the IMU at step 0."""
    rows = np.loadtxt(path)
    P = np.tile(np.eye(4), (rows.shape[0], 1, 1))
    P[:, :3, :] = rows[:, 1:].reshape(-1, 3, 4)
    return np.linalg.inv(cam_T_imu) @ P @ cam_T_imu


def umeyama_se3(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising ``sum |dst - (R src + t)|^2`` (no scale)."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    C = (dst - mu_d).T @ (src - mu_s) / src.shape[0]
    Uc, _, Vt = np.linalg.svd(C)
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(Uc @ Vt))
    R = Uc @ D @ Vt
    return R, mu_d - R @ mu_s


def ate(est_xyz: np.ndarray, gt_xyz: np.ndarray) -> tuple[float, float]:
    """(raw, aligned) translation RMSE in metres."""
    raw = float(np.sqrt(np.mean(np.sum((est_xyz - gt_xyz) ** 2, axis=1))))
    R, t = umeyama_se3(est_xyz, gt_xyz)
    al = est_xyz @ R.T + t
    return raw, float(np.sqrt(np.mean(np.sum((al - gt_xyz) ** 2, axis=1))))


def parse_settings(items: list[str]) -> dict:
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        low = value.lower()
        if low in ("true", "false"):
            out[key] = low == "true"
        elif low == "none":
            out[key] = None
        else:
            try:
                out[key] = int(value)
            except ValueError:
                try:
                    out[key] = float(value)
                except ValueError:
                    out[key] = value
    return out


def main(argv=None) -> int:
    from ekf.estimators import ESTIMATORS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=default_data_dir())
    ap.add_argument("--drive", default="0027")
    ap.add_argument("--modes", default=",".join(ESTIMATORS))
    ap.add_argument("--set", nargs="*", default=[], help="FilterConfig overrides key=value")
    args = ap.parse_args(argv)
    seq = load_sequence(args.data / f"{args.drive}.npz")
    gt = load_groundtruth(args.data / "groundtruth" / f"{args.drive}.txt", seq.calibration.cam_T_imu)
    n = min(gt.shape[0], seq.n_frames)
    config = FilterConfig().replace(**parse_settings(args.set))
    print(f"drive {args.drive}: {n} frames scored; settings {parse_settings(args.set) or 'defaults'}")
    for mode in args.modes.split(","):
        t0 = time.perf_counter()
        est = ESTIMATORS[mode](seq, config)
        wall = time.perf_counter() - t0
        raw, al = ate(est.positions[:n], gt[:n, :3, 3])
        print(
            f"{mode:16s} ATE raw {raw:7.2f} m  aligned {al:7.2f} m  "
            f"landmarks {int(est.has_landmark.sum()):5d}  updates {int(est.n_updates.sum()):6d}  "
            f"rejected {int(est.n_rejected.sum()):6d}  wall {wall:6.1f} s"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
