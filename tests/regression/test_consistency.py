"""Consistency on simulation: Monte Carlo ANEES of poses (6 dof) and landmarks (3 dof) against
the two-sided 95 % chi-square bounds chi2.ppf([.025, .975], N d) / N (DESIGN.md, "Scoring").

Near field (``monte_carlo``: landmarks within 25 m, where the first-order stereo model holds):
``ekf-invariant``, ``ekf-joint`` and ``smoother`` must be inside the bounds. ``ekf-decoupled``
(the paper's Algorithm 1, no pose-landmark cross-covariance) is pinned overconfident: that proves
the test sees inconsistency.

Default simulation (``monte_carlo_default``: landmarks to 60 m): the smoother must be inside the
bounds; the EKFs are overconfident there (tests/regression/simulation.py, NEAR_FIELD_WHY) and are
reported as measured, each with a regression ceiling a margin above today's figure."""

from __future__ import annotations

import numpy as np
import pytest

from eval.consistency import LANDMARK_DOF, POSE_DOF, VERDICT_ABOVE, VERDICT_INSIDE, anees

pytestmark = pytest.mark.slow

CONSISTENT = ("ekf-invariant", "ekf-joint", "smoother")
#: Default simulation, ANEES ceilings (pose, landmark) of the EKFs: measured ekf-joint 15.25 /
#: 36.2 and ekf-invariant 15.27 / 38.1 (10 runs x 120 frames, seed 0); about 25 % above, so that
#: a regression (or dropping the cross-covariance, which gives thousands) fails.
FAR_FIELD_CEILING = {
    "ekf-joint": {"pose": 19.0, "landmark": 45.0},
    "ekf-invariant": {"pose": 19.0, "landmark": 48.0},
}


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


def test_smoother_consistent_on_default_simulation(monte_carlo_default):
    _no_failures(monte_carlo_default, "smoother")
    for what, res in (("pose", _pose(monte_carlo_default, "smoother")),
                      ("landmark", _landmark(monte_carlo_default, "smoother"))):
        line = _report(monte_carlo_default, "smoother", what, res)
        assert res.verdict == VERDICT_INSIDE, line


@pytest.mark.parametrize("name", sorted(FAR_FIELD_CEILING))
def test_ekf_on_default_simulation_reported_with_ceiling(monte_carlo_default, name):
    """Overconfident today (far points; see NEAR_FIELD_WHY): pinned so that it cannot get worse,
    and must not turn underconfident."""
    _no_failures(monte_carlo_default, name)
    pose = _pose(monte_carlo_default, name)
    landmark = _landmark(monte_carlo_default, name)
    line_p = _report(monte_carlo_default, name, "pose", pose)
    line_l = _report(monte_carlo_default, name, "landmark", landmark)
    ceiling = FAR_FIELD_CEILING[name]
    assert pose.mean <= ceiling["pose"], f"{line_p}; regression ceiling {ceiling['pose']}"
    assert landmark.mean <= ceiling["landmark"], f"{line_l}; regression ceiling {ceiling['landmark']}"
    assert pose.mean >= pose.bounds[0], f"{line_p}: underconfident"
