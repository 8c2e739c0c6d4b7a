"""Giving freed memory back to the operating system between the phases of a long solve.

GTSAM allocates a Bayes tree as many small blocks (cliques, conditionals, factors). When the
tree is freed, glibc keeps those blocks in its heap for reuse, and the dense matrices allocated
next (the marginals') do not fit in them: on a 4,541-frame drive smoother-isam2 held 2.1 GB
after freeing its iSAM2 solver, of which 1.4 GB was free heap, and its marginals then took
0.8 GB more. ``malloc_trim(0)`` returns the free heap pages (1.4 GB there, in 0.2 s). A small
free heap is left alone: trimming it only makes the next allocations fault the pages in again
(2-3 % of a 300-frame smoother's time). Elsewhere (macOS, musl) nothing is done.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

#: Free heap below which nothing is returned (bytes).
MIN_FREE_BYTES = 256 * 2 ** 20


class _MallInfo2(ctypes.Structure):
    """glibc's ``struct mallinfo2`` (2.33 and later): ten ``size_t`` fields."""

    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
        "fordblks", "keepcost")]


@functools.lru_cache(maxsize=1)
def _libc():
    """(malloc_trim, mallinfo2 or None), or None where the C library is not glibc."""
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        libc = ctypes.CDLL(name)
        trim = libc.malloc_trim
    except (OSError, AttributeError):  # not glibc
        return None
    info = getattr(libc, "mallinfo2", None)
    if info is not None:
        info.restype = _MallInfo2
    return trim, info


def free_heap_bytes() -> int | None:
    """The C heap's free bytes (glibc's ``mallinfo2().fordblks``); None where unknown."""
    libc = _libc()
    if libc is None or libc[1] is None:
        return None
    return int(libc[1]().fordblks)


def release_freed_memory(min_free_bytes: int = MIN_FREE_BYTES) -> bool:
    """Return the C heap's free pages to the operating system (glibc ``malloc_trim(0)``) when
    at least ``min_free_bytes`` are free (always, where glibc cannot say); True where that
    was done."""
    libc = _libc()
    if libc is None:
        return False
    free = free_heap_bytes()
    if free is not None and free < min_free_bytes:
        return False
    libc[0](0)
    return True
