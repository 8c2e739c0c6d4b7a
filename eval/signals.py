"""Ctrl-C and SIGTERM as exceptions, raised where it is safe.

The command line (:mod:`eval.cli`) turns SIGTERM into :class:`Terminated` in the main thread, so
that every clean-up (``finally`` blocks, the output folder's staging, the worker pool) runs as it
does for Ctrl-C's ``KeyboardInterrupt``. Code that must not be interrupted at an arbitrary point
(the worker pool's bookkeeping: an exception inside its locks leaves them broken) waits under
:func:`deferred` and calls :meth:`Deferred.check` where stopping is safe.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from typing import Iterator


class Terminated(BaseException):
    """SIGTERM, raised in the main thread (exit code 143 at the command line)."""


def raise_terminated(signum, frame):
    raise Terminated()


class Deferred:
    """Signals noted while deferred; :meth:`check` raises the first one as its exception."""

    def __init__(self) -> None:
        self.signum: int | None = None

    def note(self, signum, frame) -> None:
        if self.signum is None:
            self.signum = signum

    def check(self) -> None:
        if self.signum == signal.SIGINT:
            raise KeyboardInterrupt()
        if self.signum == signal.SIGTERM:
            raise Terminated()


@contextlib.contextmanager
def deferred() -> Iterator[Deferred]:
    """Within the block SIGINT and SIGTERM only set a flag (checked by the caller through the
    yielded :class:`Deferred`); outside the main thread, where handlers cannot be set, nothing
    changes."""
    state = Deferred()
    if threading.current_thread() is not threading.main_thread():
        yield state
        return
    previous = {s: signal.signal(s, state.note) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield state
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    state.check()  # a signal that came as the block ended
