"""Before anything moves: is the IMU there, at the configured rate, with the configured layout, and is it the
simulated rig the configuration was written for (`[imu.rig]`, `check_rig_running`, `check_rig_adapter`)?

A hardware run used to find a silent IMU only at its first dwell, after the servos were on
and the table had moved ("no IMU sample for 2.0 s", exit 3). `check_imu_stream` listens
first, on the wall clock, for a bounded time: no frames at all, frames that do not decode
with the configured DBC/layout, or a sample rate off the configured one are a one-line
`ImuCheckError` (exit 2, nothing moved).
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from bench.config.rig import RigIdentity
from bench.errors import BenchError
from drivers.imu.layout import EXTENDED_ID_FLAG, SHIPPED_LAYOUTS, ImuLayout, shipped_layout

#: how long to listen at most, s (wall clock)
CHECK_TIMEOUT_S = 3.0
#: how much of the stream to see before judging the rate, s of samples (and at least MIN_SAMPLES)
CHECK_SPAN_S = 0.5
MIN_SAMPLES = 10
#: measured rate / configured rate must be within this factor of 1
RATE_TOLERANCE = 0.2
#: distinct frame ids noted while listening (enough for any layout; bounded on a busy bus)
MAX_IDS = 256
#: how long an SLCAN adapter may take to answer its serial number, s
RIG_SERIAL_TIMEOUT_S = 1.0


class ImuCheckError(BenchError):
    """The IMU stream is not what the configuration says (one line)."""


def check_imu_stream(receiver, rate_hz: float, where: str, *, timeout_s: float = CHECK_TIMEOUT_S,
                     monotonic: Callable[[], float] = time.monotonic) -> str:
    """Listen on `receiver` (an `ImuReceiver`) until enough samples came or `timeout_s` passed; the
    one-line finding when the stream is fine, `ImuCheckError` otherwise. `where` names the bus."""
    wanted = max(MIN_SAMPLES, int(round(CHECK_SPAN_S * rate_hz)))
    seen: set[int] = set()            # the ids on the bus, to name the layout they belong to
    forward = receiver.on_frames

    def note_ids(messages) -> None:
        if len(seen) < MAX_IDS:
            ids = getattr(messages, "ids", None)     # a `CanFrameBatch`: its id column
            seen.update(np.unique(ids).tolist() if ids is not None else
                        (m.arbitration_id | EXTENDED_ID_FLAG if m.is_extended_id else m.arbitration_id
                         for m in messages))
        if forward is not None:
            forward(messages)

    receiver.on_frames = note_ids
    try:
        return _check(receiver, rate_hz, where, timeout_s, monotonic, wanted, seen)
    finally:
        receiver.on_frames = forward


def _check(receiver, rate_hz: float, where: str, timeout_s: float, monotonic: Callable[[], float], wanted: int,
           seen: set[int]) -> str:
    counters: list[np.ndarray] = []
    times: list[np.ndarray] = []
    got = 0
    deadline = monotonic() + timeout_s
    for _ in range(int(timeout_s / 0.02) + 2):          # bounded: each poll waits at most 20 ms
        block = receiver.poll(timeout_s=0.02)
        if len(block):
            counters.append(block.counter)
            times.append(block.receive_time_s)
            got += len(block)
        if got >= wanted or monotonic() > deadline:
            break
    stats = receiver.stats
    if got == 0:
        if stats.frames == 0:
            raise ImuCheckError(f"no IMU frames on {where} in {timeout_s:g} s: is the IMU powered and on this bus?")
        raise ImuCheckError(f"{stats.frames} CAN frames on {where} in {timeout_s:g} s but no IMU sample decodes with "
                            f"the configured layout ({describe_layout(receiver.layout)}): {stats.unknown_id} unknown "
                            f"ids, {stats.wrong_length} of the wrong length, {stats.crc_errors} CRC errors"
                            + _other_layout(receiver.layout, seen))
    counter, received = np.concatenate(counters), np.concatenate(times)
    span_s = float(received[-1] - received[0])
    if len(counter) >= MIN_SAMPLES and span_s > 0:
        measured_hz = float(counter[-1] - counter[0]) / span_s
        if abs(measured_hz / rate_hz - 1.0) > RATE_TOLERANCE:
            raise ImuCheckError(f"the IMU on {where} sends about {measured_hz:.4g} samples/s, the configuration "
                                f"says imu.rate_hz = {rate_hz:g}")
        return f"IMU on {where}: {got} samples at about {measured_hz:.4g} samples/s"
    return f"IMU on {where}: {got} samples"


def check_rig_running(rig: RigIdentity | None, where: str) -> None:
    """Before anything is opened: `ImuCheckError` when the configuration names a `bench sim rig` ([imu.rig]) that
    no longer runs (its pty or port may be another process's now: a terminal, another rig)."""
    if rig is not None and not rig.running():
        raise ImuCheckError(f"this configuration was written for {rig.describe()}, which is not running: {where} "
                            "may belong to another process now; start `bench sim rig --write-config FILE` again "
                            "(for another bench, remove [imu.rig])")


def check_rig_adapter(bus, rig: RigIdentity | None, where: str, timeout_s: float = RIG_SERIAL_TIMEOUT_S) -> None:
    """`ImuCheckError` when the configuration names a rig and the SLCAN adapter on the bus is not that rig's: its
    serial number (`N`) is the rig's id. Buses that cannot be asked (socketcand, SocketCAN) are not checked."""
    ask = getattr(bus, "get_serial_number", None)
    if rig is None or ask is None:
        return
    serial = ask(timeout_s)
    if serial == rig.id:
        return
    found = (f"the SLCAN adapter on {where} answers serial number {serial!r}" if serial
             else f"nothing on {where} answers as an SLCAN adapter in {timeout_s:g} s")
    raise ImuCheckError(f"{found}, not {rig.describe()} that this configuration was written for: that rig has "
                        "stopped and its pty went to another process; start `bench sim rig --write-config FILE` "
                        "again (for another bench, remove [imu.rig])")


def describe_layout(layout: ImuLayout) -> str:
    """'packed: 3 frames per sample, ids 0x120..0x122' (the shipped name when it is one)."""
    name = next((n for n in SHIPPED_LAYOUTS if shipped_layout(n).messages == layout.messages), None)
    ids = sorted(m.frame_id for m in layout.messages)
    span = f"id {ids[0]:#x}" if len(ids) == 1 else f"ids {ids[0]:#x}..{ids[-1]:#x}"
    frames = f"{len(ids)} frame{'s' if len(ids) > 1 else ''} per sample, {span}"
    return f"{name}: {frames}" if name else f"{layout.source or 'own DBC'}: {frames}"


def _other_layout(layout: ImuLayout, seen: set[int]) -> str:
    """'; the frames are those of the shipped layout "packed": set imu.layout = "packed"', or nothing."""
    for name in SHIPPED_LAYOUTS:
        shipped = shipped_layout(name)
        if shipped.messages != layout.messages and set(shipped.keys) <= seen:
            return (f"; the frames on the bus are those of the shipped layout {name!r} ({describe_layout(shipped)}): "
                    f"set imu.layout = \"{name}\"")
    return ""


__all__ = ["ImuCheckError", "check_imu_stream", "check_rig_adapter", "check_rig_running", "describe_layout"]
