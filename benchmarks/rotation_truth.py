"""Which camera-IMU rotation a drive's ground truth and its gyro agree on, beside the file's.

    .venv/bin/python benchmarks/rotation_truth.py [FILE.npz] [--model MODEL.toml]

Hand-eye rotation from the ground truth alone (no vision): over each interval the ground
truth's camera rotation increment ``C_k``, moved into IMU axes by a candidate ``cam_R_imu``,
should equal the gyro's ``exp(tau_k w_k)`` under the velocity pairing; the candidate that
minimises the rms of their difference is printed against the file's (a rotation vector in IMU
axes, mrad), with the residual rms at both, for each pairing, and the residual at the rotation
of ``--model`` (for example a cached identified model's .toml). Default: kitti-utias 0027.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from vislam.ekf.model import Model
from vislam.ekf.prediction import paired_velocities
from vislam.eval.datasets import drive_path
from vislam.eval.groundtruth import find_ground_truth
from vislam.eval.loader import load_sequence

PAIRINGS = ("current", "next", "mean")


def imu_rotations(camera_rotations: np.ndarray, cam_R_imu: np.ndarray) -> np.ndarray:
    """The ground truth's camera rotation increments (n, 3, 3) in IMU axes: ``R^T C_k R``."""
    return np.einsum("ji,njk,kl->nil", cam_R_imu, camera_rotations, cam_R_imu)


def residuals(gyro: np.ndarray, camera_rotations: np.ndarray, cam_R_imu: np.ndarray) -> np.ndarray:
    """Rotation vectors (n, 3) of the gyro's increments against the ground truth's."""
    return Rotation.from_matrix(np.einsum("nji,njk->nik", gyro, imu_rotations(
        camera_rotations, cam_R_imu))).as_rotvec()


def rms_mrad(r: np.ndarray) -> float:
    return 1e3 * float(np.sqrt(np.mean(r ** 2)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file", nargs="?", type=Path)
    parser.add_argument("--model", type=Path, help="a model .toml whose rotation is scored too")
    args = parser.parse_args()
    path = args.file or drive_path("0027").parents[1] / "kitti-utias" / "0027.npz"
    seq = load_sequence(path)
    gt = find_ground_truth(path)
    if gt is None or gt.camera_poses is None:
        parser.error(f"{path}: no ground truth")
    P = gt.camera_poses
    n = P.shape[0] - 1
    C = (np.linalg.inv(P[:-1]) @ P[1:])[:, :3, :3]
    R_file = np.asarray(seq.calibration.cam_T_imu)[:3, :3]
    print(f"{path}: hand-eye rotation of the ground truth against the gyro over {n} intervals")
    for pairing in PAIRINGS:
        w = paired_velocities(seq.velocities, pairing)[:n, 3:]
        G = Rotation.from_rotvec(w * seq.dt[:n, None]).as_matrix()

        def res(x):
            return residuals(G, C, Rotation.from_rotvec(x).as_matrix() @ R_file).ravel()

        fit = least_squares(res, np.zeros(3))
        moved = R_file.T @ Rotation.from_rotvec(fit.x).as_matrix() @ R_file
        print(f"  {pairing:7s}: best cam_R_imu against the file's, IMU axes (mrad) "
              f"{np.round(1e3 * Rotation.from_matrix(moved).as_rotvec(), 2)}; residual rms "
              f"{rms_mrad(fit.fun):.3f} mrad an interval there, {rms_mrad(res(np.zeros(3))):.3f} "
              "at the file's")
        if args.model is not None:
            R_model = np.asarray(Model.from_toml(args.model).cam_T_imu)[:3, :3]
            print(f"           at the model's rotation: {rms_mrad(residuals(G, C, R_model)):.3f} mrad")
    yaw = np.degrees(np.sum(seq.velocities[:n, 5] * seq.dt[:n]))
    print(f"  the drive turns {yaw:.1f} degrees in all")


if __name__ == "__main__":
    main()
