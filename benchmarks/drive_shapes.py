"""Drive shapes (issue 36): time and memory of ``vislam bench`` (identification included), of the
identification alone and of each estimator, on simulated drives of every shape and length.

    python benchmarks/drive_shapes.py                      # room:2000 loop:1200 road:600 road:4541
    python benchmarks/drive_shapes.py room:2000 loop:4541  # chosen cases (SCENARIO:FRAMES)
    python benchmarks/drive_shapes.py --no-bench room:300  # estimators and calibrate only

Per case it prints one row per measured thing: wall seconds, CPU seconds (the machine may be
shared: CPU time is the figure to compare) and peak resident memory (MB): of the largest process,
and of the whole process tree (sampled every 0.2 s). Then, from the bench's results.json: the
smoother's pose NEES against its band, and the identified noise levels against the true ones
(the Done-when figures: a room drive of 2,000 frames, every landmark seen again more than 20
times, bench in at most 90 s and 2 GB; a loop and a 4,541-frame drive in at most 3 minutes and
3 GB).

``vislam bench`` runs on a file written by ``vislam simulate`` (the loop and the room) or on the
default drive in memory (the road: ``vislam bench --frames N``, as a 4,541-frame road drive is
too large for the dense file format), with an empty identification cache. Each estimator and the
identification run in a child process of their own on the drive made in memory under its true
model (peak memory includes the drive itself: the row "drive" is that baseline).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

try:  # the process tree's memory (ipython's and distributed's dependency: there with '.[test]')
    import psutil
except ImportError:  # pragma: no cover
    psutil = None

ESTIMATORS = ("dead-reckoning", "mapping", "ekf-decoupled", "ekf-joint", "ekf-invariant",
              "smoother", "smoother-isam2")
DEFAULT_CASES = ("room:2000", "loop:1200", "road:600", "road:4541")


def _tree_peak(proc: psutil.Process, stop: threading.Event, out: list) -> None:
    peak = 0
    while not stop.is_set():
        try:
            procs = [proc] + proc.children(recursive=True)
            total = 0
            for p in procs:
                try:
                    total += p.memory_info().rss
                except psutil.Error:
                    pass
            peak = max(peak, total)
        except psutil.Error:
            pass
        stop.wait(0.2)
    out.append(peak)


def measured(cmd: list[str], env: dict | None = None) -> dict:
    """Run ``cmd``; its wall and CPU seconds (its process tree's), peak RSS of its largest process
    and of its tree (MB), and its stdout."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    stop, peak = threading.Event(), []
    watcher = threading.Thread(target=_tree_peak, args=(psutil.Process(proc.pid), stop, peak)) \
        if psutil is not None else threading.Thread(target=stop.wait)
    watcher.start()
    out, err = proc.communicate()
    wall = time.perf_counter() - start
    stop.set()
    watcher.join()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"failed ({proc.returncode}): {' '.join(cmd)}\n{err[-3000:]}")
    return {
        "wall_s": wall,
        "cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
        "peak_mb": after.ru_maxrss / 1024.0,  # the largest process so far (Linux: KiB)
        "tree_mb": peak[0] / 1024.0**2 if peak else float("nan"),
        "stdout": out,
    }


# --------------------------------------------------------------------------- child processes


def _drive(scenario: str, frames: int, seed: int):
    from vislam.ekf.config import FilterConfig
    from vislam.ekf.model import apply_model
    from vislam.eval.sim_config import scenario_config
    from vislam.eval.simulate import simulate

    result = simulate(scenario_config(scenario, n_frames=frames, seed=seed, name=f"{scenario}-{frames}"))
    seq, config = apply_model(result.sequence, FilterConfig(), result.model)
    return result, seq, config


def child(what: str, scenario: str, frames: int, seed: int) -> None:
    """One measurement in this process; prints its JSON line."""
    t0, c0 = time.perf_counter(), time.process_time()
    result, seq, config = _drive(scenario, frames, seed)
    rss_drive = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    t1, c1 = time.perf_counter(), time.process_time()
    info: dict = {}
    if what == "calibrate":  # as vislam bench identifies a drive (eval.model_cache)
        from vislam.eval.model_cache import identified_model

        with tempfile.TemporaryDirectory() as cache:
            model = identified_model(result.sequence, folder=Path(cache)).model
        info = {"velocity_sigma": list(model.velocity_sigma), "gyro_sigma": list(model.gyro_sigma),
                "pixel_sigma": model.pixel_sigma}
    elif what != "drive":
        import numpy as np

        from vislam.eval import builtin
        from vislam.eval.consistency import pose_nees
        from vislam.eval.metrics import ate_rmse
        from vislam.eval.registry import EstimatorSettings

        est = getattr(builtin, what.replace("-", "_"))(seq, EstimatorSettings(filter=config))
        nees = pose_nees(est, np.arange(seq.n_frames), result.poses)
        info = {"nees_pose_mean": float(np.nanmean(nees)),
                "ate_aligned_m": ate_rmse(est.poses, result.poses, align="se3"),
                "carry_splits": est.info.get("n_carry_splits", 0)}
    t2, c2 = time.perf_counter(), time.process_time()
    print(json.dumps({
        "wall_s": t2 - t1 if what != "drive" else t1 - t0,
        "cpu_s": c2 - c1 if what != "drive" else c1 - c0,
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "drive_mb": rss_drive, **info,
    }))


# --------------------------------------------------------------------------- the cases


def bench_case(scenario: str, frames: int, seed: int, tmp: Path) -> tuple[dict, dict]:
    env = dict(os.environ, VISLAM_CACHE_DIR=str(tmp / "cache"))
    out = tmp / "bench"
    cmd = [sys.executable, "-m", "vislam.eval.cli", "bench", "-q", "--out", str(out)]
    if scenario == "road":
        cmd += ["--frames", str(frames), "--seed", str(seed)]
    else:
        subprocess.run([sys.executable, "-m", "vislam.eval.cli", "simulate", "--scenario", scenario,
                        "--frames", str(frames), "--seed", str(seed), "--out", str(tmp / "drive")],
                       check=True, capture_output=True)
        cmd += [str(tmp / "drive" / f"{scenario}-seed{seed}.npz")]
    m = measured(cmd, env)
    results = json.loads((out / "results.json").read_text())
    return m, results["sequences"][0]


def true_sigmas(scenario: str, frames: int, seed: int) -> dict:
    from vislam.ekf.config import per_axis
    from vislam.eval.sim_config import scenario_config

    c = scenario_config(scenario, n_frames=frames, seed=seed)
    return {"velocity_sigma": list(per_axis(c.velocity_sigma)),
            "gyro_sigma": list(per_axis(c.gyro_sigma)), "pixel_sigma": c.pixel_sigma}


def row(case: str, what: str, m: dict, extra: str = "") -> str:
    return (f"| {case} | {what} | {m['wall_s']:.1f} | {m['cpu_s']:.1f} | {m['peak_mb']:.0f} | "
            f"{m.get('tree_mb', float('nan')):.0f} | {extra} |")


def sigma_errors(found: dict, truth: dict) -> str:
    parts = []
    for key in ("velocity_sigma", "gyro_sigma"):
        rel = [f"{100 * (f / t - 1):+.0f}%" for f, t in zip(found[key], truth[key])]
        parts.append(f"{key.split('_')[0]} {' '.join(rel)}")
    parts.append(f"pixel {100 * (found['pixel_sigma'] / truth['pixel_sigma'] - 1):+.0f}%")
    return "; ".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("cases", nargs="*", default=list(DEFAULT_CASES), help="SCENARIO:FRAMES")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-bench", action="store_true", help="estimators and calibrate only")
    parser.add_argument("--no-estimators", action="store_true", help="vislam bench only")
    parser.add_argument("--no-calibrate", action="store_true", help="no identification alone")
    parser.add_argument("--estimators", default=",".join(ESTIMATORS))
    parser.add_argument("--child", nargs=3, metavar=("WHAT", "SCENARIO", "FRAMES"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args.child[0], args.child[1], int(args.child[2]), args.seed)
        return 0
    print("| drive | what | wall s | CPU s | peak MB (largest process) | peak MB (tree) | figures |")
    print("|---|---|---|---|---|---|---|")
    for case in args.cases:
        scenario, frames = case.split(":")
        frames = int(frames)
        truth = true_sigmas(scenario, frames, args.seed)
        if not args.no_bench:
            with tempfile.TemporaryDirectory() as tmp:
                m, seq = bench_case(scenario, frames, args.seed, Path(tmp))
            found = seq["model"]["model"]
            smoother = next((e for e in seq["estimators"] if e["name"] == "smoother"), None)
            nees = smoother and smoother.get("nees_pose_mean")
            times = ", ".join(f"{e['name']} {e['runtime_s']:.1f}" for e in seq["estimators"])
            print(row(case, "vislam bench", m, f"smoother pose NEES {nees:.2f}; identified vs true: "
                      f"{sigma_errors(found, truth)}; in-bench seconds: {times}"
                      if nees is not None else sigma_errors(found, truth)), flush=True)
        if args.no_estimators:
            continue
        for what in ["drive", *([] if args.no_calibrate else ["calibrate"]), *args.estimators.split(",")]:
            cmd = [sys.executable, __file__, "--seed", str(args.seed), "--child", what, scenario, str(frames)]
            m = measured(cmd)
            got = json.loads(m["stdout"].strip().splitlines()[-1])
            extra = ""
            if what == "calibrate":
                extra = "identified vs true: " + sigma_errors(got, truth)
            elif what != "drive":
                extra = f"aligned ATE {got['ate_aligned_m']:.4f} m; pose NEES {got['nees_pose_mean']:.2f}"
                if got["carry_splits"]:
                    extra += f"; {got['carry_splits']} tracks split at the carry cap"
            print(row(case, what, {**got, "tree_mb": m["tree_mb"]}, extra), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
