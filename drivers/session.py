"""What every device driver's session shares: connect and close under the driver's lock, and a `with` block
that makes the device safe (`safe_stop`) when it ends in an error, then closes it."""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from typing import Any, Self


class DeviceSession(ABC):
    """Base of the turntable and chamber drivers (a subclass sets `self._lock`, an `RLock`)."""

    _lock: threading.RLock

    @abstractmethod
    def _open(self) -> None: ...

    @abstractmethod
    def _close(self) -> None: ...

    @abstractmethod
    def safe_stop(self) -> Any:
        """Make the device safe, never raising (the `with` block's error is the one that propagates)."""

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
