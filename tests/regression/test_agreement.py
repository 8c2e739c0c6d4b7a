"""Agreement on simulation: each EKF keeps the smoother inside its own 3-sigma on at least the
share of frames the chi-square bound predicts.

Per run and step (1..T-1) the EKF's pose difference from the smoother of the same run is
normalised by the EKF's covariance (a 6-dof NEES, eval.consistency.pose_nees); "inside 3-sigma"
is NEES <= chi2.ppf(0.9973, 6), the 6-dof region of the 1-D 3-sigma probability. A consistent
EKF has at least that share inside: the smoother uses a superset of the data, so the difference
has covariance P_ekf - P_smoother <= P_ekf. The required share is the predicted 0.9973 less the
binomial 1 % allowance for the number of frames scored.

``ekf-invariant`` must agree. ``ekf-decoupled`` is pinned to fail (proof that the test can fail).
``ekf-joint`` is overconfident today: reported with a regression floor below today's share."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binom, chi2

from eval.consistency import POSE_DOF

pytestmark = pytest.mark.slow

THREE_SIGMA = chi2.cdf(9.0, 1)  # 0.9973
#: Share of ekf-joint frames inside: measured 0.873 (10 runs x 120 frames, seed 0); floor below.
JOINT_FLOOR = 0.80


def _share(mc, name) -> tuple[float, float, str]:
    nees = mc.versus_smoother[name][:, 1:]
    nees = nees[np.isfinite(nees)]
    assert nees.size, f"{name}: no step compared with the smoother (errors: {mc.errors[name][:1]})"
    share = float(np.mean(nees <= chi2.ppf(THREE_SIGMA, POSE_DOF)))
    required = float(binom.ppf(0.01, nees.size, THREE_SIGMA) / nees.size)
    line = (f"{name}: smoother inside the EKF's 3-sigma on {share:.4f} of {nees.size} frames "
            f"(predicted {THREE_SIGMA:.4f}, required >= {required:.4f}; "
            f"median NEES vs smoother {np.median(nees):.2f})")
    print(line)
    return share, required, line


def test_invariant_agrees_with_smoother(monte_carlo):
    share, required, line = _share(monte_carlo, "ekf-invariant")
    assert share >= required, line


def test_decoupled_disagrees_with_smoother(monte_carlo):
    share, required, line = _share(monte_carlo, "ekf-decoupled")
    assert share < required, f"{line}: the decoupled filter now agrees; was 0.007"


def test_joint_reported_with_floor(monte_carlo):
    share, required, line = _share(monte_carlo, "ekf-joint")
    assert share >= JOINT_FLOOR, f"{line}; regression floor {JOINT_FLOOR}"
