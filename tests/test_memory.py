"""graph.memory: the C heap's free pages go back to the system where the C library can
(glibc) and enough is free, and nothing happens, without error, where it cannot."""

from __future__ import annotations

import ctypes.util
import platform

import pytest

from vislam.graph import memory


@pytest.fixture
def fresh():
    memory._libc.cache_clear()
    yield
    memory._libc.cache_clear()


def test_freed_memory_is_released_on_glibc_when_enough_is_free(fresh):
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        pytest.skip("malloc_trim is glibc's")
    free = memory.free_heap_bytes()
    assert free is None or free >= 0
    assert memory.release_freed_memory(min_free_bytes=0) is True
    if free is not None:  # glibc 2.33+ reports its free heap: a small one is left alone
        assert memory.release_freed_memory(min_free_bytes=2 ** 62) is False


def test_without_malloc_trim_nothing_is_done(fresh, monkeypatch):
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None)
    assert memory.release_freed_memory(min_free_bytes=0) is False
    assert memory.free_heap_bytes() is None
