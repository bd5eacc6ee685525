"""The IMU receiver: a python-can bus drained poll by poll into the stream decoder.

`ImuReceiver({"interface": "socketcan", "channel": "can0", "fd": True}, layout)` opens
the bus with `can.Bus(**config)`; it can also take a bus the caller owns (then `close`
leaves the bus open). Every received frame is handed, untouched (but re-stamped on the run clock with a `time_base`),
to the `on_frames` callback before decoding, so a recorder can log all of them losslessly: each
poll's frames as one `CanFrameBatch` (arrays, and a sequence of python-can messages on demand). On a bus several
IMUs share (`BusShare`), "every frame" is every frame of this receiver's: its own ids, and the ids of no unit when
it is the bus's first unit.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import can
import numpy as np

from drivers.errors import ImuConfigError, ImuConnectionError
from drivers.imu.frames import CanFrameBatch
from drivers.imu.layout import ImuLayout, default_layout
from drivers.imu.samples import ImuSampleBlock, ImuStats
from drivers.imu.slcan_bus import SLCAN_CLIENTS, BulkSlcanBus
from drivers.imu.stream import StreamDecoder

#: python-can's socketcand client logs here
SOCKETCAND_LOGGER = "can.interfaces.socketcand.socketcand"


class IncompleteReadFilter(logging.Filter):
    """Drops python-can's socketcand warning "Got incomplete message => waiting for more data" (and counts it).

    Its client reads the TCP stream 1024 bytes at a time and warns whenever a read ends inside a `< frame >`
    element, which on a byte stream happens as soon as the server wrote more than one read takes (a real
    socketcand, one element per write, causes it as much as the simulated one): the next read completes the
    element and nothing is lost. Its warnings about data it does discard still pass."""

    def __init__(self) -> None:
        super().__init__()
        self.dropped = 0

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str) and record.msg.startswith("Got incomplete message"):
            self.dropped += 1
            return False
        return True


#: installed on `SOCKETCAND_LOGGER` by `open_bus` when it opens a socketcand bus
INCOMPLETE_READ_FILTER = IncompleteReadFilter()


def open_bus(config: Mapping) -> can.BusABC:
    """`can.Bus(**config)`, except that an SLCAN adapter (`interface = "slcan"`) is read by the bulk reader
    `BulkSlcanBus` unless `slcan_client = "python-can"` asks for python-can's own; any failure ->
    `ImuConnectionError` naming interface and channel."""
    if not isinstance(config, Mapping):
        raise ImuConfigError(f"a CAN bus configuration must be a table, got {type(config).__name__}")
    kwargs = dict(config)
    client = kwargs.pop("slcan_client", "bench")
    if client not in SLCAN_CLIENTS:
        raise ImuConfigError(f"slcan_client must be one of {', '.join(SLCAN_CLIENTS)}, got {client!r}")
    where = f"interface {config.get('interface')!r}, channel {config.get('channel')!r}"
    try:
        if kwargs.get("interface") == "slcan" and client == "bench":
            kwargs.pop("interface")
            kwargs.pop("fd", None)           # python-can's Bus takes it for every interface; the adapter decides
            return BulkSlcanBus(**kwargs)
        if kwargs.get("interface") == "socketcand":
            logging.getLogger(SOCKETCAND_LOGGER).addFilter(INCOMPLETE_READ_FILTER)   # idempotent
        return can.Bus(**kwargs)
    except Exception as exc:   # backends raise CanError, OSError, ImportError, ValueError, TypeError...
        raise ImuConnectionError(f"cannot open the CAN bus ({where}): {exc}") from exc


#: A poll takes at most this many frames and drains for at most this long after its first frame (the
#: rest stays queued for the next poll).
MAX_POLL_FRAMES = 65_536
MAX_DRAIN_S = 0.05


def read_frames(bus: can.BusABC, timeout_s: float, max_frames: int | None,
                deliver: Callable[[CanFrameBatch], None]) -> None:
    """One read of `bus`: wait up to `timeout_s` for a first frame, then take what is queued (at most `max_frames`,
    default `MAX_POLL_FRAMES`, and for at most `MAX_DRAIN_S` after the first) and hand it to `deliver` as one batch
    (nothing when nothing came; what was read before a `can.CanError` is still delivered, then the error raised)."""
    limit = max_frames if max_frames is not None else MAX_POLL_FRAMES
    recv_frames = getattr(bus, "recv_frames", None)   # a bus that hands over arrays (the simulator's, a shared one)
    if recv_frames is not None:
        batch = recv_frames(timeout_s, limit)
        if batch is not None and len(batch):
            deliver(batch)
        return
    recv = bus.recv
    messages: list[can.Message] = []
    drain = getattr(bus, "drain_messages", None)   # a bus that can hand over a whole batch
    try:
        msg = recv(timeout_s) if limit > 0 else None
        if msg is not None:
            messages.append(msg)
            if drain is not None and limit > 1:
                messages += drain(None if max_frames is None else limit - 1)
                msg = None
        drain_until = time.monotonic() + MAX_DRAIN_S
        while msg is not None and len(messages) < limit:
            msg = recv(0.0)
            if msg is not None:
                messages.append(msg)
                if not len(messages) % 256 and time.monotonic() > drain_until:
                    break
    finally:
        if messages:
            deliver(CanFrameBatch.from_messages(messages))


class TimeBase:
    """Maps the timestamps a CAN interface puts on frames onto the run clock (`now`, seconds).

    Interfaces stamp frames with their own clock (python-can's virtual and slcan interfaces
    with the epoch, ~1.8e9 s; an adapter with its own counter), while the run clock of a
    hardware run is the host's monotonic clock: one log with both had a duration of half a
    million hours. The offset is taken at the first frame (`offset_s` = interface time - run
    time there); every frame's time becomes interface time - offset_s. `lag_min_s` and
    `lag_max_s` record run time at receipt minus the mapped time over the run: the delivery
    latency, and how far the interface's clock drifts from the run clock (a negative lag:
    frames stamped in the run's future).
    """

    def __init__(self, now: Callable[[], float]):
        self.now = now
        self.offset_s: float | None = None
        self.lag_min_s = math.inf
        self.lag_max_s = -math.inf

    def map(self, batch: CanFrameBatch) -> CanFrameBatch:
        """`batch` re-stamped on the run clock."""
        now = self.now()
        if self.offset_s is None:
            self.offset_s = float(batch.timestamps[0]) - now
        mapped = batch.restamped(batch.timestamps - self.offset_s)
        # the batch's newest frame has the least lag, its oldest the most
        self.lag_min_s = min(self.lag_min_s, now - float(mapped.timestamps[-1]))
        self.lag_max_s = max(self.lag_max_s, now - float(mapped.timestamps[0]))
        return mapped

    def as_dict(self) -> dict[str, float]:
        """The offset and the lag extremes (empty before the first frame)."""
        if self.offset_s is None:
            return {}
        return {"can_time_offset_s": self.offset_s, "can_lag_min_s": self.lag_min_s,
                "can_lag_max_s": self.lag_max_s}


@dataclass(frozen=True)
class BusShare:
    """A bus several IMUs share (distinct ids): which of its frames are this receiver's.

    Frames of `others` (the keys of the other units on the bus) are those units', not faults of this one: they go
    neither to `on_frames` nor to the decoder. Frames of an id no unit has are faults (unknown id) and evidence:
    one receiver of the bus keeps them (`takes_unknown`, the bus's first unit), the others leave them to it; so
    every frame is recorded once, with the unit it belongs to, and counted once."""

    others: frozenset[int]
    takes_unknown: bool
    _others: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # the others' keys as one sorted array, built once: `mine` runs on every poll's batch
        object.__setattr__(self, "_others", np.array(sorted(self.others), dtype=np.int64))

    def mine(self, ids: np.ndarray, own: np.ndarray) -> np.ndarray | None:
        """Which of `ids` (keys: `EXTENDED_ID_FLAG` set for 29-bit ids) are this receiver's, `own` its sorted keys;
        None: all of them."""
        if self.takes_unknown:
            theirs = np.isin(ids, self._others)
        else:
            theirs = ~np.isin(ids, own)
        return ~theirs if theirs.any() else None


def bus_shares(units: Sequence[tuple[str, Iterable[int]]]) -> list[BusShare | None]:
    """Each unit's `BusShare`, for units given as (bus name, keys) in their order (the first unit of a bus takes
    its unknown ids); None for a unit alone on its bus (every frame there is its own, as a single IMU's)."""
    out: list[BusShare | None] = []
    for k, (bus, _) in enumerate(units):
        mates = [j for j, (other, _) in enumerate(units) if other == bus and j != k]
        if not mates:
            out.append(None)
            continue
        others = frozenset(int(key) for j in mates for key in units[j][1])
        out.append(BusShare(others, takes_unknown=min(mates) > k))
    return out


class ImuReceiver:
    """Receive an IMU's frames from a CAN bus and decode them into samples: each poll's frames go to a
    `StreamDecoder` as one piece, and a sample leaves as soon as it is complete and every older counter is
    resolved (the rules: `drivers.imu.rules`).

    With `time_base` (the run clock's `now`, or a `TimeBase` shared by the receivers of one bus), every frame's
    timestamp is mapped onto that clock (`TimeBase`) before anything else sees it: the samples' receive times and
    the logged frames then share the run's one time base. With `share`, the receiver is one of several IMUs on one
    bus and takes only its own frames (`BusShare`); without, every frame on the bus is its (a single IMU's)."""

    def __init__(self, bus: Mapping | can.BusABC, layout: ImuLayout | None = None, rate_hz: float = 1000.0,
                 reorder_window: int = 8,
                 on_frames: Callable[[CanFrameBatch], None] | None = None,
                 time_base: Callable[[], float] | TimeBase | None = None, share: BusShare | None = None):
        if not (isinstance(reorder_window, int) and reorder_window >= 1):
            raise ImuConfigError(f"reorder_window must be a positive integer, got {reorder_window!r}")
        if not (rate_hz > 0 and rate_hz != float("inf")):
            raise ImuConfigError(f"rate_hz must be positive, got {rate_hz!r}")
        self.layout = layout if layout is not None else default_layout()
        self.rate_hz = float(rate_hz)
        self.decoder = StreamDecoder(self.layout, self.rate_hz, reorder_window)
        self.on_frames = on_frames
        # receivers of one shared bus share its TimeBase: a unit's first frames may have waited for its first poll
        self.time_base = time_base if isinstance(time_base, TimeBase) or time_base is None else TimeBase(time_base)
        self.bus: can.BusABC
        if isinstance(bus, can.BusABC):
            self._owns_bus = False
            self.bus = bus
        else:
            self._owns_bus = True
            self.bus = open_bus(bus)
        self.frames_received = 0
        self.non_data_frames = 0    # error and remote frames: logged via on_frames, not decoded
        self.share = share
        self._own_keys = np.array(sorted(self.layout.keys), np.int64)
        self.other_unit_frames = 0  # frames left to the other units sharing the bus (`share`): not this one's faults
        self._closed = False

    def poll(self, max_frames: int | None = None, timeout_s: float = 0.0) -> ImuSampleBlock:
        """Drain the bus: wait up to `timeout_s` for a first frame, then take what is queued
        (at most `max_frames`, default `MAX_POLL_FRAMES`, and for at most `MAX_DRAIN_S` after the
        first frame); returns the samples completed so far (possibly none). The bounds matter on a
        bus that delivers frames as fast as they are read: draining "until empty" never ended there,
        and the caller (the sequencer, checking the table between polls) was starved."""
        if self._closed:
            raise ImuConnectionError("the IMU receiver is closed")
        try:
            read_frames(self.bus, timeout_s, max_frames, self._deliver)
        except can.CanError as exc:
            raise ImuConnectionError(f"CAN bus {self.bus.channel_info!r} failed while receiving: {exc}") from exc
        return self.decoder.take_block()

    def _deliver(self, batch: CanFrameBatch) -> None:
        if self.time_base is not None:
            batch = self.time_base.map(batch)
        self.frames_received += len(batch)
        if self.share is not None:
            mine = self.share.mine(batch.ids, self._own_keys)
            if mine is not None:
                kept = batch.select(mine)
                self.other_unit_frames += len(batch) - len(kept)
                if not len(kept):
                    return
                batch = kept
        if self.on_frames is not None:
            self.on_frames(batch)
        data = batch.data_frames()
        self.non_data_frames += len(batch) - len(data)
        if len(data):
            self.decoder.feed(*data.decoder_arrays())

    def flush(self) -> ImuSampleBlock:
        """End of a recording: resolve every pending sample and return what is left (the bus stays open: frames
        polled after it continue the stream)."""
        self.decoder.flush()
        return self.decoder.take_block()

    @property
    def stats(self) -> ImuStats:
        """A copy of the decoder's counts so far."""
        return ImuStats(**self.decoder.stats.as_dict())

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
