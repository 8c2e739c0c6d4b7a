"""`vislam score TRAJ --data FILE.npz`: score a trajectory made by any system with the
benchmark's definitions (eval/score.py): against the drive's ground truth where it has one
(ATE raw and aligned, KITTI drift, mean pose NEES under ``--cov``) and against the reference
smoother run on the same data as ``vislam bench`` runs it (vs-smoother ATE, NEES of the
difference under ``--cov``, share inside the 95 % bound).

Formats (``--format``, default from the extension: .tum/.txt tum, .csv euroc, .kitti kitti):
tum ``t x y z qx qy qz qw`` (seconds; what ``vislam bench`` writes as ``<estimator>.tum``);
kitti 12 numbers per line (3x4 ``[R | t]`` row-major, no times: one pose per frame);
euroc ``timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z[, ...]`` (# lines are headers).
Poses are world_T_imu with the world the IMU at frame 0, as vislam's estimates.

Covariances (``--cov``): vislam's convention, per pose the 6x6 covariance of [rho; phi]
(translation first, m and rad) of a right perturbation of world_T_imu. A vislam
``<estimator>.estimate.npz``, a ``.npy`` (N, 6, 6) with one per trajectory pose, or text lines
``t`` + 36 numbers row-major. Without ``--cov`` the NEES figures are null.

Association: each pose time plus ``--t-offset`` goes to the nearest frame within
``--t-max-diff`` s (evo's ``--t_offset`` / ``--t_max_diff``); only associated frames are
scored. ``--model`` and ``--config`` and the estimator flags as for ``vislam bench``: give
the same ones to reproduce a benchmark's figures.
"""

from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from vislam.eval.commands.options import (
        add_align_argument,
        add_filter_arguments,
        add_model_argument,
    )
    from vislam.eval.score import DEFAULT_T_MAX_DIFF, FORMATS

    parser.add_argument("trajectory", metavar="TRAJ", help="trajectory file (tum, kitti, euroc)")
    parser.add_argument("--data", "-d", metavar="FILE.npz",
                        help="the drive the trajectory was estimated on (required); its ground "
                             "truth is looked up as for vislam bench")
    parser.add_argument("--format", "-f", choices=FORMATS, default=None,
                        help="trajectory format (default from the extension: .tum/.txt tum, "
                             ".csv euroc, .kitti kitti)")
    parser.add_argument("--cov", metavar="COV",
                        help="pose covariances: a vislam <estimator>.estimate.npz, a .npy "
                             "(N,6,6) one per trajectory pose, or text lines 't' + 36 numbers "
                             "row-major (6x6, translation first, m and rad, right perturbation "
                             "of world_T_imu); without it the NEES figures are null")
    parser.add_argument("--t-max-diff", type=float, default=DEFAULT_T_MAX_DIFF, metavar="S",
                        help=f"largest time difference of an associated pose and frame "
                             f"(default {DEFAULT_T_MAX_DIFF:g} s, as evo's --t_max_diff)")
    parser.add_argument("--t-offset", type=float, default=0.0, metavar="S",
                        help="added to the trajectory's (and covariances') times before "
                             "association (as evo's --t_offset; default 0)")
    parser.add_argument("--out", "-o", metavar="DIR",
                        help="write score.json and score.md into DIR (checked before any "
                             "estimation; never overwrites files vislam did not write)")
    parser.add_argument("--force", action="store_true",
                        help="write into a non-empty folder vislam did not write (its files are "
                             "never replaced)")
    parser.add_argument("--no-reference", action="store_true",
                        help="do not run the reference smoother (the vs-smoother figures are null)")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar, no table")
    add_model_argument(parser)
    add_align_argument(parser)
    add_filter_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from vislam.ekf.errors import InputError
    from vislam.eval.atomic import write_json, write_text
    from vislam.eval.covariance_files import read_pose_covariances
    from vislam.eval.commands.bench import drives_under_model
    from vislam.eval.commands.options import (
        environment_settings,
        filter_config_from_args,
        model_from_args,
        smoother_settings_from_args,
    )
    from vislam.eval.output_dir import OutputDir
    from vislam.eval.readings import score_markdown
    from vislam.eval.bench_scores import default_alignment
    from vislam.eval.score import (
        SCORE_FILES,
        associate,
        check_time_options,
        load_drive,
        read_trajectory,
        score,
    )
    from vislam.eval.signals import deferred

    if not args.data:
        raise InputError("--data FILE.npz is required: the drive the trajectory was estimated "
                         "on (its frames, ground truth and reference)")
    check_time_options(args.t_max_diff, args.t_offset)
    config = filter_config_from_args(args)
    smoother = smoother_settings_from_args(args)
    model = model_from_args(args)
    # Every input is read and checked before anything runs.
    traj = read_trajectory(args.trajectory, args.format)
    cov = read_pose_covariances(args.cov) if args.cov else None
    plain = load_drive(args.data)  # its frame times: the model does not change them
    assoc = associate(traj, plain.sequence.timestamps, args.t_max_diff, args.t_offset,
                      data=str(args.data))

    def compute() -> dict:
        (bs,) = drives_under_model(args, [plain], config, smoother, model)
        result = score(traj, bs, config=config, smoother=smoother, cov=cov,
                       t_max_diff=args.t_max_diff, t_offset=args.t_offset,
                       align=default_alignment(getattr(args, "align", None), bs.sequence),
                       reference=not args.no_reference,
                       show_progress=not args.quiet, assoc=assoc)
        result["settings"] = {
            **environment_settings(),
            "model_mode": "config" if model is not None else args.model,
            "filter": config.to_dict(), "smoother": smoother.to_dict(),
        }
        return result

    if args.out:
        inputs = [args.trajectory, args.data, args.cov, args.config,
                  getattr(plain.gt, "source", None)]
        with OutputDir(args.out, force=args.force, inputs=inputs, expected=SCORE_FILES) as tmp:
            result = compute()
            text = score_markdown(result)
            with deferred():
                write_json(tmp / "score.json", result)
                write_text(tmp / "score.md", text)
    else:
        result = compute()
        text = score_markdown(result)
    if not args.quiet:
        print(text)
    if args.out:
        print(f"wrote {args.out}", file=sys.stderr)
    return 0
