"""ekf.motion_check's statistic under dead reckoning and under the ground truth's poses, for the
tracks it refutes at 1e-4 and for those it keeps.

    .venv/bin/python benchmarks/motion_check_truth.py FILE.npz

The same test with the ground truth's poses and no pose noise (pixel noise only) says whether a
refuted track fits a static point at all: a moving object's or a mismatched track's statistic
per degree of freedom stays far above 1 there too (docs/findings.md, 2026-12-03).
"""

from __future__ import annotations

import argparse

import numpy as np

from vislam.ekf.cleaning import clean_sequence
from vislam.ekf.config import FilterConfig
from vislam.ekf.model import model_config, model_sequence
from vislam.ekf.motion_check import track_tests, track_statistic
from vislam.eval.groundtruth import find_ground_truth
from vislam.eval.loader import load_sequence
from vislam.eval.model_cache import identified_model
from vislam.graph.settings import SmootherSettings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('file')
    path = parser.parse_args().file
    seq = load_sequence(path); model = identified_model(seq, FilterConfig(), SmootherSettings()).model
    cfg = model_config(FilterConfig(), model); s,_ = clean_sequence(model_sequence(seq, model), min_disparity=cfg.min_disparity)
    t = track_tests(s, cfg.velocity_cov, cfg.velocity_pairing, model.pixel_sigma, model.pixel_correlation_time)
    # the same statistic with the ground truth's poses instead of dead reckoning (no pose noise)
    gt = find_ground_truth(path, cam_T_imu=np.array(s.calibration.cam_T_imu))
    Ugt = np.linalg.inv(gt.poses); n = Ugt.shape[0]
    Fz = np.zeros((n-1,6,6)); Qz = np.zeros((n-1,6,6))
    o = s.obs
    ref = t.p_value < 1e-4
    a = (model.pixel_correlation_time-1)/(model.pixel_correlation_time+1) if model.pixel_correlation_time else 0.0
    X = np.array(s.calibration.cam_T_imu); M = np.array(s.calibration.M)
    out=[]
    for tr, f0, f1, st, dof, pv in zip(t.track, t.first, t.last, t.statistic, t.dof, t.p_value):
        if f1 >= n: continue
        rows = np.flatnonzero(o.track == tr); fr = o.frame_index[rows]; srt = np.argsort(fr)
        g, _ = track_statistic(Ugt, Fz, fr[srt], o.z[rows][srt], X, M, Qz, model.pixel_sigma, a)
        out.append((pv < 1e-4, st/dof, g/dof, f0))
    out = np.array(out)
    for flag in [1, 0]:
        m = out[:,0] == flag
        print(('refuted' if flag else 'kept   '), int(m.sum()), 'median stat/dof under DR', np.nanmedian(out[m,1]).round(2), 'under ground truth poses (no pose noise)', np.nanmedian(out[m,2]).round(2))


if __name__ == "__main__":
    main()
