"""One IMU's samples as the TUI shows them (`ImuTrack`, `ImuView`), and the units of a run of several IMUs
(`UnitView`: live state; `UnitOutcome`: result and verdict; `UnitTee`: a unit's samples to the TUI as the run polls
them). No Textual here; `bench.tui.buffer` holds the views under its lock.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from bench.acceptance.verdict import stored_outcome
from bench.finish.finish import Finished
from bench.model.result import CalibrationResult

#: The six IMU channels in display order: gyro x/y/z, accelerometer x/y/z.
CHANNELS = ("gx", "gy", "gz", "ax", "ay", "az")
#: The IMU panel's values are means over this much data (the last whole blocks reaching it): a mean over
#: T seconds resolves one increment step per T, so the 0.1 s blocks of the idle monitor resolved only
#: about 1 deg/h of a 36000 counts/s per deg/s gyro counting whole pulses; over 1 s, 0.1 deg/h.
MEAN_WINDOW_S = 1.0
#: The IMU panel marks its values stale once no sample came for this long on the session's monotonic clock
#: (real seconds): a paused run, a replay paused or ended, a silent IMU. Samples come every 0.1 s or faster
#: (the idle monitor's poll; a run drains the receiver continuously), so 3 s without one is no jitter.
STALE_AFTER_S = 3.0


@dataclass(frozen=True)
class ImuView:
    """The IMU as last seen: latest rates (counts/s), history per channel, link counters."""

    samples: int = 0                       # decoded samples seen by this buffer
    last_counter: int | None = None
    rate_hz: float = math.nan              # the samples' nominal rate
    gyro_cps: tuple[float, float, float] | None = None   # mean over the last MEAN_WINDOW_S, counts/s
    acc_cps: tuple[float, float, float] | None = None
    temperature_c: float = math.nan
    history: tuple[tuple[float, ...], ...] = ((),) * 6  # per channel, oldest first, counts/s
    lost_samples: int = 0
    bad_frames: int = 0
    mean_s: float = 0.0                    # the data the means cover (seconds of samples)
    age_s: float | None = None             # since the last sample came, session clock (s); None: no sample yet

    @property
    def stale(self) -> bool:
        """No sample for `STALE_AFTER_S` or longer: the values shown are old ones."""
        return self.age_s is not None and self.age_s >= STALE_AFTER_S


class ImuTrack:
    """One IMU's recent samples: a ring of `history` samples per channel for the sparklines, and the means over the
    last whole blocks covering `MEAN_WINDOW_S`. Not thread-safe: the buffer calls it with its lock held."""

    def __init__(self, history: int):
        self.history = int(history)
        self.at: float | None = None             # session clock when the last sample came
        self._ring = np.zeros((6, self.history))
        self._fill = 0
        self._blocks: deque[tuple[int, np.ndarray]] = deque()   # (samples, per-channel sums) of recent blocks
        self.samples = 0
        self._last_counter: int | None = None
        self._rate_hz = math.nan
        self._gyro: tuple | None = None
        self._acc: tuple | None = None
        self._temperature = math.nan
        self._mean_s = 0.0

    def add(self, block, now: float) -> None:
        """A block of samples (`drivers.imu.ImuSampleBlock`, not empty) that came at `now` (session clock)."""
        n = len(block)
        rates = np.concatenate([block.gyro_rate, block.acc_rate], axis=1)  # (n, 6) counts/s
        tail = rates[-self.history:].T
        self.at = now
        m = tail.shape[1]
        self._ring = np.roll(self._ring, -m, axis=1)
        self._ring[:, -m:] = tail
        self._fill = min(self.history, self._fill + m)
        self.samples += n
        self._last_counter = int(block.counter[-1])
        self._rate_hz = float(block.rate_hz)
        self._blocks.append((n, rates.sum(axis=0)))
        window = max(1, round(MEAN_WINDOW_S * self._rate_hz)) if math.isfinite(self._rate_hz) else n
        held = sum(k for k, _ in self._blocks)
        while len(self._blocks) > 1 and held - self._blocks[0][0] >= window:   # whole blocks, >= the window
            held -= self._blocks.popleft()[0]
        mean = np.sum([total for _, total in self._blocks], axis=0) / held
        self._mean_s = held / self._rate_hz if self._rate_hz > 0 else math.nan
        self._gyro, self._acc = tuple(map(float, mean[:3])), tuple(map(float, mean[3:]))
        self._temperature = float(block.temperature_c[-1])

    def view(self, lost: int, bad: int, now: float) -> ImuView:
        """What the panel draws, `lost` samples and `bad` frames as the link counted them, aged at `now`."""
        history = tuple(tuple(map(float, row[self.history - self._fill:])) for row in self._ring)
        age = None if self.at is None else max(0.0, now - self.at)
        return ImuView(self.samples, self._last_counter, self._rate_hz, self._gyro, self._acc, self._temperature,
                       history, lost, bad, self._mean_s, age)


def link_counts(stats) -> tuple[int, int]:
    """(lost samples, bad frames) of an `ImuStats` (None: nothing counted)."""
    if stats is None:
        return 0, 0
    return int(stats.lost_samples), int(stats.frame_faults)


@dataclass(frozen=True)
class UnitView:
    """A unit of a run of several IMUs as last seen: its serial, the face it is mounted on, its samples (`imu`),
    and why the run dropped it ('' while it is in the run)."""

    serial: str
    face: str
    imu: ImuView
    dropped: str = ""
    reference: bool = False

    @property
    def state(self) -> str:
        """receiving, waiting (no sample yet), stale (no sample for a while), or dropped with the reason."""
        if self.dropped:
            return f"dropped: {self.dropped}"
        if self.imu.age_s is None:
            return "waiting: no sample yet"
        if self.imu.stale:
            return f"stale: no sample for {self.imu.age_s:.0f} s"
        return "receiving"


@dataclass(frozen=True)
class UnitOutcome:
    """A unit's end of a run: its result (None: none) and one line, its verdict or why it has no result."""

    serial: str
    result: CalibrationResult | None
    text: str

    @property
    def verdict_word(self) -> str:
        """PASS, FAIL, a result without a verdict, or no result and why."""
        if self.result is None:
            return f"no result ({self.text})" if self.text else "no result"
        verdict = self.result.verdict
        return stored_outcome(verdict.to_dict()) if verdict is not None else "result, no verdict"


def unit_outcomes(finished: dict[str, Finished]) -> list[UnitOutcome]:
    """Each unit's end of a run of several IMUs (`RunOutcome.units`): its result and verdict, or why it has none."""
    out = []
    for serial, done in finished.items():
        if done.result is None:
            why = "; ".join(done.failures).removeprefix(f"unit {serial} has no result: ")
            out.append(UnitOutcome(serial, None, why))
            continue
        name = done.result_path.name if done.result_path is not None else "not written"
        quality = f"; quality: {'; '.join(done.failures)}" if done.failures else ""
        out.append(UnitOutcome(serial, done.result, f"result {name}{quality}"))
    return out


class UnitTee:
    """A unit's receiver (a run of several IMUs, a unit other than the reference one) whose polled samples also go
    to `on_samples(serial, block)` (the TUI's buffer): the run polls and records the unit as ever
    (`bench.run.units.UnitsSource`), the buffer sees what was polled. The rest is the receiver's."""

    def __init__(self, serial: str, receiver, on_samples: Callable[[str, Any], None]):
        self.__dict__.update(serial=serial, receiver=receiver, on_samples=on_samples)

    def poll(self, *args, **kwargs):
        block = self.receiver.poll(*args, **kwargs)
        self.on_samples(self.serial, block)
        return block

    def flush(self):
        block = self.receiver.flush()
        self.on_samples(self.serial, block)
        return block

    def __getattr__(self, name: str):
        return getattr(self.receiver, name)

    def __setattr__(self, name: str, value) -> None:
        setattr(self.receiver, name, value)       # on_frames: the receiver's


def units_summary(outcomes: tuple[UnitOutcome, ...]) -> str:
    """Every unit's verdict on one line: 'units: A1 PASS | A2 no result (dropped ...) | B1 FAIL'."""
    return "units: " + " | ".join(f"{o.serial} {o.verdict_word}" for o in outcomes)


__all__ = ["CHANNELS", "MEAN_WINDOW_S", "STALE_AFTER_S", "ImuTrack", "ImuView", "UnitOutcome", "UnitView",
           "UnitTee", "link_counts", "unit_outcomes", "units_summary"]
