"""Giving freed memory back to the operating system between the phases of a long solve.

GTSAM allocates a Bayes tree as many small blocks (cliques, conditionals, factors). When the
tree is freed, glibc keeps those blocks in its heap for reuse, and the dense matrices allocated
next (the marginals') do not fit in them: on a 4,541-frame drive smoother-isam2 held 2.1 GB
after freeing its iSAM2 solver, of which 1.4 GB was free heap, and its marginals then took
0.8 GB more. ``malloc_trim(0)`` returns the free heap pages (1.4 GB there, in 0.2 s).
Elsewhere (macOS, musl) there is no such call and nothing is done.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.lru_cache(maxsize=1)
def _malloc_trim():
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        return ctypes.CDLL(name).malloc_trim
    except (OSError, AttributeError):  # not glibc
        return None


def release_freed_memory() -> bool:
    """Return the C heap's free pages to the operating system (glibc ``malloc_trim(0)``);
    True where that was done."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True
