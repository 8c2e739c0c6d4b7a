"""The command line's shared options: the settings flags every estimating command takes (read
on top of ``--config``), ``--align``, and where and how a result was produced.

Shared by ``vislam run``, ``bench``, ``nees``, ``score``, ``calibrate`` and ``inspect``.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from vislam.ekf.config import (
    FILTER_RULES,
    LANDMARK_PARAMETERISATIONS,
    PIXEL_READINGS,
    VELOCITY_PAIRINGS,
    FilterConfig,
    settings_tables,
    show_path,
)
from vislam.ekf.errors import InputError
from vislam.eval.metrics import ALIGN_MODES
from vislam.graph.settings import GAP_PRIOR_MODES, INITIALISERS, SMOOTHER_RULES, SmootherSettings

#: Command-line flag (argparse dest) -> FilterConfig field (flags override the TOML file).
_FLAG_FIELDS = {
    "pixel_sigma": "pixel_sigma",
    "velocity_sigma": "velocity_sigma",
    "gyro_sigma": "gyro_sigma",
    "gate_probability": "gate_probability",
    "velocity_pairing": "velocity_pairing",
    "max_depth": "max_depth",
    "min_disparity": "min_disparity",
    "landmarks": "landmark_parameterisation",
    "pixel_reading": "pixel_reading",
}
#: Smoother flag (argparse dest) -> SmootherSettings field.
_SMOOTHER_FLAG_FIELDS = {"smoother_init": "init", "gap_prior": "gap_twist_prior"}


# --- settings --------------------------------------------------------------------------------
#
# The value flags are read as text (argparse only stores them) and checked after the settings
# file is merged, by the same rules as the file (ekf.config.FILTER_RULES,
# graph.settings.SMOOTHER_RULES), so that a bad value is one line naming the flag
# ("--pixel-sigma: must be a positive number from 1e-12 to 10000, got -1") and exit code 2,
# like every other input error, rather than argparse's usage message.
#
# The model. A ``--config`` file may hold a ``[model]`` table (and ``[file]``), the model of a
# drive (ekf.model: `vislam calibrate` writes one). The settings are then, lowest first: the
# defaults, the ``[filter]`` table, the model's noise model (ekf.model.model_config: sigmas
# per axis, pixel sigma, velocity pairing, no gyro-bias state when the model has no bias), and
# the flags. A key set by both ``[filter]`` and the model is an error (which one is meant?).
# The model's extrinsic and gyro bias act on the data, not the settings: apply
# ``ekf.model.model_sequence(seq, model)`` once per sequence (model_from_args gives the model)
# and convert the ground truth with ``model.cam_T_imu`` (GroundTruth.with_extrinsic).


def _flag_name(dest: str) -> str:
    return "--" + dest.replace("_", "-")


def _flag_value(dest: str, rule, raw):
    """Flag ``dest``'s value ``raw`` (text from the command line, or a value set in code)
    parsed and checked by ``rule``; InputError "--flag: must be ..., got ..." otherwise."""
    value = raw
    if isinstance(raw, str) and rule.kind == "float3":
        try:
            parts = [float(x) for x in raw.split(",")]
        except ValueError:
            raise InputError(f"{_flag_name(dest)}: must be {rule.describe()}, "
                             f"got {raw!r}") from None
        value = parts[0] if len(parts) == 1 else parts
    elif isinstance(raw, str) and rule.kind in ("float", "int"):
        if not (rule.optional and raw.strip().lower() in ("none", "off")):
            try:
                value = int(raw) if rule.kind == "int" else float(raw)
            except ValueError:
                raise InputError(f"{_flag_name(dest)}: must be {rule.describe()}, "
                                 f"got {raw!r}") from None
    try:
        return rule.check(value)
    except ValueError as exc:
        raise InputError(f"{_flag_name(dest)}: {exc}") from None


def add_filter_arguments(parser: argparse.ArgumentParser) -> None:
    """The FilterConfig flags every estimating command shares."""
    g = parser.add_argument_group("estimator settings (override --config)")
    g.add_argument("--config", metavar="TOML",
                   help="settings file ([filter] table or top level, [smoother] table, and a "
                        "drive's model: [model] and [file] tables, see ekf/model.py)")
    g.add_argument("--pixel-sigma", metavar="PX", help="stereo pixel noise sigma")
    g.add_argument("--velocity-sigma", metavar="M/S",
                   help="linear velocity sigma: one for every axis or x,y,z (0.5,0.4,0.3)")
    g.add_argument("--gyro-sigma", metavar="RAD/S",
                   help="angular velocity sigma: one for every axis or x,y,z")
    g.add_argument("--gate-probability", metavar="P", help="chi-square gate probability or 'none'")
    g.add_argument("--no-clean", action="store_true", help="do not split tracks at repeats")
    g.add_argument("--velocity-pairing", metavar="{" + ",".join(VELOCITY_PAIRINGS) + "}",
                   help="velocity for [k, k+1]")
    g.add_argument("--keep-landmarks", action="store_true", help="never marginalise landmarks")
    g.add_argument(
        "--gyro-bias",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="estimate a constant gyro bias (ekf-joint, ekf-invariant; default on)",
    )
    g.add_argument("--max-depth", metavar="M", help="reject points beyond this depth")
    g.add_argument("--min-disparity", metavar="PX", help="reject smaller disparities")
    g.add_argument("--landmarks", metavar="{" + ",".join(LANDMARK_PARAMETERISATIONS) + "}",
                   help="landmark parameterisation of ekf-joint and ekf-invariant")
    g.add_argument("--pixel-reading", metavar="{" + ",".join(PIXEL_READINGS) + "}",
                   help="how ekf-joint reads pixel errors correlated along a track: "
                        "long-run (default) or ar1 (exact, by differencing; experimental, "
                        "less accurate on simulated drives)")
    s = parser.add_argument_group("smoother settings (override the [smoother] table of --config)")
    s.add_argument("--smoother-init", metavar="{" + ",".join(INITIALISERS) + "}",
                   help="the batch smoother's initial trajectory (default ekf)")
    s.add_argument("--gap-prior", metavar="{" + ",".join(GAP_PRIOR_MODES) + "}",
                   help="twist-smoothness prior on intervals without vision (default linearised)")


def filter_config_from_args(args: argparse.Namespace) -> FilterConfig:
    """FilterConfig from ``--config`` (if given: its ``[filter]`` table, then the noise model of
    its ``[model]`` table, if any) overridden by the individual flags; every value checked, an
    InputError naming the file and key or the flag otherwise."""
    path = getattr(args, "config", None)
    config = FilterConfig()
    if path is not None:
        tables = settings_tables(path)
        config = FilterConfig.from_mapping(*tables["filter"])
        model = _model_from_tables(path, tables)
        if model is not None:
            config = _merge_model(path, tables["filter"][0], config, model)
    changes = {}
    for dest, name in _FLAG_FIELDS.items():
        raw = getattr(args, dest, None)
        if raw is not None:
            changes[name] = _flag_value(dest, FILTER_RULES[name], raw)
    if getattr(args, "no_clean", False):
        changes["clean_tracks"] = False
    if getattr(args, "keep_landmarks", False):
        changes["keep_landmarks"] = True
    if getattr(args, "gyro_bias", None) is not None:
        changes["gyro_bias"] = bool(args.gyro_bias)
    return config.replace(**changes) if changes else config


def model_from_args(args: argparse.Namespace):
    """The model (ekf.model.Model) of the ``--config`` file's ``[model]`` table, or None
    without a ``--config`` or without that table; InputError naming the file, table and key at
    any fault. Its noise model is already in :func:`filter_config_from_args`'s config; its
    extrinsic and gyro bias are the caller's to apply to the data (ekf.model.model_sequence)
    and the ground truth (GroundTruth.with_extrinsic)."""
    path = getattr(args, "config", None)
    if path is None:
        return None
    from vislam.ekf.model import model_from_settings

    return model_from_settings(path)


def _model_from_tables(path, tables):
    from vislam.ekf.model import Model

    (model, source), (file, file_source) = tables["model"], tables["file"]
    if model is None:
        if file is not None:
            raise InputError(f"{file_source}: a [file] table needs a [model] table beside it")
        return None
    return Model.from_mapping(model, source, file, file_source)


def _merge_model(path, filter_table: dict, config: FilterConfig, model) -> FilterConfig:
    """``config`` with the model's noise model; a [filter] key the model sets is an error."""
    from vislam.ekf.model import MODEL_CONFIG_FIELDS, model_config

    fields = list(MODEL_CONFIG_FIELDS) + (["gyro_bias"] if model.gyro_bias is None else [])
    if model.gyro_bias is not None and model.gyro_bias_sigma is not None:
        fields.append("gyro_bias_sigma")
    if model.speed_scale_sigma is not None:
        fields += ["speed_scale", "speed_scale_sigma", "speed_scale_walk"]
    both = [k for k in fields if k in filter_table]
    if both:
        extra = (" (the model says the data has no gyro bias)" if both[0] == "gyro_bias"
                 else "")
        raise InputError(f"{show_path(path)}: setting {both[0]!r} is in both the [filter] and "
                         f"the [model] tables{extra}; keep one (flags override both)")
    return model_config(config, model)


def smoother_settings_from_args(args: argparse.Namespace) -> SmootherSettings:
    """SmootherSettings from the ``[smoother]`` table of ``--config`` (if any) overridden by
    ``--smoother-init`` and ``--gap-prior``; checked like filter_config_from_args."""
    path = getattr(args, "config", None)
    settings = SmootherSettings.from_toml(path) if path is not None else SmootherSettings()
    changes = {}
    for dest, name in _SMOOTHER_FLAG_FIELDS.items():
        raw = getattr(args, dest, None)
        if raw is not None:
            changes[name] = _flag_value(dest, SMOOTHER_RULES[name], raw)
    return settings.replace(**changes) if changes else settings


def environment_settings() -> dict:
    """Where and how a result was produced (for settings.json)."""
    return {
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "host_cpus": os.cpu_count(),
    }


def add_align_argument(parser: argparse.ArgumentParser) -> None:
    """``--align {se3,sim3,yaw,none}`` (eval.metrics.ALIGN_MODES; dest ``align``, None when not
    given: se3 for a velocity drive, yaw for a raw-IMU drive): the alignment before every
    aligned ATE a command reports."""
    parser.add_argument(
        "--align", choices=ALIGN_MODES, default=None,
        help="alignment of the estimate onto the reference before the aligned ATE ('ATE al.'): "
             "se3 rotation and translation (the default for velocity drives), sim3 also scale, "
             "yaw rotation about gravity (world z) and translation, the 4-dof alignment of a "
             "gravity-aligned visual-inertial estimate (the default for raw-IMU drives), none "
             "the raw ATE",
    )


def add_model_argument(parser: argparse.ArgumentParser) -> None:
    """``--model identify|as-given`` (bench, score): which model the drives are run under."""
    parser.add_argument("--model", choices=("identify", "as-given"), default="identify",
                        help="identify: every estimator runs under the model identified from "
                             "each drive's own data (noise, gyro bias, pairing, extrinsic; "
                             "cached by content, see 'vislam calibrate'), and ground truth is "
                             "converted with its extrinsic, the default; as-given: the file's "
                             "extrinsic and the settings as given (the paper's). A [model] "
                             "table in --config is used as it is")
