"""The simulated IMU on a CAN bus: `SimImu` samples of the table's true motion sent as DBC frames.

A wire-level peer of the real IMU: frames come from the same encoder the tests check
the decoders against, and go out through a python-can bus (the in-process virtual bus
in tests): a step's frames as one `CanFrameBatch` to a bus that takes batches
(`send_frames`, the simulator's virtual bus), as python-can messages to any other.
Faults on demand, applied to the next matching frames: drop, corrupt the CRC, wrong
length, swap with the following frame (out of order).
"""

from __future__ import annotations

import contextlib
import threading
from dataclasses import dataclass

import can
import numpy as np

from bench.sim.controller import SimController
from bench.sim.imu import ImuSamples, SimImu
from bench.sim.table import SimTable
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.imu.encoder import ImuEncoder
from drivers.imu.frames import FLAG_FD, CanFrameBatch
from drivers.imu.layout import EXTENDED_ID_FLAG, ImuLayout, default_layout


@dataclass
class _Fault:
    kind: str               # "drop", "corrupt", "length", "swap"
    remaining: int
    frame_id: int | None    # arbitration id the fault waits for; None: any frame


class SimCanImu:
    """Sends the frames of a `SimImu` mounted on a simulated table.

    `source` is a `SimController` (its table and its simulated time are used) or a bare
    `SimTable` (time = `clock.now()` since construction).
    """

    def __init__(self, source: SimController | SimTable, imu: SimImu, bus: can.BusABC,
                 layout: ImuLayout | None = None, clock: Clock | None = None,
                 temperature_c: float = 25.0, status: int | None = None):
        if isinstance(source, SimController):
            self.table = source.table
            self._now = source.now
            # commands rewrite the trajectory: read it under their lock
            self._table_lock: contextlib.AbstractContextManager[object] = source.lock
        elif isinstance(source, SimTable):
            self.table = source
            clock = clock if clock is not None else SYSTEM_CLOCK
            t0 = clock.now()
            self._now = lambda: clock.now() - t0
            self._table_lock = contextlib.nullcontext()
        else:
            raise TypeError(f"source must be a SimController or a SimTable, got {type(source).__name__}")
        self.imu, self.bus = imu, bus
        self.layout = layout if layout is not None else default_layout()
        # a real IMU's output saturates, flagged over-range; a time-stamped layout (sbg-ecan) stamps at the IMU's rate
        self.encoder = ImuEncoder(self.layout, saturate=True, rate_hz=imu.rate_hz)
        self._message_flags = np.array([FLAG_FD if m.is_fd else 0 for m in self.layout.messages], np.uint8)
        self.temperature_c = temperature_c
        self.status = status   # None: the layout's healthy status word
        self.frames_sent = 0
        self.samples_sent = 0
        self.error: BaseException | None = None
        self._faults: list[_Fault] = []
        self._held: can.Message | None = None      # a frame waiting to be sent after the next one (swap)
        self._lock = threading.Lock()               # one sender at a time (thread or caller)
        self._fault_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    # -- faults ---------------------------------------------------------------------
    def _add_fault(self, kind: str, n: int, frame_id: int | None) -> None:
        if not (isinstance(n, int) and n >= 1):
            raise ValueError(f"the number of frames must be a positive integer, got {n!r}")
        if frame_id is not None and frame_id not in {m.frame_id for m in self.layout.messages}:
            raise ValueError(f"frame id {frame_id:#x} is not in the layout")
        with self._fault_lock:
            self._faults.append(_Fault(kind, n, frame_id))

    def drop_frames(self, n: int = 1, frame_id: int | None = None) -> None:
        """Do not send the next `n` frames (of `frame_id`, or any)."""
        self._add_fault("drop", n, frame_id)

    def corrupt_crc(self, n: int = 1, frame_id: int | None = None) -> None:
        """Send the next `n` frames with their CRC byte inverted (the last byte without a CRC)."""
        self._add_fault("corrupt", n, frame_id)

    def wrong_length(self, n: int = 1, frame_id: int | None = None) -> None:
        """Send the next `n` frames one byte short."""
        self._add_fault("length", n, frame_id)

    def swap_frames(self, frame_id: int | None = None) -> None:
        """Send the next frame of `frame_id` (default: the layout's last message) after the frame
        that follows it; with the last message of a sample that frame is the next sample's first,
        so one frame arrives out of counter order."""
        self._add_fault("swap", 1, frame_id if frame_id is not None else self.layout.messages[-1].frame_id)

    def _take_fault(self, frame_id: int) -> str | None:
        with self._fault_lock:
            for f in self._faults:
                if f.frame_id is None or f.frame_id == frame_id:
                    f.remaining -= 1
                    if f.remaining == 0:
                        self._faults.remove(f)
                    return f.kind
        return None

    # -- sending --------------------------------------------------------------------
    def _frames(self, samples: ImuSamples) -> CanFrameBatch:
        """The frames of `samples` as one batch of arrays (no per-frame Python work)."""
        # a thermal IMU reports its case temperature; otherwise the constant `temperature_c`
        temperature = samples.temperature_c if samples.temperature_c is not None else self.temperature_c
        frames = self.encoder.encode(samples.counter, samples.gyro_counts, samples.acc_counts,
                                     temperature, self.status)
        flags = np.tile(self._message_flags, len(samples))
        return CanFrameBatch(samples.time_s[frames.sample], frames.ids, frames.data, frames.lengths, flags)

    def _apply_faults(self, messages: list[can.Message]) -> list[can.Message]:
        out: list[can.Message] = []
        for msg in messages:
            if self._held is not None:
                out += [msg, self._held]
                self._held = None
                continue
            kind = self._take_fault(msg.arbitration_id) if self._faults else None
            if kind == "drop":
                continue
            if kind == "corrupt":
                crc_byte = self.layout.message(msg.arbitration_id | (EXTENDED_ID_FLAG if msg.is_extended_id else 0)
                                               ).crc_byte
                data = bytearray(msg.data)
                data[crc_byte if crc_byte is not None else -1] ^= 0xFF
                msg.data = data
            elif kind == "length":
                msg.data = bytearray(msg.data[:-1])
                msg.dlc = len(msg.data)
            elif kind == "swap":
                self._held = msg
                continue
            out.append(msg)
        return out

    def step_to(self, t: float) -> int:
        """Generate every sample ending by simulated time `t`, send its frames; frames sent."""
        with self._lock:
            with self._table_lock:
                samples = self.imu.generate(self.table, t)
            if not len(samples):
                return 0
            batch = self._frames(samples)
            send_frames = getattr(self.bus, "send_frames", None)
            if self._faults or self._held is not None:
                messages = self._apply_faults(batch.messages())
                if send_frames is not None:
                    batch = CanFrameBatch.from_messages(messages)
            elif send_frames is None:
                messages = batch.messages()
            if send_frames is not None:
                send_frames(batch)
                sent = len(batch)
            else:
                send_batch = getattr(self.bus, "send_batch", None)
                if send_batch is not None:
                    send_batch(messages)
                else:
                    for msg in messages:
                        self.bus.send(msg)
                sent = len(messages)
            self.frames_sent += sent
            self.samples_sent += len(samples)
            return sent

    def step(self) -> int:
        """`step_to` the source's current simulated time."""
        return self.step_to(self._now())

    # -- background thread ---------------------------------------------------------------
    def start(self, period_s: float = 0.005) -> None:
        """Send in a background thread, catching up with simulated time every `period_s` (wall time)."""
        if self._thread is not None:
            raise RuntimeError("the simulated IMU is already running")
        if not period_s > 0:
            raise ValueError(f"period_s must be positive, got {period_s}")
        self._stop.clear()
        self.error = None
        self._thread = threading.Thread(target=self._run, args=(period_s,), name="SimCanImu", daemon=True)
        self._thread.start()

    def _run(self, period_s: float) -> None:
        try:
            while not self._stop.is_set():
                self.step()
                self._stop.wait(period_s)
        except BaseException as exc:   # reported by stop(), never lost in the thread
            self.error = exc

    def stop(self) -> None:
        """Stop and join the thread; re-raise what made it fail, if anything did."""
        thread, self._thread = self._thread, None
        if thread is not None:
            self._stop.set()
            thread.join()
        if self.error is not None:
            error, self.error = self.error, None
            raise error

    @property
    def running(self) -> bool:
        return self._thread is not None

    def __enter__(self) -> "SimCanImu":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

