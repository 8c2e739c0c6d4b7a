"""Numeric text tables (CSV or whitespace-separated), read so that every fault names the file,
the line and the column: the IMU, track and ground-truth files of raw-IMU drives.

Lines that are empty or start with ``#`` are comments (:func:`eval.export.text_lines`, which
reads the file safely); a first line that is not numeric is a header without ``#``. Values are parsed as floats; integer columns
(nanosecond stamps, track ids) are parsed exactly as integers where asked, because 1.4e18 ns
does not fit a float's 53 bits.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from vislam.ekf.errors import InputError
from vislam.eval.export import text_lines


@dataclass(frozen=True)
class Table:
    """``values`` (n, width) floats; ``exact`` (n, k) int64 of the integer columns asked for;
    ``lines`` (n,) the file's line number of each row; ``header`` a header line without ``#``,
    or ''."""

    values: np.ndarray
    exact: np.ndarray
    lines: np.ndarray
    header: str


def read_table(path: Path, what: str, widths: tuple[int, ...], delimiter: str | None = ",",
               integer_columns: tuple[int, ...] = ()) -> Table:
    """The rows of ``path`` (a ``what``), each with one of ``widths`` columns (the first row's
    width is then required of every row); ``delimiter`` None splits on whitespace."""
    path = Path(path)
    rows: list[list[float]] = []
    exact: list[list[int]] = []
    lines: list[int] = []
    header = ""
    width = None
    for number, fields in text_lines(path, what, delimiter):
        if not rows and not header and not _is_number(fields[0]):
            header = ",".join(fields) if delimiter else " ".join(fields)
            continue
        if width is None:
            if len(fields) not in widths:
                raise InputError(f"{path}: line {number} has {len(fields)} columns, expected "
                                 f"{_choices(widths)} ({what})")
            width = len(fields)
        elif len(fields) != width:
            raise InputError(f"{path}: line {number} has {len(fields)} columns, earlier lines "
                             f"{width} ({what})")
        values = []
        for column, field in enumerate(fields, start=1):
            try:
                values.append(float(field))
            except ValueError:
                raise InputError(f"{path}: line {number}, column {column}: non-numeric value "
                                 f"{field[:40]!r} ({what})") from None
            if not np.isfinite(values[-1]):
                raise InputError(f"{path}: line {number}, column {column}: {field[:40]!r} is not "
                                 f"a finite number ({what})")
        ints = []
        for column in integer_columns:
            field = fields[column]
            try:
                ints.append(int(field))
            except ValueError:
                value = values[column]
                if value != np.floor(value) or abs(value) >= 2**63:
                    raise InputError(f"{path}: line {number}, column {column + 1}: {field[:40]!r} "
                                     f"is not an integer ({what})") from None
                ints.append(int(value))
            if abs(ints[-1]) >= 2**63:
                raise InputError(f"{path}: line {number}, column {column + 1}: {field[:40]!r} is "
                                 f"out of range ({what})")
        rows.append(values)
        exact.append(ints)
        lines.append(number)
    if not rows:
        raise InputError(f"{path}: no data rows ({what})")
    return Table(np.asarray(rows, dtype=float),
                 np.asarray(exact, dtype=np.int64).reshape(len(rows), len(integer_columns)),
                 np.asarray(lines, dtype=np.int64), header)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _choices(widths: tuple[int, ...]) -> str:
    return " or ".join(str(w) for w in widths)
