"""Injected clocks: core code asks a clock for time and sleeps through it.

`SystemClock` is wall time (monotonic). `ManualClock` only moves when told to, for
tests and for simulated runs that must finish far faster than real time; its `sleep`
advances the time instead of waiting.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    def now(self) -> float:
        """Seconds on this clock's time base (monotonic)."""

    def sleep(self, seconds: float) -> None:
        """Let `seconds` pass on this clock."""


class SystemClock:
    """Wall time from `time.monotonic`, sleeping with `time.sleep`."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class ManualClock:
    """A clock that advances only through `sleep` or `advance` (thread-safe)."""

    def __init__(self, start_s: float = 0.0):
        self._t = float(start_s)
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._t

    def advance(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError(f"a clock cannot go back ({seconds} s)")
        with self._lock:
            self._t += seconds

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self.advance(seconds)


SYSTEM_CLOCK = SystemClock()
