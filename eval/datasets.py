"""Where the shared drives live.

The data folder is ``$VISLAM_DATA`` when set, else ``../shared/data/kitti-pr3`` next to the
repository root (resolved from this file's location, not the working directory). The data is
third-party (KITTI, CC BY-NC-SA 3.0): it is read in place and never copied into the repository.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Environment variable that overrides the data folder.
DATA_ENV = "VISLAM_DATA"
#: Environment variable that overrides the folder of the 2019 edition (clean velocities).
DATA_2019_ENV = "VISLAM_DATA_2019"
#: The drives shared with the project (file stems), in the paper's order.
SHARED_DRIVES = ("0022", "0027", "0034")
#: The translation of cam_T_imu (m) from KITTI's own calibration of 2011_09_30 (calib_imu_to_velo
#: then calib_velo_to_cam), the drives' date; the files carry the lever arm there instead
#: (../shared/data/kitti-pr3/README.md). A reference, not a setting: no estimator reads it.
KITTI_CAM_T_IMU_TRANSLATION = (-0.332, 0.727, -1.138)


def repo_root() -> Path:
    """The repository root (the parent of the ``eval`` package)."""
    return Path(__file__).resolve().parent.parent


def data_dir() -> Path:
    """The data folder (it may not exist; callers check)."""
    env = os.environ.get(DATA_ENV)
    if env:
        return Path(env).expanduser()
    return (repo_root().parent / "shared" / "data" / "kitti-pr3").resolve()


def data_dir_2019() -> Path:
    """The folder of the 2019 edition of the drives (``$VISLAM_DATA_2019``, else
    ``../shared/data/kitti-pr3-2019``; it may not exist)."""
    env = os.environ.get(DATA_2019_ENV)
    if env:
        return Path(env).expanduser()
    return (repo_root().parent / "shared" / "data" / "kitti-pr3-2019").resolve()


def drive_path(name: str, directory: Path | None = None) -> Path:
    """Path of drive ``name`` (``"0027"`` or ``"0027.npz"``) in the data folder."""
    stem = name[:-4] if name.endswith(".npz") else name
    return (directory or data_dir()) / f"{stem}.npz"


def shared_drives(directory: Path | None = None) -> list[Path]:
    """The shared drives present in the data folder, in the paper's order."""
    paths = [drive_path(n, directory) for n in SHARED_DRIVES]
    return [p for p in paths if p.is_file()]
