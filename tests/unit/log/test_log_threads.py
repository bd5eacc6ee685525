"""The log reader's thread pools: at most the cores this process may use, and none within
`reader_threads_limited(1)` (an archive task: the cores are the Dask workers')."""

from __future__ import annotations

import pytest

from bench.log import threads
from bench.log.threads import MAX_READER_THREADS, reader_threads, reader_threads_limited


def test_reader_threads_are_capped_by_the_usable_cores_and_the_limit(monkeypatch):
    monkeypatch.setattr(threads, "usable_cores", lambda: 16)
    assert reader_threads() == MAX_READER_THREADS and reader_threads(2) == 2
    monkeypatch.setattr(threads, "usable_cores", lambda: 1)     # pinned to one core: inline
    assert reader_threads() == 1
    monkeypatch.setattr(threads, "usable_cores", lambda: 3)
    assert reader_threads() == 3
    with reader_threads_limited(2):
        assert reader_threads() == 2
        with reader_threads_limited(1):
            assert reader_threads() == 1
        assert reader_threads() == 2
    assert reader_threads() == 3
    with pytest.raises(ValueError, match="at least 1"), reader_threads_limited(0):
        pass


def test_usable_cores_is_this_process_affinity():
    assert 1 <= threads.usable_cores() <= (__import__("os").cpu_count() or 1)
