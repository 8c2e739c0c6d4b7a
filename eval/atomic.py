"""Atomic file and directory writing: an error or an interruption never leaves a half-written
output behind.

Files are written to a temporary sibling and renamed over the target (``os.replace`` is atomic
on POSIX within one file system). Whole output folders, and the rule that vislam never replaces
a file it did not write, are :mod:`eval.output_dir`'s.
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


def to_jsonable(x):
    """``json.dumps`` default: numpy scalars and arrays, paths; non-finite floats become null."""
    if isinstance(x, np.generic):
        return to_jsonable(x.item())
    if isinstance(x, np.ndarray):
        return [to_jsonable(v) for v in x.tolist()] if x.ndim else to_jsonable(x.item())
    if isinstance(x, Path):
        return str(x)
    if isinstance(x, float):
        return x if np.isfinite(x) else None
    if isinstance(x, dict):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_jsonable(v) for v in x]
    return x


def json_text(obj) -> str:
    """Strict JSON (NaN and infinity written as null), indented."""
    return json.dumps(to_jsonable(obj), indent=2, allow_nan=False) + "\n"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary sibling file and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the usual file mode
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text(path: str | os.PathLike, text: str) -> None:
    write_bytes(path, text.encode("utf-8"))


def write_json(path: str | os.PathLike, obj) -> None:
    write_text(path, json_text(obj))


def usual_modes(root: Path) -> None:
    """mkdtemp/mkstemp create 0700/0600; give the folder and everything in it the usual modes."""
    mask = _umask()
    os.chmod(root, 0o777 & ~mask)
    for dirpath, dirnames, filenames in os.walk(root):
        for d in dirnames:
            os.chmod(os.path.join(dirpath, d), 0o777 & ~mask)
        for f in filenames:
            os.chmod(os.path.join(dirpath, f), 0o666 & ~mask)


def atomic_symlink(target: str | os.PathLike, link: str | os.PathLike) -> bool:
    """Point ``link`` at ``target`` (relative targets stay relative), replacing it atomically.

    Only a symbolic link is ever replaced: where ``link`` is a file or folder (the user's), it
    is left alone, a warning is logged and False returned."""
    link = Path(link)
    if (link.exists() or link.is_symlink()) and not link.is_symlink():
        log.warning("%s exists and is not a symbolic link; left as it is", link)
        return False
    link.parent.mkdir(parents=True, exist_ok=True)
    tmp = link.parent / f".{link.name}.{os.getpid()}.tmp"
    tmp.unlink(missing_ok=True)
    os.symlink(target, tmp)
    try:
        os.replace(tmp, link)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return True
