"""graph.memory: the C heap's free pages go back to the system where the C library can
(glibc), and nothing happens, without error, where it cannot."""

from __future__ import annotations

import ctypes.util
import platform

import pytest

from vislam.graph import memory


def test_freed_memory_is_released_on_glibc():
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        pytest.skip("malloc_trim is glibc's")
    memory._malloc_trim.cache_clear()
    assert memory.release_freed_memory() is True


def test_without_malloc_trim_nothing_is_done(monkeypatch):
    memory._malloc_trim.cache_clear()
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None)
    try:
        assert memory.release_freed_memory() is False
    finally:
        memory._malloc_trim.cache_clear()
