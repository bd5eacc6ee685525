"""Which frames of a log's CAN topic are the unit's it is read for, in a run of several IMUs on a shared bus.

A live receiver on a bus shared by several units takes only its own frames (`drivers.imu.receiver.BusShare`); so
does the decode of a log, from the log's `units` record (each unit's bus and frame ids): a log written before the
receivers did so holds the other units' frames in `/can/raw` too, and they are theirs, not unknown ids of the
reference unit. A log without a `units` record (a single IMU), or with one this cannot read, is decoded whole.
"""

from __future__ import annotations

import json

from drivers.imu.layout import EXTENDED_ID_FLAG
from drivers.imu.receiver import BusShare, bus_shares

#: the largest 11-bit id: a recorded id above it is a 29-bit one
MAX_STANDARD_ID = 0x7FF


def _keys(unit: dict) -> list[int]:
    """A unit's frame keys from its record: `frame_keys` (exact), or in a log older than them `frame_ids`
    (ids without their format: one above 0x7FF is a 29-bit id, others taken as 11-bit ones, as the bench's
    layouts send them)."""
    if "frame_keys" in unit:
        return [int(key) for key in unit["frame_keys"]]
    ids = [int(str(text), 16) for text in unit["frame_ids"]]
    return [i | EXTENDED_ID_FLAG if i > MAX_STANDARD_ID else i for i in ids]


def recorded_share(metadata: dict[str, dict[str, str]], serial: str | None) -> BusShare | None:
    """The share of its bus of unit `serial` (None: the reference unit, whose frames are `/can/raw`) by the log's
    `units` record; None when it has its bus to itself, or the log has no readable `units` record."""
    try:
        units = json.loads(metadata["units"]["units_json"])
        buses = [(str(unit["bus"]), _keys(unit)) for unit in units]
        index = (next(k for k, unit in enumerate(units) if unit.get("reference")) if serial is None
                 else next(k for k, unit in enumerate(units) if unit.get("serial") == serial))
    except (KeyError, TypeError, ValueError, AttributeError, StopIteration):
        return None     # (a malformed record is reported by whatever needs it: `bench solve` of the units)
    return bus_shares(buses)[index]


__all__ = ["recorded_share"]
