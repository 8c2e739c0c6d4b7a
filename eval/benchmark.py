"""The benchmark (``vislam bench``) and the Monte Carlo consistency study (``vislam nees``).

Jobs are (sequence, estimator) pairs run in worker processes (``--jobs``): a local process
pool, or a Dask cluster (``--executor dask``, :mod:`eval.executors`), with the same results to
the last digit. The batch smoother starts from an EKF's estimate
(:data:`eval.registry.SMOOTHER_INITIAL_FROM`): its job is submitted when that EKF's job on the
same sequence has finished, so the EKF never runs twice.
Scores and figures are computed in the main process; every output is built in a temporary
folder and renamed into place at the end (:mod:`eval.atomic`).

``results.json`` (schema 1)::

    {"schema": 1, "rpe_definition": ..., "reference": ..., "alignment": "se3",
     "alignment_definition": ..., "sequences": [
        {"name", "path", "frames", "has_ground_truth", "has_landmark_truth",
         "estimators": [
            {"name", "error", "runtime_s", "frames_per_s", "landmarks",
             "ate_m", "ate_aligned_m", "rpe_trans_pct", "rpe_rot_deg_per_100m",
             "nees_pose_mean", "map_rmse_m", "nees_landmark_mean",
             "vs_smoother": {"ate_m", "ate_aligned_m", "map_rmse_m", "nees_pose_mean",
                             "inside_95_fraction"}}, ...]}, ...]}

Every key is always present; a figure that cannot be computed is null. ``alignment`` is the
alignment before every ``ate_aligned_m`` (against ground truth and against the smoother): one
of :data:`eval.metrics.ALIGN_MODES` (``--align``; "se3" by default, and in files written before
the key existed), ``alignment_definition`` says it in words. ``map_rmse_m`` and
``nees_landmark_mean`` compare with true landmarks (simulations only); ``vs_smoother`` compares
with the smoother's estimate on the same sequence (null for the smoothers themselves).
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.estimate import Estimate
from vislam.ekf.model import long_run_pixel_sigma
from vislam.ekf.sequence import Observations, Sequence
from vislam.eval.consistency import reference_honesty
from vislam.eval.executors import JobLost, open_executor
from vislam.eval.registry import (
    ESTIMATOR_NAMES,
    SMOOTHER_INITIAL_FROM,
    SMOOTHERS,
    UserEstimatorError,
    display_name,
    file_stem,
    uses_initial,
)
from vislam.eval.runjob import (
    RPE_DEFINITION,
    JobResult,
    Progress,
    run_estimator,
    trajectory_scores,
)
from vislam.eval.signals import deferred
from vislam.graph.settings import SmootherSettings

log = logging.getLogger(__name__)

SCHEMA = 1
#: Frames of the default simulated drive: the simulator's default drive (600 frames, 60 s);
#: `vislam bench` with every default estimator takes 30-60 s on a 2-core machine.
DEFAULT_BENCH_FRAMES = 600
#: Frames of each Monte Carlo drive of `vislam nees`.
DEFAULT_NEES_FRAMES = 200
#: Frames of the drives that set the landmark density of another range (nees_sim_config).
_DENSITY_PROBE_FRAMES = 200

ESTIMATOR_KEYS = (
    "name", "error", "runtime_s", "frames_per_s", "landmarks", "ate_m", "ate_aligned_m",
    "rpe_trans_pct", "rpe_rot_deg_per_100m", "nees_pose_mean", "map_rmse_m",
    "nees_landmark_mean", "vs_smoother",
)
VS_SMOOTHER_KEYS = ("ate_m", "ate_aligned_m", "map_rmse_m", "nees_pose_mean", "inside_95_fraction")
SEQUENCE_KEYS = ("name", "path", "frames", "has_ground_truth", "has_landmark_truth", "model",
                 "estimators")


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


@dataclass
class JobFailure:
    """An estimator that failed on a sequence (EstimationError, its module is missing, or it
    crashed: logged with its traceback, recorded in results.json as ``error``)."""

    sequence: str
    estimator: str
    error: str
    wall_s: float = float("nan")
    #: a user's estimator failed or broke the Estimate contract (registry.UserEstimatorError):
    #: bad input, which stops the whole run (exit code 2), not one failed row
    user_fault: bool = False


# --- sequences -------------------------------------------------------------------------------


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
    """A data file, its ground truth (if found) and, for simulated files, the true landmarks."""
    from vislam.eval.groundtruth import find_ground_truth
    from vislam.eval.loader import load_sequence

    seq = load_sequence(path, clean=False)
    gt = find_ground_truth(path)
    return BenchSequence(path.stem, str(path.resolve()), seq, gt, landmark_truth_beside(path, seq))


def landmark_truth_beside(path: Path, seq: Sequence) -> np.ndarray | None:
    """A simulated drive's true landmarks (``<stem>_landmarks.npz`` beside the data file, read as
    carefully as the drive), one row per track of ``seq``; None where there is no such file."""
    from vislam.eval.loader import read_npz

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
        gt = bs.gt
        converted = gt is not None and hasattr(gt, "with_extrinsic")
        if converted:
            gt = gt.with_extrinsic(model.cam_T_imu, source=f"model ({mode})")
        entry = {"mode": mode, **(record or {}), "model": model.to_dict(),
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

    out = []
    for bs in sequences:
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
        record = {"cached": found.cached, "cache_entry": None if found.path is None else str(found.path),
                  "identification": found.report}
        out += apply_model_to([bs], found.model, config, "identified", record)
    return out


# --- jobs ------------------------------------------------------------------------------------


def _job(seq: Sequence, key: str, name, config: FilterConfig, initial: Estimate | None,
         smoother: SmootherSettings | None = None):
    """Worker: one estimator (a name, ``MODULE:FUNCTION`` or a module-level callable) on one
    sequence (module-level so worker processes can pickle it)."""
    t0 = time.perf_counter()
    try:
        result = run_estimator(seq, name, config, progress=None, initial=initial, smoother=smoother)
    except UserEstimatorError as exc:
        return JobFailure(key, display_name(name), str(exc), time.perf_counter() - t0,
                          user_fault=True)
    except (EstimationError, ImportError) as exc:
        return JobFailure(key, display_name(name), f"{type(exc).__name__}: {exc}",
                          time.perf_counter() - t0)
    except Exception as exc:  # a crash of one estimator must not lose the whole benchmark
        log.debug("%s on %s crashed", name, key, exc_info=True)  # the traceback with -v
        return JobFailure(key, display_name(name), f"{type(exc).__name__}: {exc}",
                          time.perf_counter() - t0)
    result.sequence = key
    result.estimate = _c_ordered(result.estimate)
    return result


def _c_ordered(est: Estimate) -> Estimate:
    """``est`` with every array C-ordered, as it comes back from a worker process (pickling
    copies a strided array into C order): the figures computed from it (NEES, ATE) are then the
    same to the last digit whether the job ran in this process (``--jobs 1``), in the local pool
    or on Dask (the smoother's poses are strided, and a strided reduction can round
    differently)."""
    if dataclasses.is_dataclass(est):
        for f in dataclasses.fields(est):
            value = getattr(est, f.name)
            if isinstance(value, np.ndarray) and not value.flags.c_contiguous:
                setattr(est, f.name, np.ascontiguousarray(value))
    return est


def _running(labels: dict, pending: set, running: set | None = None) -> str:
    """The progress bar's words: the jobs running now (not the ones that just finished);
    ``running`` the futures the executor knows to run (default: those whose ``running()``)."""
    running = [labels[f] for f in pending if (f in running if running is not None else f.running())]
    if not running:
        return "waiting" if pending else "finishing"
    return "running " + ", ".join(sorted(running)[:2]) + (f" and {len(running) - 2} more" if len(running) > 2 else "")


def _initialiser(estimators: list[str]) -> str | None:
    return next((n for n in SMOOTHER_INITIAL_FROM if n in estimators), None)


def run_jobs(
    sequences: dict[str, Sequence],
    estimators: list[str],
    config: "FilterConfig | dict[str, FilterConfig]",
    jobs: int = 1,
    show_progress: bool = True,
    on_result: Callable[[JobResult | JobFailure], None] | None = None,
    smoother: SmootherSettings | None = None,
    executor: str = "local",
    scheduler: str | None = None,
) -> dict[tuple[str, str], JobResult | JobFailure]:
    """Run every estimator on every sequence; returns {(sequence key, estimator): result}.

    The smoother waits for its initialiser EKF on the same sequence (if that EKF is among
    ``estimators`` and ``smoother.init`` is ``"ekf"``) and starts from its estimate.
    ``config`` is one FilterConfig for every sequence, or one per sequence key. ``executor``
    runs the jobs (:mod:`eval.executors`): "local", ``jobs`` worker processes (none with
    ``jobs`` 1: in this process), or "dask", an embedded cluster of ``jobs`` workers or the
    cluster at ``scheduler``. The results do not depend on either: every job is the same
    function of its drive and settings.
    """
    configs = config if isinstance(config, dict) else {k: config for k in sequences}
    init_name = _initialiser(estimators)
    waiting = {n for n in estimators if uses_initial(n, smoother) and init_name is not None}
    # The initialiser first, so the smoother can start as early as possible; the smoother last.
    order = sorted(
        (n for n in estimators if n not in waiting),
        key=lambda n: (n != init_name, estimators.index(n)),
    )
    results: dict[tuple[str, str], JobResult | JobFailure] = {}
    total = len(sequences) * len(estimators)
    bar = Progress("bench", total=total, enabled=show_progress)

    def record(res) -> list[tuple[str, str, Estimate | None]]:
        if isinstance(res, JobFailure) and res.user_fault:
            raise UserEstimatorError(res.error)  # the user's code: stop, write nothing
        results[(res.sequence, res.estimator)] = res
        bar.update(1)
        if on_result is not None:
            on_result(res)
        follow = []
        if res.estimator == init_name:
            initial = res.estimate if isinstance(res, JobResult) else None
            if initial is not None and not np.all(np.isfinite(initial.poses)):
                initial = None  # a diverged EKF: let the smoother initialise itself
            follow = [(res.sequence, n, initial) for n in estimators if n in waiting]
        return follow

    try:
        if jobs <= 1 and executor == "local":
            queue = [(k, n, None) for k in sequences for n in order]
            while queue:
                key, name, initial = queue.pop(0)
                bar.set_description(f"running {display_name(name)} on {key}")
                queue.extend(record(_job(sequences[key], key, name, configs[key], initial, smoother)))
            return results
        # Signals are deferred while the workers are managed (an exception inside the pool's or
        # the client's locks would break them) and acted on between waits, within a tenth of a
        # second. Which job runs when is decided here, the same for every executor: every job
        # submitted at once (local) or a few per worker (dask), the smoother when its EKF is done.
        with deferred() as signals:
            pool = open_executor(executor, jobs, scheduler)
            try:
                labels: dict = {}  # future -> "estimator on sequence", while it is pending
                jobs_of: dict = {}  # future -> (sequence key, estimator)
                queue = collections.deque((k, n, None) for k in sequences for n in order)
                pending: set = set()

                def submit() -> None:
                    while queue and (pool.capacity() is None or len(pending) < pool.capacity()):
                        key, name, initial = queue.popleft()
                        fut = pool.submit(_job, sequences[key], key, name, configs[key], initial,
                                          smoother)
                        labels[fut] = f"{display_name(name)} on {key}"
                        jobs_of[fut] = (key, name)
                        pending.add(fut)

                submit()
                while pending:
                    signals.check()
                    done, _ = pool.wait(pending, 0.1)
                    for fut in done:
                        pending.discard(fut)
                        key, name = jobs_of.pop(fut)
                        del labels[fut]  # no reference left: a Dask result is freed
                        try:
                            res = pool.outcome(fut, signals)
                        except JobLost as exc:
                            res = JobFailure(key, display_name(name), str(exc))
                        # a smoother waiting for this EKF goes first: its drive and the EKF's
                        # estimate are freed the sooner
                        queue.extendleft(reversed(record(res)))
                    submit()
                    bar.set_description(_running(labels, pending, pool.running(pending)))
                signals.check()
            except BaseException:
                pool.abort()  # Ctrl-C, SIGTERM, an error: end the workers now
                raise
            pool.close()
        return results
    finally:
        bar.close()


# --- scores ----------------------------------------------------------------------------------


def reference_smoother(ests: dict[str, Estimate]) -> str | None:
    """The smoother the EKFs are compared with: the batch one if it ran, else iSAM2."""
    return next((n for n in SMOOTHERS if n in ests), None)


def score_sequence(bs: BenchSequence, estimators: list[str], outcomes: dict,
                   align: str = "se3") -> dict:
    """The results.json entry of one sequence (see the module docstring); ``align`` the
    alignment before every aligned ATE (eval.metrics.ALIGN_MODES)."""
    from vislam.eval.consistency import landmark_nees, landmark_rmse, versus_smoother

    ests = {n: o.estimate for n, o in outcomes.items() if isinstance(o, JobResult)}
    ref = reference_smoother(ests)
    rows = []
    for name in estimators:
        o = outcomes.get(name)
        row = {k: None for k in ESTIMATOR_KEYS}
        row["name"] = name
        row["vs_smoother"] = {k: None for k in VS_SMOOTHER_KEYS}
        if isinstance(o, JobFailure) or o is None:
            row["error"] = o.error if o is not None else "not run"
            rows.append(row)
            continue
        est = o.estimate
        row["runtime_s"] = o.wall_s
        row["frames_per_s"] = est.n_frames / o.wall_s if o.wall_s > 0 else None
        row["landmarks"] = int(np.count_nonzero(est.has_landmark))
        scores = trajectory_scores(est, bs.gt, align=align)
        for k in ("ate_m", "ate_aligned_m", "rpe_trans_pct", "rpe_rot_deg_per_100m", "nees_pose_mean"):
            row[k] = scores[k]
        if bs.landmark_truth is not None and row["landmarks"]:
            row["map_rmse_m"] = landmark_rmse(est, bs.landmark_truth)
            nees = landmark_nees(est, bs.landmark_truth)
            if np.any(np.isfinite(nees)):
                row["nees_landmark_mean"] = float(np.nanmean(nees))
        if ref is not None and name not in SMOOTHERS:
            row["vs_smoother"] = versus_smoother(est, ests[ref], align=align)
        rows.append(row)
    return {
        "name": bs.name,
        "path": bs.path,
        "frames": bs.sequence.n_frames,
        "has_ground_truth": bs.gt is not None,
        "has_landmark_truth": bs.landmark_truth is not None,
        "model": bs.model,
        "reference_smoother": ref,
        "estimators": rows,
    }


# --- figures ---------------------------------------------------------------------------------


def sequence_figures(folder: Path, bs: BenchSequence, ests: dict[str, Estimate]) -> list[Path]:
    """The PNG figures of one sequence into ``folder``; returns the paths written."""
    from vislam.eval import plots
    from vislam.eval.consistency import pose_nees

    written = []
    if not ests:
        return written
    gt = bs.gt
    gt_pos = np.asarray(gt.poses)[:, :3, 3] if gt is not None else None
    title = bs.name
    written.append(plots.plot_trajectories(folder / "trajectories.png", ests, gt_pos,
                                           f"{title}: trajectories, top view"))
    map_from = next(
        (n for n in (*SMOOTHERS, *SMOOTHER_INITIAL_FROM, "ekf-decoupled", "mapping")
         if n in ests and np.any(ests[n].has_landmark)),
        None,
    )
    if map_from is not None:
        written.append(plots.plot_map(folder / "map.png", ests[map_from], gt_pos, bs.landmark_truth,
                                      f"{title}: landmark map ({map_from})"))
    if gt is not None:
        written.append(plots.plot_error_over_distance(
            folder / "error_over_distance.png", ests, gt.frames, np.asarray(gt.poses),
            f"{title}: translation error over distance (no alignment)"))
    ref = reference_smoother(ests)
    # vislam's EKFs and a user's estimators (MODULE:FUNCTION, plug-ins): everything but the
    # smoothers, dead reckoning and mapping, which the smoother would only dwarf
    ekfs = {n: e for n, e in ests.items() if n.startswith("ekf-") or n not in ESTIMATOR_NAMES}
    if ref is not None and ekfs:
        written.append(plots.plot_vs_smoother(
            folder / "vs_smoother.png", ekfs, ests[ref],
            f"{title}: EKF position minus {ref}, with the EKF's ±3σ"))
    # Pose NEES over time: against ground truth where known, else against the smoother.
    if gt is not None:
        against, frames, poses, who = "ground truth", gt.frames, np.asarray(gt.poses), ests
    elif ref is not None:
        against, frames, poses = ref, np.arange(ests[ref].n_frames), ests[ref].poses
        who = {n: e for n, e in ests.items() if n not in SMOOTHERS}
    else:
        who = {}
    series = {n: pose_nees(e, frames, poses) for n, e in who.items()}
    series = {n: v for n, v in series.items() if np.any(np.isfinite(v))}
    if series:
        t = next(iter(ests.values())).timestamps
        written.append(plots.plot_nees(
            folder / "nees.png", series, dof=6, times=t - t[0],
            title=f"{title}: pose NEES against {against}",
            ylabel=f"pose NEES vs {against} (6 dof)"))
    return written


# --- summary ---------------------------------------------------------------------------------


def _fmt(x, digits=2) -> str:
    """A table cell: "–" for no value; floats fixed-point, or as 2.0e10 / 3.5e-05 when that
    would print a long number (at least 1e5) or only zeros (below 10^-digits)."""
    if x is None:
        return "–"
    if isinstance(x, float):
        if x != 0 and math.isfinite(x) and not 10.0**-digits <= abs(x) < 1e5:
            mantissa, exponent = f"{x:.1e}".split("e")
            return f"{mantissa}e{int(exponent)}"
        return f"{x:.{digits}f}"
    return str(x)


#: The columns of a drive's table in summary.md: (header, key in the row or in its
#: "vs_smoother" part, digits). A column with no value on any row of the drive is left out.
SUMMARY_COLUMNS = (
    ("time (s)", "runtime_s", 2), ("frames/s", "frames_per_s", 1), ("ATE (m)", "ate_m", 2),
    ("ATE al. (m)", "ate_aligned_m", 2), ("t_rel (%)", "rpe_trans_pct", 2),
    ("r_rel (°/100m)", "rpe_rot_deg_per_100m", 2), ("NEES", "nees_pose_mean", 2),
    ("map RMSE (m)", "map_rmse_m", 2), ("lm NEES", "nees_landmark_mean", 2),
    ("vs sm. ATE al. (m)", "vs_smoother.ate_aligned_m", 2), ("vs sm. map (m)", "vs_smoother.map_rmse_m", 2),
    ("vs sm. NEES", "vs_smoother.nees_pose_mean", 2), ("vs sm. in 95%", "vs_smoother.inside_95_fraction", 2),
)


def _cell(row: dict, key: str):
    if key.startswith("vs_smoother."):
        return (row.get("vs_smoother") or {}).get(key.split(".", 1)[1])
    return row.get(key)


def summary_markdown(results: dict) -> str:
    """The results as Markdown: per sequence the model line, readings in words
    (:func:`readings`), and a table of the columns that have a value on some row."""
    lines = ["# vislam benchmark", ""]
    lines.append(f"RPE: {results['rpe_definition']}.")
    align = _alignment_words(results)
    lines.append(f"ATE al.: the ATE after {align}.")
    lines.append("vs smoother: the estimator against the smoother's estimate on the same data "
                 f"(ATE after {align}; map RMSE over tracks both estimated; pose NEES of "
                 "the difference under the estimator's own covariance, and the share of steps "
                 "inside chi2.ppf(0.95, 6)).")
    lines.append("")
    for s in results["sequences"]:
        gt = "ground truth" if s["has_ground_truth"] else "no ground truth"
        lines.append(f"## {s['name']} ({s['frames']} frames, {gt})")
        lines.append("")
        model_line = _model_line(s.get("model"))
        if model_line:
            lines += [model_line, ""]
        said = readings(s)
        if said:
            lines += [f"- {sentence}" for sentence in said] + [""]
        header, rows = sequence_table(s)
        lines.append("| " + " | ".join(header) + " |")
        lines.append("|" + "|".join(["---"] * len(header)) + "|")
        lines += ["| " + " | ".join(cells).rstrip() + " |" for cells in rows]
        lines.append("")
    return "\n".join(lines)


def _alignment_words(results: dict) -> str:
    """The alignment of the results' aligned ATEs in words (SE(3) when not recorded)."""
    from vislam.eval.metrics import ALIGN_DESCRIPTIONS

    mode = results.get("alignment") or "se3"
    return ALIGN_DESCRIPTIONS.get(mode, f"{mode} alignment")


def sequence_table(s: dict) -> tuple[list[str], list[list[str]]]:
    """A drive's table as text cells: the header and one row per estimator, with the columns
    of :data:`SUMMARY_COLUMNS` that have a value on some row (a failed estimator: its error)."""
    ok = [r for r in s["estimators"] if not r["error"]]
    columns = [c for c in SUMMARY_COLUMNS if any(_cell(r, c[1]) is not None for r in ok)]
    rows = []
    for r in s["estimators"]:
        if r["error"]:
            rows.append([r["name"], f"failed: {r['error']}"] + [""] * max(len(columns) - 1, 0))
        else:
            rows.append([r["name"]] + [_fmt(_cell(r, key), digits) for _, key, digits in columns])
    return ["estimator"] + [c[0] for c in columns], rows


def _names(rows: list[tuple[str, float]]) -> str:
    return ", ".join(f"{name} ({_fmt(value, 1)})" for name, value in rows)


def readings(s: dict) -> list[str]:
    """A drive's results in a few sentences: the most accurate estimator, which are consistent
    and which over- or underconfident against ground truth (mean pose NEES against the band of
    one 6-dof NEES, :data:`eval.consistency.POSE_NEES_BAND`) and against the smoother, and the
    warning when the reference itself is not consistent (:func:`_reference_honesty`)."""
    from vislam.eval.consistency import POSE_NEES_BAND

    ok = [r for r in s["estimators"] if not r["error"]]
    out = []
    failed = [r["name"] for r in s["estimators"] if r["error"]]
    if failed:
        out.append(f"Failed: {', '.join(failed)} (see results.json).")
    scored = [r for r in ok if r.get("ate_aligned_m") is not None]
    if scored:
        best = min(scored, key=lambda r: r["ate_aligned_m"])
        drift = "" if best.get("rpe_trans_pct") is None else f", t_rel {_fmt(best['rpe_trans_pct'])} %"
        sentence = f"Most accurate: {best['name']} (aligned ATE {_fmt(best['ate_aligned_m'])} m{drift})"
        ekfs = [r for r in scored if r["name"].startswith("ekf-")]
        if ekfs and not best["name"].startswith("ekf-"):
            e = min(ekfs, key=lambda r: r["ate_aligned_m"])
            sentence += f"; the best EKF is {e['name']} ({_fmt(e['ate_aligned_m'])} m)"
        out.append(sentence + ".")
    else:
        near = [r for r in ok if _cell(r, "vs_smoother.ate_aligned_m") is not None]
        if near:
            e = min(near, key=lambda r: _cell(r, "vs_smoother.ate_aligned_m"))
            out.append(f"No ground truth: the estimator closest to the smoother is {e['name']} "
                       f"(aligned ATE against it {_fmt(_cell(e, 'vs_smoother.ate_aligned_m'))} m).")
    lo, hi = POSE_NEES_BAND
    for what, key in (("against ground truth", "nees_pose_mean"),
                      ("against the smoother", "vs_smoother.nees_pose_mean")):
        rows = [(r["name"], _cell(r, key)) for r in ok if _cell(r, key) is not None]
        if not rows:
            continue
        inside = [x for x in rows if lo <= x[1] <= hi]
        above = [x for x in rows if x[1] > hi]
        below = [x for x in rows if x[1] < lo]
        parts = []
        if inside:
            parts.append(f"consistent: {_names(inside)}")
        if above:
            parts.append(f"overconfident: {_names(above)}")
        if below:
            parts.append(f"underconfident: {_names(below)}")
        out.append(f"Pose NEES {what} (band [{lo:.2f}, {hi:.2f}] for the mean of one drive): "
                   + "; ".join(parts) + ".")
    out += [x for x in _reference_honesty(s) if x]
    return out


def _reference_honesty(s: dict) -> list[str]:
    """A sentence when the reference smoother's pose NEES against ground truth is outside its
    band (eval.consistency.reference_honesty): its covariance is then not a fair yardstick for
    the EKFs' (vs sm. NEES)."""
    ref = s.get("reference_smoother")
    row = next((r for r in s["estimators"] if r["name"] == ref and not r["error"]), None)
    sentence = None if row is None else reference_honesty(ref, row["nees_pose_mean"])
    return [] if sentence is None else [f"{sentence} (the vs sm. NEES columns).", ""]


def _model_line(model: dict | None) -> str:
    """One line on the model the estimators ran under (results.json's ``model``)."""
    if not model:
        return ""
    mode = model.get("mode")
    if mode == "as-given":
        failed = model.get("identification_failed")
        why = f" (identification failed: {failed})" if failed else ""
        return f"Model: the file's extrinsic and the settings as given{why}."
    m = model.get("model") or {}
    v = ", ".join(f"{x:.3g}" for x in m.get("velocity_sigma") or [])
    g = ", ".join(f"{x:.3g}" for x in m.get("gyro_sigma") or [])
    bias = "no gyro bias" if m.get("gyro_bias") is None else "gyro bias " + ", ".join(
        f"{x:.2g}" for x in m["gyro_bias"])
    how = {"identified": "identified from the data" + (" (cached)" if model.get("cached") else ""),
           "config": "from " + str(model.get("source", "--config"))}.get(mode, str(mode))
    radial = "" if m.get("radial_k1") is None else f", radial lens term k1 {m['radial_k1']:.3g}"
    tau = m.get("pixel_correlation_time")
    correlated = "" if tau is None else (
        f" correlated along tracks over {tau:.3g} frames (the estimators use "
        f"{long_run_pixel_sigma(m.get('pixel_sigma', float('nan')), tau):.3g} px)")
    slow = {what: times for what, times in (("velocity", m.get("velocity_correlation_time")),
                                            ("gyro", m.get("gyro_correlation_time"))) if times}
    drifting = "" if not slow else (
        f", {' and '.join(slow)} errors correlated in time (long-run / white variance "
        + "; ".join(f"{what} {', '.join(f'{x:.3g}' for x in times)}" for what, times in slow.items())
        + ": the estimators use the long-run sigmas)")
    text = (f"Model {how}: velocity sigma {v} m/s, gyro sigma {g} rad/s{drifting}, pixel sigma "
            f"{m.get('pixel_sigma', float('nan')):.3g} px{correlated}, pairing "
            f"{m.get('velocity_pairing')}, "
            f"{bias}{radial}")
    test = (model.get("identification") or {}).get("extrinsic_test") or {}
    if test:
        against = (f" against {test['threshold']:.3g}, {test.get('criterion', 'chi-square')}"
                   if "threshold" in test else "")
        text += (f"; extrinsic: {test['decision']} (Wald statistic {test['statistic']:.3g} on "
                 f"{test['dof']} dof{against})")
    arm = model.get("lever_arm") or {}
    if arm.get("ground_truth") is not None:
        model_p, truth_p, truth_s = (" ".join(f"{x:.2f}" for x in arm[k])
                                     for k in ("model", "ground_truth", "ground_truth_sigma"))
        text += (f"; lever arm x y z {model_p} m, the ground truth's {truth_p} +- {truth_s} m "
                 "(from the velocities against the true camera motion, no vision)")
    return text + "."


# --- the benchmark ---------------------------------------------------------------------------


@dataclass
class BenchOutput:
    out_dir: Path
    results: dict
    summary: str
    wall_s: float
    #: One line per estimator run that failed ("SEQUENCE ESTIMATOR: error"), empty when none.
    failures: list[str] = field(default_factory=list)


#: What ``vislam bench`` writes at the top of its folder (a folder per sequence besides).
BENCH_FILES = ("results.json", "summary.md", "report.html", "settings.json")


def default_out_dir(root: Path = Path("results")) -> Path:
    return root / time.strftime("%Y%m%d-%H%M%S")


def run_benchmark(
    sequences: list[BenchSequence],
    estimators: list[str],
    config: FilterConfig,
    out_dir: Path,
    jobs: int = 1,
    show_progress: bool = True,
    settings: dict | None = None,
    latest_link: Path | None = None,
    smoother: SmootherSettings | None = None,
    force: bool = False,
    extra_inputs: tuple = (),
    align: str = "se3",
    executor: str = "local",
    scheduler: str | None = None,
) -> BenchOutput:
    """Run, score, plot and write everything into ``out_dir``; ``smoother`` the smoothers'
    settings (defaults when None); ``align`` the alignment before every aligned ATE
    (eval.metrics.ALIGN_MODES, recorded as results.json's ``alignment``). The folder is checked
    before the first job starts and written as :mod:`eval.output_dir` says (``force``: write
    beside files vislam did not write, never over them). ``executor`` and ``scheduler``: where
    the jobs run (:func:`run_jobs`)."""
    from vislam.eval.atomic import atomic_symlink
    from vislam.eval.metrics import check_align_mode
    from vislam.eval.output_dir import OutputDir

    check_align_mode(align)
    t0 = time.perf_counter()
    by_key = {bs.name: bs.sequence for bs in sequences}
    smoother = smoother if smoother is not None else SmootherSettings()
    inputs = [b.path for b in sequences if b.path]
    inputs += [getattr(b.gt, "source", None) for b in sequences if b.gt is not None]
    inputs += list(extra_inputs)
    out = OutputDir(out_dir, force=force, inputs=inputs, expected=[*BENCH_FILES, *by_key])
    with out as tmp:
        configs = {bs.name: bs.config if bs.config is not None else config for bs in sequences}
        outcomes = run_jobs(by_key, estimators, configs, jobs, show_progress, smoother=smoother,
                            executor=executor, scheduler=scheduler)
        with deferred():  # a signal waits until the files are written (matplotlib's C code
            # must not be cut short), then ends the command and the staging folder goes
            results, summary = _write_results(tmp, sequences, estimators, outcomes, config, jobs,
                                              smoother, settings, t0, align=align)
    if latest_link is not None:
        atomic_symlink(Path(out_dir).name, latest_link)
    failures = [f"{s['name']} {r['name']}: {r['error']}"
                for s in results["sequences"] for r in s["estimators"] if r["error"]]
    return BenchOutput(Path(out_dir), results, summary, time.perf_counter() - t0, failures)


def _write_results(tmp: Path, sequences, estimators, outcomes, config, jobs, smoother, settings,
                   t0: float, align: str = "se3") -> tuple[dict, str]:
    from vislam.eval.atomic import write_json, write_text
    from vislam.eval.export import write_tum
    from vislam.eval.metrics import ALIGN_DESCRIPTIONS
    from vislam.eval.report import report_html

    results = {
        "schema": SCHEMA,
        "rpe_definition": RPE_DEFINITION,
        "reference": "vs_smoother compares with the batch smoother ('smoother'), or with "
                     "'smoother-isam2' when only that ran",
        "alignment": align,
        "alignment_definition": f"ate_aligned_m (ATE al.): the ATE after {ALIGN_DESCRIPTIONS[align]}",
        "estimators": list(estimators),
        "sequences": [],
    }
    for bs in sequences:
        outs = {n: outcomes[(bs.name, n)] for n in estimators if (bs.name, n) in outcomes}
        results["sequences"].append(score_sequence(bs, estimators, outs, align=align))
        ests = {n: o.estimate for n, o in outs.items() if isinstance(o, JobResult)}
        folder = tmp / bs.name
        for name, est in ests.items():
            write_tum(folder / f"{file_stem(name)}.tum", est.timestamps, est.poses)
            _save_estimate(folder / f"{file_stem(name)}.estimate.npz", est)
        sequence_figures(folder, bs, ests)
    results["wall_s"] = time.perf_counter() - t0
    summary = summary_markdown(results)
    write_json(tmp / "results.json", results)
    write_text(tmp / "summary.md", summary)
    write_text(tmp / "report.html", report_html(results, tmp))
    write_json(tmp / "settings.json", {
        "estimators": list(estimators),
        "jobs": jobs,
        "alignment": align,
        "filter": config.to_dict(),
        "smoother": smoother.to_dict(),
        "sequences": [{"name": b.name, "path": b.path, **(b.origin or {}),
                       "model": b.model,
                       "filter": None if b.config is None else b.config.to_dict()}
                      for b in sequences],
        **(settings or {}),
    })
    return results, summary


def _save_estimate(path: Path, est: Estimate) -> None:
    """The whole estimate (poses, covariances, map) for the notebook, which then loads it
    instead of running the estimator again; one that cannot be saved (not finite) is left out
    with a warning: the notebook re-runs that one."""
    try:
        est.save_npz(path)
    except EstimationError as exc:
        log.warning("%s not written: %s", path.name, exc)


# --- Monte Carlo NEES ------------------------------------------------------------------------


def monte_carlo_drives(sim_config, runs: int) -> tuple:
    """The Monte Carlo drives of ``sim_config``: (its noise-free SimResult, ``{"run000": drive,
    ...}`` with the noise of run i drawn from ``numpy.random.default_rng([seed, i])``)."""
    from vislam.eval.simulate import simulate

    truth = simulate(dataclasses.replace(sim_config, noise_free=True))
    seqs = {f"run{i:03d}": redraw_noise(truth, sim_config,
                                        np.random.default_rng([sim_config.seed, i]))
            for i in range(runs)}
    return truth, seqs


def redraw_noise(truth, sim_config, rng: np.random.Generator) -> Sequence:
    """The noise-free simulated drive ``truth`` (a SimResult made with ``noise_free=True``) with
    fresh velocity and pixel noise of ``sim_config``'s levels, drawn from ``rng``.

    The simulator draws all its streams from one seed (no separate noise seed), so the Monte
    Carlo runs add the noise here: same trajectory, landmarks and tracks in every run. As in the
    simulator, an observation whose noisy disparity falls below ``min_disparity`` is dropped
    (here the rest of its track is kept). A ``pixel_correlation`` drifts the pixel errors
    along each track as the simulator does (:func:`eval.simulate.drifting_noise`).
    """
    seq = truth.sequence
    T = seq.n_frames
    u = np.asarray(truth.true_velocities, dtype=float).copy()
    u[:, :3] += sim_config.velocity_sigma * rng.standard_normal((T, 3))
    u[:, 3:] += sim_config.gyro_sigma * rng.standard_normal((T, 3)) + np.asarray(sim_config.gyro_bias)
    error = sim_config.pixel_sigma * rng.standard_normal(seq.obs.z.shape)
    if sim_config.pixel_correlation:
        error = _drift_along_tracks(error, seq.obs.frame_index, seq.obs.track,
                                    sim_config.pixel_correlation)
    z = seq.obs.z + error
    keep = (z[:, 0] - z[:, 2]) >= sim_config.min_disparity
    obs = Observations.from_rows(seq.obs.frame_index[keep], seq.obs.track[keep], z[keep], T)
    return dataclasses.replace(
        seq, linear_velocity=u[:, :3].copy(), angular_velocity=u[:, 3:].copy(), obs=obs
    )


def _drift_along_tracks(white: np.ndarray, frame: np.ndarray, track: np.ndarray,
                        a: float) -> np.ndarray:
    """Pixel errors (N, 4) drifting along each track (AR(1) with correlation ``a`` between
    observations of a track in consecutive frames) from white draws ``white``, frame by frame
    as the simulator makes them."""
    from vislam.eval.simulate import drifting_noise

    out = np.empty_like(white)
    track = np.asarray(track, dtype=np.int64)
    last = np.zeros((int(track.max(initial=-1)) + 1, 4))
    last_frame = np.full(last.shape[0], -2, dtype=np.int64)
    order = np.argsort(frame, kind="stable")
    bounds = np.flatnonzero(np.diff(np.asarray(frame)[order])) + 1
    for rows in np.split(order, bounds):
        k, t = int(frame[rows[0]]), track[rows]
        out[rows] = drifting_noise(white[rows], last[t], last_frame[t] == k - 1, a)
        last[t], last_frame[t] = out[rows], k
    return out


def landmark_nees_by_source(est: Estimate, truth: np.ndarray) -> np.ndarray:
    """Landmark NEES per source track (n_source,): a cleaned estimate's tracks are mapped back
    through ``info["track_origin"]`` (the first track of a split one counts)."""
    from vislam.eval.consistency import landmark_nees

    nees = landmark_nees(est, truth)
    out = np.full(truth.shape[0], np.nan)
    origin = est.info.get("track_origin")
    origin = np.arange(nees.size) if origin is None else np.asarray(origin, dtype=np.int64)
    ok = np.isfinite(nees) & (origin >= 0) & (origin < out.size)
    idx = np.nonzero(ok)[0][::-1]  # reversed: the first of duplicates is written last
    out[origin[idx]] = nees[idx]
    return out


def nees_sim_config(seed: int, frames: int | None = None, max_depth: float | None = None):
    """The SimConfig of `vislam nees`: the simulator's default drive (``seed``, ``frames``
    steps) with landmarks up to ``max_depth`` m deep (None: the default 60 m, the drive as it
    is). The landmark density is per metre of path and most landmarks stand 4-50 m to the side,
    so a shorter range alone empties the view (10 m: about one observation per frame instead of
    80) and a longer one crowds it; with another range the density is scaled so the drive keeps
    the default range's observations per frame, counted on noise-free drives of the seed,
    ``_DENSITY_PROBE_FRAMES`` frames long, at both ranges (capped at the simulator's largest
    density)."""
    from vislam.eval.simulate import _SIM_UPPER_BOUNDS, DEFAULT_SIM, simulate

    config = dataclasses.replace(
        DEFAULT_SIM, seed=int(seed), n_frames=int(frames or DEFAULT_NEES_FRAMES), name=f"mc-seed{seed}"
    )
    if max_depth is None or max_depth == config.max_depth:
        return config
    probe = dataclasses.replace(config, n_frames=_DENSITY_PROBE_FRAMES, noise_free=True)
    wanted = simulate(probe).sequence.obs.frame_index.size
    seen = simulate(dataclasses.replace(probe, max_depth=float(max_depth))).sequence.obs.frame_index.size
    top = _SIM_UPPER_BOUNDS["landmark_density"]
    density = min(config.landmark_density * wanted / seen, top) if seen else top
    return dataclasses.replace(config, max_depth=float(max_depth), landmark_density=density)


def monte_carlo_nees(
    runs: int,
    seed: int,
    estimators: list[str],
    config: FilterConfig,
    frames: int | None = None,
    jobs: int = 1,
    show_progress: bool = True,
    smoother: SmootherSettings | None = None,
    sim_max_depth: float | None = None,
    executor: str = "local",
    scheduler: str | None = None,
) -> dict:
    """ANEES of pose (6 dof, steps 1..T-1) and landmarks (3 dof) over ``runs`` noise draws of
    one simulated drive (seed ``seed``, landmarks up to ``sim_max_depth`` m deep: see
    :func:`nees_sim_config`); the nees.json content. ``executor`` and ``scheduler``: where the
    runs go (:func:`run_jobs`); the numbers do not depend on it, nor on ``jobs``."""
    smoother = smoother if smoother is not None else SmootherSettings()
    from vislam.eval.consistency import LANDMARK_DOF, POSE_DOF, anees, chi2_bounds, pose_nees

    if runs < 1:
        raise InputError(f"--runs must be >= 1, got {runs}")
    sim_config = nees_sim_config(seed, frames, sim_max_depth)
    truth, seqs = monte_carlo_drives(sim_config, runs)
    T = truth.sequence.n_frames

    names = [display_name(e) for e in estimators]  # a user's callable by MODULE:FUNCTION
    pose = {n: np.full((runs, T), np.nan) for n in names}
    landmark = {n: np.full((runs, truth.landmarks.shape[0]), np.nan) for n in names}
    runtime = {n: [] for n in names}
    errors: dict[str, list[str]] = {n: [] for n in names}
    frames_all = np.arange(T)

    def reduce(res) -> None:  # keep only the NEES arrays, not every estimate
        i = int(res.sequence[3:])
        if isinstance(res, JobFailure):
            errors[res.estimator].append(res.error)
            return
        est = res.estimate
        pose[res.estimator][i] = pose_nees(est, frames_all, truth.poses)
        landmark[res.estimator][i] = landmark_nees_by_source(est, truth.landmarks)
        runtime[res.estimator].append(res.wall_s)

    outcomes = run_jobs(seqs, estimators, config, jobs, show_progress, on_result=reduce, smoother=smoother,
                        executor=executor, scheduler=scheduler)
    outcomes.clear()
    out = {
        "runs": runs,
        "seed": seed,
        "frames": T,
        "noise": "velocity and pixel noise redrawn per run (numpy default_rng([seed, run])) on "
                 "the noise-free drive of SimConfig(seed); trajectory, landmarks, tracks fixed",
        "definition": "anees_pose: mean over steps 1..T-1 of the per-step NEES averaged over runs; "
                      "anees_landmark: mean over landmarks (estimated in every run) of the per-"
                      "landmark NEES averaged over runs; bounds chi2.ppf([.025,.975], N d)/N; "
                      "verdict 'above' = overconfident, 'below' = underconfident; "
                      "inside_fraction = share of steps / landmarks inside the bounds",
        "simulation": dataclasses.asdict(sim_config),
        "filter": config.to_dict(),
        "smoother": smoother.to_dict(),
        "estimators": {},
    }
    for n in names:
        p = anees(pose[n][:, 1:], POSE_DOF)
        lm_ok = np.any(np.isfinite(landmark[n]), axis=0)
        lm = anees(landmark[n][:, lm_ok], LANDMARK_DOF) if np.any(lm_ok) else None
        per_step = np.concatenate([[np.nan], p.per_item])
        out["estimators"][n] = {
            "anees_pose": p.mean,
            "anees_landmark": lm.mean if lm else None,
            "bounds_pose": list(p.bounds),
            "bounds_landmark": list(lm.bounds if lm else chi2_bounds(runs, LANDMARK_DOF)),
            "verdict_pose": p.verdict,
            "verdict_landmark": lm.verdict if lm else None,
            "inside_fraction_pose": p.inside_fraction,
            "inside_fraction_landmark": lm.inside_fraction if lm else None,
            "landmarks_scored": int(np.count_nonzero(np.isfinite(lm.per_item))) if lm else 0,
            "runs_failed": len(errors[n]),
            "errors": errors[n][:3],
            "runtime_s_mean": float(np.mean(runtime[n])) if runtime[n] else None,
            "nees_pose_over_time": per_step,
            "nees_pose_per_run_mean": [
                float(np.nanmean(r[1:])) if np.any(np.isfinite(r[1:])) else None for r in pose[n]
            ],
        }
    out["timestamps"] = truth.sequence.timestamps - truth.sequence.timestamps[0]
    return out
