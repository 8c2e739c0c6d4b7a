"""A drive whose landmarks are seen again and again (issue 36): the simulator's room
(``scenario_config("room")``, 50 landmarks on the walls, every one re-observed after gaps, stops
included). The model identified from its data alone recovers the true noise levels, and the
smoother under it is consistent against ground truth (its pose NEES inside the band of one
drive's mean), as on the KITTI-like road. Within a minute on two cores."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest

from vislam.ekf.model import apply_model
from vislam.eval.consistency import POSE_NEES_BAND, pose_nees
from vislam.eval.sim_config import scenario_config
from vislam.eval.simulate import simulate

pytestmark = [pytest.mark.slow, pytest.mark.regression]

FRAMES = 600


@pytest.fixture(scope="module")
def room_study(regression_config):
    from vislam.eval.model_cache import identified_model
    from vislam.graph.smoother import run_smoother

    result = simulate(scenario_config("room", n_frames=FRAMES, seed=0))
    with tempfile.TemporaryDirectory() as cache:
        model = identified_model(result.sequence, regression_config, folder=Path(cache)).model
    seq, config = apply_model(result.sequence, regression_config, model)
    return result, model, run_smoother(seq, config)


def test_identification_recovers_the_room_noise_levels(room_study):
    result, model, _ = room_study
    truth = result.model
    assert model.velocity_pairing == truth.velocity_pairing
    # Every sigma within 10 % (measured at 600 frames: velocity +8 +1 +9.5 %, gyro +9 -4 +3 %,
    # pixels +1 %). Not at 2,000 frames: 5-13 % high on 5 seeds, as the room's "mean" pairing
    # correlates consecutive intervals and EM takes them as independent (docs/findings.md,
    # "Freed Bayes trees stay in the C heap"; benchmarks/drive_shapes.py room:2000).
    np.testing.assert_allclose(model.velocity_sigma, truth.velocity_sigma, rtol=0.10)
    np.testing.assert_allclose(model.gyro_sigma, truth.gyro_sigma, rtol=0.10)
    np.testing.assert_allclose(model.pixel_sigma, truth.pixel_sigma, rtol=0.10)


def test_the_smoother_is_consistent_on_the_room(room_study):
    result, _, est = room_study
    assert est.landmarks.shape[0] == result.sequence.n_tracks  # one landmark per track
    nees = float(np.nanmean(pose_nees(est, np.arange(FRAMES), result.poses)))
    lo, hi = POSE_NEES_BAND
    assert lo <= nees <= hi, f"smoother pose NEES {nees:.2f} outside [{lo}, {hi}]"
    err = np.linalg.norm(est.positions - result.poses[:, :3, 3], axis=1)
    assert err.max() < 0.1


def test_a_platform_that_only_turns_about_the_vertical_keeps_its_true_extrinsic():
    """The room's platform never pitches or rolls, so its vertical lever arm cannot be placed:
    the identification names it undetermined (graph.extrinsic, "Excitation") and keeps the
    file's extrinsic, which is the true one. Before (19aa9dd), the estimated roll and pitch's
    wobble passed for rotation: on this drive EM walked the vertical lever arm to +2.90 m from
    the true -0.31 m, and the true extrinsic was "refuted" at a Wald statistic of 227 against
    BIC's 57."""
    from vislam.graph.extrinsic import lever_arm
    from vislam.graph.identification import identify_model

    result = simulate(scenario_config("room", n_frames=1500, seed=2))
    fit = identify_model(result.sequence, radial=False)
    assert "ty" in fit.cam_T_imu_undetermined  # camera y: the IMU's vertical
    assert fit.extrinsic_test["decision"].startswith("file's kept"), fit.extrinsic_test
    np.testing.assert_allclose(lever_arm(fit.to_model("room").cam_T_imu),
                               lever_arm(result.model.cam_T_imu), atol=1e-9)
