"""The IMU receiver: a python-can bus drained through the live assembler.

`ImuReceiver({"interface": "socketcan", "channel": "can0", "fd": True}, layout)` opens
the bus with `can.Bus(**config)`; it can also take a bus the caller owns (then `close`
leaves the bus open). Every received frame is handed, untouched, to the `on_frames`
callback before decoding, so a recorder can log all of them losslessly.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import can

from drivers.errors import ImuConfigError, ImuConnectionError
from drivers.imu.assembler import SampleAssembler
from drivers.imu.layout import ImuLayout
from drivers.imu.samples import ImuSampleBlock, ImuStats


def open_bus(config: Mapping) -> can.BusABC:
    """`can.Bus(**config)`; any failure -> `ImuConnectionError` naming interface and channel."""
    if not isinstance(config, Mapping):
        raise ImuConfigError(f"a CAN bus configuration must be a table, got {type(config).__name__}")
    where = f"interface {config.get('interface')!r}, channel {config.get('channel')!r}"
    try:
        return can.Bus(**config)
    except Exception as exc:   # backends raise CanError, OSError, ImportError, ValueError, TypeError...
        raise ImuConnectionError(f"cannot open the CAN bus ({where}): {exc}") from exc


class ImuReceiver:
    """Receive an IMU's frames from a CAN bus and assemble them into samples."""

    def __init__(self, bus: Mapping | can.BusABC, layout: ImuLayout | None = None, rate_hz: float = 1000.0,
                 reorder_window: int = 8,
                 on_frames: Callable[[list[can.Message]], None] | None = None):
        self.assembler = SampleAssembler(layout, rate_hz, reorder_window)
        self.layout, self.rate_hz = self.assembler.layout, self.assembler.rate_hz
        self.on_frames = on_frames
        self.bus: can.BusABC
        if isinstance(bus, can.BusABC):
            self._owns_bus = False
            self.bus = bus
        else:
            self._owns_bus = True
            self.bus = open_bus(bus)
        self.frames_received = 0
        self.non_data_frames = 0    # error and remote frames: logged via on_frames, not decoded
        self._closed = False

    def poll(self, max_frames: int | None = None, timeout_s: float = 0.0) -> ImuSampleBlock:
        """Drain the bus: wait up to `timeout_s` for a first frame, then take what is queued
        (at most `max_frames`); returns the samples completed so far (possibly none)."""
        if self._closed:
            raise ImuConnectionError("the IMU receiver is closed")
        limit = max_frames if max_frames is not None else 1 << 62
        recv = self.bus.recv
        messages: list[can.Message] = []
        drain = getattr(self.bus, "drain_messages", None)   # a bus that can hand over a whole batch
        try:
            msg = recv(timeout_s) if limit > 0 else None
            if msg is not None:
                messages.append(msg)
                if drain is not None and limit > 1:
                    messages += drain(None if max_frames is None else limit - 1)
                    msg = None
            while msg is not None and len(messages) < limit:
                msg = recv(0.0)
                if msg is not None:
                    messages.append(msg)
        except can.CanError as exc:
            raise ImuConnectionError(f"CAN bus {self.bus.channel_info!r} failed while receiving: {exc}") from exc
        finally:
            if messages:
                self._deliver(messages)
        return self.assembler.take_block()

    def _deliver(self, messages: list[can.Message]) -> None:
        self.frames_received += len(messages)
        if self.on_frames is not None:
            self.on_frames(messages)
        data = [m for m in messages if not (m.is_error_frame or m.is_remote_frame)]
        self.non_data_frames += len(messages) - len(data)
        self.assembler.feed_messages(data)

    def flush(self) -> ImuSampleBlock:
        """End of a recording: resolve every pending sample and return what is left."""
        return self.assembler.flush()

    @property
    def stats(self) -> ImuStats:
        return self.assembler.stats

    def close(self) -> None:
        """Shut the bus down if this receiver opened it (idempotent)."""
        if not self._closed:
            self._closed = True
            if self._owns_bus:
                self.bus.shutdown()

    def __enter__(self) -> "ImuReceiver":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
