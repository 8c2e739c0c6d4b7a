"""Does a raw-IMU drive's ground truth turn as its gyro says? (issues 37-39; docs/findings.md,
"EuRoC's ground truth turns 1-1.6 mrad a second away from its gyro").

    .venv/bin/python benchmarks/gyro_truth.py [ASL_FOLDER] [--truth CSV] [--start S] [--seconds S]

For pairs of ground-truth poses ``lag`` frames apart, the relative rotation of the truth is
compared with the gyro's over the same interval (each sample held over its piece,
``ekf.strapdown.held_pieces``, the rule of every raw-IMU estimator), less the truth's own gyro
bias at the interval's start. The rms of the difference per body axis is printed beside what
the sensor sheet's noise allows: the white density ``sigma_g sqrt(T)`` and the bias walk
``sigma_w T^1.5 / sqrt(3)``. Two readings of a disagreement are then tried:

- a time offset between the truth and the IMU (the IMU's stamps moved by ``dt``);
- a constant linear gyro error (scale and misalignment, ``w_true = (I + M)(w - b)``), fitted on
  half of the pairs (alternate 5 s blocks) and scored on the other half.

The default is EuRoC V1_01 in ../shared/data, over the 30 s that gtsam's eqvio tracks cover.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from vislam.ekf.strapdown import held_pieces
from vislam.eval.asl import mav_folder, read_imu_csv, read_imu_noise
from vislam.eval.trajectory_files import read_trajectory

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "euroc-v1_01"
EQVIO_START = 1403715273.262  # s, the first frame of gtsam's eqvio_processed_30s.csv


class GyroTruth:
    """The IMU and the truth of one drive on one clock (seconds)."""

    def __init__(self, folder: Path, truth: Path, start: float, end: float):
        mav = mav_folder(folder)
        time_ns, imu = read_imu_csv(mav / "imu0" / "data.csv")
        self.origin = time_ns[0] * 1e-9  # every time below is seconds since the IMU's first stamp
        keep = (imu.time >= start - self.origin - 1.0) & (imu.time <= end - self.origin + 1.0)
        self.t, self.gyro = imu.time[keep], imu.gyro[keep]
        self.noise = read_imu_noise(mav / "imu0" / "sensor.yaml")
        traj = read_trajectory(truth).between(start, end)
        if traj.gyro_bias is None:
            raise SystemExit(f"{truth}: no gyro bias columns (an ASL/OpenVINS csv of 17 columns)")
        tg = traj.times - self.origin
        ok = tg > self.t[0]  # a sample at or before each pose (the first pose shares a stamp)
        self.tg, self.bias = tg[ok], traj.gyro_bias[ok]
        self.R = Rotation.from_matrix(traj.poses[ok, :3, :3])

    def gyro_rotation(self, t0: float, t1: float, bias: np.ndarray, M: np.ndarray | None = None,
                      shift: float = 0.0) -> Rotation:
        """The gyro's rotation from ``t0`` to ``t1`` (body frame at ``t0``)."""
        out = Rotation.identity()
        M = np.eye(3) if M is None else M
        for j, dt in held_pieces(self.t + shift, t0, t1):
            out = out * Rotation.from_rotvec(M @ (self.gyro[j] - bias) * dt)
        return out

    def pairs(self, lag: int, step: int = 3) -> list[int]:
        return list(range(0, self.tg.size - lag, step))

    def differences(self, ks: list[int], lag: int, M: np.ndarray | None = None,
                    shift: float = 0.0) -> np.ndarray:
        """(n, 3) mrad: truth's relative rotation less the gyro's, body frame at the start."""
        out = []
        for k in ks:
            truth = self.R[k].inv() * self.R[k + lag]
            gyro = self.gyro_rotation(self.tg[k], self.tg[k + lag], self.bias[k], M, shift)
            out.append((truth * gyro.inv()).as_rotvec())
        return 1e3 * np.array(out)


def rms(a: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(a * a, axis=0))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", nargs="?", type=Path, default=DATA, help="ASL folder (default EuRoC V1_01)")
    parser.add_argument("--truth", type=Path, help="ground-truth csv (default FOLDER/groundtruth/V1_01_easy.csv)")
    parser.add_argument("--start", type=float, default=EQVIO_START, help="first second (file clock)")
    parser.add_argument("--seconds", type=float, default=30.0)
    args = parser.parse_args(argv)
    truth = args.truth or args.folder / "groundtruth" / "V1_01_easy.csv"
    d = GyroTruth(args.folder, truth, args.start, args.start + args.seconds)
    period = float(np.median(np.diff(d.tg)))
    sg, sw = d.noise.gyro_noise_density, d.noise.gyro_random_walk
    print(f"{truth}: {args.seconds:g} s from {args.start:.3f}; truth every {1e3 * period:.1f} ms")
    print("lag (s) | pairs | truth - gyro, rms per axis (mrad) | the sheet allows: white, walk (mrad)")
    for lag in (1, 4, 20, 60, 100):
        T = lag * period
        e = d.differences(d.pairs(lag), lag)
        print(f"{T:6.2f} | {len(e):5d} | {np.array2string(rms(e), precision=2)} | "
              f"{1e3 * sg * np.sqrt(T):.2f}, {1e3 * sw * T ** 1.5 / np.sqrt(3):.3f}")
    lag = max(1, int(round(1.0 / period)))
    ks = d.pairs(lag)
    print(f"\nthe IMU's stamps moved by dt, lag {lag * period:.2f} s: rms over the axes (mrad)")
    for shift in (-0.01, -0.005, -0.002, 0.0, 0.002, 0.005, 0.01):
        print(f"  dt {1e3 * shift:+5.0f} ms: {np.sqrt(np.mean(d.differences(ks, lag, shift=shift) ** 2)):.3f}")
    block = ((d.tg[ks] - d.tg[0]) // 5.0).astype(int) % 2 == 0
    halves = ([k for k, b in zip(ks, block) if b], [k for k, b in zip(ks, block) if not b])
    print("\na linear gyro error (I + M) fitted on alternate 5 s blocks, scored on the others:")
    for name, (fit, held) in (("even blocks", halves), ("odd blocks", halves[::-1])):
        sol = least_squares(lambda m: d.differences(fit, lag, np.eye(3) + m.reshape(3, 3)).ravel(),
                            np.zeros(9))
        before = np.sqrt(np.mean(d.differences(held, lag) ** 2))
        after = np.sqrt(np.mean(d.differences(held, lag, np.eye(3) + sol.x.reshape(3, 3)) ** 2))
        print(f"  fit on {name}: |M| {1e3 * np.abs(sol.x).max():.1f}e-3, held-out rms {before:.3f} -> "
              f"{after:.3f} mrad")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
