"""Are two builds of vislam's estimates the same? Runs ``vislam bench`` (every built-in
estimator, the identified model, an empty identification cache) on the given drives and the
default simulation, then compares every ``.estimate.npz`` array with a saved run.

    python benchmarks/estimate_identity.py --save DIR [FILE.npz ...]       # before a change
    python benchmarks/estimate_identity.py --against DIR [FILE.npz ...]    # after it

Prints one line per estimate: identical, or the largest absolute and relative difference of
each array that differs. Wall-clock times (``step_time_s``, the timing keys of ``info_json``)
are not compared; ``info_json`` is compared as data, not as text. Exit 1 when any estimate differs by more than ``--rtol`` (default 0:
bit-identical) or is missing.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ESTIMATORS = "all"
#: Arrays that hold wall-clock time: never compared.
TIMING_ARRAYS = ("step_time_s",)
#: Keys of ``info_json`` that hold wall-clock time (seconds), dropped before comparing; its
#: order of keys is not compared either (the JSON is compared as data).
TIMING_KEYS = ("timing", "total_s", "seconds")


def _without_timing(x):
    if isinstance(x, dict):
        return {k: _without_timing(v) for k, v in x.items()
                if k not in TIMING_KEYS and not (k.endswith("_s") and isinstance(v, float))}
    if isinstance(x, list):
        return [_without_timing(v) for v in x]
    return x


def run_bench(drives: list[str], out: Path, frames: int) -> None:
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, VISLAM_CACHE_DIR=cache)
        for i, drive in enumerate([None, *drives]):
            cmd = [sys.executable, "-m", "vislam.eval.cli", "bench", "-q", "-e", ESTIMATORS,
                   "--out", str(out / f"run{i}")]
            cmd += [drive] if drive else ["--frames", str(frames)]
            subprocess.run(cmd, check=True, env=env)


def estimates(root: Path) -> dict[str, Path]:
    return {str(p.relative_to(root)): p for p in sorted(root.rglob("*.estimate.npz"))}


def compare(a: Path, b: Path, rtol: float) -> bool:
    ea, eb = estimates(a), estimates(b)
    ok = True
    for name in sorted(set(ea) | set(eb)):
        if name not in ea or name not in eb:
            print(f"{name}: missing in {'before' if name not in ea else 'after'}")
            ok = False
            continue
        za, zb = np.load(ea[name], allow_pickle=False), np.load(eb[name], allow_pickle=False)
        diffs = []
        for key in sorted(set(za.files) | set(zb.files)):
            if key not in za.files or key not in zb.files:
                diffs.append(f"{key} only in one")
                continue
            if key in TIMING_ARRAYS:
                continue
            x, y = za[key], zb[key]
            if key == "info_json":
                if _without_timing(json.loads(str(x))) != _without_timing(json.loads(str(y))):
                    diffs.append(f"{key} differs beyond its timing keys")
                    ok = False
                continue
            if x.shape != y.shape:
                diffs.append(f"{key} shape {x.shape} vs {y.shape}")
                continue
            if x.dtype.kind in "fc":
                same = np.array_equal(x, y, equal_nan=True)
                if not same:
                    d = np.nanmax(np.abs(x - y)) if x.size else 0.0
                    scale = np.nanmax(np.abs(x)) if x.size else 1.0
                    rel = d / scale if scale else d
                    diffs.append(f"{key} max|d| {d:.3g} (rel {rel:.3g})")
                    if rel > rtol:
                        ok = False
            elif not np.array_equal(x, y):
                diffs.append(f"{key} differs")
                ok = False
        print(f"{name}: {'identical' if not diffs else '; '.join(diffs)}")
    return ok


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("drives", nargs="*", help=".npz drives besides the default simulation")
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--save", type=Path, help="run and keep the estimates here")
    g.add_argument("--against", type=Path, help="run and compare with a saved folder")
    ap.add_argument("--frames", type=int, default=600, help="default simulation's length")
    ap.add_argument("--rtol", type=float, default=0.0, help="largest relative difference allowed")
    args = ap.parse_args()
    if args.save:
        run_bench(args.drives, args.save, args.frames)
        print(f"saved {len(estimates(args.save))} estimates in {args.save}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        run_bench(args.drives, Path(tmp), args.frames)
        return 0 if compare(args.against, Path(tmp), args.rtol) else 1


if __name__ == "__main__":
    raise SystemExit(main())
