"""Every benchmark figure is written (Agg, no display) as a non-empty PNG."""

from __future__ import annotations

import numpy as np
import pytest

from vislam.ekf.estimate import Estimate
from vislam.ekf.geometry import se3_exp
from vislam.eval import plots, plots_top_view

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _est(name: str, T: int = 80, M: int = 30, noise: float = 0.0, seed: int = 0) -> Estimate:
    rng = np.random.default_rng(seed)
    est = Estimate.empty(name, np.arange(T) * 0.1, M)
    twist = np.array([1.0, 0, 0, 0, 0, 0.02])
    est.poses = se3_exp(np.arange(T)[:, None] * twist + noise * rng.normal(size=(T, 6)))
    est.pose_cov = np.tile(np.diag([0.01, 0.02, 0.005, 1e-4, 1e-4, 1e-4]), (T, 1, 1))
    est.landmarks = rng.uniform(-20, 80, (M, 3))
    est.landmarks[:3] = np.nan
    est.landmark_cov = np.tile(np.eye(3), (M, 1, 1))
    return est


def _check_png(path):
    data = path.read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 5000, path
    assert not list(path.parent.glob(".*.tmp")), "temporary files left behind"


@pytest.fixture
def ests():
    return {
        "dead-reckoning": _est("dead-reckoning", noise=0.05, seed=1),
        "ekf-joint": _est("ekf-joint", noise=0.01, seed=2),
        "smoother": _est("smoother"),
    }


def test_all_figures_are_written(tmp_path, ests):
    truth = ests["smoother"].poses
    gt_pos = truth[:, :3, 3]
    _check_png(plots_top_view.plot_trajectories(tmp_path / "traj.png", ests, gt_pos, "test"))
    _check_png(plots_top_view.plot_map(tmp_path / "map.png", ests["ekf-joint"], gt_pos, ests["smoother"].landmarks))
    _check_png(plots.plot_error_over_distance(tmp_path / "err.png", ests, np.arange(70), truth[:70]))
    ekfs = {"ekf-joint": ests["ekf-joint"], "ekf-decoupled": _est("ekf-decoupled", noise=0.02)}
    _check_png(plots.plot_vs_smoother(tmp_path / "vs.png", ekfs, ests["smoother"]))
    rng = np.random.default_rng(0)
    series = {"ekf-joint": rng.chisquare(6, 80), "smoother": np.r_[np.nan, rng.chisquare(6, 79)]}
    _check_png(plots.plot_nees(tmp_path / "nees.png", series, dof=6, n_runs=1))
    _check_png(plots.plot_nees(tmp_path / "anees.png", series, dof=6, n_runs=20,
                               times=np.arange(80) * 0.1))


def test_figures_without_ground_truth_or_landmarks(tmp_path, ests):
    bare = _est("dead-reckoning")
    bare.landmarks[:] = np.nan
    _check_png(plots_top_view.plot_trajectories(tmp_path / "t.png", {"dead-reckoning": bare}))
    _check_png(plots_top_view.plot_map(tmp_path / "m.png", bare))
    _check_png(plots.plot_vs_smoother(tmp_path / "v.png", {}, ests["smoother"]))


def test_distance_travelled():
    p = np.array([[0, 0, 0], [3, 4, 0], [3, 4, 2.0]])
    assert np.allclose(plots.distance_travelled(p), [0, 5, 7])


@pytest.fixture
def figures(monkeypatch):
    """The Figure objects the plot functions save, in order (they are still written)."""
    seen = []
    save = plots.save_figure

    def capture(fig, path):
        seen.append(fig)
        return save(fig, path)

    monkeypatch.setattr(plots, "save_figure", capture)
    return seen


def _legend_texts(fig):
    return [t.get_text() for legend in fig.legends for t in legend.get_texts()]


def test_coinciding_estimators_stay_distinguishable(tmp_path, figures):
    """Pairs that draw the same curve get other line styles, widths, markers and marker
    offsets, and the legend says they coincide."""
    for a, b in (("dead-reckoning", "mapping"), ("ekf-joint", "ekf-invariant")):
        sa, sb = plots.line_style(a), plots.line_style(b)
        for key in ("color", "linestyle", "marker", "markevery"):
            assert sa[key] != sb[key], (a, b, key)
        assert sa["linewidth"] > sb["linewidth"] and sa["zorder"] < sb["zorder"], (a, b)
    unknown = [plots.line_style(f"x{i}", i) for i in range(3)]
    assert len({(s["linestyle"], s["marker"]) for s in unknown}) == 3

    same = _est("ekf-joint", noise=0.01, seed=2)
    twin = _est("ekf-invariant", noise=0.01, seed=2)
    other = _est("ekf-decoupled", noise=0.05, seed=3)
    ests = {"ekf-joint": same, "ekf-invariant": twin, "ekf-decoupled": other}
    assert plots.coincident({n: e.positions for n, e in ests.items()}) == {
        "ekf-joint": ["ekf-invariant"], "ekf-invariant": ["ekf-joint"], "ekf-decoupled": []}
    gt = _est("smoother").poses
    plots_top_view.plot_trajectories(tmp_path / "t.png", ests, gt[:, :3, 3])
    plots.plot_error_over_distance(tmp_path / "e.png", ests, np.arange(80), gt)
    for fig in figures:
        texts = _legend_texts(fig)
        assert "ekf-joint (same curve as ekf-invariant)" in texts, texts
        assert "ekf-decoupled" in texts
        lines = {line.get_label(): line for line in fig.axes[0].get_lines()}
        assert lines["ekf-joint (same curve as ekf-invariant)"].get_marker() != \
            lines["ekf-invariant (same curve as ekf-joint)"].get_marker()


def test_nees_puts_wild_estimators_apart_with_readable_means(tmp_path, figures):
    rng = np.random.default_rng(1)
    series = {"ekf-joint": rng.chisquare(6, 80), "ekf-invariant": rng.chisquare(6, 80),
              "ekf-decoupled": np.full(80, 2.0461224441e10)}
    _check_png(plots.plot_nees(tmp_path / "n.png", series, dof=6, times=np.arange(80) * 0.1,
                               ylabel="pose NEES vs ground truth (6 dof)"))
    fig = figures[-1]
    main, apart = fig.axes
    assert main.get_ylim() == pytest.approx((0.1, 1000.0))
    assert main.get_ylabel() == "pose NEES (6 dof)"
    assert [line.get_label() for line in apart.get_lines()][-1].startswith("ekf-decoupled")
    texts = _legend_texts(fig)
    assert "ekf-decoupled (mean 2.0e10, own panel below)" in texts, texts
    assert not any("20461224441" in t for t in texts)
    assert fig.legends[0].get_title().get_text() == "pose NEES vs ground truth (6 dof)"
    assert any("ekf-decoupled (mean 2.0e10)" in t.get_text() for t in main.texts)
    # Nothing wild: one panel, on the same axis.
    plots.plot_nees(tmp_path / "m.png", {"ekf-joint": series["ekf-joint"]}, dof=6)
    assert len(figures[-1].axes) == 1 and figures[-1].axes[0].get_ylim() == pytest.approx((0.1, 1000))


def test_readable_numbers():
    assert plots.readable(20461224441.08) == "2.0e10"
    assert plots.readable(5.1234) == "5.12"
    assert plots.readable(0.001) == "1.0e-3"
    assert plots.readable(None) == "n/a" and plots.readable(float("nan")) == "n/a"


def test_vs_smoother_drops_invisible_bands_and_clips_huge_ones(tmp_path, figures):
    smoother = _est("smoother")
    narrow = _est("ekf-decoupled", noise=0.05, seed=4)
    narrow.pose_cov = np.tile(np.eye(6) * 1e-12, (80, 1, 1))
    wide = _est("ekf-joint", noise=0.01, seed=5)
    wide.pose_cov = np.tile(np.eye(6) * 1e4, (80, 1, 1))
    plots.plot_vs_smoother(tmp_path / "v.png", {"ekf-decoupled": narrow, "ekf-joint": wide}, smoother)
    fig = figures[-1]
    axes = np.array(fig.axes).reshape(3, 2)
    for ax in axes[:, 0]:
        assert not ax.collections, "a band with no visible width is drawn"
        assert any("too narrow to draw" in t.get_text() for t in ax.texts)
    dev = np.abs(wide.positions - smoother.positions).max(axis=0)
    for r, ax in enumerate(axes[:, 1]):
        assert ax.collections, "the band is drawn"
        assert ax.get_ylim()[1] < 2 * dev[r] + 0.01, "the y range follows the deviation"
        assert any("±3σ clipped (up to 300 m)" in t.get_text() for t in ax.texts)


def test_map_says_what_it_leaves_out(tmp_path, figures):
    est = _est("ekf-joint")
    est.landmarks[3] = [5000.0, 0.0, 0.0]  # far off the drive
    truth = est.landmarks + 0.1
    plots_top_view.plot_map(tmp_path / "m.png", est, truth_landmarks=truth)
    ax = figures[-1].axes[0]
    title = ax.get_title().replace("\n", " ")
    assert "26 of 27 estimated landmarks shown" in title, title
    assert "1 more than 60 m outside the trajectory's extent" in title
    assert "3 tracks without a finite landmark" in title
    estimates, truths = ax.collections
    assert truths.get_zorder() > estimates.get_zorder(), "truth drawn on top"
    assert len(truths.get_facecolors()) == 0 or truths.get_facecolors()[0][3] == 0, "hollow"


def test_a_drifting_estimate_runs_off_the_top_view_and_says_how_far(tmp_path, figures):
    """Dead reckoning on a raw IMU drifts tens of metres in a 30 s room flight: the view keeps
    to the truth and the estimates near it, and the drifting one's legend says how far it goes;
    the axes name the raw-IMU world (gravity-aligned, not forward/left at start)."""
    near = _est("smoother-imu", T=80)
    drift = _est("dead-reckoning-imu", T=80)
    drift.poses = drift.poses.copy()
    drift.poses[:, 1, 3] -= np.linspace(0, 300.0, 80)  # 300 m off a 7.9 m path
    truth = near.poses[:, :3, 3]
    plots_top_view.plot_trajectories(tmp_path / "t.png", {"dead-reckoning-imu": drift, "smoother-imu": near},
                            truth, world="raw-imu")
    ax = figures[-1].axes[0]
    assert ax.get_xlabel() == plots_top_view.WORLD_AXES["raw-imu"][0]
    assert ax.get_ylim()[0] > -20.0  # the 300 m drift does not set the view
    texts = _legend_texts(figures[-1])
    drifting = [t for t in texts if t.startswith("dead-reckoning-imu")]
    assert drifting and "off the view, up to" in drifting[0], texts
    assert "smoother-imu" in texts
    # without ground truth, the estimate of the median extent anchors the view
    plots_top_view.plot_trajectories(tmp_path / "u.png", {"dead-reckoning-imu": drift, "smoother-imu": near})
    assert figures[-1].axes[0].get_ylim()[0] > -20.0
    assert figures[-1].axes[0].get_xlabel() == plots_top_view.WORLD_AXES["velocity"][0]
    # estimates that stay near each other all stay in view
    plots_top_view.plot_trajectories(tmp_path / "v.png", {"smoother-imu": near, "ekf": _est("ekf", noise=0.01)},
                            truth)
    assert not any("off the view" in t for t in _legend_texts(figures[-1]))
