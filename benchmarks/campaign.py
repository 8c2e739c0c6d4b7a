"""A campaign that measures generalisation (issue 34, item 5): random simulated drives with the
faults real drives have, each run as `vislam bench` with no flags runs it.

    .venv/bin/python benchmarks/campaign.py [--drives 200] [--first-seed 0] [--jobs 2]
                                            [--frames 250] [--out DIR] [--cache DIR]
                                            [--model identified|true]

Drive ``seed`` is :func:`eval.campaign.draw_drive` ``(seed, frames)`` (its module docstring
lists the faults and their ranges); :func:`eval.campaign.evaluate_drive` runs dead reckoning,
ekf-joint, ekf-invariant and the smoother on it under the model identified from its own data
and asserts (1) every SLAM estimator's aligned ATE at most 1.1x dead reckoning's, (2) dead
reckoning's and the smoother's mean pose NEES inside the band bench reports.

Prints one row per drive (seed, faults, observations per frame, each estimator's aligned ATE
and mean pose NEES, the worst ATE ratio, pass/fail of each assertion), the pass rate of each
assertion, and the worst cases by ATE ratio and by NEES; writes ``campaign.json`` into
``--out`` (default: the current folder), rewritten after every drive (``complete`` false until
the last), so that a campaign stopped early keeps the drives it finished. The drives run in
``--jobs`` worker processes; the figures do not depend on how many. Identified models go to a
fresh temporary cache unless ``--cache`` names one, so that every figure is the code's as it
is now.

Measured on main 786e560 (200 drives, seeds 0-199, 250 frames, 2 jobs on a shared 2-core
machine: 61 min; 2.8-19.7 s of CPU a drive, mean 6.4): the ATE assertion holds on 176 (88.0 %),
the NEES assertion on 77 (38.5 %), both on 76 (38.0 %). No estimator failed outright. Every
NEES failure is overconfidence (none below the band). With under 3 observations a frame the
NEES assertion fails on 57 of 59 drives and the ATE assertion on 18 of 59 (18 of the 24 ATE
failures are there; the worst, smoother or EKF up to 2.9x dead reckoning's); there the
identified velocity sigma is a median 0.38x the true one on the clean edition (0.06-9x) and
0.60x on the noisy one. A speed-scale error on clean velocities fails the NEES assertion at
every density (29 of 31 drives). Velocity-error correlation is never identified on these 25 s
drives (0 of 79), and the noisy edition with it (no speed error) fails NEES on 11 of 17 drives
with 3 or more observations a frame. Even drives with no optional fault fail NEES on 2 of 11
(dead reckoning 17-19): one drive's mean pose NEES is correlated along the drive, so some such
failures are chance.

Measured on branch h-undet (issue 34 items 1 and 3: undetermined noise levels take conservative
values, docs/findings.md "Undetermined means conservative"), drives 0-29 (the base on the
same 30: ATE 26, NEES 16, both 15): the ATE assertion holds on 17 (56.7 %), the NEES
assertion on 24 (80 %), both on 16 (53.3 %); 838 s wall on the shared machine, 4.1-23.7 s of
CPU a drive (mean 9.3). Of the 6 NEES failures, 2 are sparse noisy drives above the band and 4
clean drives below it (the model too wide); 11 of the 13 ATE failures are clean velocities,
where the conservative slow-error prior lets vision carry the forward motion.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

WORST = 10


def _evaluate(seed: int, frames: int, model: str = "identified"):
    from vislam.eval.campaign import draw_drive, evaluate_drive

    return evaluate_drive(draw_drive(seed, frames), model=model)


def run_campaign(seeds: list[int], frames: int, jobs: int, on_done=None,
                 model: str = "identified") -> list:
    """The outcomes of ``seeds``, in the order of ``seeds``."""
    if jobs <= 1:
        out = []
        for s in seeds:
            out.append(_evaluate(s, frames, model))
            if on_done:
                on_done(out[-1])
        return out
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(_evaluate, s, frames, model) for s in seeds]
        out = []
        for f in futures:
            out.append(f.result())
            if on_done:
                on_done(out[-1])
        return out


def _num(x, digits=3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{digits}g}"


def row(o) -> str:
    from vislam.eval.campaign import ESTIMATORS

    cells = [f"{o.drive.seed:>5}", f"{o.obs_per_frame:6.1f}"]
    for name in ESTIMATORS:
        f = o.figures[name]
        cells.append("  failed    " if f.error else
                     f"{_num(f.ate_aligned_m):>6}/{_num(f.nees_pose_mean):<6}")
    cells += [f"{_num(o.ate_ratio):>5}", "ok  " if o.assertion("ate") else "FAIL",
              "ok  " if o.assertion("nees") else "FAIL", o.drive.describe()]
    return " ".join(cells)


def header() -> str:
    from vislam.eval.campaign import ESTIMATORS

    short = {"dead-reckoning": "dead-reck.", "ekf-joint": "ekf-joint", "ekf-invariant": "ekf-inv.",
             "smoother": "smoother"}
    return (" seed obs/fr " + " ".join(f"{short[n]:^13}" for n in ESTIMATORS)
            + " ratio ate  nees faults")


def to_json(o) -> dict:
    d = o.drive
    return {
        "seed": d.seed,
        "faults": list(d.faults),
        "edition": d.edition,
        "description": d.describe(),
        "target_obs_per_frame": d.target_obs_per_frame,
        "obs_per_frame": o.obs_per_frame,
        "sim": dataclasses.asdict(d.sim),
        "speed_scale": None if d.speed_scale is None else dataclasses.asdict(d.speed_scale),
        "figures": {k: dataclasses.asdict(v) for k, v in o.figures.items()},
        "ate_ratio": o.ate_ratio if math.isfinite(o.ate_ratio) else None,
        "worst_nees_factor": o.worst_nees if math.isfinite(o.worst_nees) else None,
        "assertions": {a.name: {"ok": a.ok, "detail": list(a.detail)} for a in o.assertions},
        "ok": o.ok,
        "model": o.model,
        "wall_s": o.wall_s,
        "cpu_s": o.cpu_s if math.isfinite(o.cpu_s) else None,
    }


def write_json(path: Path, doc: dict) -> None:
    """``doc`` as JSON at ``path``, replaced whole (never half-written)."""
    tmp_path = path.with_suffix(".json.tmp")
    tmp_path.write_text(json.dumps(doc, indent=1))
    tmp_path.replace(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--drives", type=int, default=200)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--frames", type=int, default=None,
                        help="frames of each drive (default eval.campaign.DEFAULT_FRAMES)")
    parser.add_argument("--out", default=".", help="folder of campaign.json (default: here)")
    parser.add_argument("--cache", default=None,
                        help="model cache folder (default: a fresh temporary one)")
    parser.add_argument("--model", choices=("identified", "true"), default="identified",
                        help="identified: as `vislam bench` runs a drive (default); true: under "
                             "each drive's true model (eval.campaign.drive_true_model), the "
                             "ceiling a perfect identification would reach")
    args = parser.parse_args(argv)
    from vislam.eval.campaign import DEFAULT_FRAMES, summarise
    from vislam.eval.consistency import POSE_NEES_BAND

    if args.drives < 1 or args.jobs < 1 or args.first_seed < 0:
        print("campaign: --drives and --jobs must be >= 1, --first-seed >= 0", file=sys.stderr)
        return 2
    frames = args.frames or DEFAULT_FRAMES
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = None
    if args.cache is None:
        tmp = tempfile.TemporaryDirectory(prefix="vislam-campaign-cache-")
        os.environ["VISLAM_CACHE_DIR"] = tmp.name
    else:
        os.environ["VISLAM_CACHE_DIR"] = str(Path(args.cache).resolve())
    seeds = list(range(args.first_seed, args.first_seed + args.drives))
    print(f"campaign: {len(seeds)} drives (seeds {seeds[0]}-{seeds[-1]}), {frames} frames each, "
          f"{args.jobs} jobs, {args.model} model; ATE = aligned ATE (m), NEES = mean pose NEES, band "
          f"[{POSE_NEES_BAND[0]:.2f}, {POSE_NEES_BAND[1]:.2f}]; ratio = worst SLAM ATE / dead "
          "reckoning's")
    print(header())
    path = out_dir / "campaign.json"
    doc = {"schema": 1, "model": args.model, "frames": frames, "first_seed": args.first_seed, "drives": 0,
           "nees_band": list(POSE_NEES_BAND), "complete": False, "outcomes": []}

    def done(o) -> None:  # one row, and campaign.json so far: a stopped campaign keeps its drives
        print(row(o), flush=True)
        doc["outcomes"].append(to_json(o))
        doc["drives"] = len(doc["outcomes"])
        write_json(path, doc)

    t0 = time.perf_counter()
    outcomes = run_campaign(seeds, frames, args.jobs, on_done=done, model=args.model)
    wall = time.perf_counter() - t0
    if tmp is not None:
        tmp.cleanup()
    summary = summarise(outcomes)
    print()
    for name, words in (("ate", "every SLAM estimator's aligned ATE <= 1.1x dead reckoning's"),
                        ("nees", "dead reckoning's and the smoother's pose NEES inside the band"),
                        ("both", "both")):
        print(f"pass rate, {words}: {summary.passed[name]}/{summary.drives} "
              f"({100 * summary.rate(name):.1f} %)")
    walls = [o.wall_s for o in outcomes]
    cpus = [o.cpu_s for o in outcomes]
    print(f"wall time {wall:.0f} s; per drive in its worker: wall {min(walls):.1f}-"
          f"{max(walls):.1f} s (mean {sum(walls) / len(walls):.1f}), CPU {min(cpus):.1f}-"
          f"{max(cpus):.1f} s (mean {sum(cpus) / len(cpus):.1f})")
    for title, key in (("by ATE ratio", lambda o: o.ate_ratio),
                       ("by NEES (factor outside the band)", lambda o: o.worst_nees)):
        print(f"\nworst {WORST} {title}:")
        print(header())
        for o in sorted(outcomes, key=key, reverse=True)[:WORST]:
            print(row(o))
    doc.update({"complete": True, "pass": summary.passed, "wall_s": wall})
    write_json(path, doc)
    print(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
