"""vislam's own estimators as whole-drive callables ``(seq, settings) -> Estimate``
(:mod:`vislam.eval.registry`).

The smoothers are registered from here in ``pyproject.toml`` (entry points of the group
``vislam.estimators``: the same mechanism and the same contract as a user's estimator); GTSAM is
imported only when one runs, so ``vislam run -e ekf-joint`` never imports GTSAM. The per-frame
filters are registered as their classes (:mod:`vislam.ekf.estimators`); their whole-drive forms
here serve code that wraps one (a user's estimator that post-processes an EKF's estimate).
"""

from __future__ import annotations

from vislam.ekf.estimate import Estimate
from vislam.ekf.sequence import Sequence


def _filter(name: str, seq: Sequence, settings) -> Estimate:
    from vislam.ekf.estimators import ESTIMATORS

    return ESTIMATORS[name](seq, settings.filter, settings.progress)


def dead_reckoning(seq: Sequence, settings) -> Estimate:
    """Velocities only (the paper's prediction step, no vision)."""
    return _filter("dead-reckoning", seq, settings)


def mapping(seq: Sequence, settings) -> Estimate:
    """Dead-reckoned poses, landmarks mapped from them (no pose update)."""
    return _filter("mapping", seq, settings)


def ekf_decoupled(seq: Sequence, settings) -> Estimate:
    """The paper's Algorithm 1 as written: pose and landmarks updated apart."""
    return _filter("ekf-decoupled", seq, settings)


def ekf_joint(seq: Sequence, settings) -> Estimate:
    """Pose and active landmarks in one state, with their cross-covariance."""
    return _filter("ekf-joint", seq, settings)


def ekf_invariant(seq: Sequence, settings) -> Estimate:
    """The right-invariant EKF on SE_K(3)."""
    return _filter("ekf-invariant", seq, settings)


def smoother(seq: Sequence, settings) -> Estimate:
    """GTSAM batch smoother (Levenberg-Marquardt over the whole drive); starts from
    ``settings.initial`` when given (the benchmark passes the EKF's estimate)."""
    from vislam.graph.smoother import run_smoother

    return run_smoother(seq, settings.filter, initial=settings.initial,
                        progress=settings.progress, settings=settings.smoother)


def smoother_isam2(seq: Sequence, settings) -> Estimate:
    """GTSAM iSAM2, one frame at a time."""
    from vislam.graph.isam2 import run_isam2

    return run_isam2(seq, settings.filter, progress=settings.progress, settings=settings.smoother)


def smoother_fixed_lag(seq: Sequence, settings) -> Estimate:
    """GTSAM's incremental fixed-lag smoother (window ``fixed_lag_s`` seconds)."""
    from vislam.graph.isam2 import run_fixed_lag

    return run_fixed_lag(seq, settings.filter, progress=settings.progress, settings=settings.smoother)


def dead_reckoning_imu(drive, settings) -> Estimate:
    """Raw-IMU dead reckoning: strapdown integration from a rest at the start, with its
    propagated covariance (:mod:`ekf.inertial_dead_reckoning`)."""
    from vislam.ekf.inertial_dead_reckoning import run_inertial_dead_reckoning

    est = run_inertial_dead_reckoning(drive)
    est.name = "dead-reckoning-imu"
    return est


def smoother_imu(drive, settings) -> Estimate:
    """GTSAM's visual-inertial smoother: preintegrated IMU factors between camera frames,
    projection factors for the tracks (:mod:`graph.inertial_smoother`)."""
    from vislam.graph.inertial_smoother import smooth

    est = smooth(drive).estimate
    est.name = "smoother-imu"
    return est


dead_reckoning_imu.drive_kind = "raw-imu"
smoother_imu.drive_kind = "raw-imu"
