"""Modbus register maps in a configuration: `register_map = "file.toml"` or an inline `[SECTION.modbus]` table.

The chamber's `register_map` may also name a shipped preset ("watlow-f4", "generic";
`drivers.chamber.presets`), and its tables say `preset = "..."` (default watlow-f4).

One loader for every device with a register map (the turntable's `[table]`, the chamber's
`[chamber]`): the numbers with a documented range are checked here, the rest by the
driver's own map (`RegisterMap.from_dict`, `ChamberRegisterMap.from_dict`), whose error is
turned into one `ConfigError` ``file:line: key: message`` pointing at the offending key.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from bench.config.reader import ConfigError, Located, Table, describe, parse_toml, read_text, show
from bench.errors import InputError
from drivers.chamber.presets import PRESETS, ChamberMap, chamber_map_from_dict, preset_map
from drivers.turntable.modbus_map import RegisterMap
from schedules.tomllines import LineMap, locate_lines


@dataclass(frozen=True)
class MapKind:
    """How one device's register map is built: the driver's builder and the ranges the configuration checks."""

    build: Callable[[Mapping[str, Any], str], Any]
    #: number key -> (lower, upper, unit): what the driver accepts, within a sane range
    ranges: dict[str, tuple[float, float, str]]
    #: names `register_map` may give instead of a file (shipped maps)
    presets: tuple[str, ...] = ()
    preset: Callable[[str], Any] | None = None


TABLE_MAP = MapKind(RegisterMap.from_dict, {"angle_scale_deg": (1e-9, 1.0, "deg"),
                                            "rate_scale_dps": (1e-9, 1.0, "deg/s"), "watchdog_s": (0.0, 3600.0, "s")})
CHAMBER_MAP = MapKind(chamber_map_from_dict, {"temperature_scale_c": (1e-4, 10.0, "degC"),
                                              "ramp_scale_c_per_min": (1e-4, 10.0, "degC/min")}, PRESETS, preset_map)

_MAP_KEY = re.compile(r"(?:unknown key )?([A-Za-z_][\w]*(?:\.\w+)*)(?=[: ])")


def build_map(data: Any, source: str, lines: LineMap, prefix: tuple, kind: MapKind) -> Any:
    """A register map from a parsed TOML table; a ConfigError at the offending key's line otherwise."""
    if isinstance(data, dict):  # the driver checks the rest (types, unknown keys, registers)
        numbers = Table(Located(source, lines, Path(".")), prefix, data, allowed=tuple(data))
        for key, (low, high, unit) in kind.ranges.items():
            if numbers.has(key) and isinstance(data[key], (int, float)) and not isinstance(data[key], bool):
                numbers.number(key, ge=low, le=high, unit=unit)
    try:
        return kind.build(data, source)
    except ValueError as exc:         # RegisterMapError and ChamberMapError are ValueErrors
        message = str(exc).removeprefix(f"{source}: ")
        found = _MAP_KEY.match(message)
        path = prefix
        if found and (found.group(0).startswith("unknown key") or message[found.end():].startswith((":", " must"))):
            key = found.group(1)
            path = prefix + tuple(key.split("."))
            message = message.replace(f"unknown key {key}", "unknown key", 1).removeprefix(key).lstrip(": ")
        raise ConfigError(source, lines.line(*path), ".".join(map(str, path)) or None, message) from exc


def load_map_file(path: str | Path, kind: MapKind) -> Any:
    """A register map file (a [modbus] table, or its keys at the top level): a ConfigError
    `file:line: key: message` when it cannot be used."""
    text = read_text(Path(path), "the register map file")
    data, lines = parse_toml(text, str(path)), locate_lines(text)
    prefix: tuple[str, ...] = ()
    if "modbus" in data:
        for key in data:
            if key != "modbus":
                raise ConfigError(str(path), lines.line(key), key,
                                  "unknown key (a register map file holds one [modbus] table)")
        data, prefix = data["modbus"], ("modbus",)
    return build_map(data, str(path), lines, prefix, kind)


def load_register_map(path: str | Path) -> RegisterMap:
    """The turntable's register map file (`bench table --register-map`, `[table] register_map`)."""
    return load_map_file(path, TABLE_MAP)


def load_chamber_register_map(path: str | Path) -> ChamberMap:
    """The chamber's register map: a preset's name or a file (`bench chamber --register-map`,
    `bench sim chamber --register-map`, `[chamber] register_map`)."""
    if CHAMBER_MAP.preset is not None and str(path) in CHAMBER_MAP.presets:
        return CHAMBER_MAP.preset(str(path))
    if not Path(path).exists() and not Path(path).suffix:
        raise InputError(f"no register map preset or file {show(str(path))} (presets: "
                         f"{', '.join(CHAMBER_MAP.presets)})")
    return load_map_file(path, CHAMBER_MAP)


def register_map_value(t: Table, dialect: str, section: str, kind: MapKind) -> Any:
    """`register_map = "file.toml"` or an inline `[SECTION.modbus]` of table `t` (None when neither is given)."""
    inline, in_file = t.has("modbus"), t.has("register_map")
    if not (inline or in_file):
        return None
    if dialect != "modbus":
        raise t.error("modbus" if inline else "register_map",
                      f"a register map is for the modbus dialect only ({section}.dialect is {dialect!r})")
    if inline and in_file:
        raise t.error("register_map", f"give either register_map (a file) or a [{section}.modbus] table, not both")
    if inline:
        data = t.get("modbus")
        if not isinstance(data, dict):
            raise t.error("modbus", f"must be a table ([{section}.modbus]), got {describe(data)}")
        return build_map(data, t.doc.source, t.doc.lines, t.path + ("modbus",), kind)
    name = t.get("register_map")
    if kind.preset is not None and name in kind.presets:
        return kind.preset(name)
    path = t.file("register_map")
    if not t.is_file("register_map", path):
        if path.exists():  # a directory, a device such as /dev/zero, a FIFO
            raise t.error("register_map", f"{show(str(path))} is not a regular file")
        presets = f" (or a preset: {', '.join(kind.presets)})" if kind.presets else ""
        raise t.error("register_map", f"no such register map file {show(str(path))}{presets}")
    return load_map_file(path, kind)


__all__ = ["CHAMBER_MAP", "TABLE_MAP", "MapKind", "build_map", "load_chamber_register_map", "load_map_file",
           "load_register_map", "register_map_value"]
