"""Pose and landmark ANEES against the simulated landmark range (issue 13, item 2).

    .venv/bin/python benchmarks/nees_depth_sweep.py [--runs 20] [--frames 200]
        [--depths 10,25,40,60,100] [--estimators ekf-joint,ekf-invariant,smoother]
        [--jobs N] [--seed 0] [--out DIR]

For each maximum landmark depth (`vislam nees --sim-max-depth`: the landmark density is scaled
so every range keeps the default drive's observations per frame), each estimator runs on the
same --runs noise draws of one simulated drive; ekf-joint and ekf-invariant once per landmark
parameterisation (ekf.config.LANDMARK_PARAMETERISATIONS), the others (the smoother, initialised
from the EKF as in `vislam nees`) once, under the default parameterisation. Writes
nees_depth_sweep.json (every figure) and nees_depth_sweep.png into --out, prints a table.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

from vislam.ekf.config import LANDMARK_PARAMETERISATIONS, FilterConfig
from vislam.ekf.errors import InputError
from vislam.eval import plots
from vislam.eval.atomic import write_json
from vislam.eval.montecarlo import DEFAULT_NEES_FRAMES, monte_carlo_nees, nees_sim_config
from vislam.eval.commands.nees import sim_depth_error
from vislam.eval.consistency import LANDMARK_DOF, POSE_DOF, chi2_bounds
from vislam.eval.output_dir import OutputDir
from vislam.eval.registry import estimators_from_flag
from vislam.eval.simulate import simulate

DEPTHS = (10.0, 25.0, 40.0, 60.0, 100.0)
ESTIMATORS = ("ekf-joint", "ekf-invariant", "smoother")
#: Estimators whose landmarks follow FilterConfig.landmark_parameterisation.
PARAMETERISED = ("ekf-joint", "ekf-invariant")
FILES = ("nees_depth_sweep.json", "nees_depth_sweep.png")
KEYS = ("anees_pose", "anees_landmark", "verdict_pose", "verdict_landmark", "inside_fraction_pose",
        "inside_fraction_landmark", "landmarks_scored", "runs_failed", "errors", "runtime_s_mean")


def depths_arg(text: str) -> list[float]:
    try:
        depths = [float(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of numbers: {text!r}") from None
    why = next((w for w in map(sim_depth_error, depths) if w), None)
    if why:
        raise argparse.ArgumentTypeError(f"each depth {why}")
    return sorted(set(depths))


def sweep(args, estimators: list[str]) -> dict:
    """Every figure of the sweep (the JSON's content)."""
    default = FilterConfig().landmark_parameterisation
    rows = []
    for depth in args.depths:
        sim = nees_sim_config(args.seed, args.frames, depth)
        drive = simulate(dataclasses.replace(sim, noise_free=True)).sequence
        context = {"max_depth": depth, "landmark_density": sim.landmark_density,
                   "observations_per_frame": drive.obs.frame_index.size / drive.n_frames,
                   "tracks": drive.n_tracks}
        for param in LANDMARK_PARAMETERISATIONS:
            names = [n for n in estimators if n in PARAMETERISED or param == default]
            if not names:
                continue
            t0 = time.perf_counter()
            result = monte_carlo_nees(
                args.runs, args.seed, names, FilterConfig(landmark_parameterisation=param),
                frames=args.frames, jobs=min(args.jobs, args.runs * len(names)),
                show_progress=False, sim_max_depth=depth,
            )
            for name, r in result["estimators"].items():
                rows.append({**context, "estimator": name,
                             "parameterisation": param if name in PARAMETERISED else None,
                             **{k: r[k] for k in KEYS}})
            print(f"{depth:g} m, {param}: {', '.join(names)} in {time.perf_counter() - t0:.0f} s",
                  file=sys.stderr)
    return {
        "runs": args.runs,
        "frames": result["frames"],
        "seed": args.seed,
        "depths": args.depths,
        "parameterisations": list(LANDMARK_PARAMETERISATIONS),
        "others_under_parameterisation": default,
        "bounds_pose": list(chi2_bounds(args.runs, POSE_DOF)),
        "bounds_landmark": list(chi2_bounds(args.runs, LANDMARK_DOF)),
        "definition": result["definition"],
        "noise": result["noise"],
        "rows": rows,
    }


def table(data: dict) -> str:
    def f(x, verdict=None):
        return "–" if x is None else f"{x:.2f}" + ("" if verdict in (None, "inside") else f" {verdict}")

    bp, bl = data["bounds_pose"], data["bounds_landmark"]
    lines = [
        f"ANEES over {data['runs']} runs ({data['frames']} frames, seed {data['seed']}); 95 % "
        f"bounds pose [{bp[0]:.2f}, {bp[1]:.2f}], landmark [{bl[0]:.2f}, {bl[1]:.2f}]",
        "| max depth (m) | obs/frame | estimator | landmarks | ANEES pose | ANEES landmark | failed |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in data["rows"]:
        lines.append(
            f"| {r['max_depth']:g} | {r['observations_per_frame']:.0f} | {r['estimator']} "
            f"| {r['parameterisation'] or '–'} | {f(r['anees_pose'], r['verdict_pose'])} "
            f"| {f(r['anees_landmark'], r['verdict_landmark'])} | {r['runs_failed']} |"
        )
    return "\n".join(lines)


def figure(path: Path, data: dict) -> None:
    pose, landmark = {}, {}
    for r in data["rows"]:
        key = (r["estimator"], r["parameterisation"])
        pose.setdefault(key, []).append(r["anees_pose"])
        landmark.setdefault(key, []).append(r["anees_landmark"])
    plots.plot_nees_depth_sweep(
        path, data["depths"], pose, landmark, data["runs"],
        title=f"ANEES against landmark range: {data['runs']} Monte Carlo runs of "
              f"{data['frames']} frames (seed {data['seed']})",
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20, help="Monte Carlo runs per point (default 20)")
    ap.add_argument("--frames", type=int, default=DEFAULT_NEES_FRAMES,
                    help=f"frames of the drive (default {DEFAULT_NEES_FRAMES})")
    ap.add_argument("--depths", type=depths_arg, default=list(DEPTHS), metavar="LIST",
                    help=f"maximum landmark depths, m (default {','.join(f'{d:g}' for d in DEPTHS)})")
    ap.add_argument("--estimators", default=",".join(ESTIMATORS), metavar="LIST",
                    help=f"comma-separated (default {','.join(ESTIMATORS)})")
    ap.add_argument("--jobs", "-j", type=int, default=os.cpu_count() or 1, help="worker processes")
    ap.add_argument("--seed", type=int, default=0, help="seed of the drive and the noise")
    ap.add_argument("--out", type=Path, default=None,
                    help="output folder (default results/nees-depth-sweep-<YYYYmmdd-HHMMSS>)")
    args = ap.parse_args(argv)
    if args.runs < 1 or args.frames < 2 or args.jobs < 1:
        ap.error("--runs and --jobs must be >= 1, --frames >= 2")
    out = args.out or Path("results") / time.strftime("nees-depth-sweep-%Y%m%d-%H%M%S")
    try:
        estimators = estimators_from_flag(args.estimators, ESTIMATORS)
        with OutputDir(out, expected=FILES) as tmp:
            data = sweep(args, estimators)
            write_json(tmp / FILES[0], data)
            figure(tmp / FILES[1], data)
    except InputError as exc:
        print(f"nees_depth_sweep: {exc}", file=sys.stderr)
        return 2
    print(table(data))
    print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
