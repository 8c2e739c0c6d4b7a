"""ekf-joint under two readings of pixel errors that drift along a track, on simulated road
drives whose errors are AR(1) (issue 34; docs/findings.md, "Pixel errors as AR(1) in ekf-joint").

    .venv/bin/python benchmarks/ar1_pixel_ekf.py --a 0.9 --frames 300 --seeds 10
    .venv/bin/python benchmarks/ar1_pixel_ekf.py --drive FILE.npz --config MODEL.toml

Each drive runs under its true model: ``long-run`` (every estimator's reading, independent rows
with the long-run sigma ``s sqrt(tau)``) and ``ar1`` (``pixel_reading = "ar1"``: the exact
differenced rows with a clone of the previous pose, ekf/joint.py). Prints each seed's aligned
ATE (m) and mean pose NEES, and their means. With ``--a 0`` both readings are the white filter,
the floor of its own consistency on these drives.

With ``--smoother`` each drive also runs the batch smoother under both readings
(``benchmarks/ar1_pixel_smoother.py``'s exact AR(1) factors, a Python factor per row: slow), to
tell the reading from the filter; ``--pixel-sigma`` sets the drives' pixel noise (px).

With ``--drive`` (a real drive and its model from ``vislam calibrate FILE --out MODEL.toml``)
it prints two candidate rules for choosing the reading: the readings' out-of-sample pixel
likelihood (each update's log predictive density of its accepted rows, ``JointState.last_loglik``,
summed over the frames where both readings accepted the same landmarks, and per half of the
drive), and the smoother's whitened residuals' correlation along tracks (lags 1-3) against that
between different tracks of one frame, and along tracks with each frame's mean removed.
"""

from __future__ import annotations

import argparse

import numpy as np


def prequential(seq, config, reading):
    """{frame: (log predictive density, accepted track ids)} of ekf-joint's updates."""
    from vislam.ekf import joint

    record = {}
    update = joint.JointState.update

    def recording(self, model, tracks, z):
        out = update(self, model, tracks, z)
        if self.last_loglik is not None:
            record[self.frame] = (self.last_loglik,
                                  frozenset(self.lm_track[self.last_accepted].tolist()))
        return out

    joint.JointState.update = recording
    try:
        joint.run_joint(seq, config.replace(pixel_reading=reading))
    finally:
        joint.JointState.update = update
    return record


def residual_correlations(seq, config):
    """Along-track lag 1-3, same-frame cross-track, and along-track without frame means."""
    from vislam.graph.factors import stereo_residuals
    from vislam.graph.smoother import solve_smoother
    from vislam.graph.track_correlation import _WHITEN, along_track_correlation

    sol = solve_smoother(seq, config)
    rows = sol.problem.rows
    r = stereo_residuals(sol.poses, sol.landmarks, sol.calibration, rows)[0] * _WHITEN
    f, nf = rows.frame, rows.frame.max() + 1
    rho = along_track_correlation(r, f, rows.track)[0]
    n = np.bincount(f, minlength=nf)
    S = np.stack([np.bincount(f, weights=r[:, c], minlength=nf) for c in range(3)], axis=1)
    Q = np.stack([np.bincount(f, weights=r[:, c] ** 2, minlength=nf) for c in range(3)], axis=1)
    cross = (S**2 - Q).sum() / (3 * (n * (n - 1)).sum()) / float(np.mean(r * r))
    keep = n[f] >= 5
    rho_within = along_track_correlation((r - S[f] / n[f][:, None])[keep], f[keep],
                                         rows.track[keep])[0]
    return rho[:3], cross, rho_within[:3], r.shape[0] / nf


def real_drive(path: str, config_path: str) -> int:
    from vislam.ekf.model import model_sequence
    from vislam.eval.commands.options import filter_config_from_args, model_from_args
    from vislam.eval.loader import load_sequence

    ns = argparse.Namespace(config=config_path)
    config, model = filter_config_from_args(ns), model_from_args(ns)
    seq = model_sequence(load_sequence(path), model)
    a, b = prequential(seq, config, "long-run"), prequential(seq, config, "ar1")
    common = [f for f in a if f in b and a[f][1] == b[f][1]]
    d = np.array([b[f][0] - a[f][0] for f in common])
    rows = sum(len(a[f][1]) for f in common)
    h = d.size // 2
    print(f"{path}: ar1 - long-run log predictive density over {len(common)} of {len(a)} frames: "
          f"{d.sum():.1f} ({d.sum() / rows:.3f} a row; halves {d[:h].sum():.1f} / {d[h:].sum():.1f})")
    rho, cross, rho_within, per_frame = residual_correlations(seq, config)
    print(f"smoother residuals ({per_frame:.1f} rows a frame): along-track lag 1-3 "
          f"{np.round(rho, 3).tolist()}, same frame across tracks {cross:.3f}, along-track "
          f"without frame means {np.round(rho_within, 3).tolist()}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--a", type=float, default=0.9, help="AR(1) coefficient of the errors")
    parser.add_argument("--frames", type=int, default=300, help="frames per drive")
    parser.add_argument("--seeds", type=int, default=10, help="drives (seeds 0..N-1)")
    parser.add_argument("--pixel-sigma", type=float, default=None, help="pixel noise (px)")
    parser.add_argument("--smoother", action="store_true",
                        help="also the batch smoother under both readings (slow)")
    parser.add_argument("--drive", metavar="FILE.npz", help="a real drive instead (the rules)")
    parser.add_argument("--config", metavar="MODEL.toml", help="its model (with --drive)")
    args = parser.parse_args(argv)
    if args.drive:
        if not args.config:
            parser.error("--drive needs --config MODEL.toml (vislam calibrate FILE --out)")
        return real_drive(args.drive, args.config)

    from vislam.ekf.config import FilterConfig
    from vislam.ekf.joint import run_joint
    from vislam.ekf.model import apply_model
    from vislam.eval.consistency import pose_nees
    from vislam.eval.metrics import ate_rmse
    from vislam.eval.sim_config import SimConfig
    from vislam.eval.simulate import DEFAULT_SIM, simulate, true_model

    readings = ("long-run", "ar1") + (("smoother long-run", "smoother ar1") if args.smoother else ())
    ate = {r: [] for r in readings}
    nees = {r: [] for r in readings}
    extra = {} if args.pixel_sigma is None else {"pixel_sigma": args.pixel_sigma}
    for seed in range(args.seeds):
        sim = simulate(SimConfig(**{**DEFAULT_SIM.__dict__, "seed": seed, "n_frames": args.frames,
                                    "pixel_correlation": args.a, **extra}))
        model = true_model(sim)
        seq, config = apply_model(sim.sequence, FilterConfig(), model)
        frames = np.arange(len(sim.poses))
        for r in readings:
            if r.startswith("smoother"):
                from ar1_pixel_smoother import solve

                est = solve(seq, config, model, r.split()[1], marginals=True)[0]
            else:
                est = run_joint(seq, config.replace(pixel_reading=r))
            ate[r].append(ate_rmse(est.poses, sim.poses, align="se3"))
            nees[r].append(float(np.nanmean(pose_nees(est, frames, sim.poses))))
    print(f"a {args.a}, {args.frames} frames, seeds 0-{args.seeds - 1}: ekf-joint (and smoother) "
          "aligned ATE (m) / mean pose NEES")
    for r in readings:
        print(f"{r:17s} ATE " + " ".join(f"{x:.4f}" for x in ate[r]) + f"  mean {np.mean(ate[r]):.4f}")
        print(f"{'':17s} NEES " + " ".join(f"{x:.2f}" for x in nees[r]) + f"  mean {np.mean(nees[r]):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
