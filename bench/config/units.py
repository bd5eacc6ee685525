"""Several IMUs in one run: the `[[imu]]` entries of a configuration, their mountings and their buses.

Each `[[imu]]` entry takes the keys of a single `[imu]` (the loader's own parser reads them) and adds `mounting`
(a named face or a 3x3 matrix), `id_offset` and `lever_arm_mm` (the unit's place from the rotation centre). Checked
here, each with file, line and key: a serial per unit (required, distinct, a safe name: it names the unit's log topics
and output files), a proper rotation, a finite lever arm within bounds, frame ids that stay distinct on a shared bus,
and a bus load each configured bit rate can carry.
"""

from __future__ import annotations

import dataclasses
import math
import re
from typing import Any, Callable

import numpy as np

from bench.config.reader import Table, describe, show, suggest

#: a `bench.config.load.ImuConfig` (not imported: the loader imports this module)
ImuConfig = Any

#: the most `[[imu]]` entries of one configuration
MAX_UNITS = 16
#: how far a mounting matrix may be from a rotation: |C C^T - I| and |det C - 1| per element
ORTHONORMAL_TOLERANCE = 1e-6
#: a unit's serial names its log topics (`/imu/<serial>/...`) and its output files
SERIAL_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
#: the CAN bus load (worst-case bit stuffing) above which a configuration is refused
MAX_BUS_LOAD = 1.0
#: the largest lever arm component, mm: a unit further than this from the table's rotation centre is a typo
MAX_LEVER_ARM_MM = 2000.0

#: `mounting` by name: which of the unit's axes points along the fixture's z (the inner frame's axis, "up" at the
#: table's zero); the other two follow cyclically (x-up: the unit's y along the fixture's x, its z along the
#: fixture's y). Rows: the unit's x, y, z axes in fixture coordinates (the rotation `C_i^b` from fixture to unit).
FACES: dict[str, tuple[tuple[float, ...], ...]] = {
    "z-up": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "z-down": ((1, 0, 0), (0, -1, 0), (0, 0, -1)),
    "x-up": ((0, 0, 1), (1, 0, 0), (0, 1, 0)),
    "x-down": ((0, 0, -1), (0, 1, 0), (1, 0, 0)),
    "y-up": ((0, 1, 0), (0, 0, 1), (1, 0, 0)),
    "y-down": ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
}


def mounting_of(t: Table) -> tuple[str, tuple[tuple[float, ...], ...]]:
    """`mounting` of an `[[imu]]` entry: (its name, or "matrix", and the rotation's rows); default z-up."""
    value = t.get("mounting", "z-up")
    if isinstance(value, str):
        if value not in FACES:
            raise t.error("mounting", f"unknown face {show(value)}" + suggest(value, FACES))
        return value, FACES[value]
    if not (isinstance(value, list) and len(value) == 3):
        raise t.error("mounting", f"must be a face ({', '.join(FACES)}) or 3 rows of 3 numbers, got "
                                  f"{describe(value)}")
    rows = []
    for i, row in enumerate(value):
        if not (isinstance(row, list) and len(row) == 3 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and abs(v) <= 1.0 + 1e-9
                for v in row)):
            raise t.doc.error(t.path + ("mounting", i), f"must be 3 finite numbers within -1..1 (the unit's axis in "
                                                        f"fixture coordinates), got {show(row)}")
        rows.append(tuple(float(v) for v in row))
    matrix = np.array(rows)
    off = float(np.max(np.abs(matrix @ matrix.T - np.eye(3))))
    if off > ORTHONORMAL_TOLERANCE:
        raise t.error("mounting", f"is not orthonormal: its rows are off unit length or perpendicularity by up to "
                                  f"{off:.3g} (allowed {ORTHONORMAL_TOLERANCE:g})")
    if np.linalg.det(matrix) < 0:
        raise t.error("mounting", "is a reflection (determinant -1), not a rotation: the unit's axes must be "
                                  "right-handed")
    return "matrix", tuple(rows)


def lever_arm_of(t: Table) -> tuple[float, float, float] | None:
    """`lever_arm_mm` of an `[[imu]]` entry: the unit's place from the rotation centre in fixture axes, mm; None
    when not given."""
    if not t.has("lever_arm_mm"):
        return None
    value = t.get("lever_arm_mm")
    if not (isinstance(value, list) and len(value) == 3 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise t.error("lever_arm_mm", f"must be 3 finite numbers (the unit's x, y, z from the table's rotation "
                                      f"centre in the fixture's axes, mm), got {show(value)}")
    if max(abs(v) for v in value) > MAX_LEVER_ARM_MM:
        raise t.error("lever_arm_mm", f"{show(value)} puts the unit more than {MAX_LEVER_ARM_MM:g} mm from the "
                                      "table's rotation centre along an axis (the value is in mm)")
    return (float(value[0]), float(value[1]), float(value[2]))


def lever_arm_in_body_m(unit: ImuConfig) -> np.ndarray | None:
    """The unit's lever arm in its own body axes, m (its mounting applied); None without one."""
    if unit.lever_arm_mm is None:
        return None
    rotation = np.eye(3) if unit.mounting is None else np.array(unit.mounting, dtype=float)
    return rotation @ (np.array(unit.lever_arm_mm, dtype=float) * 1e-3)


def frame_bits(length: int, extended: bool) -> int:
    """The most bits one data frame of `length` bytes takes on the bus, with worst-case bit stuffing (and the
    3-bit interframe space); a CAN FD frame counted as if all of it ran at the nominal bit rate (an upper bound)."""
    data = 8 * length
    if extended:
        return data + 67 + (54 + data - 1) // 4
    return data + 47 + (34 + data - 1) // 4


def bus_name(unit: ImuConfig) -> str:
    return f"{unit.interface}:{unit.channel}"


def bus_load(units: list[ImuConfig], bitrate: int) -> float:
    """The share of `bitrate` the units' frames take (worst-case stuffing)."""
    bits_per_s = sum(unit.rate_hz * sum(frame_bits(m.length, m.is_extended_id) for m in unit.layout.messages)
                     for unit in units)
    return bits_per_s / bitrate


def imu_units(root: Table, allowed: tuple[str, ...], parse_one: Callable[[Table], ImuConfig]) -> tuple[ImuConfig, ...]:
    """The checked `[[imu]]` entries of the configuration's root table."""
    entries = root.get("imu")
    if not 1 <= len(entries) <= MAX_UNITS:
        raise root.error("imu", f"must hold 1..{MAX_UNITS} [[imu]] entries, got {len(entries)}")
    units: list[ImuConfig] = []
    serials: dict[str, int] = {}
    for k, entry in enumerate(entries):
        if not isinstance(entry, dict):
            raise root.doc.error(("imu", k), f"must be a table ([[imu]]), got {describe(entry)}")
        t = Table(root.doc, ("imu", k), entry, allowed)
        name, mounting = mounting_of(t)
        offset = t.integer("id_offset", 0, ge=-0x1FFFFFFF, le=0x1FFFFFFF)
        lever_arm = lever_arm_of(t)
        unit = parse_one(t)
        serial = unit.identity.serial
        where = ("imu", k, "identity", "serial")
        if not serial:
            raise root.doc.error(where, "every [[imu]] entry needs its serial ([imu.identity] serial): it names "
                                        "the unit's log topics and output files")
        if not SERIAL_PATTERN.fullmatch(serial):
            raise root.doc.error(where, f"{show(serial)} must be 1..64 letters, digits, '.', '_' or '-' (not "
                                        "first): it names the unit's log topics and output files")
        if serial in serials:
            raise root.doc.error(where, f"{show(serial)} is already the serial of [[imu]] entry "
                                        f"{serials[serial] + 1}")
        serials[serial] = k
        try:
            layout = unit.layout.with_id_offset(offset)
        except ValueError as exc:     # ImuConfigError
            raise t.error("id_offset", str(exc)) from None
        units.append(dataclasses.replace(unit, layout=layout, id_offset=offset, mounting=mounting,
                                         mounting_name=name, lever_arm_mm=lever_arm))
    _check_buses(root, units)
    return tuple(units)


def _check_buses(root: Table, units: list[ImuConfig]) -> None:
    """Units on one bus: distinct frame ids, one bit rate, a load the bit rate carries."""
    buses: dict[str, list[int]] = {}
    for k, unit in enumerate(units):
        buses.setdefault(bus_name(unit), []).append(k)
    for name, members in buses.items():
        owner: dict[int, int] = {}
        for k in members:
            for key in units[k].layout.keys:
                if key in owner:
                    raise root.doc.error(("imu", k, "id_offset"), f"frame id {key & 0x1FFFFFFF:#x} is also sent by "
                                         f"[[imu]] entry {owner[key] + 1} on bus {name}: give the units on one bus "
                                         "distinct id offsets")
                owner[key] = k
        rates: set[int] = {rate for k in members if (rate := units[k].bitrate) is not None}
        if len(rates) > 1:
            raise root.doc.error(("imu", members[-1], "bitrate"), f"the units on bus {name} give different bit "
                                                                  f"rates ({', '.join(map(str, sorted(rates)))})")
        if rates:
            bitrate = rates.pop()
            load = bus_load([units[k] for k in members], bitrate)
            if load > MAX_BUS_LOAD:
                raise root.doc.error(("imu", members[-1]), f"the {len(members)} unit(s) on bus {name} need about "
                                     f"{100 * load:.0f} % of its {bitrate} bit/s (worst-case bit stuffing): put "
                                     "some on another bus, or lower their rates")


__all__ = ["FACES", "MAX_LEVER_ARM_MM", "MAX_UNITS", "bus_load", "frame_bits", "imu_units", "lever_arm_in_body_m",
           "lever_arm_of", "mounting_of"]
