"""Output folders that never lose a user's files.

Every command that writes results (``run``, ``bench``, ``nees``, ``simulate``) goes through
:class:`OutputDir`. The rules, all checked when the folder is opened, before any estimation:

* ``--out`` missing: it is created, with its parents (removed again if the command fails).
* ``--out`` an empty folder, or a folder holding vislam's marker file: it is used.
* ``--out`` a non-empty folder without the marker: an error, unless ``force``; even then vislam
  never replaces or removes a file it did not write (a name clash is an error).
* ``--out`` a file, below a file, not writable, or the folder of an input (the data, its
  ground truth, a settings file): an error.

The results are built in a hidden staging folder and moved in only when complete, so an error,
Ctrl-C or SIGTERM leaves ``--out`` as it was. The marker (``.vislam-output.json``) records each
file vislam wrote with its SHA-256; a later run replaces only the files listed there, and only
while they are unchanged. Nothing is ever deleted: files of an earlier run that this run does
not write again stay (the marker could have been copied or edited by hand, so it is no proof
that a file is vislam's to delete). Writers of
the same folder are serialised by an advisory lock (``flock``) on its parent while the staging
folder is moved in; each file is replaced atomically (``os.replace``).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

from vislam.ekf.errors import InputError
from vislam.eval.atomic import usual_modes, write_text
from vislam.eval.signals import deferred

log = logging.getLogger(__name__)

#: The file recording what vislam wrote in a folder.
MARKER = ".vislam-output.json"
_STAGING = ".vislam-staging-"
_MARKER_SCHEMA = 1


class OutputDir:
    """One command's output folder; use as a context manager around the whole command::

        with OutputDir(args.out, force=args.force, inputs=[args.file], expected=FILES) as tmp:
            ...estimate, then write every file into ``tmp``...
        # on leaving the block without an exception the files are in ``args.out``

    ``expected``: relative paths the command will write (checked for clashes before any
    work); ``inputs``: files the command reads (data, ground truth, settings), whose folders
    are refused; ``flag`` names the option in messages.
    """

    def __init__(
        self,
        out: str | os.PathLike,
        *,
        force: bool = False,
        inputs: Iterable[str | os.PathLike] = (),
        expected: Iterable[str] = (),
        flag: str = "--out",
    ) -> None:
        self.requested = Path(out)
        self.flag = flag
        try:
            self.final = Path(os.path.abspath(out))
        except FileNotFoundError:  # a relative path, and the current folder was deleted
            raise InputError(f"{flag} {out}: the current folder no longer exists; "
                             "give an absolute path") from None
        self.force = force
        self.inputs = [Path(os.path.abspath(p)) for p in inputs if p is not None and str(p)]
        self.expected = list(expected)
        self.staging: Path | None = None
        self._created: list[Path] = []

    # --- the context manager -------------------------------------------------------------
    def __enter__(self) -> Path:
        # Making and recording the staging folder is one step for signals: a SIGTERM between
        # the two would leave a folder nobody removes.
        try:
            with deferred():
                self.check()
                self.staging = self._make_staging()
        except BaseException:
            self._cleanup()
            raise
        return self.staging

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is None:
                self.commit()
        finally:
            self._cleanup()
        return False

    # --- checks ----------------------------------------------------------------------------
    def _where(self) -> str:
        return f"{self.flag} {self.requested}"

    def check(self) -> None:
        """Every check that does not write: raises :class:`InputError` naming the fault."""
        final = self.final
        for inp in self.inputs:
            folder = inp if inp.is_dir() else inp.parent
            if _same(final, inp):
                raise InputError(f"{self._where()}: is the input {inp}; choose another folder")
            if _same(final, folder):
                raise InputError(
                    f"{self._where()}: is the folder of the input {inp}; choose another folder "
                    "(vislam never writes results among the data)"
                )
        if final.is_symlink() and not final.exists():
            raise InputError(f"{self._where()}: is a broken symbolic link")
        if final.exists() and not final.is_dir():
            raise InputError(f"{self._where()}: exists and is a file, not a folder")
        if not final.exists():
            anc = final.parent
            while not anc.exists():
                if anc.is_symlink():
                    raise InputError(f"{self._where()}: {anc} is a broken symbolic link")
                anc = anc.parent
            if not anc.is_dir():
                raise InputError(f"{self._where()}: {anc} is a file, not a folder")
            return
        with _locked(final.parent):  # a concurrent writer's commit is never seen half done
            self._check_existing()

    def _others(self) -> list[str]:
        """The folder's entries other than vislam's marker and staging folders."""
        return [e for e in _entries(self.final) if e != MARKER and not e.startswith(_STAGING)]

    def _check_existing(self) -> None:
        owned = self._owned()
        entries = self._others()
        if entries and owned is None and not self.force:
            shown = ", ".join(repr(e) for e in sorted(entries)[:3])
            more = f" and {len(entries) - 3} more" if len(entries) > 3 else ""
            raise InputError(
                f"{self._where()}: folder exists and holds files vislam did not write "
                f"({shown}{more}); choose a new folder, or add --force to write beside them "
                "(vislam never replaces files it did not write)"
            )
        for rel in self.expected:
            self._check_replaceable(rel, owned or {})

    def _owned(self) -> dict[str, str] | None:
        """The marker's {relative path: sha256}, or None without a (readable) marker."""
        path = self.final / MARKER
        if not path.is_file():
            return None
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            files = data["files"]
            if not isinstance(files, dict):
                raise TypeError("files is not a table")
            return {str(k): str(v) for k, v in files.items()}
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise InputError(
                f"{self._where()}: unreadable marker file {MARKER} ({exc}); remove it only if "
                "the folder holds nothing of yours"
            ) from None

    def _check_replaceable(self, rel: str, owned: dict[str, str]) -> None:
        """``rel`` may be written: absent, or a file vislam wrote and nobody changed since."""
        target = self.final / rel
        parts = Path(rel).parts
        for i in range(1, len(parts)):  # a parent component that is a file blocks the path
            p = self.final.joinpath(*parts[:i])
            if p.is_symlink() or (p.exists() and not p.is_dir()):
                raise InputError(f"{self._where()}: {p} is in the way of {rel!r} and was not "
                                 "written by vislam; nothing was written")
        if not (target.exists() or target.is_symlink()):
            return
        if target.is_dir() and not target.is_symlink():
            # A folder vislam wrote (e.g. a sequence's folder of the benchmark) may be reused
            # when everything in it is vislam's.
            for dirpath, _, filenames in os.walk(target):
                for f in filenames:
                    sub = os.path.relpath(os.path.join(dirpath, f), self.final)
                    self._check_replaceable(sub, owned)
            return
        if rel in owned and not target.is_symlink() and _sha256(target) == owned[rel]:
            return
        why = "was changed since vislam wrote it" if rel in owned else "was not written by vislam"
        raise InputError(f"{self._where()}: {rel!r} exists and {why}; nothing was written "
                         "(vislam never replaces files it did not write)")

    # --- staging -----------------------------------------------------------------------------
    def _make_staging(self) -> Path:
        final = self.final
        try:
            if final.is_dir():
                return Path(tempfile.mkdtemp(dir=final, prefix=_STAGING))
            self._mkdir_parents(final.parent)
            return Path(tempfile.mkdtemp(dir=final.parent, prefix=f".{final.name}{_STAGING}"))
        except OSError as exc:
            where = final if final.is_dir() else final.parent
            raise InputError(f"{self._where()}: cannot write in {where} "
                             f"({exc.strerror or exc})") from None

    def _mkdir_parents(self, folder: Path) -> None:
        missing = []
        p = folder
        while not p.exists():
            missing.append(p)
            p = p.parent
        for p in reversed(missing):
            p.mkdir()
            self._created.append(p)

    def _cleanup(self) -> None:
        with deferred():  # a signal waits until the staging folder is gone
            self._remove_staging()

    def _remove_staging(self) -> None:
        if self.staging is not None and (self.staging.exists() or self.staging.is_symlink()):
            _remove_tree(self.staging)
        self.staging = None
        for p in reversed(self._created):  # parents made for a folder that was never written
            with contextlib.suppress(OSError):
                p.rmdir()
        self._created = []

    # --- commit -----------------------------------------------------------------------------
    def commit(self) -> None:
        """Move the staged files into place (under the lock, with SIGINT/SIGTERM deferred)."""
        staging = self.staging
        assert staging is not None, "commit() outside the with block"
        new = {rel: _sha256(staging / rel) for rel in _files(staging)}
        usual_modes(staging)
        with deferred(), _locked(self.final.parent):  # a signal waits until all is moved in
            if not self.final.exists():
                if staging.parent == self.final.parent:
                    _write_marker(staging, new, {})
                    os.rename(staging, self.final)
                    self.staging = None
                    self._created = []
                    return
                raise InputError(f"{self._where()}: folder disappeared while vislam was running")
            self._merge(new)
        self._created = []

    def _merge(self, new: dict[str, str]) -> None:
        staging = self.staging
        owned = self._owned()
        if owned is None and self._others() and not self.force:
            raise InputError(f"{self._where()}: files appeared in the folder while vislam was "
                             "running; nothing was written")
        owned = owned or {}
        for rel in new:  # every clash is found before anything is moved
            self._check_replaceable(rel, owned)
        keep: dict[str, str] = {}
        for rel, sha in owned.items():
            if rel in new:
                continue
            target = self.final / rel
            unchanged = target.is_file() and not target.is_symlink() and _sha256(target) == sha
            if not unchanged:
                continue  # gone, or changed by the user: no longer vislam's
            keep[rel] = sha  # an earlier run's file: left in place (never deleted)
        for rel in sorted(new):
            target = self.final / rel
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(staging / rel, target)
        _write_marker(self.final, new, keep)


# --- helpers ---------------------------------------------------------------------------------


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _entries(folder: Path) -> list[str]:
    try:
        return os.listdir(folder)
    except OSError:
        return []


def _files(root: Path) -> list[str]:
    out = []
    for dirpath, _, filenames in os.walk(root):
        for f in filenames:
            out.append(os.path.relpath(os.path.join(dirpath, f), root))
    return sorted(out)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _write_marker(folder: Path, new: dict[str, str], keep: dict[str, str]) -> None:
    files = {**keep, **new}
    text = json.dumps({
        "schema": _MARKER_SCHEMA,
        "written_by": "vislam",
        "note": "files vislam wrote here (path: sha256); vislam replaces only these, and only "
                "while unchanged; it deletes nothing",
        "files": dict(sorted(files.items())),
    }, indent=2) + "\n"
    write_text(folder / MARKER, text)


def _remove_tree(path: Path) -> None:
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink(missing_ok=True)
    except OSError as exc:  # pragma: no cover - best effort clean-up
        log.warning("could not remove %s: %s", path, exc)


@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    """An exclusive advisory lock on ``folder`` (the output's parent) for the commit."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
