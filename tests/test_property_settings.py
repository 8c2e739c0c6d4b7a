"""Property-based tests of the settings (issue 11): random settings files and flag values.

Random TOML documents (keys from the valid set plus junk; values of every TOML type, including
nan, inf, huge, tiny, negative, strings, arrays, tables; odd layouts; corrupted or random bytes)
are written to a file and read the way the command line reads them (eval.commands.options
``filter_config_from_args`` then ``smoother_settings_from_args``). Property: either an
InputError, one line, naming the file; or settings whose every field follows its rule, whose
values are the file's, and whose covariances are finite and positive definite. Nothing else may
escape. The flags get the same property, the error naming the flag.

``VISLAM_PROPERTY_EXAMPLES`` raises the number of examples for a bigger local sweep.
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
import os
import re
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import event, given, settings
from hypothesis import strategies as st

from vislam.ekf.config import FILTER_RULES, FilterConfig
from vislam.ekf.errors import InputError
from vislam.eval.commands.options import filter_config_from_args, smoother_settings_from_args
from vislam.graph.settings import SMOOTHER_RULES, SmootherSettings

EXAMPLES = int(os.environ.get("VISLAM_PROPERTY_EXAMPLES", "500"))

JUNK_KEYS = ["bogus", "Pixel_Sigma", "pixel-sigma", "", " ", "filter", "smoother", "smoothr",
             "a.b", "é", "pixel_sigma\n", "__class__"]
KEYS = st.sampled_from(sorted(FILTER_RULES) + sorted(SMOOTHER_RULES) + JUNK_KEYS)

#: TOML value text that the value strategy cannot produce from Python values.
RAW_TOKENS = ["1e400", "-1e400", "1e-400", "+inf", "-nan", "+nan", "-0.0", "0x1F", "0o17", "0b11",
              "1_000.5", "9223372036854775807", "-9223372036854775808", "1e308", "1e-12",
              "1e4", "10000.000001", "1e6", "0.99", "1", "0", "-1", "1024", "1025", "true", "false",
              '"none"', '"off"', '"OFF"', "'literal'", '"mean"', '"next"', '"fej"', '"unscented"',
              '"isam2"', '"dead-reckoning"', '"exact"', '"joint"', "[]", "{}", "[1, 2]",
              "1979-05-27T07:32:00Z", "07:32:00"]


class Raw(str):
    """Value text written into the document as is."""


def _escape(text: str) -> str:
    out = []
    for ch in text:
        if ch in '"\\':
            out.append("\\" + ch)
        elif " " <= ch <= "~":
            out.append(ch)
        elif ord(ch) <= 0xFFFF:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(f"\\U{ord(ch):08X}")
    return '"' + "".join(out) + '"'


def _key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _escape(key)


def _value(v) -> str:
    if isinstance(v, Raw):
        return str(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return _escape(v)
    if isinstance(v, (dt.datetime, dt.date, dt.time)):
        return v.isoformat()
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"


TEXT = st.text(st.characters(exclude_categories=("Cs",)), max_size=12)
SCALARS = st.one_of(
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.integers(min_value=-3, max_value=2000),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-1e5, max_value=1e5),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e200, -1e200, 1e-200, 1e-13, 0.0, -1.0, 0.5,
                     1e4, 1e3, 1e6]),
    TEXT,
    st.sampled_from(RAW_TOKENS).map(Raw),
    st.datetimes(min_value=dt.datetime(1, 1, 1), max_value=dt.datetime(9999, 12, 31)),
)
VALUES = st.recursive(
    SCALARS,
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.sampled_from(["a", "b", "pixel_sigma"]), inner,
                                            max_size=2)),
    max_leaves=8,
)
HEADERS = st.sampled_from(["[filter]", "[smoother]", "[[filter]]", "[smoothr]", "[filter.sub]",
                           "[ filter ]", "[\"smoother\"]", "[[smoother]]"])
ALL_RULES = {**FILTER_RULES, **SMOOTHER_RULES}


def rule_values(rule) -> st.SearchStrategy:
    """Values near what ``rule`` allows: inside, on and just past its bounds, the choices."""
    if rule.kind == "bool":
        out = st.booleans()
    elif rule.kind == "choice":
        out = st.sampled_from(rule.choices)
    elif rule.kind == "int":
        out = st.one_of(st.integers(rule.lo, min(rule.hi, 64)), st.integers(rule.lo, rule.hi),
                        st.sampled_from([rule.lo, rule.hi, rule.lo - 1, rule.hi + 1]))
    else:
        edges = [rule.lo, rule.hi, np.nextafter(rule.lo, -1.0), np.nextafter(rule.hi, 2 * rule.hi),
                 np.nextafter(rule.lo, rule.hi), np.nextafter(rule.hi, rule.lo)]
        out = st.one_of(st.floats(rule.lo, rule.hi), st.sampled_from([float(e) for e in edges]),
                        st.integers(math.ceil(rule.lo), min(int(rule.hi), 100)))
    if rule.optional:
        out = st.one_of(out, st.sampled_from(['"none"', '"off"', '"None"']).map(Raw))
    return out


@st.composite
def tables(draw, keys: list[str]) -> list[str]:
    """``key = value`` lines: mostly known keys with plausible values, sometimes junk, rarely
    a key twice (invalid TOML)."""
    key_strategy = st.one_of(st.sampled_from(keys), st.sampled_from(keys), st.sampled_from(keys),
                             KEYS)
    pairs = draw(st.lists(key_strategy, max_size=6, unique=draw(st.integers(0, 9)) > 0))
    lines = []
    for key in pairs:
        plausible = key in ALL_RULES and draw(st.integers(0, 3)) > 0
        value = draw(rule_values(ALL_RULES[key]) if plausible else VALUES)
        lines.append(f"{_key(key)} = {_value(value)}")
    return lines


@st.composite
def documents(draw) -> bytes:
    """A TOML document (often valid, often with bad values or layout), sometimes corrupted."""
    filter_keys, smoother_keys = list(FILTER_RULES), list(SMOOTHER_RULES)
    layout = draw(st.sampled_from(["top", "filter", "top+smoother", "filter+smoother", "smoother",
                                   "odd"]))
    lines = []
    if layout.startswith("top"):
        lines += draw(tables(filter_keys))
    if layout.startswith("filter"):
        lines += ["[filter]"] + draw(tables(filter_keys))
    if layout.endswith("smoother"):
        lines += ["[smoother]"] + draw(tables(smoother_keys))
    if layout == "odd":
        lines += draw(tables(filter_keys))
        for header in draw(st.lists(HEADERS, max_size=3)):
            lines += [header] + draw(tables(filter_keys + smoother_keys))
    data = ("\n".join(lines) + "\n").encode("utf-8")
    damage = draw(st.sampled_from(["none"] * 12 + ["insert", "truncate", "bom", "random"]))
    if damage == "insert":  # often not UTF-8 any more (lone continuation bytes, 0xff ...)
        at = draw(st.integers(0, len(data)))
        data = data[:at] + draw(st.binary(min_size=1, max_size=4)) + data[at:]
    elif damage == "truncate":
        data = data[: draw(st.integers(0, len(data)))]
    elif damage == "bom":
        data = b"\xef\xbb\xbf" + data
    elif damage == "random":
        data = draw(st.binary(max_size=64))
    return data


def _check_settings(obj, rules) -> None:
    for name, rule in rules.items():
        value = getattr(obj, name)
        assert rule.check(value) == value and type(rule.check(value)) is type(value), (name, value)
        if isinstance(value, float):
            assert math.isfinite(value)


def _check_matrices(cfg: FilterConfig) -> None:
    for m in (cfg.pixel_cov, cfg.velocity_cov, cfg.initial_pose_cov):
        assert np.all(np.isfinite(m))
        np.linalg.cholesky(m)  # positive definite, else LinAlgError
        assert np.all(np.linalg.eigvalsh(m) > 0)


def _expected(key: str, value):
    """A file value as the settings store it (an int in a float field compares equal)."""
    if key == "gate_probability" and isinstance(value, str):
        return None
    if isinstance(value, list):  # a per-axis sigma is stored as a tuple
        return tuple(value)
    return value


def _kind(msg: str) -> str:
    """The kind of an error message, for hypothesis' statistics."""
    for words in ("not valid TOML", "not UTF-8", "unknown", "must be a table", "must be"):
        if words in msg:
            return words
    return msg


@settings(max_examples=EXAMPLES)
@given(documents())
def test_any_settings_file_is_either_refused_naming_it_or_valid(data):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "settings.toml"
        path.write_bytes(data)
        args = argparse.Namespace(config=str(path))
        try:
            cfg = filter_config_from_args(args)
            smoother = smoother_settings_from_args(args)
        except InputError as exc:
            msg = str(exc)
            assert str(path) in msg and len(msg.splitlines()) == 1, msg
            event(f"refused: {_kind(msg)}")
            return
    event("accepted")
    _check_settings(cfg, FILTER_RULES)
    _check_settings(smoother, SMOOTHER_RULES)
    _check_matrices(cfg)
    # what was accepted is what the file says (its text parses, since it was accepted)
    import tomllib

    doc = tomllib.loads(data.decode("utf-8-sig"))
    table = doc["filter"] if "filter" in doc else {k: v for k, v in doc.items() if k != "smoother"}
    for key, value in table.items():
        assert getattr(cfg, key) == _expected(key, value), key
    for key, value in doc.get("smoother", {}).items():
        assert getattr(smoother, key) == _expected(key, value), key


FLAG_FIELDS = {"pixel_sigma": "pixel_sigma", "velocity_sigma": "velocity_sigma",
               "gyro_sigma": "gyro_sigma", "gate_probability": "gate_probability",
               "velocity_pairing": "velocity_pairing", "max_depth": "max_depth",
               "min_disparity": "min_disparity"}
SMOOTHER_FLAGS = {"smoother_init": "init", "gap_prior": "gap_twist_prior"}
FLAG_TEXT = st.one_of(
    TEXT,
    st.floats().map(repr),
    st.integers(-10, 10**6).map(str),
    st.sampled_from(RAW_TOKENS + ["none", "off", " 0.5 ", "1e-12", "nan", "inf", "-inf", "1e999",
                                  "current", "mean", "ekf", "linearised", "off", "", "--"]),
)


def _as_flag_text(value) -> str:
    if isinstance(value, Raw):
        return str(value).strip('"')
    return value if isinstance(value, str) else repr(value)


@st.composite
def flag_values(draw) -> tuple[str, str]:
    dest = draw(st.sampled_from(sorted(FLAG_FIELDS) + sorted(SMOOTHER_FLAGS)))
    field = FLAG_FIELDS.get(dest) or SMOOTHER_FLAGS[dest]
    if draw(st.booleans()):
        return dest, _as_flag_text(draw(rule_values(ALL_RULES[field])))
    return dest, draw(FLAG_TEXT)


@settings(max_examples=EXAMPLES)
@given(flag_values())
def test_any_flag_value_is_either_refused_naming_the_flag_or_valid(flag_value):
    dest, text = flag_value
    args = argparse.Namespace(config=None, **{dest: text})
    flag = "--" + dest.replace("_", "-")
    try:
        cfg = filter_config_from_args(args)
        smoother = smoother_settings_from_args(args)
    except InputError as exc:
        msg = str(exc)
        assert msg.startswith(f"{flag}: must be ") and len(msg.splitlines()) == 1, msg
        event("refused")
        return
    event("accepted")
    _check_settings(cfg, FILTER_RULES)
    _check_settings(smoother, SMOOTHER_RULES)
    _check_matrices(cfg)
    if dest in FLAG_FIELDS:
        value = getattr(cfg, FLAG_FIELDS[dest])
    else:
        value = getattr(smoother, SMOOTHER_FLAGS[dest])
    if isinstance(value, float):
        assert value == float(text)
    elif value is None:
        assert text.strip().lower() in ("none", "off")
    else:
        assert value == text


@settings(max_examples=EXAMPLES)
@given(st.sampled_from(sorted(FILTER_RULES)), SCALARS)
def test_replace_is_either_refused_naming_the_setting_or_valid(name, value):
    for obj, rules in ((FilterConfig(), FILTER_RULES), (SmootherSettings(), SMOOTHER_RULES)):
        key = name if name in rules else next(iter(rules))
        try:
            new = obj.replace(**{key: value})
        except InputError as exc:
            assert f"setting {key!r} must be " in str(exc) and len(str(exc).splitlines()) == 1
            continue
        _check_settings(new, rules)
        if isinstance(new, FilterConfig):
            _check_matrices(new)
