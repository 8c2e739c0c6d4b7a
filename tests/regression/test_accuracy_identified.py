"""Accuracy of ``vislam bench``'s default, every estimator under the model identified from the
drive's own data (issue 12), on both published editions of KITTI drive 0027 against the same
ground truth (converted with the identified extrinsic, as the benchmark does):

* ``kitti-pr3/0027.npz``: noisy velocities (0.5 m/s, 0.05 rad/s per sample, gyro offsets), many
  tracks;
* ``kitti-pr3-2019/0027.npz``: clean velocities, about 3 tracks per frame.

Same code, same defaults, nothing chosen per file. Bounds: measured x 1.1 (so that a regression
fails), and the issue's targets where they are met (shared edition), checked by
:func:`vislam.testing.assert_accuracy` on a :func:`vislam.testing.run_drive` study. The
identification itself is pinned too: the linear velocity sigma of the shared edition (its
README: 0.5 m/s), the verdict that the file's extrinsic is refuted by the data and the pixel
errors' correlation along tracks (both editions).
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.regression.breaks import skip_or_fail
from vislam.testing import assert_accuracy

pytestmark = [pytest.mark.slow, pytest.mark.realdata, pytest.mark.regression]

ESTIMATORS = ("dead-reckoning", "ekf-joint", "ekf-invariant", "smoother")
MARGIN = 1.10
#: edition -> estimator -> measured (aligned ATE m, t_rel %) under the identified model
MEASURED = {
    "kitti-pr3": {
        "dead-reckoning": (3.51, 3.35),
        "ekf-joint": (4.40, 2.07),
        "ekf-invariant": (4.44, 2.08),
        "smoother": (2.55, 1.26),
    },
    # The aim here (every SLAM estimator within 1.1x dead reckoning's ATE, t_rel at most
    # dead reckoning's) is met by all three; the smoother's ATE is 0.90x dead reckoning's
    # (the aim: 0.8x).
    "kitti-pr3-2019": {
        "dead-reckoning": (0.71, 0.80),
        "ekf-joint": (0.73, 0.71),
        "ekf-invariant": (0.74, 0.71),
        "smoother": (0.64, 0.71),
    },
}
#: The issue's targets on the shared edition (met): better EKF aligned ATE and smoother t_rel.
TARGET_EKF_ATE_M = 5.9
TARGET_SMOOTHER_T_REL = 1.55
#: The issue's targets on the 2019 edition (met): 1.1x dead reckoning's aligned ATE (0.714 m)
#: and its t_rel (0.801 %).
TARGETS_2019 = {name: {"ate_aligned_max": 0.78, "t_rel_max": 0.80}
                for name in ("ekf-joint", "ekf-invariant", "smoother")}


def _bench(path, regression_config):
    """Every estimator on ``path`` under the model identified from its data, as ``vislam bench``
    does (:func:`vislam.testing.run_drive` with ``model="identified"``)."""
    from vislam.eval.drives import load_bench_sequence
    from vislam.testing import run_drive

    if not path.is_file():
        skip_or_fail(f"{path} not found")
    bs = load_bench_sequence(path)
    if bs.gt is None:
        skip_or_fail(f"no ground truth for {path}")
    study = run_drive(list(ESTIMATORS), bs, config=regression_config, model="identified", jobs=2)
    print(f"\n{path}: identified and estimated in {study.wall_s:.1f} s")
    return study


@pytest.fixture(scope="module")
def shared(kitti_data_dir, regression_config):
    return _bench(kitti_data_dir / "0027.npz", regression_config)


@pytest.fixture(scope="module")
def edition_2019(regression_config):
    from vislam.eval.datasets import data_dir_2019

    folder = data_dir_2019()
    if not folder.is_dir():
        skip_or_fail(f"data folder {folder} not found (set VISLAM_DATA_2019)")
    return _bench(folder / "0027.npz", regression_config)


def _check(edition, study, name, **targets):
    a, t = MEASURED[edition][name]
    bounds = {"ate_aligned_max": round(a * MARGIN + 0.005, 2), "t_rel_max": round(t * MARGIN + 0.005, 2)}
    for check in assert_accuracy(study, name=name, **bounds):
        print(f"{check.message} (measured {a if 'ATE' in check.quantity else t})")
    if targets:
        for check in assert_accuracy(study, name=name, **targets):
            print(f"{check.message} (the issue's target)")


@pytest.mark.parametrize("name", ESTIMATORS)
def test_shared_edition_accuracy(shared, name):
    targets = {}
    if name in ("ekf-joint", "ekf-invariant"):
        targets["ate_aligned_max"] = TARGET_EKF_ATE_M
    if name == "smoother":
        targets["t_rel_max"] = TARGET_SMOOTHER_T_REL
    _check("kitti-pr3", shared, name, **targets)


@pytest.mark.parametrize("name", ESTIMATORS)
def test_2019_edition_accuracy(edition_2019, name):
    _check("kitti-pr3-2019", edition_2019, name, **TARGETS_2019.get(name, {}))


def test_the_identified_models(shared, edition_2019):
    m_shared = shared.model
    assert m_shared["mode"] == "identified"
    sigma = np.array(m_shared["model"]["velocity_sigma"])
    assert np.all((0.45 <= sigma) & (sigma <= 0.6)), sigma  # the README's 0.5 m/s
    assert m_shared["model"]["gyro_bias"] is not None  # the README's gyro offsets
    for study in (shared, edition_2019):
        test = study.model["identification"]["extrinsic_test"]
        assert test["decision"].startswith("identified"), test  # the file's is refuted
        assert test["statistic"] > 10 * test["threshold"]
    m19 = edition_2019.model["model"]
    assert m19["gyro_bias"] is None  # clean angular velocities: BIC says no bias
    assert max(m19["velocity_sigma"]) < 0.2  # clean velocities
    for study in (shared, edition_2019):  # a tracker's drift: errors correlated along tracks
        test = study.model["identification"]["pixel_correlation_test"]
        assert test["lag1"] > 0.5
        # corrected for the landmark fit: 14.9 and 21.6 frames, from residuals' 5.3 and 7.3
        assert study.model["model"]["pixel_correlation_time"] > 2.0 * test["estimate"] > 8.0
