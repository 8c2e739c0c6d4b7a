"""Consistency on simulation: Monte Carlo ANEES of poses (6 dof) and landmarks (3 dof) against
the two-sided 95 % chi-square bounds chi2.ppf([.025, .975], N d) / N (DESIGN.md, "Scoring").

Default simulation (``monte_carlo_default``: landmarks to 60 m, disparities down to ~6 px):
``ekf-invariant``, ``ekf-joint`` and ``smoother`` must be inside the bounds, poses and landmarks.
The EKFs hold far landmarks in anchored inverse depth (ekf/inverse_depth.py); with Euclidean
landmarks they were overconfident there (pose ANEES ~15-25, landmarks ~37-46).

Near field (``monte_carlo``: landmarks within 25 m) is the second case: the same three inside.
``ekf-decoupled`` (the paper's Algorithm 1, no pose-landmark cross-covariance) is pinned
overconfident: that proves the test sees inconsistency, and so does the deliberate break
``VISLAM_REGRESSION_BREAK=half-pixel-noise`` (tests/regression/breaks.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from vislam.eval.consistency import LANDMARK_DOF, POSE_DOF, VERDICT_ABOVE, VERDICT_INSIDE, anees

pytestmark = pytest.mark.slow

CONSISTENT = ("ekf-invariant", "ekf-joint", "smoother")


def _pose(mc, name):
    return anees(mc.pose_nees[name][:, 1:], POSE_DOF)  # step 0 is exact by construction


def _landmark(mc, name):
    nees = mc.landmark_nees[name]
    return anees(nees[:, np.any(np.isfinite(nees), axis=0)], LANDMARK_DOF)


def _report(mc, name, what, res) -> str:
    lo, hi = res.bounds
    scored = int(np.count_nonzero(np.isfinite(res.per_item)))
    line = (f"{name} {what} ANEES {res.mean:.2f} over {mc.runs} runs x {scored} items, "
            f"95 % bounds [{lo:.2f}, {hi:.2f}]: {res.verdict}")
    print(line)
    return line


def _no_failures(mc, name):
    assert not mc.errors[name], f"{name} failed in {len(mc.errors[name])} runs: {mc.errors[name][:1]}"


@pytest.mark.parametrize("name", CONSISTENT)
def test_pose_anees_inside_bounds(monte_carlo, name):
    _no_failures(monte_carlo, name)
    res = _pose(monte_carlo, name)
    line = _report(monte_carlo, name, "pose", res)
    assert res.verdict == VERDICT_INSIDE, line


@pytest.mark.parametrize("name", CONSISTENT)
def test_landmark_anees_inside_bounds(monte_carlo, name):
    _no_failures(monte_carlo, name)
    res = _landmark(monte_carlo, name)
    line = _report(monte_carlo, name, "landmark", res)
    assert res.verdict == VERDICT_INSIDE, line


def test_decoupled_is_overconfident(monte_carlo):
    """The test can see inconsistency: the filter without cross-covariance is far above."""
    _no_failures(monte_carlo, "ekf-decoupled")
    pose = _pose(monte_carlo, "ekf-decoupled")
    landmark = _landmark(monte_carlo, "ekf-decoupled")
    lines = [_report(monte_carlo, "ekf-decoupled", "pose", pose),
             _report(monte_carlo, "ekf-decoupled", "landmark", landmark)]
    assert pose.verdict == VERDICT_ABOVE and landmark.verdict == VERDICT_ABOVE, "; ".join(lines)


@pytest.mark.parametrize("name", CONSISTENT)
@pytest.mark.parametrize("what", ["pose", "landmark"])
def test_default_simulation_inside_bounds(monte_carlo_default, name, what):
    _no_failures(monte_carlo_default, name)
    res = (_pose if what == "pose" else _landmark)(monte_carlo_default, name)
    line = _report(monte_carlo_default, name, what, res)
    assert res.verdict == VERDICT_INSIDE, line
