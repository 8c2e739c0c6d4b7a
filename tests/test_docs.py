"""The documentation against the code: the generated configuration reference is current, the
command-line page names every flag, the README stays short and its drive sketch runs."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from vislam.eval.cli import COMMANDS, build_parser
from vislam.eval.config_reference import REGENERATE, configuration_markdown
from vislam.eval.registry import ESTIMATOR_NAMES

REPO = Path(__file__).resolve().parent.parent
DOCS = REPO / "docs"


def _text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def test_configuration_reference_is_generated_from_the_code():
    assert _text(DOCS / "configuration.md") == configuration_markdown(), (
        f"docs/configuration.md differs from the settings' definitions; run `{REGENERATE}`")


def test_readme_is_short_and_in_the_users_order():
    text = _text(REPO / "README.md")
    assert len(text.splitlines()) <= 150
    headings = re.findall(r"^## (.+)$", text, flags=re.M)
    order = ["What a results folder holds", "Your own drive", "Your own estimator", "Commands"]
    assert [h for h in headings if h in order] == order, headings
    assert "../shared" not in text  # the data is third-party: docs/findings.md says where
    assert ".venv/bin/python -m pytest -q -m regression" in text


def test_links_between_the_docs_resolve():
    for page in [REPO / "README.md", *DOCS.glob("*.md")]:
        for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", _text(page)):
            if "://" not in target:
                assert (page.parent / target).exists(), f"{page.name}: link to {target}"


def _subparsers():
    parser = build_parser()
    (sub,) = [a for a in parser._actions if a.dest == "command"]
    return sub.choices


def test_cli_page_names_every_command_and_flag():
    text = _text(DOCS / "cli.md")
    readme = _text(REPO / "README.md")
    choices = _subparsers()
    assert set(choices) == set(COMMANDS)
    for name, parser in choices.items():
        assert f"## `vislam {name}`" in text, name
        assert f"`vislam {name}" in readme, name
        for action in parser._actions:
            for flag in action.option_strings:
                if flag not in ("-h", "--help"):
                    assert flag in text, f"docs/cli.md does not name vislam {name} {flag}"


def test_estimators_page_names_every_estimator():
    text = _text(DOCS / "estimators.md")
    for name in ESTIMATOR_NAMES:
        assert f"## `{name}`" in text, name


def test_findings_are_dated_and_reproducible():
    text = _text(DOCS / "findings.md")
    sections = re.split(r"^## ", text, flags=re.M)[2:]  # after the title and "The drives"
    assert sections
    for section in sections:
        title = section.splitlines()[0]
        assert re.search(r"\(20\d\d-\d\d-\d\d", title), f"finding without a date: {title}"
        assert "Reproduce:" in section, f"finding without its command: {title}"


def test_readme_drive_sketch_writes_a_drive_vislam_reads(tmp_path, monkeypatch):
    """The README's conversion sketch, run on the arrays of a simulated drive, gives a file and
    ground truth that load to the same drive."""
    from vislam.eval.cli import main
    from vislam.eval.groundtruth import find_ground_truth
    from vislam.eval.loader import load_sequence

    sim = tmp_path / "sim"
    assert main(["simulate", "--out", str(sim), "--frames", "30", "--seed", "3"]) == 0
    with np.load(sim / "sim-seed3.npz") as f:
        arrays = {k: f[k] for k in f.files}
    rows = np.loadtxt(sim / "groundtruth" / "sim-seed3.txt", ndmin=2)
    cam_poses = np.tile(np.eye(4), (len(rows), 1, 1))
    cam_poses[:, :3, :] = rows[:, -12:].reshape(-1, 3, 4)  # a time column may come first
    names = {"t": arrays["time_stamps"].ravel(), "frame": arrays["obs_frame"],
             "track": arrays["obs_track"], "px": arrays["obs_pixels"],
             "v": arrays["linear_velocity"], "w": arrays["rotational_velocity"],
             "K": arrays["K"], "b": float(arrays["b"]), "cam_T_imu": arrays["cam_T_imu"],
             "cam_poses": cam_poses}
    sketch = re.search(r"## Your own drive.*?```python\n(.*?)```", _text(REPO / "README.md"),
                       flags=re.S).group(1)
    mine = tmp_path / "mine"
    (mine / "groundtruth").mkdir(parents=True)
    monkeypatch.chdir(mine)
    exec(compile(sketch, "README.md", "exec"), names)

    ours, theirs = load_sequence(mine / "mydrive.npz"), load_sequence(sim / "sim-seed3.npz")
    np.testing.assert_array_equal(ours.timestamps, theirs.timestamps)
    np.testing.assert_array_equal(ours.linear_velocity, theirs.linear_velocity)
    np.testing.assert_array_equal(ours.angular_velocity, theirs.angular_velocity)
    assert ours.n_tracks == theirs.n_tracks
    np.testing.assert_array_equal(ours.obs.frame_ptr, theirs.obs.frame_ptr)
    np.testing.assert_array_equal(ours.obs.track, theirs.obs.track)
    np.testing.assert_array_equal(ours.obs.z, theirs.obs.z)
    gt_ours = find_ground_truth(mine / "mydrive.npz")
    gt_theirs = find_ground_truth(sim / "sim-seed3.npz")
    np.testing.assert_allclose(gt_ours.poses, gt_theirs.poses, atol=1e-12)
