"""Is the file's lever arm refuted on its own? The Wald statistic of the lever-arm block,
with the identified rotation, at the identified model's smoother.

    .venv/bin/python benchmarks/lever_arm_wald.py FILE.npz

The hypothesis is the identified extrinsic's rotation with the file's lever arm. It is tested
at the smoother solved under EM's white noise levels and under the estimators' long-run ones
(graph.extrinsic.extrinsic_step's information and covariance at the identified extrinsic), with
the rotation held (conditional) and free (marginal). The whole file extrinsic is tested beside
it, with BIC's thresholds (docs/findings.md, 2026-12-03).
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.model import model_config, model_sequence
from vislam.eval.loader import load_sequence
from vislam.eval.model_cache import identified_model
from vislam.graph.extrinsic import extrinsic_step, theta_between, lever_arm
from vislam.graph.settings import SmootherSettings
from vislam.graph.smoother import solve_smoother


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('file')
    path = parser.parse_args().file
    seq = load_sequence(path); model = identified_model(seq, FilterConfig(), SmootherSettings()).model
    Xid = np.array(model.cam_T_imu); Xf = np.array(seq.calibration.cam_T_imu)
    R = Xid[:3,:3]; pf = lever_arm(Xf)
    Xh = np.eye(4); Xh[:3,:3] = R; Xh[:3,3] = -R @ pf
    s = model_sequence(seq, model)
    n = len(s.obs.track)
    for name, cfg in [('white (EM)', model_config(FilterConfig(), dataclasses.replace(model, velocity_correlation_time=None, gyro_correlation_time=None)).replace(pixel_sigma=model.pixel_sigma)),
                      ('long-run (estimators)', model_config(FilterConfig(), model))]:
        sol = solve_smoother(s, cfg, SmootherSettings(compute_marginals=False))
        st = extrinsic_step(sol, Xid, cfg)
        d = theta_between(Xid, Xh)
        S = st.information
        cond = float(d[:3] @ S[:3,:3] @ d[:3])
        C = st.covariance; marg = float(d[:3] @ np.linalg.solve(C[:3,:3], d[:3]))
        dfull = theta_between(Xid, Xf)
        full = float(dfull @ np.linalg.solve(C, dfull))
        print(f'{name}: lever arm block (file arm, identified rotation): Wald conditional {cond:.1f}, marginal {marg:.1f}; whole file extrinsic {full:.1f}; BIC 3 ln n = {3*np.log(n):.1f}, 6 ln n = {6*np.log(n):.1f}')


if __name__ == "__main__":
    main()
