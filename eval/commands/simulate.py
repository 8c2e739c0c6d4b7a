"""`vislam simulate`: write a simulated KITTI-like drive with its ground truth.

Writes ``OUT/NAME.npz`` (the shared data's format), ``OUT/groundtruth/NAME.txt`` (KITTI poses of
the left camera with time) and ``OUT/NAME_landmarks.npz`` (true landmarks, poses, velocities).
The same seed and settings always give the same bytes.
"""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path

from ekf.errors import InputError
from eval.simulate import DEFAULT_SIM, SimConfig, simulate, simulation_stats, write_simulation


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
        "--name", default=None, help="file name stem (default sim-seed{SEED})"
    )
    parser.add_argument(
        "--pixel-sigma", type=float, default=d.pixel_sigma, help="stereo pixel noise, px (default %(default)s)"
    )
    parser.add_argument(
        "--velocity-sigma",
        type=float,
        default=d.velocity_sigma,
        help="linear-velocity noise per sample, m/s (default %(default)s)",
    )
    parser.add_argument(
        "--gyro-sigma",
        type=float,
        default=d.gyro_sigma,
        help="angular-velocity noise per sample, rad/s (default %(default)s)",
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


def config_from_args(args: argparse.Namespace) -> SimConfig:
    bias = args.gyro_bias if args.gyro_bias is not None else [0.0]
    if len(bias) == 1:
        bias = bias * 3
    if len(bias) != 3:
        raise InputError(f"--gyro-bias takes one or three values, got {len(bias)}")
    name = args.name if args.name is not None else f"sim-seed{args.seed}"
    check_name(name)
    return SimConfig(
        seed=args.seed,
        n_frames=args.frames,
        name=name,
        pixel_sigma=args.pixel_sigma,
        velocity_sigma=args.velocity_sigma,
        gyro_sigma=args.gyro_sigma,
        gyro_bias=tuple(bias),
        landmark_density=args.landmark_density,
        repeat_event_rate=args.repeat_event_rate,
        noise_free=args.noise_free,
    )


#: Largest dense feature array (4, M, T) of float64 it writes; the data format is dense.
MAX_FEATURE_BYTES = 2 * 1024**3
_NAME_OK = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*")


def check_name(name: str) -> None:
    """``--name`` is a file name stem: no folders, no leading dot, nothing a shell would mangle."""
    if not _NAME_OK.fullmatch(name) or len(name) > 200:
        raise InputError(
            f"--name {name!r}: must be a plain file name stem (letters, digits, '_', '-', '+', "
            "'.', not starting with '.' or '-', no '/'); the files go into --out"
        )


def outputs(name: str) -> tuple[str, ...]:
    """The files ``vislam simulate`` writes, relative to ``--out`` (eval.simulate.write_simulation)."""
    return (f"{name}.npz", f"groundtruth/{name}.txt", f"{name}_landmarks.npz")


def run(args: argparse.Namespace) -> int:
    from eval.output_dir import OutputDir

    config = config_from_args(args)
    with OutputDir(args.out, force=args.force, expected=outputs(config.name),
                   exclusive=False) as tmp:
        start = time.perf_counter()
        result = simulate(config)
        sim_s = time.perf_counter() - start
        dense = 4 * result.sequence.n_tracks * result.sequence.n_frames * 8
        if dense > MAX_FEATURE_BYTES:
            raise InputError(
                f"--frames {args.frames}: the drive's dense feature array would take "
                f"{dense / 1024**3:.1f} GiB (limit {MAX_FEATURE_BYTES / 1024**3:.0f} GiB); "
                "use fewer frames or a lower --landmark-density"
            )
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
