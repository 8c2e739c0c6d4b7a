"""Readers of raw-IMU drives (issue 37): ASL folders with a track file, gtsam's eqvio csv, and
time-stamped ground truth. Small files made here; every fault is one InputError naming the
file and the line (and column where there is one); random damage never raises anything else."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_inv
from vislam.eval.asl import read_asl_folder
from vislam.eval.eqvio import COLUMNS, read_eqvio_drive, read_eqvio_tracks
from vislam.eval.trajectory_files import TimedTrajectory, read_trajectory, write_trajectory

T0 = 1403715273262142976
STEP = 5_000_000  # 200 Hz
N_IMU = 120
FRAME_EVERY = 10  # 20 Hz

IMU_YAML = """%YAML:1.0
sensor_type: imu
T_BS:
  cols: 4
  rows: 4
  data: [1.0, 0.0, 0.0, 0.0,
         0.0, 1.0, 0.0, 0.0,
         0.0, 0.0, 1.0, 0.0,
         0.0, 0.0, 0.0, 1.0]
rate_hz: 200
gyroscope_noise_density: 1.6968e-04
gyroscope_random_walk: 1.9393e-05
accelerometer_noise_density: 2.0000e-3
accelerometer_random_walk: 3.0000e-3
"""

CAM_YAML = """%YAML:1.0
sensor_type: camera
T_BS:
  cols: 4
  rows: 4
  data: [0.0, -1.0, 0.0, {tx},
         1.0, 0.0, 0.0, -0.06,
         0.0, 0.0, 1.0, 0.01,
         0.0, 0.0, 0.0, 1.0]
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375]
distortion_model: radial-tangential
distortion_coefficients: [-0.28, 0.07, 0.0002, 1.8e-05]
"""


def imu_rows(n: int = N_IMU) -> list[str]:
    rng = np.random.default_rng(0)
    rows = []
    for i in range(n):
        w = rng.normal(0, 0.01, 3)
        a = np.array([9.81, 0.1, -0.2]) + rng.normal(0, 0.02, 3)
        rows.append(",".join([str(T0 + i * STEP)] + [repr(float(x)) for x in (*w, *a)]))
    return rows


def track_rows(stereo: bool = False) -> list[str]:
    rows = []
    for f in range(1, N_IMU // FRAME_EVERY - 1):
        stamp = T0 + f * FRAME_EVERY * STEP
        for track in range(5):
            uv = [100.0 + 10 * track + f, 200.0 - track]
            if stereo:
                uv += [uv[0] - 20.0, uv[1]]
            rows.append(",".join([str(stamp), str(track)] + [repr(x) for x in uv]))
    return rows


def write_asl(root: Path, imu: list[str] | None = None, tracks: list[str] | None = None,
              imu_yaml: str = IMU_YAML, cam_yaml: str = CAM_YAML.format(tx=-0.02),
              cam1_yaml: str | None = None) -> tuple[Path, Path]:
    mav = root / "mav0"
    (mav / "imu0").mkdir(parents=True, exist_ok=True)
    (mav / "cam0").mkdir(exist_ok=True)
    (mav / "imu0" / "data.csv").write_text(
        "#timestamp [ns],w_RS_S_x,w_RS_S_y,w_RS_S_z,a_RS_S_x,a_RS_S_y,a_RS_S_z\n"
        + "\n".join(imu_rows() if imu is None else imu) + "\n")
    (mav / "imu0" / "sensor.yaml").write_text(imu_yaml)
    (mav / "cam0" / "sensor.yaml").write_text(cam_yaml)
    if cam1_yaml is not None:
        (mav / "cam1").mkdir(exist_ok=True)
        (mav / "cam1" / "sensor.yaml").write_text(cam1_yaml)
    track_file = root / "tracks.csv"
    track_file.write_text("#timestamp [ns],track,u,v\n"
                          + "\n".join(track_rows() if tracks is None else tracks) + "\n")
    return root, track_file


def assert_input_error(call, *fragments: str) -> str:
    with pytest.raises(InputError) as info:
        call()
    message = str(info.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message, (fragment, message)
    return message


# --- ASL folders ----------------------------------------------------------------------------


def test_asl_folder_reads_imu_calibration_and_tracks(tmp_path):
    root, tracks = write_asl(tmp_path)
    drive = read_asl_folder(root, tracks)
    n_frames = N_IMU // FRAME_EVERY - 2
    # the IMU cut to the frames' span (frames 1..n at every 10th sample), time 0 at the first frame
    assert drive.imu.time.size == (n_frames - 1) * FRAME_EVERY + 1
    assert drive.time_origin_ns == T0 + FRAME_EVERY * STEP
    np.testing.assert_allclose(np.diff(drive.imu.time), STEP * 1e-9)
    assert drive.n_frames == n_frames and drive.n_tracks == 5
    assert drive.obs.z.shape == (len(track_rows()), 2) and not drive.stereo
    np.testing.assert_allclose(drive.timestamps, np.arange(n_frames) * 0.05, atol=1e-12)
    body_T_cam = np.array([[0, -1, 0, -0.02], [1, 0, 0, -0.06], [0, 0, 1, 0.01], [0, 0, 0, 1.0]])
    np.testing.assert_allclose(drive.calibration.cam_T_imu, se3_inv(body_T_cam))
    assert drive.calibration.distortion_model == "radtan"
    assert drive.calibration.noise.accel_noise_density == 2.0e-3
    assert drive.calibration.noise.accel_random_walk == 3.0e-3
    # rows of a frame sorted by track, pixels kept
    tracks_f0, z_f0 = drive.obs.frame(0)
    assert list(tracks_f0) == [0, 1, 2, 3, 4]
    np.testing.assert_allclose(z_f0[1], [111.0, 199.0])


def test_asl_stereo_needs_a_rectified_pair(tmp_path):
    stereo = track_rows(stereo=True)
    rectified = CAM_YAML.format(tx=0.09).replace("0.0, -1.0, 0.0, 0.09", "0.0, -1.0, 0.0, -0.02") \
        .replace("1.0, 0.0, 0.0, -0.06", "1.0, 0.0, 0.0, 0.05")
    root, tracks = write_asl(tmp_path, tracks=stereo, cam1_yaml=rectified)
    drive = read_asl_folder(root, tracks)
    assert drive.stereo and drive.calibration.baseline == pytest.approx(0.11)
    rotated = CAM_YAML.format(tx=0.09).replace("0.0, -1.0, 0.0", "0.0, 1.0, 0.0", 1) \
        .replace("1.0, 0.0, 0.0, -0.06", "-1.0, 0.0, 0.0, -0.06")
    root2, tracks2 = write_asl(tmp_path / "b", tracks=stereo, cam1_yaml=rotated)
    assert_input_error(lambda: read_asl_folder(root2, tracks2), "cam1", "rectified pair")
    root3, tracks3 = write_asl(tmp_path / "c", tracks=stereo)
    assert_input_error(lambda: read_asl_folder(root3, tracks3), "tracks.csv", "cam1/sensor.yaml")


def _imu_with(edit) -> list[str]:
    rows = imu_rows()
    edit(rows)
    return rows


IMU_FAULTS = [
    ("duplicate stamp", lambda r: r.__setitem__(5, r[4].split(",", 1)[0] + "," + r[5].split(",", 1)[1]), ("line 7", "duplicates the one on line 6",)),
    ("step back", lambda r: r.__setitem__(5, str(T0) + "," + r[5].split(",", 1)[1]), ("line 7", "earlier than",)),
    ("gap", lambda r: r.__delitem__(slice(40, 60)), ("line 42", "gap of 0.105 s",)),
    ("non-numeric", lambda r: r.__setitem__(3, r[3].replace(",", ",x", 1)), ("line 5, column 2", "non-numeric",)),
    ("nan", lambda r: r.__setitem__(3, r[3].rsplit(",", 1)[0] + ",nan"), ("line 5, column 7", "not a finite number",)),
    ("columns", lambda r: r.__setitem__(8, r[8] + ",1.0"), ("line 10 has 8 columns",)),
    ("fractional stamp", lambda r: r.__setitem__(2, "1403715273.5," + r[2].split(",", 1)[1]), ("line 4, column 1", "not an integer",)),
]


@pytest.mark.parametrize("name, edit, fragments", IMU_FAULTS, ids=[f[0] for f in IMU_FAULTS])
def test_imu_csv_faults_name_line_and_column(tmp_path, name, edit, fragments):
    root, tracks = write_asl(tmp_path, imu=_imu_with(edit))
    assert_input_error(lambda: read_asl_folder(root, tracks), "imu0/data.csv", *fragments)


TRACK_FAULTS = [
    ("outside the IMU", lambda r: r.append(f"{T0 + (N_IMU + 3) * STEP},0,1.0,2.0"), ("outside the IMU's span",)),
    ("twice", lambda r: r.append(r[0]), ("observed twice at the same frame",)),
    ("negative id", lambda r: r.__setitem__(0, r[0].replace(",0,", ",-3,", 1)), ("line 2, column 2", "negative track id",)),
    ("columns", lambda r: r.__setitem__(2, r[2] + ",5"), ("line 4 has 5 columns",)),
]


@pytest.mark.parametrize("name, edit, fragments", TRACK_FAULTS, ids=[f[0] for f in TRACK_FAULTS])
def test_track_csv_faults(tmp_path, name, edit, fragments):
    rows = track_rows()
    edit(rows)
    root, tracks = write_asl(tmp_path, tracks=rows)
    assert_input_error(lambda: read_asl_folder(root, tracks), "tracks.csv", *fragments)


YAML_FAULTS = [
    ("imu", lambda y: y.replace("gyroscope_random_walk: 1.9393e-05\n", ""), ("imu0/sensor.yaml", "missing key 'gyroscope_random_walk'",)),
    ("imu", lambda y: y.replace("accelerometer_random_walk: 3.0000e-3", "accelerometer_random_walk: -1"), ("imu0/sensor.yaml", "expected a positive number",)),
    ("imu", lambda y: y.replace("0.0, 1.0, 0.0, 0.0,", "0.0, 2.0, 0.0, 0.0,"), ("imu0/sensor.yaml", "'T_BS' is not a rigid transform",)),
    ("imu", lambda y: y.replace("rate_hz: 200", "rate_hz: [200"), ("imu0/sensor.yaml", "not readable YAML",)),
    ("cam", lambda y: y.replace("intrinsics: [458.654, 457.296, 367.215, 248.375]", "intrinsics: [1, 2]"), ("cam0/sensor.yaml", "'intrinsics' has 2 value(s)",)),
    ("cam", lambda y: y.replace("radial-tangential", "fov"), ("cam0/sensor.yaml", "'distortion_model' is 'fov'",)),
    ("cam", lambda y: y.replace("pinhole", "omni"), ("cam0/sensor.yaml", "only 'pinhole'",)),
]


@pytest.mark.parametrize("which, edit, fragments", YAML_FAULTS)
def test_sensor_yaml_faults_name_the_key(tmp_path, which, edit, fragments):
    if which == "imu":
        root, tracks = write_asl(tmp_path, imu_yaml=edit(IMU_YAML))
    else:
        root, tracks = write_asl(tmp_path, cam_yaml=edit(CAM_YAML.format(tx=-0.02)))
    assert_input_error(lambda: read_asl_folder(root, tracks), *fragments)


def test_not_an_asl_folder_and_no_tracks(tmp_path):
    assert_input_error(lambda: read_asl_folder(tmp_path, None), "not an ASL folder")
    root, _ = write_asl(tmp_path / "x")
    assert_input_error(lambda: read_asl_folder(root, None), "--tracks")


# --- gtsam's eqvio csv ----------------------------------------------------------------------


def test_packaged_eqvio_drive():
    drive = read_eqvio_drive("eqvio")
    assert drive.n_frames == 601 and drive.imu.time.size == 6001
    assert len(drive.obs) == 13316 and drive.n_tracks == 307 and not drive.stereo
    assert drive.imu_rate == pytest.approx(200.0, rel=1e-3)
    assert np.all(np.diff(drive.timestamps) > 0) and drive.timestamps[-1] <= drive.imu.time[-1]
    # pixels of the ideal pinhole: inside EuRoC's 752 x 480 image, give or take the undistortion
    assert np.all(np.abs(drive.obs.z[:, 0] - 376) < 600) and np.all(np.abs(drive.obs.z[:, 1] - 240) < 500)
    frames, _, ids, z, K = read_eqvio_tracks("eqvio")
    assert frames.size == 601 and K[0, 0] == pytest.approx(458.654)


def eqvio_text(meta_edit=None, extra: list[str] = ()) -> str:
    blank = [""] * len(COLUMNS)

    def row(**kw):
        r = list(blank)
        for k, v in kw.items():
            r[COLUMNS.index(k)] = str(v)
        return ",".join(r)

    meta = {"camera_fx": 400, "camera_fy": 400, "camera_cx": 300, "camera_cy": 200, "T_ci_tx": 0.1,
            "T_ci_ty": 0, "T_ci_tz": 0, "T_ci_qw": 1, "T_ci_qx": 0, "T_ci_qy": 0, "T_ci_qz": 0}
    if meta_edit:
        meta_edit(meta)
    lines = [",".join(COLUMNS)] + [row(row_type="meta", key=k, value=v) for k, v in meta.items()]
    for i in range(30):
        lines.append(row(row_type="imu", t_abs=f"100.{i * 5:03d}", gx=0.01, gy=0, gz=0, ax=0, ay=0, az=9.8))
    for f in range(1, 5):
        for lm in range(3):
            lines.append(row(row_type="vision_feature", t_abs=f"100.{f * 25:03d}", frame_idx=f - 1,
                             landmark_id=lm, u_norm=0.1 * lm, v_norm=-0.05))
    return "\n".join(lines + list(extra)) + "\n"


def test_small_eqvio_reads_with_pixels_of_its_camera(tmp_path):
    path = tmp_path / "e.csv"
    path.write_text(eqvio_text())
    drive = read_eqvio_drive(path)
    assert drive.n_frames == 4 and drive.n_tracks == 3
    np.testing.assert_allclose(drive.obs.frame(0)[1][2], [300 + 400 * 0.2, 200 - 400 * 0.05])
    np.testing.assert_allclose(drive.timestamps, [0.025, 0.05, 0.075, 0.1])
    np.testing.assert_allclose(drive.calibration.cam_T_imu[:3, 3], [-0.1, 0, 0])


@pytest.mark.parametrize("text_edit, fragments", [
    (lambda t: t.replace("row_type", "kind", 1), ("line 1", "not the eqvio csv header")),
    (lambda t: t.replace("meta,", "metadata,", 1), ("line 2, column row_type", "unknown row type")),
    (lambda t: t.replace("100.010", "1e2", 1), ("column t_abs", "not a time in seconds")),
    (lambda t: t.replace("imu,100.010", "imu,100.005", 1), ("duplicates the one",)),
    (lambda t: t.replace(",9.8,", ",inf,", 1), ("column az", "not finite")),
], ids=["header", "row type", "stamp", "duplicate", "inf"])
def test_eqvio_faults(tmp_path, text_edit, fragments):
    path = tmp_path / "e.csv"
    path.write_text(text_edit(eqvio_text()))
    assert_input_error(lambda: read_eqvio_drive(path), "e.csv", *fragments)


def test_eqvio_missing_meta_and_frames_outside(tmp_path):
    path = tmp_path / "e.csv"
    path.write_text(eqvio_text(lambda m: m.pop("camera_cy")))
    assert_input_error(lambda: read_eqvio_drive(path), "no meta row for key 'camera_cy'")
    late = ",".join(["vision_feature", "101.000", "", "", "4", "0"] + [""] * 12 + ["0.1", "0.1", "", ""])
    path.write_text(eqvio_text(extra=[late]))
    assert_input_error(lambda: read_eqvio_drive(path), "outside the IMU's span")


# --- ground truth ---------------------------------------------------------------------------


def test_trajectory_round_trip_with_state(tmp_path):
    rng = np.random.default_rng(3)
    from scipy.spatial.transform import Rotation

    n = 7
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, 1, (n, 3))).as_matrix()
    poses[:, :3, 3] = rng.normal(0, 5, (n, 3))
    times = 1403715273.0 + 0.05 * np.arange(n)
    state = rng.normal(0, 1, (n, 9))
    path = tmp_path / "gt.csv"
    write_trajectory(path, TimedTrajectory(times, poses, "x", "asl", state))
    back = read_trajectory(path)
    assert back.form == "asl"
    np.testing.assert_allclose(back.poses, poses, atol=1e-12)
    np.testing.assert_allclose(back.times, times, atol=1e-6)
    np.testing.assert_allclose(back.velocity, state[:, :3])
    np.testing.assert_allclose(back.accel_bias, state[:, 6:])
    np.testing.assert_allclose(back.between(times[2], times[4]).times, times[2:5])
    tum = tmp_path / "gt.txt"
    q = Rotation.from_matrix(poses[:, :3, :3]).as_quat()
    tum.write_text("\n".join(" ".join(repr(float(x)) for x in (t, *p[:3, 3], *qq))
                             for t, p, qq in zip(times, poses, q)) + "\n")
    back = read_trajectory(tum)
    assert back.form == "tum" and back.state is None
    np.testing.assert_allclose(back.poses, poses, atol=1e-12)


def test_trajectory_faults(tmp_path):
    path = tmp_path / "gt.csv"
    path.write_text("#time(ns),px,py,pz,qw,qx,qy,qz\n1,0,0,0,1,0,0,0\n2,0,0,0,2,0,0,0\n")
    assert_input_error(lambda: read_trajectory(path), "gt.csv", "line 3")
    path.write_text("")
    assert_input_error(lambda: read_trajectory(path), "gt.csv", "no pose lines")


# --- random damage --------------------------------------------------------------------------


def _mutate(text: str, data) -> str:
    ops = data.draw(st.lists(st.tuples(st.integers(0, max(len(text) - 1, 0)),
                                       st.sampled_from(["drop", "insert", "replace", "cut"]),
                                       st.sampled_from(list(",.-e0123456789\n #nanif\x00é"))),
                             min_size=1, max_size=4))
    for pos, op, ch in ops:
        if op == "drop":
            text = text[:pos] + text[pos + 1:]
        elif op == "insert":
            text = text[:pos] + ch + text[pos:]
        elif op == "replace":
            text = text[:pos] + ch + text[pos + 1:]
        else:
            text = text[:pos]
    return text


@given(data=st.data())
def test_damaged_asl_files_raise_input_error_or_read(tmp_path_factory, data):
    root, tracks = write_asl(tmp_path_factory.mktemp("asl"))
    target = data.draw(st.sampled_from([root / "mav0/imu0/data.csv", tracks, root / "mav0/imu0/sensor.yaml",
                                        root / "mav0/cam0/sensor.yaml"]))
    target.write_text(_mutate(target.read_text(), data), encoding="utf-8", errors="surrogateescape")
    try:
        drive = read_asl_folder(root, tracks)
    except InputError as exc:
        message = str(exc)
        assert "\n" not in message and re.search(r"(data\.csv|tracks\.csv|sensor\.yaml|mav0)", message)
    else:
        assert np.all(np.isfinite(drive.imu.gyro)) and np.all(np.diff(drive.imu.time) > 0)


@given(data=st.data())
def test_damaged_eqvio_and_trajectories_raise_input_error_or_read(tmp_path_factory, data):
    folder = tmp_path_factory.mktemp("eq")
    path = folder / "e.csv"
    path.write_text(_mutate(eqvio_text(), data))
    try:
        read_eqvio_drive(path)
    except InputError as exc:
        assert "\n" not in str(exc) and "e.csv" in str(exc)
    gt = folder / "gt.csv"
    gt.write_text(_mutate("#time(ns),px,py,pz,qw,qx,qy,qz\n1,0,0,0,1,0,0,0\n2,1,0,0,1,0,0,0\n", data))
    try:
        read_trajectory(gt)
    except InputError as exc:
        assert "\n" not in str(exc) and "gt.csv" in str(exc)
