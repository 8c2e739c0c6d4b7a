"""`vislam config`: the commented default settings file, read back by --config unchanged."""

from __future__ import annotations

from pathlib import Path

import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.model import MODEL_CONFIG_FIELDS, model_config
from vislam.eval.cli import build_parser, main
from vislam.eval.config_reference import (
    default_settings_toml,
    filter_settings,
    model_settings,
    smoother_settings,
)
from vislam.eval.commands.options import (
    filter_config_from_args,
    model_from_args,
    smoother_settings_from_args,
)
from vislam.graph.settings import SmootherSettings


def _settings(argv):
    args = build_parser().parse_args(argv)
    return (filter_config_from_args(args), smoother_settings_from_args(args),
            model_from_args(args))


def _printed(capsys) -> str:
    assert main(["config"]) == 0
    return capsys.readouterr().out


def test_printed_file_gives_the_defaults(tmp_path, capsys):
    path = tmp_path / "f.toml"
    path.write_text(_printed(capsys), encoding="utf-8")
    with_file = _settings(["bench", "--config", str(path)])
    without = _settings(["bench"])
    assert with_file[0] == without[0] == FilterConfig()
    assert with_file[0].to_dict() == without[0].to_dict()
    assert with_file[1] == without[1] == SmootherSettings()
    assert with_file[2] is None and without[2] is None


def test_every_setting_is_in_the_file_with_its_meaning(capsys):
    text = _printed(capsys)
    for s in filter_settings() + smoother_settings():
        assert s.meaning, f"{s.name} has no #: comment in its dataclass"
        assert f"\n{s.name} = " in text
    for s in model_settings():
        assert s.meaning, f"[model] {s.name} has no #: comment in ekf.model.Model"


def test_model_example_is_a_valid_model(tmp_path, capsys):
    """Uncommented, with the [filter] keys the model sets deleted, the example is read."""
    text = _printed(capsys)
    head, example = text.split("# [model]\n")
    drop = set(MODEL_CONFIG_FIELDS) | {"gyro_bias"}
    kept = [line for line in head.splitlines() if line.split(" = ")[0] not in drop]
    body = [line[2:] if line.startswith("# ") else line.lstrip("#") for line in
            example.splitlines()]
    path = tmp_path / "model.toml"
    path.write_text("\n".join(kept + ["[model]"] + body) + "\n", encoding="utf-8")
    config, _, model = _settings(["run", "x.npz", "--estimator", "ekf-joint", "--out", "o",
                                  "--config", str(path)])
    assert model is not None and model.gyro_bias is None
    assert config == model_config(FilterConfig(), model)


def test_out_writes_the_printed_file(tmp_path, capsys):
    printed = _printed(capsys)
    out = tmp_path / "settings.toml"
    assert main(["config", "--out", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == printed == default_settings_toml()


@pytest.mark.parametrize("existing", ["file", "folder"])
def test_out_never_replaces_anything(tmp_path, capsys, existing):
    out = tmp_path / "settings.toml"
    if existing == "file":
        out.write_text("mine = 1\n", encoding="utf-8")
    else:
        out.mkdir()
    assert main(["config", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "vislam config: error: --out" in err
    if existing == "file":
        assert out.read_text(encoding="utf-8") == "mine = 1\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["settings.toml"]


def test_out_in_a_missing_folder(tmp_path, capsys):
    out = tmp_path / "nowhere" / "settings.toml"
    assert main(["config", "--out", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not Path(tmp_path / "nowhere").exists()
