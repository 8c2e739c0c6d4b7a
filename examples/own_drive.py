"""A drive of your own: your arrays into the documented .npz and ground-truth file, then
`vislam inspect`, `vislam run` and `vislam score` against your ground truth.

The arrays come from vislam's simulator (`vislam.simulate`), standing in for your own:
replace `my_arrays` with the code that reads your drive. Everything after it is what you would
type (README, "Your own drive"; docs/cli.md). About ten seconds on two cores.

    python examples/own_drive.py [--out DIR] [--frames 100] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np


def my_arrays(frames: int, seed: int) -> dict:
    """Your drive's arrays (here a simulated one: replace this with your own reader)."""
    from vislam import SimConfig, simulate

    sim = simulate(SimConfig(n_frames=frames, seed=seed))
    seq = sim.sequence
    return {
        "t": seq.timestamps,  # (T,) s, strictly increasing
        "z": seq.obs.to_dense(seq.n_tracks),  # (4, M, T) px [uL, vL, uR, vR], -1 unobserved
        "v": seq.linear_velocity.T,  # (3, T) m/s, body velocity in the IMU frame
        "w": seq.angular_velocity.T,  # (3, T) rad/s, in the IMU frame
        "K": seq.calibration.K,  # (3, 3) left camera intrinsics
        "b": seq.calibration.baseline,  # m
        "cam_T_imu": seq.calibration.cam_T_imu,  # (4, 4) p_cam = cam_T_imu @ p_imu
        "imu_poses": sim.poses,  # (T, 4, 4) your reference system's world_T_imu
    }


def vislam(*args: str) -> None:
    """`vislam ARGS` as you would type it (the same Python, so the same installation)."""
    print("$ vislam " + " ".join(args), flush=True)
    subprocess.run([sys.executable, "-m", "vislam.eval.cli", *args], check=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="working folder (default: a new temporary one)")
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="vislam-own-drive-"))
    a = my_arrays(args.frames, args.seed)

    # The drive: one .npz with the documented keys, shapes and units.
    drive = out / "data" / "mydrive.npz"
    drive.parent.mkdir(parents=True, exist_ok=True)
    np.savez(drive, time_stamps=a["t"][None], features=a["z"], linear_velocity=a["v"],
             rotational_velocity=a["w"], K=a["K"], b=np.array(a["b"]), cam_T_imu=a["cam_T_imu"])
    # Its ground truth beside it, DIR/groundtruth/NAME.txt: per frame the 12 numbers of the left
    # camera's pose in the left camera's frame at frame 0 (KITTI's format). From IMU poses:
    cam_poses = a["cam_T_imu"] @ a["imu_poses"] @ np.linalg.inv(a["cam_T_imu"])
    (drive.parent / "groundtruth").mkdir(exist_ok=True)
    np.savetxt(drive.parent / "groundtruth" / "mydrive.txt", cam_poses[:, :3, :].reshape(-1, 12))

    vislam("inspect", str(drive))  # what is in it: tracks, disparities, velocities, ground truth
    run = out / "run"
    vislam("run", str(drive), "-e", "ekf-invariant", "--out", str(run), "-q", "--no-plots")
    # Score the trajectory the run wrote, as you would score one from another system. The
    # settings as given (as `vislam run` used them) rather than a model identified from the
    # data; no reference smoother (without --no-reference: the figures against it too).
    vislam("score", str(run / "trajectory.tum"), "--data", str(drive), "--cov",
           str(run / "estimate.npz"), "--model", "as-given", "--no-reference",
           "--out", str(out / "score"), "-q")

    metrics = json.loads((run / "metrics.json").read_text())
    score = json.loads((out / "score" / "score.json").read_text())["scores"]
    for name, s in [("vislam run, metrics.json", metrics), ("vislam score, score.json", score)]:
        print(f"{name}: ATE {s['ate_m']:.4f} m (se3-aligned {s['ate_aligned_m']:.4f} m) over "
              f"{s['gt_frames']} frames, pose NEES {s['nees_pose_mean']:.2f} (6 when consistent)")
    print(f"results in {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
