"""The drives a study runs on: data files (with the ground truth and true landmarks found beside
them) or the simulator's default drive, each under the model it is run with (identified from
its own data, a ``[model]`` table, or the file's values as given).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.sequence import Sequence
from vislam.graph.settings import SmootherSettings

log = logging.getLogger(__name__)

#: Frames of the default simulated drive: the simulator's default drive (600 frames, 60 s);
#: `vislam bench` with every default estimator takes 30-60 s on a 2-core machine.
DEFAULT_BENCH_FRAMES = 600


@dataclass(frozen=True)
class KnownTruth:
    """Ground-truth poses of a drive: ``frames`` (n,) step indices, ``poses`` (n, 4, 4)."""

    frames: np.ndarray
    poses: np.ndarray
    path: str | None = None


@dataclass
class BenchSequence:
    """A drive to benchmark: its measurements and whatever truth is known."""

    name: str
    path: str | None
    sequence: Sequence
    gt: object | None = None  # .frames, .poses (eval.groundtruth.GroundTruth or KnownTruth)
    landmark_truth: np.ndarray | None = None  # (n_tracks, 3) per source track
    origin: dict | None = None  # how it was made (simulation settings)
    config: FilterConfig | None = None  # the filter settings under this drive's model
    #: the model in use, as results.json records it; its "mode": "identified" from the data
    #: (the default, cached), "config" (a [model] table in --config) or "as-given"
    model: dict | None = None
    #: a raw-IMU drive's ground truth against its gyro (eval.inertial_truth.gyro_agreement,
    #: as a dict), None for velocity drives and where there is no such truth
    truth_check: dict | None = None


def simulated_sequence(seed: int = 0, frames: int | None = None) -> BenchSequence:
    """The simulator's default drive (``seed``, ``frames`` steps) with its exact truth."""
    from vislam.eval.simulate import DEFAULT_SIM, simulate

    config = dataclasses.replace(
        DEFAULT_SIM, seed=int(seed), n_frames=int(frames or DEFAULT_BENCH_FRAMES),
        name=f"sim-seed{seed}",
    )
    result = simulate(config)
    T = result.sequence.n_frames
    return BenchSequence(
        name=config.name,
        path=None,
        sequence=result.sequence,
        gt=KnownTruth(np.arange(T), result.poses),
        landmark_truth=result.landmarks,
        origin={"simulation": dataclasses.asdict(config)},
    )


def expand_paths(paths: list[str]) -> list[Path]:
    """.npz files, and the .npz files directly inside folders (simulator landmark files left out)."""
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(f for f in p.glob("*.npz") if not f.name.endswith("_landmarks.npz"))
            if not found:
                raise InputError(f"{p}: folder holds no .npz data file")
            files.extend(found)
        elif p.is_file():
            files.append(p)
        else:
            raise InputError(f"{p}: no such file or folder ({_where_the_drives_are()})")
    return files


def _where_the_drives_are() -> str:
    """Where vislam looks for the shared KITTI drives, for a path that does not exist."""
    from vislam.eval.datasets import DATA_ENV, data_dir

    folder = data_dir()
    found = sorted(folder.glob("*.npz")) if folder.is_dir() else []
    where = (f"the shared drives are in {folder}, e.g. {found[0]}" if found
             else f"no drives in {folder} either")
    return f"{where}; set {DATA_ENV} to the folder of yours"


def load_bench_sequence(path: Path) -> BenchSequence:
    """A data file, its ground truth (if found) and, for simulated files, the true landmarks.
    A raw-IMU drive (:mod:`eval.inertial_files`) comes with its ground truth at the camera
    frames in the estimates' gravity-aligned world (:mod:`eval.inertial_truth`)."""
    from vislam.eval.groundtruth import find_ground_truth
    from vislam.eval.inertial_files import is_inertial_file, load_inertial_drive
    from vislam.eval.loader import load_sequence

    if is_inertial_file(path):
        from vislam.eval.inertial_truth import find_inertial_truth, gyro_agreement

        drive = load_inertial_drive(path)
        truth = find_inertial_truth(path, drive)
        agreement = None if truth is None else gyro_agreement(drive, truth)
        return BenchSequence(path.stem, str(path.resolve()), drive,
                             None if truth is None else truth.truth,
                             landmark_truth_beside(path, drive),
                             truth_check=None if agreement is None else agreement.to_dict())

    seq = load_sequence(path, clean=False)
    gt = find_ground_truth(path)
    return BenchSequence(path.stem, str(path.resolve()), seq, gt, landmark_truth_beside(path, seq))


def landmark_truth_beside(path: Path, seq: Sequence) -> np.ndarray | None:
    """A simulated drive's true landmarks (``<stem>_landmarks.npz`` beside the data file, read as
    carefully as the drive), one row per track of ``seq``; None where there is no such file."""
    from vislam.eval.safe_reading import read_npz

    path = Path(path)
    lm_file = path.with_name(f"{path.stem}_landmarks.npz")
    if not lm_file.is_file():
        return None
    d = read_npz(lm_file, ("landmarks",))
    if "landmarks" in d and d["landmarks"].shape == (seq.n_tracks, 3):
        return np.asarray(d["landmarks"], dtype=float)
    return None


def collect_sequences(paths: list[str], frames: int | None = None, seed: int = 0) -> list[BenchSequence]:
    """The sequences of ``paths`` (files or folders), or the default simulation when empty."""
    if not paths:
        return [simulated_sequence(seed, frames)]
    seqs = [load_bench_sequence(p) for p in expand_paths(paths)]
    seen: dict[str, int] = {}
    for s in seqs:  # unique names: they name output folders
        n = seen.get(s.name, 0)
        seen[s.name] = n + 1
        if n:
            s.name = f"{s.name}-{n}"
    return seqs


def apply_model_to(sequences: list[BenchSequence], model, config: FilterConfig | None = None,
                   mode: str = "config", record: dict | None = None) -> list[BenchSequence]:
    """Each drive under ``model`` (ekf.model.Model): its extrinsic and gyro bias applied to the
    data, its ground truth converted with the model's extrinsic (a simulated drive's truth
    is already in the IMU frame) and, with ``config``, the filter settings under the model
    (:func:`ekf.model.model_config`). ``mode`` and ``record`` go to results.json."""
    from vislam.ekf.model import model_config, model_sequence

    out = []
    for bs in sequences:
        if is_raw_imu(bs):
            out += as_given([bs])
            continue
        gt = bs.gt
        converted = gt is not None and hasattr(gt, "with_extrinsic")
        if converted:
            gt = gt.with_extrinsic(model.cam_T_imu, source=f"model ({mode})")
        entry = {"mode": mode, **(record or {}), "model": model.to_dict(),
                 "pixel_reading": "long-run" if config is None else config.pixel_reading,
                 "ground_truth_extrinsic": (f"the model's ({mode})" if converted else
                                            "none needed (truth in the IMU frame)" if gt is not None
                                            else None)}
        seq = model_sequence(bs.sequence, model)
        if converted:
            entry["lever_arm"] = _lever_arm_record(gt, seq, model)
        out.append(dataclasses.replace(
            bs, sequence=seq, gt=gt, model=entry,
            config=None if config is None else model_config(config, model)))
    return out


def _lever_arm_record(gt, seq: Sequence, model) -> dict:
    """The model's lever arm beside the one the ground truth and the velocities agree on
    (:mod:`eval.lever_arm_truth`), IMU axes, m; the latter None where the truth is too short."""
    from vislam.eval.lever_arm_truth import lever_arm_from_truth
    from vislam.graph.extrinsic import lever_arm

    record = {"model": lever_arm(model.cam_T_imu).tolist(), "ground_truth": None,
              "ground_truth_sigma": None,
              "definition": "the camera's position from the point the velocities are of, IMU "
                            "axes (m); ground_truth: least squares of the ground-truth camera "
                            "motion against the velocities (eval.lever_arm_truth), block-"
                            "jackknife sigma"}
    try:
        fit = lever_arm_from_truth(gt.camera_poses, seq.velocities, seq.dt,
                                   np.asarray(model.cam_T_imu)[:3, :3], model.velocity_pairing)
    except InputError as exc:
        record["ground_truth_error"] = str(exc)
        return record
    record["ground_truth"] = fit.lever_arm.tolist()
    record["ground_truth_sigma"] = fit.sigma.tolist()
    return record


#: What a raw-IMU drive is run under, in words (results.json's model record).
RAW_IMU_MODEL = ("not identified: raw-IMU drives are run under the file's calibration and the "
                 "IMU's data-sheet noise (identification of raw-IMU drives: issue 39)")


def is_raw_imu(bs: BenchSequence) -> bool:
    """Whether ``bs`` is a raw-IMU drive (:class:`ekf.inertial.InertialDrive`)."""
    from vislam.eval.registry import drive_kind

    return drive_kind(bs.sequence) == "raw-imu"


def as_given(sequences: list[BenchSequence]) -> list[BenchSequence]:
    """Each drive with the file's values and the settings as given (``--model as-given``)."""
    out = []
    for bs in sequences:
        entry = {"mode": "as-given", "model": None,
                 "cam_T_imu": np.asarray(bs.sequence.calibration.cam_T_imu).tolist(),
                 "ground_truth_extrinsic": None if bs.gt is None else "the file's"}
        out.append(dataclasses.replace(bs, model=entry))
    return out


def identify_models(sequences: list[BenchSequence], config: FilterConfig,
                    smoother: SmootherSettings, *,
                    on_start: Callable[[BenchSequence], None] | None = None) -> list[BenchSequence]:
    """Each drive under the model identified from its own data
    (:func:`eval.model_cache.identified_model`, cached by content); ``on_start(bs)`` is called
    before a drive's identification runs (not when the cache has it). A drive whose model
    cannot be identified (EstimationError: too short, the smoother fails) is benchmarked as
    given, with a warning and ``identification_failed`` in its record."""
    from vislam.eval.model_cache import identified_model
    from vislam.graph.memory import release_freed_memory

    out = []
    for bs in sequences:
        if is_raw_imu(bs):
            (given,) = as_given([bs])
            given.model["identification"] = RAW_IMU_MODEL
            out.append(given)
            continue
        announce = None if on_start is None else (lambda bs=bs: on_start(bs))
        try:
            found = identified_model(bs.sequence, config, smoother, on_miss=announce)
        except EstimationError as exc:  # too short, or the smoother fails on it: as given
            log.warning("%s: cannot identify the model (%s); the file's values and the "
                        "settings as given are used", bs.name, exc)
            (given,) = as_given([bs])
            given.model["identification_failed"] = str(exc)
            out.append(given)
            continue
        if not found.cached:
            # the identification's solves are freed: their heap goes back to the system before
            # the estimators' workers start (forked from this process, each would carry it)
            release_freed_memory()
        record = {"cached": found.cached, "cache_entry": None if found.path is None else str(found.path),
                  "identification": found.report}
        out += apply_model_to([bs], found.model, config, "identified", record)
    return out


def bench_sequence(drive) -> BenchSequence:
    """A BenchSequence from a path (ground truth beside it), a SimConfig or a SimResult."""
    from vislam.eval.simulate import SimConfig, SimResult, simulate

    if isinstance(drive, BenchSequence):
        return drive
    if isinstance(drive, SimConfig):
        drive = simulate(drive)
    if isinstance(drive, SimResult):
        T = drive.sequence.n_frames
        return BenchSequence(drive.sequence.name, None, drive.sequence,
                             KnownTruth(np.arange(T), drive.poses), drive.landmarks,
                             {"simulation": dataclasses.asdict(drive.config)})
    if isinstance(drive, (str, Path)):
        path = Path(drive)
        if not path.is_file():
            raise InputError(f"{path}: no such drive")
        return load_bench_sequence(path)
    raise TypeError(f"drive: a path to a .npz, a SimConfig or a SimResult, got {type(drive).__name__}")
