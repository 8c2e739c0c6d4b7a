"""The random draws of a simulated drive (:mod:`eval.simulate` puts them together): the
trajectory (smooth random speed, yaw rate and pitch), the landmarks beside the path, the tracker
with its pixel noise, and the velocity samples. Each function draws from the stream it is
given, in a fixed order: moving code between these functions must never change a draw (every
simulated drive is the same, to the byte, for one seed)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from vislam.ekf.camera import distort_pixels, project
from vislam.ekf.geometry import homogeneous, se3_exp, se3_inv
from vislam.ekf.sequence import Calibration
from vislam.eval.sim_config import KITTI_IMAGE_SIZE, SimConfig

if TYPE_CHECKING:
    from scipy.interpolate import PchipInterpolator

#: Extra path (m) simulated beyond the last frame so landmarks ahead of it exist.
LOOKAHEAD_M = 80.0
#: Landmarks further than this along the path from the car are never looked at (m).
WINDOW_M = 150.0
#: Noise-free projections closer than this to the image border are not tracked (px), so that
#: noisy pixels stay inside the image (and never equal the -1 of "unobserved").
BORDER_PX = 5.0


# --------------------------------------------------------------------------- the drive


def smooth_profile(rng, t_end: float, spacing: float, draw) -> PchipInterpolator:
    """A PCHIP curve through knots every ``spacing`` seconds with values ``draw(n)``."""
    from scipy.interpolate import PchipInterpolator  # here: its import is 0.4 s of every command's start

    n = int(np.ceil(t_end / spacing)) + 2
    knots_t = np.arange(n) * spacing
    return PchipInterpolator(knots_t, draw(n))


def instantaneous_twists(config: SimConfig, rng, t: np.ndarray) -> np.ndarray:
    """Body twists (n, 6) at times ``t``: forward speed, Euler-kinematics angular velocity."""
    return twist_profile(config, rng, float(t[-1]) + 1.0)(t)


def twist_profile(config: SimConfig, rng, span: float):
    """The road's motion as a function of time: draws the random knots of speed, yaw rate and
    pitch up to ``span`` s (in :func:`instantaneous_twists`'s order) and returns ``twists(t)``,
    the body twists (n, 6) at any times ``t`` (the PCHIP curves, extended beyond their knots
    by their end pieces)."""
    speed = smooth_profile(
        rng, span, config.knot_spacing_s, lambda n: rng.uniform(config.speed_min, config.speed_max, n)
    )

    def yaw_knots(n):
        rates = rng.uniform(-config.max_yaw_rate, config.max_yaw_rate, n)
        return np.where(rng.random(n) < config.straight_fraction, 0.0, rates)

    yaw_rate = smooth_profile(rng, span, config.knot_spacing_s, yaw_knots)
    max_pitch = np.deg2rad(config.max_pitch_deg)

    def pitch_knots(n):
        values = rng.uniform(-max_pitch, max_pitch, n)
        values[0] = 0.0  # level at frame 0, so the world z axis is up
        return values

    pitch = smooth_profile(rng, span, 2.0 * config.knot_spacing_s, pitch_knots)
    dpitch = pitch.derivative()

    def twists(t: np.ndarray) -> np.ndarray:
        theta, dtheta, dpsi = pitch(t), dpitch(t), yaw_rate(t)
        u = np.zeros((t.size, 6))
        u[:, 0] = speed(t)
        u[:, 3] = -dpsi * np.sin(theta)
        u[:, 4] = dtheta
        u[:, 5] = dpsi * np.cos(theta)
        return u

    return twists


def integrate_mean_pairing(twists: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """Poses (T, 4, 4) from identity with the constant twist ``(u_k + u_{k+1}) / 2`` on each
    interval ``[k, k+1]`` of length ``dt[k]``: the simulator's definition of the true motion."""
    twists = np.asarray(twists, dtype=float)
    steps = se3_exp(np.asarray(dt, dtype=float)[:, None] * 0.5 * (twists[:-1] + twists[1:]))
    poses = np.empty((twists.shape[0], 4, 4))
    poses[0] = np.eye(4)
    for k, step in enumerate(steps):
        poses[k + 1] = poses[k] @ step
    return poses


# --------------------------------------------------------------------------- room and loop

#: room: the platform's waypoints keep this far from the walls (m), so that the camera (about
#: 1.4 m from the IMU) stays inside the room.
ROOM_MARGIN_M = 2.0
#: room: the platform's largest linear (m/s^2) and angular (rad/s^2) acceleration.
ROOM_ACCEL = (0.5, 1.0)
#: room: the share of waypoints where the platform looks round on the spot.
ROOM_LOOK_ROUND = 0.9
#: room: landmarks stand within this height (m) above or below the camera's.
ROOM_LANDMARK_BAND_M = 0.6
#: loop: the corners' radius is at most this (m), and their curvature ramps in over a quarter
#: of it (a clothoid-like entry, so the yaw rate has no jump).
LOOP_MAX_RADIUS_M = 60.0


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2.0 * np.pi) - np.pi)


def room_drive(config: SimConfig, rng, n: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Twists (n, 6) and poses (n, 4, 4) of a platform on the floor of a room: planar motion
    with yaw (body x forward, z up), driving round the room through random waypoints, one per
quadrant in turn (each lap either way round, at random), at up to ``speed_max`` m/s
    (slower while it turns, turning on the spot when a waypoint is behind it), yaw rate up to
    ``max_yaw_rate``, accelerations bounded (ROOM_ACCEL). At a share ``stop_probability`` of
    the waypoints it stops for 1-4 s (twists exactly zero), and at a share ROOM_LOOK_ROUND it looks round,
turning 180-360 degrees on the spot. Each step's twist is chosen from the
    pose so far, and the pose follows by the mean pairing (:func:`integrate_mean_pairing`)."""
    half = np.asarray(config.room_size) / 2.0 - ROOM_MARGIN_M
    half = np.maximum(half, 0.25)
    accel, yaw_accel = ROOM_ACCEL[0] * dt, ROOM_ACCEL[1] * dt
    u = np.zeros((n, 6))
    poses = np.empty((n, 4, 4))
    poses[0] = np.eye(4)
    quadrant = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    lap_step, visited = 1, 0

    def next_waypoint(i: int) -> np.ndarray:  # a random point of quadrant i (mod 4)
        return quadrant[i % 4] * rng.uniform(0.2 * half, half)

    waypoint = next_waypoint(0)
    stop_left, spin_left = 0, 0.0
    v = w = 0.0
    for k in range(n - 1):
        pose = poses[k]
        if stop_left > 0:
            v_goal = w_goal = 0.0
            if v == 0.0 and w == 0.0:
                stop_left -= 1
        elif abs(spin_left) > 0.05:  # looking round on the spot
            v_goal = 0.0
            w_goal = float(np.sign(spin_left) * min(config.max_yaw_rate, 1.5 * abs(spin_left)))
            spin_left -= dt * w
        else:
            d = waypoint - pose[:2, 3]
            dist = float(np.hypot(d[0], d[1]))
            if dist < 0.3:
                visited += 1
                if visited % 4 == 0:  # a lap of the room done: the next goes either way round
                    lap_step = 1 if rng.random() < 0.5 else -1
                waypoint = next_waypoint(visited * lap_step)
                if rng.random() < config.stop_probability:
                    stop_left = int(rng.integers(int(round(1.0 / dt)), int(round(4.0 / dt)) + 1))
                if rng.random() < ROOM_LOOK_ROUND:
                    spin_left = float(rng.choice([-1.0, 1.0]) * rng.uniform(np.pi, 2.0 * np.pi))
                d = waypoint - pose[:2, 3]
                dist = float(np.hypot(d[0], d[1]))
            err = _wrap(np.arctan2(d[1], d[0]) - np.arctan2(pose[1, 0], pose[0, 0]))
            w_goal = float(np.clip(1.5 * err, -config.max_yaw_rate, config.max_yaw_rate))
            v_goal = config.speed_max * max(0.0, np.cos(err)) ** 2 * min(1.0, dist)
        v += float(np.clip(v_goal - v, -accel, accel))
        w += float(np.clip(w_goal - w, -yaw_accel, yaw_accel))
        u[k + 1, 0], u[k + 1, 5] = v, w
        poses[k + 1] = pose @ se3_exp(dt * 0.5 * (u[k] + u[k + 1]))
    return u, poses


def room_landmarks(config: SimConfig, rng, camera_z: float) -> np.ndarray:
    """``room_landmarks`` points (n, 3) on the room's four walls (uniform along them), within
    ROOM_LANDMARK_BAND_M of the camera's height ``camera_z``."""
    sx, sy = config.room_size
    n = config.room_landmarks
    s = rng.uniform(0.0, 2.0 * (sx + sy), n)  # along the walls, anticlockwise from (-x, -y)
    corner = np.array([[-sx / 2, -sy / 2], [sx / 2, -sy / 2], [sx / 2, sy / 2], [-sx / 2, sy / 2]])
    edge = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    ends = np.cumsum([sx, sy, sx, sy])
    wall = np.minimum(np.searchsorted(ends, s, side="right"), 3)
    along = s - np.r_[0.0, ends][wall]
    xy = corner[wall] + along[:, None] * edge[wall]
    z = camera_z + rng.uniform(-ROOM_LANDMARK_BAND_M, ROOM_LANDMARK_BAND_M, n)
    return np.column_stack([xy, z])


def loop_curvature(s: np.ndarray, lap: float) -> np.ndarray:
    """Curvature (1/m) at arc lengths ``s`` of a closed loop of length ``lap``: a rounded
    rectangle (sides 0.3 and 0.2 of the straight length, turning left), its corners of radius
    ``min(LOOP_MAX_RADIUS_M, lap / 4 pi)`` entered and left on linear ramps of a quarter radius.
    Each corner turns exactly pi/2 and the shape is symmetric, so the loop closes."""
    r = min(LOOP_MAX_RADIUS_M, lap / (4.0 * np.pi))
    ramp = r / 4.0
    plateau = np.pi * r / 2.0 - ramp
    corner = plateau + 2.0 * ramp
    straight = lap - 4.0 * corner
    sides = (0.3 * straight, 0.2 * straight, 0.3 * straight, 0.2 * straight)
    x = np.mod(s, lap)
    out = np.zeros_like(x)
    start = 0.0
    for side in sides:
        c = x - (start + side)  # position within the corner after this side
        inside = (c >= 0.0) & (c < corner)
        rise = np.clip(c / ramp, 0.0, 1.0)
        fall = np.clip((corner - c) / ramp, 0.0, 1.0)
        out = np.where(inside, np.minimum(rise, fall) / r, out)
        start += side + corner
    return out


def loop_drive(config: SimConfig, rng, t: np.ndarray, n_frames: int):
    """Twists (n, 6), poses (n, 4, 4), the lap's length (m) and the twists as a function of
    time (any times, for streams stamped off the camera's) of a car driving a flat closed
    loop (:func:`loop_curvature`) at a smooth random speed in ``[speed_min, speed_max]``: the
    lap is sized so that the first ``n_frames`` frames drive ``1 + loop_overlap`` laps, so the
    drive comes back to its start and drives the start again. Yaw rate is curvature times
    speed at the arc length the mean pairing gives."""
    span = float(t[-1]) + 1.0
    speed = smooth_profile(
        rng, span, config.knot_spacing_s, lambda n: rng.uniform(config.speed_min, config.speed_max, n)
    )
    v = speed(t)
    dt = np.diff(t)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
    lap = float(s[n_frames - 1]) / (1.0 + config.loop_overlap)
    u = np.zeros((t.size, 6))
    u[:, 0] = v
    u[:, 5] = loop_curvature(s, lap) * v

    def twists(tq: np.ndarray) -> np.ndarray:
        """The twists at any times: the arc length by the same trapezoid from the grid time
        before (the first or last grid time outside the grid), so the grid's own are u."""
        vq = speed(tq)
        k = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, t.size - 1)
        sq = s[k] + 0.5 * (v[k] + vq) * (tq - t[k])
        out = np.zeros((tq.size, 6))
        out[:, 0] = vq
        out[:, 5] = loop_curvature(sq, lap) * vq
        return out

    return u, integrate_mean_pairing(u, dt), lap, twists


def nearby_points(points: np.ndarray, positions: np.ndarray, radius: float):
    """``candidates(k)`` of :func:`observe_landmarks`: the points (sorted indices) within
    ``radius`` of ``positions[k]``."""

    def candidates(k: int) -> np.ndarray:
        d = points - positions[k]
        return np.flatnonzero(np.einsum("ij,ij->i", d, d) <= radius * radius)

    return candidates


# --------------------------------------------------------------------------- landmarks


def place_landmarks(
    config: SimConfig, rng, poses: np.ndarray, road_z: float
) -> tuple[np.ndarray, np.ndarray]:
    """Landmarks (N, 3) along both sides of the path of ``poses``, sorted by the arc length
    (N,) of the path point they stand beside (returned too). ``road_z``: height of the road
    relative to the IMU."""
    pos = poses[:, :3, 3]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])
    n = int(round(config.landmark_density * arc[-1]))
    s = np.sort(rng.uniform(0.0, arc[-1], n))
    # Fractional frame index of each arc length; positions and headings interpolated there.
    f = np.interp(s, arc, np.arange(arc.size))
    i0 = np.minimum(np.floor(f).astype(int), arc.size - 2)
    a = (f - i0)[:, None]
    base = (1 - a) * pos[i0] + a * pos[i0 + 1]
    forward = (1 - a) * poses[i0, :3, 0] + a * poses[i0 + 1, :3, 0]
    left = np.stack([-forward[:, 1], forward[:, 0], np.zeros(n)], axis=1)
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    kind = rng.random(n)
    far = kind < config.far_fraction
    ground = ~far & (kind < config.far_fraction + config.ground_fraction)
    side = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    lateral = np.select(
        [far, ground],
        [rng.uniform(20.0, 50.0, n), rng.uniform(1.0, 10.0, n)],
        rng.uniform(4.0, 20.0, n),
    ) * side
    above_road = np.select(
        [far, ground],
        [rng.uniform(0.0, 20.0, n), rng.uniform(0.0, 0.15, n)],
        rng.uniform(0.0, 10.0, n),
    )
    height = road_z + above_road
    return base + lateral[:, None] * left + height[:, None] * np.array([0.0, 0.0, 1.0]), s


# --------------------------------------------------------------------------- observations


def drifting_noise(white: np.ndarray, previous: np.ndarray, continuing: np.ndarray,
                   a: float) -> np.ndarray:
    """One frame's pixel errors (k, 4) from its white draws ``white`` (k, 4, already times
    pixel_sigma): ``a previous + sqrt(1 - a^2) white`` where a track ``continuing`` from the
    frame before (its error there ``previous``), ``white`` where a track starts (the AR(1)
    drift of the module docstring; ``a`` 0: ``white`` itself)."""
    if not a:
        return white
    out = white.copy()
    out[continuing] = a * previous[continuing] + np.sqrt(1.0 - a * a) * white[continuing]
    return out


def observe_landmarks(
    config: SimConfig, rng_tracks, rng_pixels, poses, points, point_arc, calib: Calibration,
    repeat_frames: np.ndarray | None = None, candidates=None, same_track: bool = False,
):
    """Run the tracker over the first ``len(poses)`` frames; at ``repeat_frames`` (bool per
    frame) every continuing track repeats its previous observation exactly.

    ``candidates(k)`` the indices (sorted) of the landmarks looked at in frame ``k``; None: those
    within WINDOW_M of path length (``point_arc``, the road). ``same_track``: a landmark seen
    again after its track ended continues that track (the same index: a tracker that recognises
    it), instead of starting a new one.

    Returns rows (frame, track, z) of the observations, the noise-free pixels of those rows,
    and the landmark of each track index.
    """
    M = calib.M
    width, height = KITTI_IMAGE_SIZE
    n_pts = points.shape[0]
    sigma = 0.0 if config.noise_free else config.pixel_sigma
    p_len = 1.0 / config.mean_track_length
    active = np.zeros(n_pts, dtype=bool)
    track_of = np.full(n_pts, -1, dtype=np.int64)
    last_z = np.zeros((n_pts, 4))
    last_error = np.zeros((n_pts, 4))  # each point's pixel error at its previous observation
    remaining = np.zeros(n_pts, dtype=np.int64)
    track_landmark: list[np.ndarray] = []
    next_id = 0
    rows_f, rows_t, rows_z, rows_z0 = [], [], [], []
    cam_T_world = calib.cam_T_imu @ se3_inv(poses)
    # Only landmarks placed within WINDOW_M of path length of the car are looked at (points
    # are sorted by arc length): this keeps the cost linear in the drive's length. A landmark
    # outside that window would have to be seen across a loop of the road; it counts as occluded.
    pos = poses[:, :3, 3]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])
    lo_all = np.searchsorted(point_arc, arc - WINDOW_M, side="left")
    hi_all = np.searchsorted(point_arc, arc + WINDOW_M, side="right")
    for k in range(poses.shape[0]):
        if candidates is None:
            lo, hi = int(lo_all[k]), int(hi_all[k])
            idx = np.arange(lo, hi)
        else:
            idx = candidates(k)
        q = points[idx] @ cam_T_world[k, :3, :3].T + cam_T_world[k, :3, 3]
        depth = q[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            z0 = project(M, homogeneous(q))  # paper eq. 1-3
            if config.radial_k1:
                z0 = distort_pixels(z0, calib.K, config.radial_k1)
        visible = (
            (depth >= config.min_depth)
            & (depth <= config.max_depth)
            & (z0[:, 0] <= width - 1 - BORDER_PX)
            & (z0[:, 2] >= BORDER_PX)
            & (z0[:, 1] >= BORDER_PX)
            & (z0[:, 1] <= height - 1 - BORDER_PX)
        )
        was_active = active[idx]
        keep = was_active & visible & (remaining[idx] > 0)
        p_detect = 1.0 if k == 0 else config.detect_probability
        # A track that ends now cannot restart now (ended tracks were active).
        start = ~was_active & visible & (rng_tracks.random(idx.size) < p_detect)
        local = np.flatnonzero(keep | start)
        error = drifting_noise(sigma * rng_pixels.standard_normal((local.size, 4)),
                               last_error[idx[local]], keep[local], config.pixel_correlation)
        z = z0[local] + error
        ok = z[:, 0] - z[:, 2] >= config.min_disparity
        local, z = local[ok], z[ok]
        seen = idx[local]
        error = error[ok]
        if repeat_frames is not None and repeat_frames[k]:
            again = keep[local]
            z[again] = last_z[seen[again]]
            error[again] = last_error[seen[again]]
        last_z[seen] = z
        last_error[seen] = error
        new = seen[start[local]]
        starting = new
        if same_track:  # a landmark with a track already continues it
            new = new[track_of[new] < 0]
        track_of[new] = next_id + np.arange(new.size)
        remaining[starting] = rng_tracks.geometric(p_len, starting.size)
        track_landmark.append(new)
        next_id += new.size
        # Every track not observed now has ended for good (also any left outside the window).
        active[:] = False
        active[seen] = True
        remaining[seen] -= 1
        rows_f.append(np.full(seen.size, k, dtype=np.int64))
        rows_t.append(track_of[seen])
        rows_z.append(z)
        rows_z0.append(z0[local])
    return (
        np.concatenate(rows_f),
        np.concatenate(rows_t),
        np.concatenate(rows_z),
        np.concatenate(rows_z0),
        np.concatenate(track_landmark),
    )


# --------------------------------------------------------------------------- velocities


def noise_sigma(value):
    """A sigma setting as the simulator multiplies it: the float itself (bit for bit what it
    always was) or three numbers (3,)."""
    return value if isinstance(value, float) else np.asarray(value, dtype=float)


def velocity_samples(u_all: np.ndarray, T: int, pairing: str) -> np.ndarray:
    """The noise-free velocity samples (T, 6) of instantaneous twists ``u_all`` (n > T, 6)
    under ``pairing`` (module docstring)."""
    if pairing == "mean":
        return u_all[:T]
    w = 0.5 * (u_all[:-1] + u_all[1:])  # the true twist of each interval
    if pairing == "current":
        return w[:T].copy()
    out = np.empty((T, 6))
    out[0] = u_all[0]
    out[1:] = w[: T - 1]
    return out


def interpolated_twists(t: np.ndarray, u: np.ndarray):
    """The twists of a drive made step by step (the room) at any times: linear between its
    samples ``u`` at times ``t`` (the platform's accelerations are constant over a step), the
    first and last sample held outside them."""

    def twists(tq: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(tq, t, u[:, j]) for j in range(u.shape[1])], axis=1)

    return twists


def offset_samples(u_all: np.ndarray, t_all: np.ndarray, twists, T: int, pairing: str,
                   velocity_offset: float, gyro_offset: float) -> np.ndarray:
    """The noise-free samples (T, 6) of streams stamped late by the offsets (s): the linear part
    of :func:`velocity_samples` of the motion at ``t_all - velocity_offset``, the angular part
    of that at ``t_all - gyro_offset`` (``twists(t)`` the motion at any times); a zero offset
    takes ``u_all`` itself, so the drive is the same to the byte."""
    out = velocity_samples(u_all, T, pairing).copy()
    n = T + 1  # the samples velocity_samples reads
    for cols, offset in ((slice(0, 3), velocity_offset), (slice(3, 6), gyro_offset)):
        if offset:
            shifted = twists(t_all[:n] - offset)
            out[:, cols] = velocity_samples(shifted, T, pairing)[:, cols]
    return out


def velocity_noise(config: SimConfig, rng_velocity, T: int) -> np.ndarray:
    """The errors (T, 6) added to the velocity samples: white (or, with
    ``velocity_correlation``, AR(1) along the drive) linear-velocity noise, then white gyro
    noise plus the constant gyro bias; zeros for a noise-free drive."""
    noise = np.zeros((T, 6))
    if not config.noise_free:
        white = rng_velocity.standard_normal((T, 3))
        if config.velocity_correlation:  # the drive as one track of AR(1) errors
            from vislam.graph.track_correlation import ar1_along_tracks

            white = ar1_along_tracks(np.arange(T), np.zeros(T, dtype=np.int64),
                                     config.velocity_correlation, white)
        noise[:, :3] = noise_sigma(config.velocity_sigma) * white
        noise[:, 3:] = noise_sigma(config.gyro_sigma) * rng_velocity.standard_normal((T, 3))
        noise[:, 3:] += np.asarray(config.gyro_bias)
    return noise
