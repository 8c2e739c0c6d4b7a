"""A raw-IMU drive: :class:`InertialDrive`, beside the velocity drive :class:`ekf.sequence.Sequence`.

What a visual-inertial system records (EuRoC, TUM-VI, a user's own rig):

- the IMU's samples at their own rate (:class:`ekf.filter.ImuSamples`: time, specific force,
  angular rate, in the IMU frame; no gravity removed);
- camera frames at their times, with feature tracks (:class:`ekf.sequence.Observations`,
  the same sparse rows as a velocity drive: four pixel columns for stereo, two for monocular);
- the calibration (:class:`InertialCalibration`): the left camera's intrinsics ``K`` with an
  optional lens distortion, the stereo baseline (None for a single camera), the camera-IMU
  extrinsic, the IMU's noise densities and bias random walks (:class:`ImuNoise`, the data
  sheet's figures) and the magnitude of gravity.

Times are seconds since ``time_origin_ns`` (the first IMU sample's stamp, in integer
nanoseconds as ASL files give it): absolute stamps of 1.4e9 s would keep only 0.2 us in a
float. Conventions are today's: ``cam_T_imu`` takes IMU-frame points to the camera frame
(``p_cam = cam_T_imu @ p_imu``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from vislam.ekf.errors import InputError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import se3_inv
from vislam.ekf.sequence import Observations

#: Lens distortion models a calibration may carry, with their number of coefficients:
#: ``radtan`` (k1, k2, p1, p2: OpenCV's / Kalibr's radial-tangential) and ``equidistant``
#: (k1..k4: Kalibr's fisheye). ``none``: pixels of an ideal pinhole (undistorted tracks).
DISTORTION_MODELS = {"none": 0, "radtan": 4, "equidistant": 4}

#: Standard gravity, m/s^2 (the default magnitude where a source gives none).
STANDARD_GRAVITY = 9.80665
#: The accelerometer's turn-on bias, sigma per axis (m/s^2), that every raw-IMU estimator assumes
#: before the data (the EKFs' rest initialisation, :class:`ekf.imu_init.RestConfig`, and the
#: smoother's prior, :class:`graph.inertial_smoother.InertialSmootherSettings`) and that the
#: simulator draws (:class:`eval.imu_sim_config.ImuSimConfig`): one figure, so that estimators
#: compared on one drive start from the same belief. A data sheet rarely gives it (EuRoC's ADIS16448
#: drive carries 0.16 m/s^2 on one axis by its ground truth).
ACCEL_TURN_ON_BIAS_SIGMA = 0.05


@dataclass(frozen=True)
class ImuNoise:
    """The IMU's continuous-time noise model (Kalibr's / the ASL ``sensor.yaml`` convention).

    ``gyro_noise_density`` rad/s/sqrt(Hz) and ``accel_noise_density`` m/s^2/sqrt(Hz): white
    noise of the samples (a sample at rate f has sigma ``density * sqrt(f)``);
    ``gyro_random_walk`` rad/s^2/sqrt(Hz) and ``accel_random_walk`` m/s^3/sqrt(Hz): the
    biases' random walk (over dt their change has sigma ``walk * sqrt(dt)``)."""

    gyro_noise_density: float
    gyro_random_walk: float
    accel_noise_density: float
    accel_random_walk: float

    def as_array(self) -> np.ndarray:
        """``[gyro noise, gyro walk, accel noise, accel walk]`` (the file form's ``imu_noise``)."""
        return np.array([self.gyro_noise_density, self.gyro_random_walk,
                         self.accel_noise_density, self.accel_random_walk])

    @classmethod
    def from_array(cls, values) -> ImuNoise:
        g, gw, a, aw = (float(v) for v in np.asarray(values, dtype=float).ravel())
        return cls(g, gw, a, aw)


@dataclass(frozen=True)
class InertialCalibration:
    """Camera and IMU calibration of a raw-IMU drive (module docstring).

    ``K`` (3, 3) the left camera's intrinsics (pixels); ``distortion_model`` one of
    :data:`DISTORTION_MODELS` with its ``distortion`` coefficients; ``baseline`` the stereo
    baseline in metres (rectified pair, right camera along the left's +x), None for one camera;
    ``cam_T_imu`` (4, 4); ``noise`` the IMU's data-sheet noise; ``gravity`` m/s^2."""

    K: np.ndarray
    cam_T_imu: np.ndarray
    noise: ImuNoise
    baseline: float | None = None
    distortion_model: str = "none"
    distortion: tuple[float, ...] = ()
    gravity: float = STANDARD_GRAVITY

    @property
    def stereo(self) -> bool:
        return self.baseline is not None

    @property
    def imu_T_cam(self) -> np.ndarray:
        return se3_inv(self.cam_T_imu)


@dataclass(frozen=True)
class InertialDrive:
    """One raw-IMU drive (module docstring).

    ``timestamps`` (T,) camera frame times, s since ``time_origin_ns``; ``imu`` the whole
    IMU stream (n samples, strictly increasing times covering every frame); ``obs`` the
    tracks (``z`` (N, 4) stereo or (N, 2) monocular pixels); ``n_tracks`` the number of track
    indices; ``track_id`` (n_tracks,) each track's id in the source file."""

    name: str
    timestamps: np.ndarray
    imu: ImuSamples
    obs: Observations
    n_tracks: int
    calibration: InertialCalibration
    time_origin_ns: int = 0
    track_id: np.ndarray | None = None
    source: str | None = None

    @property
    def n_frames(self) -> int:
        return int(self.timestamps.size)

    @property
    def stereo(self) -> bool:
        return self.calibration.stereo

    @property
    def imu_rate(self) -> float:
        """Median IMU sample rate, Hz."""
        return float(1.0 / np.median(np.diff(self.imu.time)))

    def imu_between(self, k: int) -> ImuSamples:
        """The samples of frame interval ``(t_k-1, t_k]`` with the sample at or before
        ``t_k-1`` in front (what an integrator needs to cover the whole interval)."""
        t0, t1 = self.timestamps[k - 1], self.timestamps[k]
        a = max(int(np.searchsorted(self.imu.time, t0, side="right")) - 1, 0)
        b = int(np.searchsorted(self.imu.time, t1, side="right"))
        return ImuSamples(self.imu.time[a:b], self.imu.accel[a:b], self.imu.gyro[a:b])


def with_frames(drive: InertialDrive, frames: np.ndarray) -> InertialDrive:
    """``drive`` with the camera frames ``frames`` (ascending indices) only: their stamps and
    observations, the IMU and everything else unchanged."""
    frames = np.asarray(frames, dtype=np.int64)
    obs = drive.obs
    slot = np.full(drive.n_frames, -1, dtype=np.int64)
    slot[frames] = np.arange(frames.size)
    f = slot[obs.frame_index]
    keep = f >= 0
    sub = Observations.from_rows(f[keep], obs.track[keep], obs.z[keep], int(frames.size))
    return dataclasses.replace(drive, timestamps=np.asarray(drive.timestamps)[frames], obs=sub)


def imu_on_camera_clock(drive: InertialDrive, offset: float) -> tuple[InertialDrive, int, int]:
    """``drive`` with its IMU stamps moved onto the camera's clock, for an IMU whose stamps are
    ``offset`` s late against the camera's (the model key ``imu_time_offset``: a sample stamped
    ``t`` holds the motion at camera time ``t - offset``), and the number of camera frames
    dropped at the start and at the end because the moved IMU no longer covers them.

    Every raw-IMU estimator integrates the samples between camera frames by their stamps, so
    this is how each of them applies the offset. The time origin moves with the IMU's first
    sample (it stays ``time_origin_ns`` + the stamp, absolute camera times unchanged), and the
    drive's ``source`` says what was moved. InputError for an offset that is not finite or
    leaves fewer than two frames."""
    d = float(offset)
    if not np.isfinite(d):
        raise InputError(f"{drive.name}: imu_time_offset {offset!r} is not a finite number of seconds")
    if d == 0.0:
        return drive, 0, 0
    t_imu = np.asarray(drive.imu.time, dtype=float) - d
    t = np.asarray(drive.timestamps, dtype=float)
    covered = (t >= t_imu[0]) & (t <= t_imu[-1])
    frames = np.flatnonzero(covered)
    if frames.size < 2:
        raise InputError(f"{drive.name}: imu_time_offset {d:g} s moves the IMU off all but "
                         f"{frames.size} of the {t.size} camera frames")
    head, tail = int(frames[0]), int(t.size - 1 - frames[-1])
    shift_ns = int(round(t_imu[0] * 1e9))
    origin = shift_ns * 1e-9
    moved = with_frames(drive, frames)
    imu = ImuSamples(t_imu - origin, drive.imu.accel, drive.imu.gyro)
    note = f"IMU stamps moved {-1e3 * d:+.4g} ms onto the camera's clock (imu_time_offset {d:.6g} s)"
    source = f"{drive.source}; {note}" if drive.source else note
    return (dataclasses.replace(moved, imu=imu, timestamps=moved.timestamps - origin,
                                time_origin_ns=int(drive.time_origin_ns) + shift_ns, source=source),
            head, tail)
