"""The settings that differ between result folders (:mod:`eval.compare`): settings flattened
to dotted keys, numbers equal within a relative :data:`SETTINGS_RTOL`, bookkeeping
(:data:`SETTINGS_IGNORED`) left out."""

from __future__ import annotations

import json
import math

from vislam.eval.compare_readings import ABSENT, clip, num

#: Relative tolerance under which two numeric settings count as equal.
SETTINGS_RTOL = 1e-3
#: Path components of settings never compared (bookkeeping, not settings).
SETTINGS_IGNORED = frozenset({"created", "command", "cache_entry", "cached", "identification"})


def _flatten(obj, prefix: str = "") -> dict[str, object]:
    """{dotted key: leaf}; lists of named objects keyed by name, lists of numbers kept whole."""
    out: dict[str, object] = {}
    if isinstance(obj, dict):
        for k, v in obj.items():
            if str(k) in SETTINGS_IGNORED:
                continue
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(obj, list) and obj and all(isinstance(x, dict) for x in obj):
        named = all(isinstance(x.get("name"), str) for x in obj)
        for i, x in enumerate(obj):
            out.update(_flatten(x, f"{prefix}[{x['name'] if named else i}]"))
    else:
        out[prefix] = obj
    return out


def _same_setting(a, b) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return a == b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(a, b, rel_tol=SETTINGS_RTOL, abs_tol=1e-12)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same_setting(x, y) for x, y in zip(a, b))
    return a == b


def _show_setting(x) -> str:
    if x is _MISSING:
        return ABSENT
    if isinstance(x, bool) or x is None:
        return json.dumps(x)
    if isinstance(x, (int, float)):
        return num(float(x)) if isinstance(x, float) else str(x)
    if isinstance(x, list):
        return "[" + ", ".join(_show_setting(v) for v in x) + "]"
    return clip(str(x), 80)


_MISSING = object()


def settings_diff(settings: list[dict]) -> list[tuple[str, list[str]]]:
    """The settings whose value differs from the baseline's in some folder:
    [(dotted key, shown value per folder)]."""
    flat = [_flatten(s) for s in settings]
    keys = union([list(f) for f in flat])
    out = []
    for k in keys:
        vals = [f.get(k, _MISSING) for f in flat]
        base = vals[0]
        if all(v is not _MISSING and base is not _MISSING and _same_setting(base, v)
               for v in vals[1:]):
            continue
        out.append((k, [_show_setting(v) for v in vals]))
    return out


def union(lists) -> list[str]:
    """The names of every list, each once, in the order first seen."""
    out: list[str] = []
    for names in lists:
        for n in names:
            if n not in out:
                out.append(n)
    return out
