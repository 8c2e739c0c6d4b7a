"""The smoother's LM loop on Python-owned values (graph.smoother._python_values_lm) against
GTSAM's own LevenbergMarquardtOptimizer on the same graph: the check the speed-scale and the
joint-bias graphs share."""

from __future__ import annotations

import gtsam
import numpy as np

from vislam.graph.pose_conversions import X


def assert_lm_reaches_gtsams_minimum(start, settings, frames: int):
    """Solves ``start`` (a graph.factors.GraphProblem) with the smoother's LM and with GTSAM's
    at ``settings``'s stopping rule and damping; asserts the error fell, both end at the same
    error and at the same poses (every 13th of ``frames``). Returns ``(ours, theirs)``, the
    solutions' Values, for the caller's own variables."""
    from vislam.graph.smoother import _levenberg_marquardt

    ours, n_iter, e0, e1 = _levenberg_marquardt(start, settings)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(settings.relative_error_tol)
    params.setUseFixedLambdaFactor(settings.lm_damping == "fixed")
    theirs = gtsam.LevenbergMarquardtOptimizer(start.graph, start.values, params).optimize()
    assert n_iter >= 1 and e1 < e0
    np.testing.assert_allclose(e1, start.graph.error(theirs), rtol=1e-6)
    for k in range(0, frames, 13):
        np.testing.assert_allclose(ours.atPose3(X(k)).matrix(), theirs.atPose3(X(k)).matrix(), atol=1e-6)
    return ours, theirs
