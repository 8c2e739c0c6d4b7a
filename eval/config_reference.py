"""Every setting of a settings file, read from the settings' own definitions.

The settings are dataclasses whose fields carry their meaning in ``#:`` comments (the
convention Sphinx reads): :class:`ekf.config.FilterConfig` (the ``[filter]`` table),
:class:`graph.settings.SmootherSettings` (``[smoother]``) and :class:`ekf.model.Model`
(``[model]``, keys in ``ekf.model.MODEL_CHECKS``). This module reads those comments and the
defaults, and writes them two ways:

- :func:`default_settings_toml`: a commented settings file holding every default, which
  ``--config`` reads unchanged (``vislam config`` prints it);
- :func:`configuration_markdown`: docs/configuration.md (``python -m
  vislam.eval.config_reference`` prints it; tests/test_docs.py fails when the file differs).

A comment block belongs to every field that follows it with no blank line or other line between
(``initial_position_sigma`` and ``initial_rotation_sigma`` share one).
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import math
import numbers
import re
import textwrap
from dataclasses import dataclass

import numpy as np

from vislam.ekf.config import FILTER_RULES, FilterConfig, Rule
from vislam.ekf.model import MODEL_CHECKS, MODEL_CONFIG_FIELDS, REQUIRED_KEYS, Model
from vislam.graph.settings import SMOOTHER_RULES, SmootherSettings

#: Width of the comment lines in the settings file.
WIDTH = 92
#: The command that writes docs/configuration.md (named in its header and by the test).
REGENERATE = "python -m vislam.eval.config_reference > docs/configuration.md"

#: A field of a dataclass body: ``    name: type`` (four spaces in).
_FIELD = re.compile(r"^    ([A-Za-z_][A-Za-z0-9_]*)\s*:")


@dataclass(frozen=True)
class Setting:
    """One key of a settings table: its name, default (``dataclasses.MISSING`` where a value is
    required), meaning (the ``#:`` comment, one paragraph) and the rule it is checked by (None
    where the table has no Rule, as ``[model]``)."""

    name: str
    default: object
    meaning: str
    rule: Rule | None


def field_comments(cls: type) -> dict[str, str]:
    """``{field: meaning}`` from the ``#:`` comments in the source of dataclass ``cls``; a
    field with none gets ""."""
    comments: dict[str, str] = {}
    block: list[str] = []
    applies = False  # the block applies to the next field
    collecting = False  # a "#:" line continues the block
    for line in inspect.getsource(cls).splitlines():
        stripped = line.strip()
        if line.startswith("    def ") or line.startswith("    @"):
            break  # the fields come before the methods
        if stripped.startswith("#:"):
            if not collecting:
                block = []
            block.append(stripped[2:].strip())
            applies = collecting = True
        elif match := _FIELD.match(line):
            comments[match.group(1)] = " ".join(block) if applies else ""
            collecting = False
        else:  # a blank line, the docstring, anything else: the block ends
            applies = collecting = False
    return comments


def _settings(cls: type, rules: dict[str, Rule]) -> list[Setting]:
    meaning = field_comments(cls)
    return [Setting(f.name, f.default, meaning.get(f.name, ""), rules[f.name])
            for f in dataclasses.fields(cls)]


def filter_settings() -> list[Setting]:
    """The ``[filter]`` table: every FilterConfig field."""
    return _settings(FilterConfig, FILTER_RULES)


def smoother_settings() -> list[Setting]:
    """The ``[smoother]`` table: every SmootherSettings field."""
    return _settings(SmootherSettings, SMOOTHER_RULES)


def model_settings() -> list[Setting]:
    """The ``[model]`` table: every key ekf.model checks, in the order a model file has them
    (required keys have no default; the others are absent by default)."""
    meaning = field_comments(Model)
    defaults = {f.name: f.default for f in dataclasses.fields(Model)}
    return [Setting(key, dataclasses.MISSING if key in REQUIRED_KEYS else defaults[key],
                    meaning.get(key, ""), None) for key in MODEL_CHECKS]


# --- TOML ---------------------------------------------------------------------------------------


def toml_value(value: object) -> str:
    """``value`` (a default: bool, int, float, text, a tuple of numbers) as TOML; a float is
    written in the shortest form that reads back to the same float."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        if not math.isfinite(float(value)):
            raise ValueError(f"TOML settings hold finite numbers, not {value!r}")
        return repr(float(value))
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string for the plain text of a choice
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if value is None:
        return '"none"'
    raise TypeError(f"no TOML form for {type(value).__name__}")


def _comment(text: str, width: int = WIDTH) -> list[str]:
    return textwrap.wrap(text, width - 2, initial_indent="# ", subsequent_indent="# ",
                         break_on_hyphens=False) if text else []


def _table_lines(settings: list[Setting]) -> list[str]:
    lines: list[str] = []
    for s in settings:
        lines += _comment(s.meaning)
        if s.rule is not None:
            lines += _comment(f"Allowed: {s.rule.describe()}.")
        lines.append(f"{s.name} = {toml_value(s.default)}")
        lines.append("")
    return lines


def _model_example() -> Model:
    """An example model: the default noise model per axis, a camera 0.27 m ahead of the IMU
    (KITTI's axes: camera z forward is the IMU's x)."""
    config = FilterConfig()
    cam_T_imu = [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, -0.27],
                 [0.0, 0.0, 0.0, 1.0]]
    return Model(velocity_sigma=tuple(config.velocity_sigmas), gyro_sigma=tuple(config.gyro_sigmas),
                 pixel_sigma=config.pixel_sigma, velocity_pairing=config.velocity_pairing,
                 cam_T_imu=np.array(cam_T_imu), source="an example: vislam calibrate writes one")


def default_settings_toml() -> str:
    """A settings file holding every default, each with its meaning and what it may be: the
    ``[filter]`` and ``[smoother]`` tables, and a commented-out ``[model]`` example.
    ``--config`` reads it unchanged and gets exactly the defaults."""
    lines = [
        "# vislam settings: every default, as `vislam config` writes it. Pass it with",
        "# `--config FILE` to run, bench, nees, calibrate, inspect and score; flags override it.",
        "# Every setting is optional: delete a line and its default applies.",
        "# The reference: docs/configuration.md.",
        "",
        "# The noise model and the filters' choices (ekf/config.py FilterConfig); the smoothers",
        "# share the noise model.",
        "[filter]",
        "",
    ]
    lines += _table_lines(filter_settings())
    lines += ["# The GTSAM smoothers' own settings (graph/settings.py SmootherSettings).",
              "[smoother]", ""]
    lines += _table_lines(smoother_settings())
    model_keys = ", ".join(MODEL_CONFIG_FIELDS)
    lines += _comment(
        "A drive's model (ekf/model.py; `vislam calibrate FILE.npz --out model.toml` writes "
        "one). Its noise model replaces [filter] settings: to use a [model] table here, delete "
        "from [filter] the keys it sets, " + model_keys + ", and gyro_bias where the model has "
        "no gyro_bias, as in this example (a key in both tables is an error). Its extrinsic, "
        "gyro bias and radial term act on the data. Without a [model] table `vislam bench` "
        "identifies one per drive (--model identify).")
    for line in _model_example().to_toml().splitlines():
        if line.startswith("#"):
            continue
        lines.append("# " + line if line else "#")
    return "\n".join(lines).rstrip("\n") + "\n"


# --- Markdown -----------------------------------------------------------------------------------


def _md_default(s: Setting) -> str:
    if s.default is dataclasses.MISSING:
        return "required"
    if s.default is None:
        return "absent"
    if s.default == () or s.default == "":
        return "absent"
    return f"`{toml_value(s.default)}`"


def _md_table(settings: list[Setting], allowed: bool = True) -> list[str]:
    if allowed:
        lines = ["| setting | default | allowed | meaning |", "| --- | --- | --- | --- |"]
    else:
        lines = ["| key | default | meaning |", "| --- | --- | --- |"]
    for s in settings:
        meaning = s.meaning.replace("|", "\\|")
        if allowed:
            rule = s.rule.describe().replace("|", "\\|")
            lines.append(f"| `{s.name}` | {_md_default(s)} | {rule} | {meaning} |")
        else:
            lines.append(f"| `{s.name}` | {_md_default(s)} | {meaning} |")
    return lines


def configuration_markdown() -> str:
    """docs/configuration.md: every setting of a settings file with its default, what it may
    be and its meaning, from the settings' definitions."""
    lines = [
        "# Configuration",
        "",
        f"<!-- Generated from the settings' definitions by `{REGENERATE}`;",
        "     do not edit: tests/test_docs.py fails when this file differs. -->",
        "",
        "Every estimating command (`run`, `bench`, `nees`, `calibrate`, `inspect`, `score`) reads",
        "a TOML settings file given by `--config FILE`. `vislam config` prints one that holds every",
        "default below, with its meaning (`vislam config --out settings.toml` writes it).",
        "",
        "Where a setting comes from, lowest first: the default; the `[filter]` / `[smoother]`",
        "table; the noise model of a `[model]` table (or, with `vislam bench --model identify`, the",
        "default, the model identified from each drive); the flags (`--pixel-sigma`,",
        "`--velocity-sigma`, `--gyro-sigma`, `--gate-probability`, `--no-clean`,",
        "`--velocity-pairing`, `--keep-landmarks`, `--[no-]gyro-bias`, `--max-depth`,",
        "`--min-disparity`, `--landmarks`, `--pixel-reading`, `--smoother-init`, `--gap-prior`;",
        "see cli.md).",
        "",
        "Filter settings are in a `[filter]` table or, without one, at the top level. Every value",
        "is checked for type, finiteness and range wherever it comes from; a bad one is one line",
        "naming the file, table and key (or the flag), exit code 2. An int is accepted where a",
        "number is expected, never the reverse; `velocity_sigma` and `gyro_sigma` take one number",
        "(every axis) or three (x, y, z of the IMU body frame).",
        "",
        "## `[filter]`: the noise model and the filters (ekf/config.py `FilterConfig`)",
        "",
        "The smoothers share the noise model (the sigmas, pairing, cleaning and limits).",
        "",
    ]
    lines += _md_table(filter_settings())
    lines += ["", "## `[smoother]`: the GTSAM smoothers (graph/settings.py `SmootherSettings`)", ""]
    lines += _md_table(smoother_settings())
    lines += [
        "",
        "## `[model]`: the model of a drive (ekf/model.py `Model`)",
        "",
        "`vislam calibrate FILE.npz --out model.toml` writes one; `vislam bench` identifies one per",
        "drive unless `--model as-given` or a `[model]` table is given. Its noise model replaces",
        "the `[filter]` settings `" + "`, `".join(MODEL_CONFIG_FIELDS)
        + "` (a key in both tables is an error) with the",
        "per-interval sigmas (times each correlation time's square root); its extrinsic, gyro",
        "bias and radial term act on the data, and ground truth is converted with its extrinsic.",
        "An optional `[file]` table beside it holds the data file's own values (same keys, all",
        "optional), for comparison.",
        "",
    ]
    lines += _md_table(model_settings(), allowed=False)
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(configuration_markdown(), end="")
