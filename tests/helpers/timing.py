"""Timing a device poll for the benchmarks (benchmarks/table_poll_rtt.py, chamber_speed.py)."""

from __future__ import annotations

import statistics
import time
from typing import Callable


def poll_ms(read: Callable[[], object], polls: int, warm_up: int = 20) -> tuple[float, float]:
    """(median ms, p90 ms) of `polls` calls of `read`, after `warm_up` untimed ones (connection and caches)."""
    for _ in range(warm_up):
        read()
    times = []
    for _ in range(polls):
        t0 = time.perf_counter()
        read()
        times.append(time.perf_counter() - t0)
    times.sort()
    return statistics.median(times) * 1e3, times[int(0.9 * len(times))] * 1e3
