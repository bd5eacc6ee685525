"""A run of several IMUs (`[[imu]]`): one receiver per unit on the run clock, each unit recorded on its own topics.

The sequencer drives the run with the reference unit (the first `[[imu]]` entry) as it drives a single IMU: its
samples time the dwells and turns, its frames and samples go where a single IMU's go (`/can/raw`,
`/imu/samples`). `UnitsSource` is what the sequencer polls instead: each poll drains the reference unit, then every
other unit's receiver, whose frames and samples the recorder writes on the unit's topics
(`bench.log.format.unit_topics`). The log's `units` record names every unit, its bus, ids and mounting.
Units sharing a bus each take only their own frames from it, those of ids no unit has going to the bus's first
unit (`unit_shares`): no unit counts another's frames as faults, and every frame is recorded once.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Callable

from bench.config.load import BenchConfig, ImuConfig
from bench.config.units import bus_name
from bench.errors import BenchError
from bench.log.events import UNIT_DROPPED
from bench.log.recorder import McapRecorder
from drivers.imu import ImuStats
from drivers.imu.receiver import BusShare, ImuReceiver, bus_shares


@dataclass
class UnitLink:
    """A unit other than the reference one: its serial and its receiver."""

    serial: str
    receiver: ImuReceiver


class UnitFailed(BenchError):
    """A unit other than the reference one failed and the configuration says stop (`[run] on_unit_failure`)."""


@dataclass
class _Watch:
    """When a unit's last sample came (run clock, s; None: not polled yet) and its garbled frames then."""

    last_sample_at: float | None = None
    garbled_then: int = 0


def _garbled(stats: ImuStats) -> int:
    """Frames of the unit's own ids it could not use (a shared bus's other ids are not the unit's garbage)."""
    return stats.crc_errors + stats.wrong_length + stats.duplicates + stats.late


class UnitsSource:
    """The sequencer's IMU source in a run of several units: `reference` (a receiver, or the simulator's pumped
    one) polled as ever, then each of `units`, recorded on its own topics by `recorder`.

    A unit that fails (no valid sample for `timeout_s` of the run's clock `now`: silent, or only garbled frames) is
    reported with `warn(message, details)` and dropped: no longer read, its result none and saying why
    (`on_failure` "continue"); or `poll` raises `UnitFailed` and the sequencer stops the run safely ("stop"). A unit
    that loses some samples but keeps sending is not dropped: its lost samples are in its result and its verdict
    judges them ([acceptance] max_lost_samples)."""

    def __init__(self, reference, units: list[UnitLink], recorder: McapRecorder, *,
                 now: Callable[[], float] | None = None, timeout_s: float = 2.0, on_failure: str = "continue",
                 warn: Callable[[str, dict], None] | None = None):
        self._reference, self.units, self._recorder = reference, list(units), recorder
        self._now, self._timeout_s, self._on_failure, self.warn = now, timeout_s, on_failure, warn
        self._watch = {unit.serial: _Watch() for unit in units}
        #: serial -> why it was dropped
        self.dropped: dict[str, str] = {}
        for unit in units:
            unit.receiver.on_frames = self._recording(unit)

    def _recording(self, unit: UnitLink):
        """A unit's frames to its topic: those its receiver took (on a shared bus only its own ids, and the ids of
        no unit when it is the bus's first unit: `drivers.imu.receiver.BusShare`), each frame recorded once."""
        def record(frames) -> None:
            self._recorder.on_unit_can_frames(unit.serial, frames)
        return record

    def poll(self, *args, **kwargs):
        block = self._reference.poll(*args, **kwargs)
        self.drain_units()
        return block

    def drain_units(self, flush: bool = False) -> None:
        """Every other unit's samples received so far to its topic (`flush`: with those still pending); a unit
        silent for longer than the timeout fails (not when flushing at the end)."""
        for unit in list(self.units):
            block = unit.receiver.flush() if flush else unit.receiver.poll()
            if len(block):
                self._recorder.on_unit_imu(unit.serial, block)
            if not flush and self._now is not None:
                self._check(unit, len(block) > 0)

    def _check(self, unit: UnitLink, sampled: bool) -> None:
        assert self._now is not None
        now, watch, stats = self._now(), self._watch[unit.serial], unit.receiver.stats
        if sampled or watch.last_sample_at is None:
            watch.last_sample_at, watch.garbled_then = now, _garbled(stats)
            return
        quiet_s = now - watch.last_sample_at
        if quiet_s <= self._timeout_s:
            return
        garbled = _garbled(stats) - watch.garbled_then
        reason = (f"no valid sample for {quiet_s:.1f} s, {garbled} garbled frame(s) of its ids (CRC, length, late, "
                  f"duplicate)" if garbled else f"silent: no sample for {quiet_s:.1f} s")
        if self._on_failure == "stop":
            raise UnitFailed(f"unit {unit.serial} failed: {reason} ([run] on_unit_failure = \"stop\")")
        self.units.remove(unit)
        self.dropped[unit.serial] = reason
        if self.warn is not None:
            self.warn(f"unit {unit.serial} dropped from the run: {reason}; the other units go on",
                      {UNIT_DROPPED: unit.serial, "reason": reason, "imu_stats": stats.as_dict()})

    def flush(self):
        return self._reference.flush()

    @property
    def stats(self):
        return self._reference.stats

    @property
    def on_frames(self):
        return self._reference.on_frames

    @on_frames.setter
    def on_frames(self, callback) -> None:
        self._reference.on_frames = callback


def unit_record(unit: ImuConfig, reference: bool) -> dict:
    """What the log's `units` record says of one unit."""
    return {"serial": unit.identity.serial, "model": unit.identity.model, "reference": reference,
            "interface": str(unit.interface), "channel": str(unit.channel), "bus": bus_name(unit),
            "rate_hz": unit.rate_hz, "dbc": unit.dbc.name, "layout": unit.layout_name, "id_offset": unit.id_offset,
            "frame_ids": [f"{key & 0x1FFFFFFF:#x}" for key in unit.layout.keys],
            # the ids as keys (bit 31: a 29-bit id): what a decode of the log leaves to each unit of a shared bus
            "frame_keys": list(unit.layout.keys),
            "mounting": unit.mounting_name, "mounting_matrix": [list(row) for row in unit.mounting or ()],
            # only when configured: a run without lever arms records what it always did
            **({"lever_arm_mm": list(unit.lever_arm_mm)} if unit.lever_arm_mm is not None else {})}


def units_metadata(config: BenchConfig) -> dict[str, dict[str, str]]:
    """The log's `units` record of a run of several units ({} for a single IMU)."""
    if not config.several:
        return {}
    return {"units": {"units_json": json.dumps([unit_record(unit, k == 0) for k, unit in enumerate(config.units)]),
                      "reference": config.units[0].identity.serial}}


def unit_shares(config: BenchConfig) -> list[BusShare | None]:
    """Each unit's share of its bus (`drivers.imu.receiver.BusShare`; None: alone on its bus, a single IMU)."""
    if not config.several:
        return [None]
    return bus_shares([(bus_name(unit), unit.layout.keys) for unit in config.units])


def other_serials(config: BenchConfig) -> list[str]:
    """The serials of the units other than the reference one (each its own log topics)."""
    return [unit.identity.serial for unit in config.units[1:]]


__all__ = ["UnitFailed", "UnitLink", "UnitsSource", "other_serials", "unit_record", "unit_shares",
           "units_metadata"]
