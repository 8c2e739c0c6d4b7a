"""The simulators' faults with a known answer (issue 39, item 3): streams stamped late against the
camera (velocity drives: the linear- and angular-velocity streams; raw-IMU drives: the IMU) and an
IMU noisier than its data sheet. Zero offsets and a scale of 1 leave every drive unchanged (to
1e-12); a fault shows up where it should, and its true value is recorded."""

import dataclasses

import numpy as np
import pytest

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import so3_log
from vislam.ekf.inertial_dead_reckoning import WORLD_GRAVITY_DIRECTION
from vislam.ekf.strapdown import NavState, integrate
from vislam.eval.imu_sim import simulate_imu
from vislam.eval.imu_sim_config import EUROC_IMU_NOISE, ImuSimConfig
from vislam.eval.sim_config import SimConfig, scenario_config
from vislam.eval.sim_drawing import twist_profile
from vislam.eval.simulate import simulate

from tests.fingerprint import assert_same_fingerprint, fingerprint, pinned

SHORT = dict(n_frames=120)
V_OFF, G_OFF = 0.03, -0.1


def imu_fingerprint(drive, truth) -> list[tuple]:
    """A raw-IMU drive's arrays (measurements and ground truth), fingerprinted."""
    return fingerprint((drive.timestamps, drive.imu.time, drive.imu.accel, drive.imu.gyro,
                        drive.obs.frame_ptr, drive.obs.track, drive.obs.z, truth.imu_poses,
                        truth.gyro_bias, truth.accel_bias))


#: Raw-IMU drives pinned in tests/sim_fingerprints.json (tests/fingerprint.py), first pinned by
#: sha256 at 996e369, before the faults existed: the default settings (zero offset, noise scale
#: 1) must reproduce them (to 1e-12: their last bits follow the processor's BLAS kernel).
IMU_CASES = [
    ("imu/mono_room_41", dict(n_frames=41)),
    ("imu/stereo_road_41", dict(n_frames=41, scenario="road", camera="stereo", seed=3,
                                sampling="instant")),
]


@pytest.mark.parametrize("name,settings", IMU_CASES)
def test_raw_imu_drive_without_faults_is_unchanged(name, settings):
    assert_same_fingerprint(imu_fingerprint(*simulate_imu(ImuSimConfig(**settings))), pinned(name))
    explicit = ImuSimConfig(**settings, imu_time_offset=0.0, imu_noise_scale=1.0)
    assert_same_fingerprint(imu_fingerprint(*simulate_imu(explicit)), pinned(name))


# --------------------------------------------------------------------------- velocity drives


@pytest.mark.parametrize("scenario", ["road", "loop", "room"])
def test_velocity_streams_hold_the_motion_at_the_shifted_times(scenario):
    base = scenario_config(scenario, noise_free=True, **SHORT)
    zero = simulate(base)
    late = simulate(dataclasses.replace(base, velocity_time_offset=V_OFF, gyro_time_offset=G_OFF))
    # The trajectory, the camera and the truth are the drive's own; only the streams move.
    np.testing.assert_array_equal(late.poses, zero.poses)
    np.testing.assert_array_equal(late.true_velocities, zero.true_velocities)
    np.testing.assert_array_equal(late.sequence.obs.z, zero.sequence.obs.z)
    np.testing.assert_array_equal(late.sequence.timestamps, zero.sequence.timestamps)
    np.testing.assert_array_equal(zero.sequence.linear_velocity, zero.true_velocities[:, :3])
    # Each stream against the zero-offset drive's twists interpolated on its 10 Hz grid at the
    # shifted times, inside the grid (cubic; the room's, made step by step with constant
    # accelerations, linear): close at the shifted times, far at the stamps.
    from scipy.interpolate import CubicSpline, make_interp_spline

    t = zero.sequence.timestamps
    spline = (make_interp_spline(t, zero.true_velocities, k=1) if scenario == "room"
              else CubicSpline(t, zero.true_velocities))
    for cols, off, stream in ((slice(0, 3), V_OFF, late.sequence.linear_velocity),
                              (slice(3, 6), G_OFF, late.sequence.angular_velocity)):
        inside = (t - off >= t[0]) & (t - off <= t[-1])
        inside[[0, -1]] = False
        shifted = spline(t[inside] - off)[:, cols]
        err = np.abs(stream[inside] - shifted).max()
        unshifted = np.abs(stream[inside] - zero.true_velocities[inside, cols]).max()
        assert unshifted > 10 * err, (scenario, off, err, unshifted)


def test_road_streams_are_its_curves_evaluated_at_the_shifted_times_exactly():
    config = SimConfig(noise_free=True, velocity_time_offset=V_OFF, gyro_time_offset=G_OFF, **SHORT)
    late = simulate(config)
    rng_drive = np.random.default_rng(np.random.SeedSequence(config.seed).spawn(6)[0])
    t = late.sequence.timestamps
    from vislam.eval.sim_drawing import LOOKAHEAD_M

    # the road's curves rebuilt from its stream as the simulator builds them (their span)
    n_all = config.n_frames + int(np.ceil((LOOKAHEAD_M + config.max_depth) / config.speed_min
                                          * config.rate_hz))
    twists = twist_profile(config, rng_drive, float((n_all - 1) / config.rate_hz) + 1.0)
    np.testing.assert_array_equal(late.sequence.linear_velocity, twists(t - V_OFF)[:, :3])
    np.testing.assert_array_equal(late.sequence.angular_velocity, twists(t - G_OFF)[:, 3:])


@pytest.mark.parametrize("pairing", ["current", "next"])
def test_offset_streams_keep_the_pairing(pairing):
    base = SimConfig(noise_free=True, velocity_pairing=pairing, **SHORT)
    late = simulate(dataclasses.replace(base, gyro_time_offset=G_OFF))
    same = simulate(dataclasses.replace(base, velocity_pairing="mean", gyro_time_offset=G_OFF))
    w = late.sequence.angular_velocity
    u = np.concatenate([same.sequence.angular_velocity,
                        simulate(dataclasses.replace(base, velocity_pairing="mean",
                                                     gyro_time_offset=G_OFF,
                                                     n_frames=SHORT["n_frames"] + 1)
                                 ).sequence.angular_velocity[-1:]])
    interval = 0.5 * (u[:-1] + u[1:])
    expected = interval if pairing == "current" else np.concatenate([u[:1], interval[:-1]])
    np.testing.assert_allclose(w, expected, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(late.sequence.linear_velocity,
                                  simulate(base).sequence.linear_velocity)


def test_noise_draws_do_not_move_with_the_offsets():
    base = SimConfig(**SHORT)
    zero, late = simulate(base), simulate(dataclasses.replace(base, velocity_time_offset=V_OFF))
    free = dataclasses.replace(base, noise_free=True)
    zero0, late0 = simulate(free), simulate(dataclasses.replace(free, velocity_time_offset=V_OFF))
    np.testing.assert_allclose(late.sequence.linear_velocity - late0.sequence.linear_velocity,
                               zero.sequence.linear_velocity - zero0.sequence.linear_velocity,
                               atol=1e-12)
    np.testing.assert_array_equal(late.sequence.angular_velocity, zero.sequence.angular_velocity)
    np.testing.assert_array_equal(late.sequence.obs.z, zero.sequence.obs.z)


def test_offsets_are_recorded(tmp_path):
    from vislam.eval.sim_files import write_simulation

    late = simulate(SimConfig(velocity_time_offset=V_OFF, gyro_time_offset=G_OFF, **SHORT))
    paths = write_simulation(late, tmp_path / "late", "late")
    held = np.load(paths["landmarks"])
    assert float(held["velocity_time_offset"]) == V_OFF and float(held["gyro_time_offset"]) == G_OFF
    assert "velocity_time_offset" in late.model.source and "gyro_time_offset" in late.model.source
    assert dataclasses.asdict(late.config)["gyro_time_offset"] == G_OFF
    zero = write_simulation(simulate(SimConfig(**SHORT)), tmp_path / "zero", "zero")
    assert "velocity_time_offset" not in np.load(zero["landmarks"]).files


@pytest.mark.parametrize("key", ["velocity_time_offset", "gyro_time_offset"])
@pytest.mark.parametrize("value", [np.nan, np.inf, 1.5, -1.2, 1.3, "0.1", True])
def test_bad_stream_offsets_are_refused_naming_them(key, value):
    frames = 120 if value != 1.3 else 100  # 1.3 s: more than a tenth of a 9.9 s drive
    with pytest.raises(InputError, match=key):
        SimConfig(n_frames=frames, **{key: value})
    SimConfig(n_frames=120, **{key: -1.0})  # a tenth of 11.9 s is more than 1 s: 1 s allowed


# --------------------------------------------------------------------------- raw-IMU drives


def _state_at(truth, time: float) -> NavState:
    p = truth.trajectory(np.array([time]))
    return NavState(p.R[0], p.v[0], p.p[0], np.zeros(3), np.zeros(3))


@pytest.mark.parametrize("scenario", ["room", "road"])
def test_imu_samples_integrate_to_the_truth_of_the_shifted_times(scenario):
    off = 0.03
    config = ImuSimConfig(scenario=scenario, n_frames=101, noise_free=True, imu_time_offset=off)
    drive, truth = simulate_imu(config)
    zero_drive, zero_truth = simulate_imu(dataclasses.replace(config, imu_time_offset=0.0))
    np.testing.assert_array_equal(drive.timestamps, zero_drive.timestamps)
    np.testing.assert_array_equal(drive.obs.z, zero_drive.obs.z)
    np.testing.assert_array_equal(truth.frame_poses, zero_truth.frame_poses)
    assert truth.imu_time_offset == off and zero_truth.imu_time_offset == 0.0
    g = drive.calibration.gravity * WORLD_GRAVITY_DIRECTION
    ta, tb = drive.timestamps[60], drive.timestamps[80]  # 3-4 s: moving
    end, _ = integrate(_state_at(truth, ta - off), None, drive.imu, ta, tb, g)
    want, stamped = _state_at(truth, tb - off), _state_at(truth, tb)
    assert np.linalg.norm(so3_log(want.R.T @ end.R)) < 1e-9
    np.testing.assert_allclose(end.v, want.v, atol=1e-8)
    np.testing.assert_allclose(end.p, want.p, atol=1e-4)
    # ... and not at the truth of the stamps
    assert np.linalg.norm(end.p - stamped.p) > 100 * np.linalg.norm(end.p - want.p)
    assert np.linalg.norm(end.v - stamped.v) > 1e3 * np.linalg.norm(end.v - want.v)


def test_imu_noise_scale_scales_the_noise_and_not_the_declared_densities():
    X = 3.0
    config = ImuSimConfig(n_frames=201, imu_noise_scale=X)
    drive, truth = simulate_imu(config)
    ref_drive, ref_truth = simulate_imu(dataclasses.replace(config, imu_noise_scale=1.0))
    free, _ = simulate_imu(dataclasses.replace(config, noise_free=True))
    assert drive.calibration.noise == EUROC_IMU_NOISE == ref_drive.calibration.noise
    assert truth.imu_noise_scale == X and "imu_noise_scale" in drive.source
    nz, rate, dt = EUROC_IMU_NOISE, config.imu_rate_hz, 1.0 / config.imu_rate_hz
    for meas, ref_meas, clean, bias, ref_bias, density, walk in (
            (drive.imu.gyro, ref_drive.imu.gyro, free.imu.gyro, truth.gyro_bias,
             ref_truth.gyro_bias, nz.gyro_noise_density, nz.gyro_random_walk),
            (drive.imu.accel, ref_drive.imu.accel, free.imu.accel, truth.accel_bias,
             ref_truth.accel_bias, nz.accel_noise_density, nz.accel_random_walk)):
        white = meas - clean - bias  # the residual of a noise-only drive, less its bias
        assert np.std(white) / (density * np.sqrt(rate)) == pytest.approx(X, rel=0.03)
        steps = np.diff(bias, axis=0)
        assert np.std(steps) / (walk * np.sqrt(dt)) == pytest.approx(X, rel=0.03)
        # the same draws, scaled: the initial bias (a turn-on sigma, not a density) is not
        np.testing.assert_allclose(white, X * (ref_meas - clean - ref_bias), rtol=1e-9, atol=1e-12)
        np.testing.assert_array_equal(bias[0], ref_bias[0])


def test_raw_imu_faults_are_recorded(tmp_path):
    from vislam.eval.imu_sim_files import write_imu_simulation

    drive, truth = simulate_imu(ImuSimConfig(n_frames=41, imu_time_offset=-0.02,
                                             imu_noise_scale=2.5))
    held = np.load(tmp_path / f"{write_imu_simulation(tmp_path, drive, truth).stem}_landmarks.npz")
    assert float(held["imu_time_offset"]) == -0.02 and float(held["imu_noise_scale"]) == 2.5
    plain, plain_truth = simulate_imu(ImuSimConfig(n_frames=41))
    out = tmp_path / "plain"
    held = np.load(out / f"{write_imu_simulation(out, plain, plain_truth).stem}_landmarks.npz")
    assert held.files == ["landmarks"]


@pytest.mark.parametrize("key,value", [
    ("imu_time_offset", np.nan), ("imu_time_offset", np.inf), ("imu_time_offset", 1.5),
    ("imu_time_offset", 0.5), ("imu_time_offset", "0.01"), ("imu_noise_scale", 0.0),
    ("imu_noise_scale", -1.0), ("imu_noise_scale", np.nan), ("imu_noise_scale", np.inf),
    ("imu_noise_scale", 1e4), ("imu_noise_scale", True)])
def test_bad_imu_faults_are_refused_naming_them(key, value):
    with pytest.raises(InputError, match=key):
        ImuSimConfig(n_frames=41, **{key: value})  # 2 s: 0.5 s is more than a tenth


# --------------------------------------------------------------------------- the command


def test_simulate_command_flags(tmp_path, capsys):
    from vislam.eval.cli import main

    assert main(["simulate", "--out", str(tmp_path / "v"), "--frames", "60",
                 "--velocity-time-offset", "0.03", "--gyro-time-offset", "-0.05"]) == 0
    held = np.load(tmp_path / "v" / "sim-seed0_landmarks.npz")
    assert float(held["velocity_time_offset"]) == 0.03 and float(held["gyro_time_offset"]) == -0.05
    assert main(["simulate", "--imu", "--out", str(tmp_path / "i"), "--frames", "41",
                 "--imu-time-offset", "0.02", "--imu-noise-scale", "4"]) == 0
    held = np.load(next((tmp_path / "i").glob("*_landmarks.npz")))
    assert float(held["imu_time_offset"]) == 0.02 and float(held["imu_noise_scale"]) == 4.0
    for argv, flag in ((["--imu-time-offset", "0.01"], "--imu-time-offset"),
                       (["--imu-noise-scale", "2"], "--imu-noise-scale"),
                       (["--imu", "--velocity-time-offset", "0.01"], "--velocity-time-offset"),
                       (["--imu", "--gyro-time-offset", "0.01"], "--gyro-time-offset"),
                       (["--velocity-time-offset", "nan"], "velocity_time_offset"),
                       (["--imu", "--imu-noise-scale", "-2"], "imu_noise_scale")):
        out = tmp_path / f"bad{len(list(tmp_path.iterdir()))}"
        assert main(["simulate", "--out", str(out), "--frames", "60", *argv]) == 2
        assert flag in capsys.readouterr().err
        assert not out.exists() or not any(out.iterdir())
