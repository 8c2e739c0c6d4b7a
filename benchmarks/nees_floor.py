"""Where the time of one `vislam nees` Monte Carlo run goes, and the least its compiled kernels take.

    .venv/bin/python benchmarks/nees_floor.py [--runs 50] [--cores 2] [--repeat 3] [--frames N]
        [--seed 0]

Runs the first drive of the default study (run000 of ``vislam nees --seed S``) through each
default estimator in this process, BLAS on one thread as in the study's workers, best of
``--repeat``. Per estimator it prints the wall time and the part spent in compiled kernels that
no change to the Python around them can remove:

- the EKFs: their dense stacked updates (Cholesky of S, the triangular solves, the N x N product
  ``Y^T Y`` of ``P - K S K^T``), replayed here at the sizes the run used (recorded from its
  ``dpotrf`` / ``dtrsm`` calls). They are near one core's rate already: the replay prints it;
- the smoother: GTSAM's Levenberg-Marquardt iterations (``info["timing"]["optimise_s"]``).

Then what ``--runs`` runs take on ``--cores`` cores (perfectly parallel, no start-up): at the
measured times, and at the kernels alone.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time

import numpy as np
from scipy.linalg.blas import dtrsm
from scipy.linalg.lapack import dpotrf

#: The EKF modules whose stacked update calls LAPACK's dpotrf and BLAS's dtrsm by these names.
EKF_MODULES = {"ekf-joint": "vislam.ekf.joint", "ekf-invariant": "vislam.ekf.invariant"}


@contextlib.contextmanager
def recorded_kernels(module_name: str):
    """Inside it, the sizes of every ``dpotrf`` (n,) and ``dtrsm`` (rows, columns) call of
    ``module_name`` are appended to the yielded dict's lists; the module is restored after."""
    import importlib

    module = importlib.import_module(module_name)
    sizes = {"potrf": [], "trsm": []}
    potrf, trsm = module.dpotrf, module.dtrsm

    def rec_potrf(a, *args, **kw):
        sizes["potrf"].append(a.shape[0])
        return potrf(a, *args, **kw)

    def rec_trsm(alpha, a, b, *args, **kw):
        sizes["trsm"].append(b.shape)
        return trsm(alpha, a, b, *args, **kw)

    module.dpotrf, module.dtrsm = rec_potrf, rec_trsm
    try:
        yield sizes
    finally:
        module.dpotrf, module.dtrsm = potrf, trsm


def replay_kernels(sizes: dict, seed: int = 0) -> tuple[float, float]:
    """Seconds that the recorded kernels take on random data of their sizes (each ``dtrsm`` of
    more than one column followed by the ``Y^T Y`` product of its result), and their rate in
    Gflop/s (Cholesky n^3/3, solve rows^2 cols, product cols^2 rows)."""
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(seed)
    top = max([*sizes["potrf"], *(r for r, _ in sizes["trsm"])], default=0)
    G = rng.standard_normal((top, top))
    spd = G @ G.T + top * np.eye(top)
    L_full = np.linalg.cholesky(spd)
    B_full = rng.standard_normal((top, max((c for _, c in sizes["trsm"]), default=1)))
    seconds, flops = 0.0, 0.0
    with threadpool_limits(limits=1, user_api="blas"):
        for n in sizes["potrf"]:
            a = np.asfortranarray(spd[:n, :n])
            t0 = time.perf_counter()
            dpotrf(a, lower=1, clean=0, overwrite_a=1)
            seconds += time.perf_counter() - t0
            flops += n**3 / 3
        for rows, cols in sizes["trsm"]:
            L, b = L_full[:rows, :rows], np.asfortranarray(B_full[:rows, :cols])
            t0 = time.perf_counter()
            y = dtrsm(1.0, L, b, lower=1, overwrite_b=1)
            if cols > 1:
                y.T @ y
            seconds += time.perf_counter() - t0
            flops += rows**2 * cols + (cols**2 * rows if cols > 1 else 0)
    return seconds, (flops / seconds / 1e9 if seconds > 0 else 0.0)


def time_estimator(name: str, seq, config, smoother, initial, repeat: int):
    """(best wall s, compiled-kernel s, a note, the estimate) of ``name`` on ``seq``."""
    from vislam.eval.study import run_estimator

    best, est, sizes = np.inf, None, None
    for _ in range(repeat):
        with (recorded_kernels(EKF_MODULES[name]) if name in EKF_MODULES
              else contextlib.nullcontext()) as recorded:
            t0 = time.perf_counter()
            est = run_estimator(seq, name, config, progress=None, initial=initial,
                                smoother=smoother).estimate
            wall = time.perf_counter() - t0
        if wall < best:
            best, sizes, timing = wall, recorded, dict(est.info.get("timing", {}))
    if name in EKF_MODULES:
        kernels, rate = min(replay_kernels(sizes) for _ in range(repeat))
        note = (f"dense updates replayed: {len(sizes['potrf'])} Cholesky, S up to "
                f"{max(sizes['potrf'], default=0)} rows, {rate:.0f} Gflop/s")
        return best, kernels, note, est
    kernels = float(timing.get("optimise_s", np.nan))
    note = f"GTSAM LM, {est.info.get('iterations')} iterations"
    return best, kernels, note, est


def main(argv=None) -> int:
    from vislam.ekf.config import FilterConfig
    from vislam.eval.montecarlo import monte_carlo_drives, nees_sim_config
    from vislam.eval.commands.nees import NEES_DEFAULT
    from vislam.graph.settings import SmootherSettings

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    _, seqs = monte_carlo_drives(nees_sim_config(args.seed, args.frames), 1)
    seq = seqs["run000"]
    config, smoother = FilterConfig(), SmootherSettings()
    print(f"vislam nees --seed {args.seed}, run000: {seq.n_frames} frames, "
          f"{seq.obs.frame_index.size} observations, BLAS {config.blas_threads} thread(s), "
          f"best of {args.repeat}")
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    print(f"{'estimator':15s} {'wall (s)':>9s} {'kernels (s)':>12s}  kernels")
    initial, total, floor = None, 0.0, 0.0
    for name in NEES_DEFAULT:
        wall, kernels, note, est = time_estimator(name, seq, config, smoother, initial, args.repeat)
        if name == "ekf-joint":
            initial = est  # the smoother starts from it, as in the study
        total, floor = total + wall, floor + kernels
        print(f"{name:15s} {wall:9.3f} {kernels:12.3f}  {note}")
    print(f"{'one run':15s} {total:9.3f} {floor:12.3f}")
    scale = args.runs / args.cores
    print(f"{args.runs} runs on {args.cores} cores: {total * scale:.1f} s at these times, "
          f"{floor * scale:.1f} s in the kernels alone")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
