"""The raw-IMU camera-IMU time offset: applying it (ekf.inertial.imu_on_camera_clock) and
finding it by maximum likelihood around the raw-IMU smoother (graph.inertial_time_offset)."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

from vislam.ekf.errors import InputError
from vislam.ekf.inertial import imu_on_camera_clock, with_frames
from vislam.eval.cli import main
from vislam.eval.imu_sim import simulate_imu
from vislam.eval.imu_sim_config import ImuSimConfig
from vislam.eval.inertial_files import load_inertial_drive, save_inertial_drive
from vislam.graph.inertial_time_offset import (SEARCH_LIMIT, ImuOffsetFit, identify_imu_time_offset,
                                               profile_drive)

#: A short room flight (6 s, 2 s of it at rest): its offset is determined to about 1.3 ms.
ROOM = dict(scenario="room", n_frames=121, seed=1)


@functools.cache
def room(offset: float, **changes):
    return simulate_imu(ImuSimConfig(**dict(ROOM, imu_time_offset=offset, **changes)))[0]


@functools.cache
def room_fit(offset: float):
    return identify_imu_time_offset(room(offset))


def _absolute(drive, t):
    return drive.time_origin_ns * 1e-9 + np.asarray(t)


@pytest.mark.parametrize("offset", [0.01, -0.01])
def test_moving_the_stamps_by_the_offset_gives_the_imu_of_a_drive_without_one(offset):
    """A noise-free IMU whose stamps are ``offset`` late (two samples), moved onto the camera's
    clock, holds at each absolute time what the same IMU without an offset holds there; the camera
    frames keep their absolute times, and the frames the moved IMU no longer covers (at the end
    for a late IMU, at the start for an early one) are dropped and counted."""
    late = room(offset, noise_free=True)
    ideal = room(0.0, noise_free=True)
    moved, head, tail = imu_on_camera_clock(late, offset)
    assert (head, tail) == ((0, 1) if offset > 0 else (1, 0))
    assert moved.n_frames == late.n_frames - 1
    t_moved = _absolute(moved, moved.imu.time)
    t_ideal = _absolute(ideal, ideal.imu.time)
    common, i, j = np.intersect1d(np.round(t_moved, 6), np.round(t_ideal, 6), return_indices=True)
    assert common.size > 0.9 * t_ideal.size
    np.testing.assert_allclose(moved.imu.gyro[i], ideal.imu.gyro[j], atol=1e-9)
    np.testing.assert_allclose(moved.imu.accel[i], ideal.imu.accel[j], atol=1e-9)
    kept = np.arange(head, late.n_frames - tail)
    np.testing.assert_allclose(_absolute(moved, moved.timestamps), _absolute(late, late.timestamps[kept]),
                               atol=2e-9)
    assert moved.imu.time[0] == 0.0
    assert moved.source.startswith(late.source) and f"imu_time_offset {offset:g} s" in moved.source
    # the observations follow their frames
    np.testing.assert_array_equal(moved.obs.z, with_frames(late, kept).obs.z)


def test_no_offset_is_the_drive_itself_and_bad_offsets_are_refused():
    d = room(0.0, noise_free=True)
    assert imu_on_camera_clock(d, 0.0) == (d, 0, 0)
    for bad in (np.nan, np.inf):
        with pytest.raises(InputError, match="imu_time_offset"):
            imu_on_camera_clock(d, bad)
    with pytest.raises(InputError, match="all but"):
        imu_on_camera_clock(d, 100.0)


def test_a_drive_too_short_for_the_search_is_refused():
    d = room(0.0, noise_free=True)
    t = d.timestamps
    short = with_frames(d, np.flatnonzero(t <= d.imu.time[0] + SEARCH_LIMIT + 0.2))
    short = dataclasses.replace(short, imu=dataclasses.replace(
        d.imu, time=d.imu.time[d.imu.time <= short.timestamps[-1] + 0.1],
        accel=d.imu.accel[d.imu.time <= short.timestamps[-1] + 0.1],
        gyro=d.imu.gyro[d.imu.time <= short.timestamps[-1] + 0.1]))
    with pytest.raises(InputError, match="inside the IMU's span"):
        profile_drive(short)


def test_a_30_ms_late_imu_is_found_within_2_ms_and_kept():
    f = room_fit(0.03)
    assert f.kept and not f.at_limit
    assert abs(f.estimate - 0.03) < 0.002
    assert 0.0002 < f.sigma < 0.003 and abs(f.estimate - 0.03) < 3 * f.sigma
    assert f.offset == f.estimate
    # the profile is the smoother's cost: lowest at the estimate among every offset tried
    assert abs(f.profile[np.argmin(f.profile[:, 1]), 0] - f.estimate) < f.sigma
    assert f.statistic > 20 * f.threshold
    d = f.to_dict()
    assert d["kept"] and d["offset_s"] == f.estimate and set(d) >= {"sigma_s", "statistic", "at_limit"}


def test_an_imu_on_time_keeps_no_offset():
    f = room_fit(0.0)
    assert not f.kept and f.offset == 0.0
    assert abs(f.estimate) < 3 * f.sigma
    assert "not supported by the data" in f.words() and "zero" in f.words()


def test_the_decision_words():
    fit = ImuOffsetFit(estimate=0.2, sigma=0.001, statistic=1e4, n_intervals=100, at_limit=True)
    assert not fit.kept and fit.offset == 0.0 and "search limit" in fit.words()
    fit = ImuOffsetFit(estimate=0.012, sigma=0.001, statistic=np.log(100) + 0.1, n_intervals=100,
                       at_limit=False)
    assert fit.kept and fit.offset == 0.012 and "+12.00 +- 1.00 ms, kept" in fit.words()
    fit = dataclasses.replace(fit, statistic=np.log(100) - 0.1)
    assert not fit.kept and fit.offset == 0.0


def test_calibrate_finds_the_offset_and_writes_the_drive_on_the_cameras_clock(tmp_path, capsys):
    path = save_inertial_drive(tmp_path / "late.npz", room(0.03))
    out = tmp_path / "identified.npz"
    assert main(["calibrate", str(path), "--max-iterations", "1", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "camera-IMU time offset" in text and "kept (likelihood ratio" in text
    line = next(x for x in text.splitlines() if x.startswith("applied: "))
    applied = float(line.split()[1]) * 1e-3
    assert abs(applied - 0.03) < 0.002
    written, given = load_inertial_drive(out), load_inertial_drive(path)
    np.testing.assert_allclose(_absolute(written, written.imu.time[:5]),
                               _absolute(given, given.imu.time[:5]) - applied, atol=1e-5)
    np.testing.assert_array_equal(written.imu.gyro, given.imu.gyro)
    assert written.n_frames == given.n_frames - 1  # the last frame is past the moved IMU


def test_calibrate_on_a_drive_too_short_for_the_offset_says_so_and_identifies_the_rest(
        tmp_path, capsys, monkeypatch):
    import vislam.graph.inertial_time_offset as ito

    monkeypatch.setattr(ito, "MIN_FRAMES", 10_000)  # this drive's 113 frames are now too few
    path = save_inertial_drive(tmp_path / "short.npz", room(0.0))
    assert "needs 10000 or more" in ito.too_short(room(0.0))
    assert main(["calibrate", str(path), "--max-iterations", "1"]) == 0
    text = capsys.readouterr().out
    assert "camera-IMU time offset: not estimated" in text and "needs 10000 or more" in text
    assert "| gyro noise density" in text
