"""results.json's drive-fitted RPE (``rpe_drive``, :func:`eval.metrics.drive_rpe`) as typed
objects, for :func:`eval.results.load_results`: the segment lengths a drive's truth gave, the
statistics over the segments of every length and per length, or in words why there is none.
Every fault (a key of the wrong type, a length that is not a positive number) is an
:class:`~ekf.errors.InputError` naming the file and the key."""

from __future__ import annotations

from dataclasses import dataclass

from vislam.ekf.errors import InputError
from vislam.eval.json_reading import count, number, short, text_or_none
from vislam.eval.rpe_segments import lengths_text

#: The figures of each segment length (results.json's ``rpe_drive.per_length[k]``), each
#: {mean, median, rmse}.
RPE_LENGTH_KEYS = ("trans_m", "trans_pct", "rot_deg", "rot_deg_per_m")


@dataclass(frozen=True)
class ErrorStats:
    """Mean, median and RMSE of an error over segments (None: no value)."""

    mean: float | None
    median: float | None
    rmse: float | None


@dataclass(frozen=True)
class SegmentLengthRpe:
    """The drive-fitted RPE over the segments of one length: their number and the statistics
    of the translation error (m, % of the segment's true path) and rotation error (deg, deg/m);
    None where the length has no segment."""

    length_m: float
    n_segments: int
    trans_m: ErrorStats | None
    trans_pct: ErrorStats | None
    rot_deg: ErrorStats | None
    rot_deg_per_m: ErrorStats | None


@dataclass(frozen=True)
class DriveRpe:
    """The drive-fitted RPE of an estimator (results.json's ``rpe_drive``,
    :func:`eval.metrics.drive_rpe`): the segment lengths chosen from the drive's true path,
    the statistics over the segments of every length together and per length, and ``note``:
    in words why there is no figure (None when there is one)."""

    lengths_m: tuple[float, ...]
    path_length_m: float | None
    frames: int | None
    n_segments: int
    trans_pct: ErrorStats | None
    rot_deg_per_m: ErrorStats | None
    per_length: tuple[SegmentLengthRpe, ...]
    note: str | None

    @property
    def lengths_text(self) -> str:
        """The lengths in words ("4, 8, 12, 16 and 20 m"; "none")."""
        return lengths_text(self.lengths_m)


def _stats(x, where: str) -> ErrorStats | None:
    if x is None:
        return None
    if not isinstance(x, dict):
        raise InputError(f"{where}: expected an object or null, got {short(x)}")
    return ErrorStats(**{k: number(x.get(k), f"{where}.{k}") for k in ("mean", "median", "rmse")})


def drive_rpe_of(x, where: str) -> DriveRpe | None:
    """The :class:`DriveRpe` of results.json's ``rpe_drive`` object ``x`` (placed ``where`` in
    messages); None for null or absent."""
    if x is None:
        return None
    if not isinstance(x, dict):
        raise InputError(f"{where}: expected an object or null, got {short(x)}")
    lengths = x.get("lengths_m", [])
    if not isinstance(lengths, list):
        raise InputError(f"{where}.lengths_m: expected a list, got {short(lengths)}")
    lengths_m = []
    for k, v in enumerate(lengths):
        value = number(v, f"{where}.lengths_m[{k}]")
        if value is None or value <= 0:
            raise InputError(f"{where}.lengths_m[{k}]: expected a length in metres, got {short(v)}")
        lengths_m.append(value)
    rows = x.get("per_length", [])
    if not isinstance(rows, list):
        raise InputError(f"{where}.per_length: expected a list, got {short(rows)}")
    per_length = []
    for k, row in enumerate(rows):
        w = f"{where}.per_length[{k}]"
        if not isinstance(row, dict):
            raise InputError(f"{w}: expected an object, got {short(row)}")
        length = number(row.get("length_m"), f"{w}.length_m")
        if length is None:
            raise InputError(f"{w}: missing key 'length_m'")
        per_length.append(SegmentLengthRpe(
            length_m=length, n_segments=count(row.get("n_segments", 0), f"{w}.n_segments") or 0,
            **{key: _stats(row.get(key), f"{w}.{key}") for key in RPE_LENGTH_KEYS}))
    frames = count(x.get("frames"), f"{where}.frames")
    return DriveRpe(
        lengths_m=tuple(lengths_m),
        path_length_m=number(x.get("path_length_m"), f"{where}.path_length_m"),
        frames=frames, n_segments=count(x.get("n_segments", 0), f"{where}.n_segments") or 0,
        trans_pct=_stats(x.get("trans_pct"), f"{where}.trans_pct"),
        rot_deg_per_m=_stats(x.get("rot_deg_per_m"), f"{where}.rot_deg_per_m"),
        per_length=tuple(per_length), note=text_or_none(x.get("note"), f"{where}.note"))


__all__ = ["DriveRpe", "ErrorStats", "RPE_LENGTH_KEYS", "SegmentLengthRpe", "drive_rpe_of"]
