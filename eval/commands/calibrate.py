"""`vislam calibrate`: identify the noise model of a drive from the data alone (no ground truth).

EM around the batch smoother (:mod:`graph.identification`): per-axis velocity and gyro noise,
the stereo pixel noise, the velocity pairing with the largest likelihood, and a constant gyro
bias when its likelihood ratio passes the BIC, and a radial lens term of the pixels when its
Wald statistic passes the BIC (:mod:`graph.radial`; the files carry no distortion
coefficient, so the file's value is none), and with ``--time-offsets`` each velocity stream's
time offset against the camera when its score passes the BIC (:mod:`graph.time_offset`;
estimate, sigma, statistic and decision printed for both streams). Prints each value with its standard deviation
beside the settings it would replace, and writes the model as TOML (``--out``, the ``[model]``
table every command's ``--config`` reads).

The camera-IMU extrinsic is identified too (:mod:`graph.extrinsic`: a variable of the stereo
factors, with its covariance from the whole drive), unless ``--extrinsic file`` keeps the
file's. The report gives each component with its sigma beside the file's, the lever arm (the
camera's position, IMU axes), names the components the drive cannot determine, and ends
with a verdict on the file's extrinsic ("file lever arm 2.1 m from the data's: 14 sigma"),
then the data check of :mod:`graph.data_check` under the identified model: stretches of the
drive where velocities and vision still disagree beyond their noise.

What the data determine is the camera's position relative to the point whose velocity the file
gives, which need not be the IMU's origin of the ground truth. On both editions of KITTI 0027,
the ground truth's lateral velocity (KITTI's extrinsic) minus the file's grows with the roll rate
by 1.8 m and with the yaw rate by 0.4 m (2019 edition, both regressed at once): the velocities
are those of a point about 1.7 m below and 0.4 m ahead of KITTI's IMU origin. The lever-arm
equation solved on the ground truth alone (:mod:`eval.lever_arm_truth`) gives a forward lever
arm of 0.78 +- 0.05 m (2019 edition) and 0.75 +- 0.09 m (shared), against KITTI's 1.14 m; the
identified vertical lever arm (about 2 m on the 2019 edition) is that point's too.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from vislam.eval.commands.options import add_filter_arguments

    parser.add_argument("file", metavar="FILE.npz", help="the drive (.npz data file; a raw-IMU "
                        "drive gets its IMU noise and pixel sigma identified: "
                        "eval.commands.calibrate_imu)")
    parser.add_argument("--out", "-o", metavar="MODEL.toml",
                        help="write the model here (a [model] table for --config; for a raw-IMU "
                             "drive: DRIVE.npz, the drive with the identified imu_noise)")
    parser.add_argument("--force", action="store_true",
                        help="replace --out even when it is a file vislam did not write")
    parser.add_argument("--pairings", metavar="LIST", default="current,next,mean",
                        help="velocity pairings to compare (default current,next,mean)")
    parser.add_argument("--max-iterations", type=int, default=12, metavar="N",
                        help="EM steps per pairing (a raw-IMU drive: in all) at most (default 12)")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N",
                        help="identify on the drive's central N frames at most (default 1500, "
                             "as vislam bench does; 0: every frame)")
    parser.add_argument("--extrinsic", choices=("identify", "file"), default="identify",
                        help="identify the camera-IMU extrinsic (default) or keep the file's")
    parser.add_argument("--time-offsets", action="store_true",
                        help="also estimate the velocity and gyro streams' time offsets against "
                             "the camera (off by default; vislam bench does not: docs/estimators.md; "
                             "a raw-IMU drive's camera-IMU offset is always estimated)")
    add_filter_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from vislam.eval.inertial_files import is_inertial_file

    if is_inertial_file(args.file):  # issue 39 item 2: the raw-IMU smoother's EM
        from vislam.eval.commands.calibrate_imu import run_raw_imu

        return run_raw_imu(args)
    from vislam.ekf.config import VELOCITY_PAIRINGS
    from vislam.ekf.errors import InputError
    from vislam.eval.atomic import write_text
    from vislam.eval.loader import load_sequence
    from vislam.eval.commands.options import filter_config_from_args, smoother_settings_from_args
    from vislam.graph.identification import MAX_FRAMES, identify_model

    config = filter_config_from_args(args)
    smoother = smoother_settings_from_args(args).replace(compute_marginals=False)
    pairings = tuple(p.strip() for p in args.pairings.split(",") if p.strip())
    bad = [p for p in pairings if p not in VELOCITY_PAIRINGS]
    if not pairings or bad:
        raise InputError(f"--pairings {args.pairings!r}: each must be one of "
                         f"{', '.join(VELOCITY_PAIRINGS)}")
    if not 3 <= args.max_iterations <= 1000:
        raise InputError(f"--max-iterations must be between 3 and 1000, got {args.max_iterations}")
    max_frames = MAX_FRAMES if args.max_frames is None else (args.max_frames or None)
    if args.max_frames is not None and args.max_frames != 0 and args.max_frames < 3:
        raise InputError(f"--max-frames must be 0 (every frame) or at least 3, got {args.max_frames}")
    out = Path(args.out) if args.out else None
    if out is not None:
        _check_out(out, args.force)
    seq = load_sequence(args.file, clean=False)

    fit = identify_model(seq, config, smoother, pairings=pairings,
                         max_iterations=args.max_iterations,
                         extrinsic=args.extrinsic == "identify",
                         time_offsets=args.time_offsets, max_frames=max_frames)
    how = "EM around the smoother" + ("" if args.extrinsic == "identify"
                                      else "; the extrinsic is the file's, not identified")
    model = fit.to_model(f"vislam calibrate {Path(args.file).name} ({how})")
    print(report(seq.name, seq.n_frames, fit, config))
    if fit.solution is not None:  # issue 12's data check, under the identified model
        from vislam.graph.data_check import velocity_check

        print("")
        print("\n".join(velocity_check(fit.solution, fit.config).lines()))
    if fit.drift_test:  # issue 34's drift check, under the model as the estimators use it
        print("")
        print("\n".join(fit.drift_test["lines"]))
        if fit.noise_widening > 1.0:
            print(f"  so the model widens every noise level (the table's sigmas) "
                  f"{fit.noise_widening:.2f}x: the least widening under which the stretches agree")
    if out is not None:
        write_text(out, model.to_toml())
        print(f"wrote {out}", file=sys.stderr)
    return 0


def _check_out(out: Path, force: bool) -> None:
    """``--out`` is a new file, or a model file vislam wrote (or ``--force``)."""
    from vislam.ekf.errors import InputError
    from vislam.ekf.model import MODEL_FILE_HEADER

    if out.is_dir():
        raise InputError(f"--out {out}: is a folder; give a file name such as model.toml")
    if out.exists() and not force:
        try:
            head = out.read_text(encoding="utf-8", errors="replace")[:len(MODEL_FILE_HEADER)]
        except OSError as exc:
            raise InputError(f"--out {out}: cannot read ({exc.strerror})") from None
        if head != MODEL_FILE_HEADER:
            raise InputError(f"--out {out}: exists and was not written by vislam; choose another "
                             "name, or --force to replace it")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"--out {out}: folder {parent} does not exist")


def _fmt(values, digits: int = 4) -> str:
    return " ".join(f"{float(v):.{digits}g}" for v in np.atleast_1d(values))


def _verdict(fit) -> list[str]:
    """The file's extrinsic against the identified one, in the data's sigmas."""
    from vislam.ekf.model import EXTRINSIC_COMPONENTS
    from vislam.graph.extrinsic import lever_arm, mahalanobis, theta_between

    if fit.cam_T_imu_cov is None:
        return []
    test = fit.extrinsic_test
    C, F = fit.cam_T_imu, fit.file_cam_T_imu
    theta = theta_between(C, F)  # file - identified
    determined = np.array([n not in fit.cam_T_imu_undetermined for n in EXTRINSIC_COMPONENTS])
    lines = []
    if test:
        chi2_part = (f"; chi-square {test['level']:.0%}: {test['chi2_threshold']:.1f}"
                     if "chi2_threshold" in test else "")
        lines.append(f"file extrinsic: Wald statistic {test['statistic']:.1f} on {test['dof']} dof "
                     f"against {test['threshold']:.1f} ({test.get('criterion', 'chi-square')}"
                     f"{chi2_part}): {test['decision']}")
        oos = test.get("out_of_sample")
        if oos:
            lines.append(f"  out of sample: the identified extrinsic, fitted without each of "
                         f"{oos['folds']} stretches, predicts it better than the file's by "
                         f"{oos['gain']:.1f} in log-likelihood over the drive (in sample "
                         f"{oos['in_sample']:.1f}; better on {oos['folds_better']} of "
                         f"{oos['folds']} stretches)")
    if np.allclose(C, F):
        return lines
    for what, part, unit, scale in (("lever arm", slice(0, 3), "m", 1.0),
                                    ("rotation", slice(3, 6), "deg", 180.0 / np.pi)):
        mask = np.zeros(6, dtype=bool)
        mask[part] = determined[part]
        if not mask.any():
            lines.append(f"file {what}: the drive cannot determine it; the file's is kept")
            continue
        d2, _ = mahalanobis(theta, fit.cam_T_imu_cov, mask)
        size = (float(np.linalg.norm(lever_arm(F) - lever_arm(C))) if what == "lever arm"
                else float(np.linalg.norm(theta[3:])) * scale)
        n_sigma = float(np.sqrt(d2))
        word = "DISAGREES with" if n_sigma > 3.0 else "agrees with"
        lines.append(f"file {what} {size:.3g} {unit} from the data's: {n_sigma:.1f} sigma "
                     f"({word} the data at 3 sigma)")
    return lines


def _motion_correlation_line(m: dict) -> str:
    """The velocity and gyro errors' long-run sigma (graph.motion_correlation), one line."""
    if not m:
        return "velocity and gyro errors in time: not measured"
    if not m.get("tested"):
        return f"velocity and gyro errors in time: not tested ({m.get('why', '')})"
    ratios = ", ".join(f"{a} {r:.3g}" for a, r in zip(m["axes"], m["variance_ratio"]))
    kept = (", ".join(m["kept"]) + ": the estimators use the long-run interval sigma "
            + ", ".join(f"{a} {s:.3g}" for a, s in zip(m["axes"], m["long_run_interval_sigma"])
                        if a in m["kept"])) if m["kept"] else "none kept (white)"
    return (f"velocity and gyro errors in time: long-run / white variance over {m['n_blocks']} "
            f"blocks of {m['block_frames']} frames {ratios} against {m['threshold']:.3g} "
            f"({m['criterion']}): {kept}")


def _rotation_reason(fit) -> str:
    """Why translation components are undetermined where the drive's rotation is the reason
    (graph.extrinsic.rotation_excitation_sigma): "" otherwise."""
    from vislam.ekf.model import EXTRINSIC_COMPONENTS
    from vislam.graph.extrinsic import UNDETERMINED_SIGMA

    sigma = fit.extrinsic_test.get("translation_sigma_from_rotation")
    if sigma is None:
        return ""
    by_rotation = [f"{n} within {s:.2g} m"
                   for n, s, limit in zip(EXTRINSIC_COMPONENTS, sigma, UNDETERMINED_SIGMA)
                   if n in fit.cam_T_imu_undetermined and s > limit]
    if not by_rotation:
        return ""
    return (f"; the drive's rotation alone places {', '.join(by_rotation)} at best (it turns "
            f"about no other axis beyond the gyro's noise, and a lever arm shows only through "
            f"rotation)")


def undetermined_lines(fit) -> list[str]:
    """The noise levels the drive cannot determine, each with the value the model takes and
    why (graph.parameter_uncertainty); a line saying so when every level is determined."""
    levels = [lv.to_dict() for lv in fit.noise_levels]
    levels += list(fit.motion_correlation_test.get("levels", []))
    open_levels = [lv for lv in levels if not lv["determined"]]
    if not levels:
        return []
    if not open_levels:
        return ["noise levels: the drive determines every one (each is its estimate)"]
    out = [f"noise levels the drive cannot determine ({len(open_levels)} of {len(levels)}; "
           "the model takes a conservative value, never the estimate alone):"]
    for lv in open_levels:
        out.append(f"  {lv['name']}: estimate {lv['estimate']:.3g}, the model takes "
                   f"{lv['value']:.3g} ({lv['why']})")
    return out


def report(name: str, frames: int, fit, config) -> str:
    """The identified model beside the settings it replaces, and a verdict per quantity."""
    from vislam.ekf.driver import MAX_CARRIED
    from vislam.ekf.model import EXTRINSIC_COMPONENTS, long_run_pixel_sigma
    from vislam.graph.extrinsic import lever_arm, lever_arm_covariance

    given_v, given_g = config.velocity_sigmas, config.gyro_sigmas
    lines = [
        f"calibrate {name} ({frames} frames): EM around the smoother, {fit.iterations} steps "
        f"({'converged' if fit.converged else 'NOT converged'}), {fit.seconds:.1f} s",
        *([f"identified on frames {fit.frames[0]}-{fit.frames[1] - 1} of {fit.n_frames}: the drive's "
           f"central {fit.frames[1] - fit.frames[0]} (--max-frames 0 reads every frame)"]
          if fit.frames != (0, fit.n_frames) else []),
        *([f"returning tracks: {fit.returning_tracks_split} returns identified as new landmarks "
           f"(more than {MAX_CARRIED} in gaps at once; the estimators keep them as one)"]
          if fit.returning_tracks_split else []),
        "",
        "| quantity | identified | sigma | file / settings as given |",
        "|---|---|---|---|",
        f"| velocity sigma x y z (m/s) | {_fmt(fit.velocity_sigma)} | "
        f"{_fmt(fit.velocity_sigma_std, 2)} "
        f"| {_fmt(given_v)} |",
        f"| gyro sigma x y z (rad/s) | {_fmt(fit.gyro_sigma)} | "
        f"{_fmt(fit.gyro_sigma_std, 2)} "
        f"| {_fmt(given_g)} |",
        f"| pixel sigma (px) | {fit.pixel_sigma:.4g} | {fit.pixel_sigma_std:.2g} | {config.pixel_sigma:.4g} |",
        f"| pixel error correlation time along a track (frames) | "
        f"{'none' if fit.pixel_correlation_time is None else f'{fit.pixel_correlation_time:.3g}'} "
        f"| | none |",
        f"| gyro bias x y z (rad/s) | "
        f"{'none' if fit.gyro_bias is None else _fmt(fit.gyro_bias)} | "
        f"{'' if fit.gyro_bias_std is None else _fmt(fit.gyro_bias_std, 2)} | "
        f"{'estimated' if config.gyro_bias else 'off'} |",
        f"| velocity pairing | {fit.pairing} | | {config.velocity_pairing} |",
        f"| radial lens term k1 (x_d = x (1 + k1 r^2)) | "
        f"{'none' if fit.radial_k1 is None else f'{fit.radial_k1:.4g}'} | "
        f"{'' if fit.radial_k1 is None else f'{fit.radial_k1_std:.2g}'} | none |",
    ]
    C, F = fit.cam_T_imu, fit.file_cam_T_imu
    if fit.cam_T_imu_cov is None:
        lines.append("| cam_T_imu | not identified (the file's) | | |")
    else:
        sig = fit.cam_T_imu_sigma
        sig_t = " ".join("undetermined" if not np.isfinite(x) else f"{x:.2g}" for x in sig[:3])
        sig_r = " ".join("undetermined" if not np.isfinite(x) else f"{x:.2g}" for x in sig[3:])
        p_cov = lever_arm_covariance(C, fit.cam_T_imu_cov)
        lines += [
            f"| cam_T_imu translation (m) | {_fmt(C[:3, 3])} | {sig_t} | {_fmt(F[:3, 3])} |",
            f"| cam_T_imu rotation (rotvec, rad; rows below) | | {sig_r} | |",
            f"| lever arm: camera from the point the velocities are of, IMU axes x y z (m) | {_fmt(lever_arm(C))} | "
            f"{_fmt(np.sqrt(np.diag(p_cov)), 2)} | {_fmt(lever_arm(F))} |",
        ]
        for i in range(3):
            lines.append(f"| cam_T_imu row {i + 1} | {_fmt(C[i])} | | {_fmt(F[i])} |")
    lines.append("")
    t = fit.bias_test
    lines.append(f"gyro bias: likelihood ratio {t['statistic']:.1f} against {t['threshold']:.2f} "
                 f"(BIC, 3 ln n; chi-square 3 dof {t['level']:.0%}: {t['chi2_threshold']:.2f}): "
                 f"{t['decision']}")
    held = t.get("out_of_sample")
    if held:
        lines.append(f"  out of sample: the bias, fitted without each of {held['folds']} "
                     f"stretches, predicts it better than none by {held['gain']:.1f} in "
                     f"log-likelihood over the drive (in sample {held['in_sample']:.1f}; better on "
                     f"{held['folds_better']} of {held['folds']} stretches)")
    o = fit.time_offset_test
    if not o:
        lines.append("time offsets of the streams against the camera: not estimated "
                     "(--time-offsets estimates them)")
    else:
        for stream, key in (("velocity", "linear-velocity"), ("gyro", "angular-velocity")):
            e = o[stream]
            lines.append(f"{key} stamps late against the camera's: {e['estimate'] * 1e3:.1f} ms, "
                         f"sigma {e['sigma'] * 1e3:.1f} ms, statistic {e['statistic']:.1f} "
                         f"against {o['threshold']:.2f} ({o['criterion']}): {e['decision']}")
    r = fit.radial_test
    if r:
        size = "" if r.get("std") is None else (
            f"; the file's pinhole pixels (no term) are {abs(r['estimate']) / r['std']:.1f} sigma "
            f"from the estimate {r['estimate']:.4g}")
        lines.append(f"radial lens term: Wald statistic {r['statistic']:.1f} against "
                     f"{r['threshold']:.2f} ({r['criterion']}): {r['decision']}{size}")
    c = fit.pixel_correlation_test
    if c and c.get("lag1") is None:
        lines.append("pixel errors along a track: too few tracks seen in consecutive frames to "
                     "measure their correlation (taken as none)")
    elif c:
        used = "" if fit.pixel_correlation_time is None else (
            f"; the estimators use the long-run pixel sigma {fit.pixel_sigma:.3g} x "
            f"sqrt({fit.pixel_correlation_time:.3g}) = "
            f"{long_run_pixel_sigma(fit.pixel_sigma, fit.pixel_correlation_time):.3g} px")
        corrected = "" if c.get("corrected") is None or fit.pixel_correlation_time is None else (
            f"; corrected for the landmark fit (which keeps part of a slow error out of the "
            f"residuals): {c['corrected']:.3g} frames, pixel sigma {c['white_sigma']:.3g} / "
            f"sqrt({c['variance_ratio']:.3g}) = {fit.pixel_sigma:.3g} px")
        lines.append(f"pixel errors along a track: lag-1 correlation {c['lag1']:.3f} over "
                     f"{c['pairs_lag1']} pairs, statistic {c['statistic']:.1f} against "
                     f"{c['threshold']:.2f} ({c['criterion']}): {c['decision']}, the residuals' "
                     f"correlation time {c['estimate']:.3g} frames ({c['lags_summed']} lags)"
                     f"{corrected}{used}")
    lines.append(_motion_correlation_line(fit.motion_correlation_test))
    scores = ", ".join(f"{p} {s:.2f}" for p, s in sorted(fit.pairing_scores.items(), key=lambda x: x[1]))
    lines.append(f"velocity pairing: sum of log per-sample variance {scores} (lowest wins)")
    if fit.cam_T_imu_undetermined:
        names = ", ".join(fit.cam_T_imu_undetermined)
        lines.append(f"extrinsic: the drive cannot determine {names} "
                     f"(of {', '.join(EXTRINSIC_COMPONENTS)}); the file's value is kept there"
                     f"{_rotation_reason(fit)}")
    lines += _verdict(fit)
    lines += undetermined_lines(fit)
    for what, found, given in (("velocity sigma", fit.velocity_sigma, given_v),
                               ("gyro sigma", fit.gyro_sigma, given_g),
                               ("pixel sigma", [fit.pixel_sigma], [config.pixel_sigma])):
        ratio = float(np.max(np.maximum(np.asarray(given) / found, np.asarray(found) / given)))
        if ratio > 1.5:
            lines.append(f"settings' {what} is {ratio:.1f}x off the data's: estimators given it "
                         "misweigh velocities against vision")
    return "\n".join(lines)
