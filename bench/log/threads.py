"""How many threads the log reader's pools may use (chunk decompression, CAN frame decoding).

By default a pool has at most `MAX_READER_THREADS`, and never more than the cores this
process may run on (`os.sched_getaffinity`: a reader pinned to one core, `taskset -c 0`,
decompresses inline instead of switching between threads that cannot run at once).
`reader_threads_limited(n)` caps that for the code it wraps, in this thread of control
(a context variable): a task of `bench solve --archive` runs with 1, because there the
cores belong to the Dask workers, one task each (as Dask starts its workers with
`OMP_NUM_THREADS=1`); a reader that spawned threads of its own would compete with the
other workers for the same cores.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

#: the most threads one pool of the reader has (more gains nothing on the logs measured)
MAX_READER_THREADS = 4

_limit: ContextVar[int | None] = ContextVar("reader_threads_limit", default=None)


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system has one)."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except (AttributeError, OSError):     # no affinity on this system (macOS, Windows)
        return os.cpu_count() or 1


def reader_threads(at_most: int = MAX_READER_THREADS) -> int:
    """Threads a pool of the reader may have now (1: work inline, no pool)."""
    limit = _limit.get()
    return max(1, min(at_most, usable_cores(), limit if limit is not None else at_most))


@contextmanager
def reader_threads_limited(threads: int) -> Iterator[None]:
    """Within the block, a pool of the reader has at most `threads` (1: none)."""
    if threads < 1:
        raise ValueError(f"threads must be at least 1, not {threads}")
    token = _limit.set(threads)
    try:
        yield
    finally:
        _limit.reset(token)


__all__ = ["MAX_READER_THREADS", "reader_threads", "reader_threads_limited", "usable_cores"]
