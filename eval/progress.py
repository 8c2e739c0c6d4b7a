"""A progress bar on stderr (tqdm) for long runs, silent unless stderr is a terminal."""

from __future__ import annotations

import sys

class Progress:
    """A progress bar on stderr (tqdm), silent when stderr is not a terminal or when disabled.

    Estimators may call it as ``progress(done, total)`` or use ``progress.update(n)``.
    """

    def __init__(self, desc: str, total: int | None = None, enabled: bool = True, position=None):
        self._bar = None
        if enabled and sys.stderr.isatty():
            from tqdm import tqdm

            self._bar = tqdm(
                total=total, desc=desc, file=sys.stderr, leave=False, position=position,
                dynamic_ncols=True,
            )

    def __call__(self, done: int, total: int | None = None) -> None:
        if self._bar is None:
            return
        if total is not None and self._bar.total != total:
            self._bar.total = total
        self._bar.n = int(done)
        self._bar.refresh()

    def update(self, n: int = 1) -> None:
        if self._bar is not None:
            self._bar.update(n)

    def set_description(self, desc: str) -> None:
        if self._bar is not None:
            self._bar.set_description(desc)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
