"""`vislam simulate`: write a simulated KITTI-like drive with its ground truth.

Writes ``OUT/NAME.npz`` (the shared data's format), ``OUT/groundtruth/NAME.txt`` (KITTI poses of
the left camera with time), ``OUT/NAME_landmarks.npz`` (true landmarks, poses, velocities) and
``OUT/NAME_model.toml`` (the true model of the drive: ekf.model). The same seed and settings
always give the same bytes. Faults a model identification must find: per-axis velocity noise
(``--velocity-sigma 0.05,0.04,0.03``), a gyro bias, the velocity pairing of the samples, and a
wrong extrinsic in the file (``--file-extrinsic-fault kitti``, ``--file-extrinsic-offset``),
velocity errors that drift in time (``--velocity-correlation``), and streams stamped late against
the camera (``--velocity-time-offset``, ``--gyro-time-offset``; with ``--imu``:
``--imu-time-offset``, and an IMU noisier than its data sheet, ``--imu-noise-scale``).
"""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path

from vislam.ekf.errors import InputError
from vislam.eval.sim_config import (
    DEFAULT_SIM,
    FILE_EXTRINSIC_FAULTS,
    SCENARIO_DEFAULTS,
    SIM_SCENARIOS,
    SIM_VELOCITY_PAIRINGS,
    SimConfig,
    scenario_config,
)
from vislam.eval.sim_files import write_simulation
from vislam.eval.imu_sim_config import CAMERAS as IMU_CAMERAS
from vislam.eval.imu_trajectories import SCENARIOS as IMU_SCENARIOS
from vislam.eval.simulate import simulate, simulation_stats


def _numbers(text: str) -> list[float]:
    """One flag token: a number, or numbers separated by commas ("0.5,0.4,0.3")."""
    try:
        return [float(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number or comma-separated numbers: {text!r}") \
            from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    d = DEFAULT_SIM
    parser.add_argument("--out", required=True,
                        help="output folder (created if missing; files already there are kept, "
                             "and vislam never replaces a file it did not write)")
    parser.add_argument("--force", action="store_true",
                        help="write into a non-empty folder vislam did not write (its files are "
                             "never replaced)")
    parser.add_argument("--seed", type=int, default=d.seed, help="random seed (default %(default)s)")
    parser.add_argument(
        "--frames", type=int, default=d.n_frames, help="number of frames at 10 Hz (default %(default)s)"
    )
    parser.add_argument(
        "--scenario", choices=tuple(dict.fromkeys(SIM_SCENARIOS + IMU_SCENARIOS)), default=d.scenario,
        help="the drive's shape: road (a KITTI-like drive, tracks never come back), loop (a car "
        "that drives a closed loop and sees its first landmarks again), room (a platform in a "
        "10 x 8 m room, 50 landmarks on the walls seen again and again, stops included); with "
        "--imu: room (a drone), handheld or road (a car) (default %(default)s)",
    )
    parser.add_argument(
        "--imu", action="store_true",
        help="a raw-IMU drive (accelerometer and gyro at 200 Hz, tracks at 20 Hz, a rest at the "
        "start, EuRoC's IMU noise) instead of a velocity drive; its ground truth is "
        "groundtruth/NAME.csv",
    )
    parser.add_argument(
        "--camera", choices=IMU_CAMERAS, default=None,
        help="--imu: one camera (mono, two pixel columns) or a rectified stereo pair (default mono)",
    )
    parser.add_argument(
        "--name", default=None,
        help="file name stem (default sim-seed{SEED} for the road, {SCENARIO}-seed{SEED} else)"
    )
    parser.add_argument(
        "--pixel-sigma", type=float, default=d.pixel_sigma, help="stereo pixel noise, px (default %(default)s)"
    )
    parser.add_argument(
        "--velocity-sigma",
        type=_numbers,
        nargs="+",
        default=None,
        metavar="M/S",
        help="linear-velocity noise per sample, m/s: one value for every axis or three (x, y, z; "
        f"'0.5,0.4,0.3' or '0.5 0.4 0.3') (default {d.velocity_sigma}; room "
        f"{SCENARIO_DEFAULTS['room']['velocity_sigma']})",
    )
    parser.add_argument(
        "--gyro-sigma",
        type=_numbers,
        nargs="+",
        default=None,
        metavar="RAD/S",
        help=f"angular-velocity noise per sample, rad/s: one value or three (default {d.gyro_sigma}; "
        f"room {SCENARIO_DEFAULTS['room']['gyro_sigma']})",
    )
    parser.add_argument(
        "--gyro-bias",
        type=float,
        nargs="+",
        default=None,
        metavar="B",
        help="constant gyro bias, rad/s: one value for every axis or three (default 0)",
    )
    parser.add_argument(
        "--landmark-density",
        type=float,
        default=d.landmark_density,
        help="landmarks per metre of path (default %(default)s)",
    )
    parser.add_argument(
        "--repeat-event-rate",
        type=float,
        default=d.repeat_event_rate,
        help="probability per frame of a repeat event like the shared drives' (every continuing "
        "track repeats its previous observation; 0027 has about 0.08) (default %(default)s)",
    )
    parser.add_argument(
        "--noise-free", action="store_true", help="no pixel, velocity or bias noise at all"
    )
    parser.add_argument(
        "--velocity-pairing",
        choices=SIM_VELOCITY_PAIRINGS,
        default=d.velocity_pairing,
        help="which velocity sample covers [k, k+1] in the data made: current (u_k), next "
        "(u_{k+1}) or mean (their mean) (default %(default)s)",
    )
    parser.add_argument(
        "--file-extrinsic-fault",
        choices=FILE_EXTRINSIC_FAULTS,
        default=d.file_extrinsic_fault,
        help="write a wrong cam_T_imu into the file: 'kitti' stores imu_T_cam's translation "
        "where cam_T_imu's belongs, like the shared data (default %(default)s: the true one)",
    )
    parser.add_argument(
        "--radial-k1",
        type=float,
        default=d.radial_k1,
        help="a radial lens term the file's pixels carry beyond its pinhole K: x_d = x (1 + k1 "
        "r^2) in normalised coordinates (default %(default)s: none)",
    )
    parser.add_argument(
        "--pixel-correlation",
        type=float,
        metavar="A",
        default=d.pixel_correlation,
        help="correlation of a track's pixel errors from one frame to the next, like a "
        "tracker's drift: AR(1), in [0, 0.99) (default %(default)s: independent)",
    )
    parser.add_argument(
        "--velocity-correlation",
        type=float,
        metavar="A",
        default=d.velocity_correlation,
        help="correlation of the linear-velocity errors from one sample to the next, like a "
        "velocity source that drifts: AR(1), in [0, 0.99); the true model then carries their "
        "long-run sigma, which 'vislam calibrate' measures (default %(default)s: white)",
    )
    parser.add_argument(
        "--file-extrinsic-offset",
        type=float,
        nargs=6,
        default=None,
        metavar=("TX", "TY", "TZ", "RX", "RY", "RZ"),
        help="add this to the file's cam_T_imu: translation (m) and rotation vector (rad, "
        "applied on the left) (default 0)",
    )
    parser.add_argument(
        "--velocity-time-offset", type=float, metavar="S", default=d.velocity_time_offset,
        help="the linear-velocity stream's stamps late against the camera's by S seconds (the "
        "sample stamped t holds the motion at t - S; negative: early); within 1 s and a tenth "
        "of the drive (default %(default)s)",
    )
    parser.add_argument(
        "--gyro-time-offset", type=float, metavar="S", default=d.gyro_time_offset,
        help="the same for the angular-velocity stream (default %(default)s)",
    )
    parser.add_argument(
        "--imu-time-offset", type=float, metavar="S", default=None,
        help="--imu: the IMU's stamps late against the camera's by S seconds (the sample "
        "stamped t holds the motion at t - S); within 1 s and a tenth of the drive (default 0)",
    )
    parser.add_argument(
        "--imu-noise-scale", type=float, metavar="X", default=None,
        help="--imu: the IMU's white noise and bias walks are X times the data sheet's "
        "densities, which the file still declares (an IMU noisier than its sheet; default 1)",
    )


def config_from_args(args: argparse.Namespace) -> SimConfig:
    bias = args.gyro_bias if args.gyro_bias is not None else [0.0]
    if len(bias) == 1:
        bias = bias * 3
    if len(bias) != 3:
        raise InputError(f"--gyro-bias takes one or three values, got {len(bias)}")
    scenario = getattr(args, "scenario", DEFAULT_SIM.scenario)
    stem = "sim" if scenario == "road" else scenario
    name = args.name if args.name is not None else f"{stem}-seed{args.seed}"
    check_name(name)
    offset = getattr(args, "file_extrinsic_offset", None)
    base = {**DEFAULT_SIM.__dict__, **SCENARIO_DEFAULTS[scenario]}
    return scenario_config(
        scenario,
        seed=args.seed,
        n_frames=args.frames,
        name=name,
        pixel_sigma=args.pixel_sigma,
        velocity_sigma=_sigma_arg(args, "velocity_sigma", base["velocity_sigma"]),
        gyro_sigma=_sigma_arg(args, "gyro_sigma", base["gyro_sigma"]),
        gyro_bias=tuple(bias),
        landmark_density=args.landmark_density,
        repeat_event_rate=args.repeat_event_rate,
        noise_free=args.noise_free,
        velocity_pairing=getattr(args, "velocity_pairing", DEFAULT_SIM.velocity_pairing),
        file_extrinsic_fault=getattr(args, "file_extrinsic_fault",
                                     DEFAULT_SIM.file_extrinsic_fault),
        file_extrinsic_offset=tuple(offset) if offset is not None
        else DEFAULT_SIM.file_extrinsic_offset,
        radial_k1=getattr(args, "radial_k1", DEFAULT_SIM.radial_k1),
        pixel_correlation=getattr(args, "pixel_correlation", DEFAULT_SIM.pixel_correlation),
        velocity_correlation=getattr(args, "velocity_correlation",
                                     DEFAULT_SIM.velocity_correlation),
        velocity_time_offset=getattr(args, "velocity_time_offset",
                                     DEFAULT_SIM.velocity_time_offset),
        gyro_time_offset=getattr(args, "gyro_time_offset", DEFAULT_SIM.gyro_time_offset),
    )


def _sigma_arg(args: argparse.Namespace, dest: str, default):
    """``--velocity-sigma`` / ``--gyro-sigma``: tokens of one or three numbers (commas or
    spaces) -> a float or a tuple of three; InputError naming the flag otherwise."""
    raw = getattr(args, dest, None)
    if raw is None:
        return default
    values = [x for token in raw for x in (token if isinstance(token, list) else [token])]
    if len(values) == 1:
        return float(values[0])
    if len(values) != 3:
        flag = "--" + dest.replace("_", "-")
        raise InputError(f"{flag} takes one or three values, got {len(values)} ({dest})")
    return tuple(float(x) for x in values)


_NAME_OK = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*")


def check_readable(seq, frames: int) -> None:
    """Refuse a drive whose file vislam's reader would refuse: its sparse observations (8 bytes
    a pixel coordinate) or its per-track arrays beyond ``VISLAM_MAX_ARRAY_BYTES``. The file
    grows with the observations (the sparse layout), not with tracks x frames."""
    from vislam.eval.drive_keys import BYTES_PER_TRACK
    from vislam.eval.safe_reading import MAX_ARRAY_BYTES_ENV, max_array_bytes

    limit = max_array_bytes()
    pixel_bytes = int(seq.obs.z.size) * 8
    track_bytes = int(seq.n_tracks) * BYTES_PER_TRACK
    if max(pixel_bytes, track_bytes) > limit:
        raise InputError(
            f"--frames {frames}: the drive's {len(seq.obs)} observations ({pixel_bytes} bytes "
            f"of pixels) and {seq.n_tracks} tracks ({track_bytes} bytes of per-track arrays) "
            f"pass the reader's limit of {limit} bytes an array ({MAX_ARRAY_BYTES_ENV}): "
            "vislam could not read the file; use fewer frames or a lower --landmark-density")


def check_name(name: str) -> None:
    """``--name`` is a file name stem: no folders, no leading dot, nothing a shell would mangle."""
    if not _NAME_OK.fullmatch(name) or len(name) > 200:
        raise InputError(
            f"--name {name!r}: must be a plain file name stem (letters, digits, '_', '-', '+', "
            "'.', not starting with '.' or '-', no '/'); the files go into --out"
        )


def _defaults() -> dict:
    """Every flag's default (what the raw-IMU simulation checks the velocity flags against)."""
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return {a.dest: a.default for a in parser._actions}


def outputs(name: str) -> tuple[str, ...]:
    """The files ``vislam simulate`` writes, relative to ``--out`` (eval.sim_files.write_simulation)."""
    return (f"{name}.npz", f"groundtruth/{name}.txt", f"{name}_landmarks.npz",
            f"{name}_model.toml")


def run(args: argparse.Namespace) -> int:
    from vislam.eval.output_dir import OutputDir

    if getattr(args, "imu", False):
        from vislam.eval.commands.simulate_imu import run_imu

        return run_imu(args, _defaults(), check_name)
    for dest in ("camera", "imu_time_offset", "imu_noise_scale"):
        if getattr(args, dest, None) is not None:
            raise InputError(f"--{dest.replace('_', '-')}: a setting of raw-IMU simulations; "
                             "add --imu")
    if args.scenario not in SIM_SCENARIOS:
        raise InputError(f"--scenario {args.scenario}: a raw-IMU scenario; add --imu, or choose "
                         f"one of {', '.join(SIM_SCENARIOS)}")

    config = config_from_args(args)
    with OutputDir(args.out, force=args.force, expected=outputs(config.name)) as tmp:
        start = time.perf_counter()
        result = simulate(config)
        sim_s = time.perf_counter() - start
        check_readable(result.sequence, args.frames)
        staged = write_simulation(result, tmp, config.name)
    paths = {role: Path(args.out) / p.relative_to(tmp) for role, p in staged.items()}
    stats = simulation_stats(result)
    print(
        f"simulated {config.name}: {stats['frames']:.0f} frames, {stats['path_length_m']:.0f} m, "
        f"speed {stats['speed_min']:.1f}-{stats['speed_max']:.1f} m/s, "
        f"{stats['tracks']:.0f} tracks, {stats['obs_per_frame_mean']:.1f} observations per frame "
        f"(min {stats['obs_per_frame_min']:.0f}, max {stats['obs_per_frame_max']:.0f}), "
        f"mean track length {stats['track_length_mean']:.1f} frames, in {sim_s:.2f} s"
    )
    for role, path in paths.items():
        print(f"wrote {role}: {path}")
    return 0
