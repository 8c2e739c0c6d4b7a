"""The EKFs use far landmarks by default (docs/findings.md, "Far landmarks in the EKFs"): only
``min_disparity`` cuts (1 px is 390 m on KITTI's rig), as in the smoother."""

from __future__ import annotations

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.estimators import ESTIMATORS
from vislam.eval.simulate import SimConfig, simulate


@pytest.mark.parametrize("name", ["ekf-joint", "ekf-invariant"])
def test_landmarks_beyond_a_hundred_metres_update_the_filter(name):
    """Every landmark 150-300 m away (disparities of 1.3-2.6 px, 0.01 px noise): the defaults
    initialise them and update with them; a max_depth of 100 m rejects every observation."""
    drive = simulate(SimConfig(seed=3, n_frames=40, min_depth=150.0, max_depth=300.0,
                               pixel_sigma=0.01))
    seq = drive.sequence
    est = ESTIMATORS[name](seq, FilterConfig())
    seen = int(est.n_updates.sum() + est.n_rejected.sum() + est.n_initialised.sum())
    assert est.n_initialised.sum() > 0
    assert est.n_updates.sum() > 0.5 * seen, (est.n_updates.sum(), est.n_rejected.sum(), seen)
    near_only = ESTIMATORS[name](seq, FilterConfig(max_depth=100.0))
    assert near_only.n_updates.sum() == 0 and near_only.n_initialised.sum() == 0
    assert np.isfinite(est.poses).all()
