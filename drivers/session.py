"""What every device driver's session shares: the clock and the lock, connect and close under that lock,
the stop and the state read every dialect implements, the check of a state, and a `with` block that makes
the device safe (`safe_stop`) when it ends in an error, then closes it."""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from typing import Any, Generic, Self, TypeVar

from drivers.clock import SYSTEM_CLOCK, Clock

StateT = TypeVar("StateT")


class DeviceSession(ABC, Generic[StateT]):
    """Base of the turntable and chamber drivers; `StateT` is what one `read_state` returns.

    Public methods serialise access with `self._lock` (a poller thread and the sequencer can share a driver).
    """

    dialect: str = ""

    def __init__(self, clock: Clock = SYSTEM_CLOCK):
        self.clock = clock
        self._lock = threading.RLock()

    # -- what a dialect implements -----------------------------------------------
    @abstractmethod
    def _open(self) -> None: ...

    @abstractmethod
    def _close(self) -> None: ...

    @abstractmethod
    def _stop(self) -> None: ...

    @abstractmethod
    def _read_state(self) -> StateT: ...

    @abstractmethod
    def _state_error(self, state: StateT) -> Exception | None:
        """The error a state shows (a fault, an alarm, an e-stop), for `check_state` to raise; None if none."""

    @abstractmethod
    def safe_stop(self) -> Any:
        """Make the device safe, never raising (the `with` block's error is the one that propagates)."""

    # -- the interface -----------------------------------------------------------
    def stop(self) -> None:
        """The device's stop (`_stop`, see the device's interface for what it does)."""
        with self._lock:
            self._stop()

    def read_state(self) -> StateT:
        with self._lock:
            return self._read_state()

    def check_state(self, state: StateT | None = None) -> StateT:
        """Read (or take) a state and raise the error it shows (`_state_error`), if any."""
        state = self.read_state() if state is None else state
        error = self._state_error(state)
        if error is not None:
            raise error
        return state

    def connect(self) -> Self:
        with self._lock:
            self._open()
        return self

    def close(self) -> None:
        with self._lock:
            self._close()

    def __enter__(self) -> Self:
        return self.connect()

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is not None:
                self.safe_stop()
        finally:
            self.close()


__all__ = ["DeviceSession"]
