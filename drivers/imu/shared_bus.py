"""One opened CAN bus read by several IMU receivers: units that share a bus share one adapter or connection.

An SLCAN adapter is one serial port, and a serial port has one reader: two units on the bus of one adapter
cannot each open it. `SharedBus` opens it once; `view(keys)` gives each unit's `ImuReceiver` a bus of its own
(`BusView`) that receives the frames of the unit's ids (`keys`, as `ImuLayout.keys`: the arbitration id, with
`EXTENDED_ID_FLAG` for a 29-bit one), or every frame when `keys` is None. Whichever view is polled reads the
bus and hands each view its frames; a view keeps what it was handed until its own poll, at most
`MAX_PENDING_FRAMES` (beyond, frames are dropped and counted in `frames_dropped`: a view nobody polls any
more, a unit dropped from the run, costs bounded memory). The views are read from one thread (the run's);
a lock keeps two readers from interleaving anyway.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Iterable

import can
import numpy as np

from drivers.imu.frames import CanFrameBatch
from drivers.imu.receiver import read_frames

#: frames a view holds for its receiver before it drops them (about 85 s of a 2 kHz IMU's packed frames)
MAX_PENDING_FRAMES = 1 << 19


class SharedBus:
    """`bus` (opened once, shut down by `shutdown`) read through `view`s."""

    def __init__(self, bus: can.BusABC, max_pending_frames: int = MAX_PENDING_FRAMES):
        self.bus = bus
        self.max_pending_frames = max_pending_frames
        self._views: list[BusView] = []
        # reentrant: a view garbage-collected while the lock is held detaches itself (python-can's __del__)
        self._lock = threading.RLock()

    def view(self, keys: Iterable[int] | None = None) -> "BusView":
        """A bus receiving the frames of `keys` (None: every frame) from now on."""
        view = BusView(self, keys)
        with self._lock:
            self._views.append(view)
        return view

    def _share(self, batch: CanFrameBatch) -> None:
        for view in self._views:
            view._put(batch)

    def _read(self, view: "BusView", timeout_s: float | None, max_frames: int | None) -> CanFrameBatch | None:
        """Read the bus until `view` has a frame or `timeout_s` has passed (None: until a frame comes); then take
        `view`'s frames (at most `max_frames`)."""
        deadline = math.inf if timeout_s is None else time.monotonic() + timeout_s
        with self._lock:
            while not view._pending:
                remaining = max(0.0, deadline - time.monotonic())
                read_frames(self.bus, min(remaining, 1.0), max_frames, self._share)
                if remaining <= 0.0:
                    break
            return view._take(max_frames)

    def _detach(self, view: "BusView") -> None:
        with self._lock:
            if view in self._views:
                self._views.remove(view)

    def shutdown(self) -> None:
        """Shut the bus down (its views receive nothing more)."""
        with self._lock:
            views, self._views = self._views, []
        del views                   # dropped outside the lock
        self.bus.shutdown()


class BusView(can.BusABC):
    """One receiver's bus on a `SharedBus`: the frames of its ids (`recv_frames`, as `ImuReceiver` reads a bus
    that hands over arrays); `send` goes onto the shared bus; `shutdown` detaches the view only."""

    def __init__(self, shared: SharedBus, keys: Iterable[int] | None):
        super().__init__(channel=shared.bus.channel_info)
        self.channel_info = f"{shared.bus.channel_info} (shared)"
        self._shared = shared
        self._keys = None if keys is None else np.array(sorted(set(keys)), dtype=np.int64)
        self._pending: deque[CanFrameBatch] = deque()
        self._pending_frames = 0
        self.frames_dropped = 0

    @property
    def shared(self) -> SharedBus:
        """The shared bus this view reads."""
        return self._shared

    def _put(self, batch: CanFrameBatch) -> None:
        if self._keys is not None:
            batch = batch.select(np.isin(batch.ids, self._keys))
        if not len(batch):
            return
        if self._pending_frames + len(batch) > self._shared.max_pending_frames:
            self.frames_dropped += len(batch)
            return
        self._pending.append(batch)
        self._pending_frames += len(batch)

    def _take(self, limit: int | None) -> CanFrameBatch | None:
        out: list[CanFrameBatch] = []
        room = math.inf if limit is None else limit
        while self._pending and room > 0:
            batch = self._pending.popleft()
            if len(batch) > room:
                self._pending.appendleft(batch[int(room):])
                batch = batch[:int(room)]
            out.append(batch)
            room -= len(batch)
            self._pending_frames -= len(batch)
        return CanFrameBatch.concat(out) if out else None

    def recv_frames(self, timeout: float | None = 0.0, limit: int | None = None) -> CanFrameBatch | None:
        """Wait up to `timeout` for a frame of this view's ids, then take those it holds (at most `limit`) as one
        batch; None when none came."""
        if limit is not None and limit <= 0:
            return None
        return self._shared._read(self, timeout, limit)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        batch = self.recv_frames(timeout, 1)
        return (batch.message(0) if batch is not None else None), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._shared.bus.send(msg, timeout)

    def shutdown(self) -> None:
        self._shared._detach(self)
        super().shutdown()


__all__ = ["MAX_PENDING_FRAMES", "BusView", "SharedBus"]
