"""How the smoother's pixel residuals are correlated along each track (no ground truth needed).

    .venv/bin/python benchmarks/track_residuals.py [FILE.npz ...] [--sim SEED]

The smoother treats every stereo observation as independent. This script solves the smoother
under the model `vislam bench` identifies (cached) and prints, per drive, the spread of its
pixel residuals ``[uL, uR, v]`` and their correlation between observations of the same track
``lag`` frames apart (1, 2, 4, 8), and that of the disparity residual ``uL - uR`` at lag 1.
With white pixel noise, fitting each landmark makes neighbouring residuals slightly negative
(``--sim``: the default simulator, about -0.1); a tracker whose feature positions drift
along a track gives strongly positive ones, and a track of n observations then carries the
information of far fewer (for AR(1) errors with correlation rho, n (1 - rho) / (1 + rho)).
Issue 13: on both editions of KITTI 0027, lag 1 is about 0.87 in u and 0.96 in disparity.
It also prints what the model takes from them (graph.track_correlation): the residuals'
correlation time, and the errors' once corrected for the landmark fit (which keeps part of a
slow error out of the residuals), with the share of variance the fit leaves.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.eval.drives import identify_models, load_bench_sequence
from vislam.eval.datasets import drive_path
from vislam.graph.factors import stereo_residuals
from vislam.graph.settings import SmootherSettings
from vislam.graph.smoother import solve_smoother
from vislam.graph.track_correlation import lag_pairs, solution_track_correlation

LAGS = (1, 2, 4, 8)


def track_correlations(solution) -> tuple[np.ndarray, dict[int, tuple[int, np.ndarray]], float]:
    """Residual spread (3,), ``{lag: (pairs, correlation (3,))}`` and the disparity residual's
    lag-1 correlation of a solved smoother (:class:`graph.smoother.SmootherSolution`)."""
    rows = solution.problem.rows
    r, _ = stereo_residuals(solution.poses, solution.landmarks, solution.calibration, rows)
    out, disparity = {}, float("nan")
    d = r[:, 0] - r[:, 1]
    for lag, (i, j) in lag_pairs(rows.frame, rows.track, LAGS).items():
        a, b = r[i], r[j]
        out[lag] = (int(i.size), np.array([np.corrcoef(a[:, c], b[:, c])[0, 1] for c in range(3)]))
        if lag == 1:
            disparity = float(np.corrcoef(d[i], d[j])[0, 1])
    return r.std(axis=0), out, disparity


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path)
    parser.add_argument("--sim", type=int, default=None, metavar="SEED",
                        help="also the default simulated drive of this seed (white pixel noise)")
    args = parser.parse_args()
    settings = SmootherSettings(compute_marginals=False)
    drives = []
    for path in args.files or [drive_path("0027")]:
        (bs,) = identify_models([load_bench_sequence(Path(path))], FilterConfig(), settings)
        drives.append((str(path), bs.sequence, bs.config))
    if args.sim is not None:
        from vislam.eval.simulate import default_sequence

        drives.append((f"simulator seed {args.sim}", default_sequence(args.sim), FilterConfig()))
    for name, seq, config in drives:
        solution = solve_smoother(seq, config, settings)
        spread, lags, disparity = track_correlations(solution)
        c = solution_track_correlation(solution)
        print(f"{name}: residual sd [uL, uR, v] {np.round(spread, 3).tolist()} px; "
              f"disparity lag-1 correlation {disparity:.3f}")
        corrected = ("" if c.corrected is None else
                     f"; the errors' {c.corrected:.3g} frames once corrected for the landmark fit "
                     f"(residual variance share {c.variance_ratio:.3f})")
        print(f"  correlation time: the residuals' {c.estimate:.3g} frames{corrected}; "
              f"model: {'none' if c.time is None else f'{c.time:.3g}'}")
        for lag, (pairs, corr) in lags.items():
            print(f"  lag {lag}: correlation [uL, uR, v] {np.round(corr, 3).tolist()} ({pairs} pairs)")


if __name__ == "__main__":
    main()
