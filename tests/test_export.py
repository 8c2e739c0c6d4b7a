"""TUM / KITTI trajectory files and reproducible npz archives."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_exp
from vislam.eval.export import (
    atomic_write,
    read_kitti,
    read_tum,
    save_npz_reproducible,
    write_kitti,
    write_tum,
)


def _poses(n=20, seed=0):
    rng = np.random.default_rng(seed)
    return se3_exp(rng.normal(0, [5, 5, 5, 1, 1, 1], (n, 6)))


def test_tum_round_trip(tmp_path):
    poses = _poses()
    t = 1317384506.40 + 0.1 * np.arange(poses.shape[0])
    path = write_tum(tmp_path / "sub" / "traj.txt", t, poses)
    lines = path.read_text().splitlines()
    assert len(lines) == poses.shape[0] and len(lines[0].split()) == 8
    t2, poses2 = read_tum(path)
    np.testing.assert_array_equal(t2, t)
    np.testing.assert_allclose(poses2, poses, atol=1e-12)
    # Quaternion order x, y, z, w (scalar last): the identity is 0 0 0 1.
    write_tum(tmp_path / "id.txt", [0.0], np.eye(4)[None])
    assert [float(x) for x in (tmp_path / "id.txt").read_text().split()][4:] == [0, 0, 0, 1]


def test_tum_readable_by_evo(tmp_path):
    from evo.tools import file_interface

    poses = _poses()
    t = np.arange(poses.shape[0]) * 0.1
    write_tum(tmp_path / "traj.tum", t, poses)
    traj = file_interface.read_tum_trajectory_file(str(tmp_path / "traj.tum"))
    np.testing.assert_allclose(np.array(traj.poses_se3), poses, atol=1e-12)


def test_kitti_round_trip(tmp_path):
    poses = _poses()
    path = write_kitti(tmp_path / "traj.txt", poses)
    rows = np.loadtxt(path)
    assert rows.shape == (poses.shape[0], 12)
    np.testing.assert_array_equal(rows[:, :4], poses[:, 0, :4])  # row-major, exact digits
    np.testing.assert_array_equal(read_kitti(path), poses)


def test_writers_reject_bad_input(tmp_path):
    with pytest.raises(InputError, match="shape"):
        write_kitti(tmp_path / "x.txt", np.eye(4))
    with pytest.raises(InputError, match="timestamps"):
        write_tum(tmp_path / "x.txt", [0.0, 1.0], _poses(3))
    (tmp_path / "bad.txt").write_text("1 2 3\n")
    with pytest.raises(InputError, match="12 columns"):
        read_kitti(tmp_path / "bad.txt")
    assert not (tmp_path / "x.txt").exists()


def test_atomic_write_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")

    def failing(fh):
        fh.write(b"partial")
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError):
        atomic_write(target, failing)
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_reproducible_npz_has_fixed_member_times_and_loads(tmp_path):
    arrays = {"a": np.arange(10.0), "b": np.array(0.5), "c": -np.ones((4, 3, 2))}
    p1 = save_npz_reproducible(tmp_path / "one.npz", arrays)
    p2 = save_npz_reproducible(tmp_path / "two.npz", arrays)
    assert p1.read_bytes() == p2.read_bytes()
    with zipfile.ZipFile(p1) as zf:
        assert [i.date_time for i in zf.infolist()] == [(1980, 1, 1, 0, 0, 0)] * 3
        assert [i.filename for i in zf.infolist()] == ["a.npy", "b.npy", "c.npy"]
    with np.load(p1) as d:
        for k, v in arrays.items():
            np.testing.assert_array_equal(d[k], v)
            assert d[k].shape == v.shape
