"""Reading a JSON results file with every check: a size limit, UTF-8, NaN and infinity read as
no value (None), and typed look-ups whose :class:`~ekf.errors.InputError` names the file and
the key (``results.json: sequences[0].estimators[1].ate_m: expected a number or null``)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from vislam.ekf.errors import InputError

#: Largest JSON file read (bytes).
MAX_JSON_BYTES = 256 * 1024 * 1024


def read_json(path: Path) -> object:
    """The JSON of ``path`` (NaN and infinity read as None); InputError naming the file."""
    try:
        size = path.stat().st_size
        if size > MAX_JSON_BYTES:
            raise InputError(f"{path}: {size} bytes, more than the {MAX_JSON_BYTES} a results "
                             "file may have")
        with open(path, "rb") as fh:
            text = fh.read().decode("utf-8")
        return json.loads(text, parse_constant=lambda c: None)  # NaN / Infinity: no value
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}, "
                         f"column {exc.colno})") from None
    except RecursionError:
        raise InputError(f"{path}: JSON nested too deeply") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None


def short(x) -> str:
    """A value as a message shows it (at most 40 characters)."""
    text = json.dumps(x) if not isinstance(x, str) else repr(x)
    return text if len(text) <= 40 else text[:37] + "..."


def number(x, where: str) -> float | None:
    """A figure: a finite float, or None for null / non-finite; anything else is an error."""
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise InputError(f"{where}: expected a number or null, got {short(x)}")
    x = float(x)
    return x if math.isfinite(x) else None


def count(x, where: str) -> int | None:
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, int) or x < 0:
        raise InputError(f"{where}: expected a count (an integer >= 0) or null, got {short(x)}")
    return x


def text_or_none(x, where: str) -> str | None:
    if x is not None and not isinstance(x, str):
        raise InputError(f"{where}: expected text or null, got {short(x)}")
    return x


def require(obj, key: str, kind, where: str):
    if not isinstance(obj, dict) or key not in obj:
        raise InputError(f"{where}: missing key {key!r}")
    value = obj[key]
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        name = getattr(kind, "__name__", None) or "/".join(k.__name__ for k in kind)
        raise InputError(f"{where}.{key}: expected {name}, got {short(value)}")
    return value


def named_objects(items: list, where: str, what: str, within: str = ""):
    """(place, object, name) of each item of ``items`` (placed ``where[i]`` in messages): an
    object with a text ``name`` no other item has."""
    seen = set()
    for i, item in enumerate(items):
        place = f"{where}[{i}]"
        if not isinstance(item, dict):
            raise InputError(f"{place}: expected an object, got {short(item)}")
        name = require(item, "name", str, place)
        if name in seen:
            raise InputError(f"{place}.name: {what} {name!r} appears twice{within}")
        seen.add(name)
        yield place, item, name
