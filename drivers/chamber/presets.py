"""The chamber's Modbus register maps by name: the shipped presets and a map from configuration.

`watlow-f4` (the Watlow Series F4P's own registers, `drivers.chamber.watlow_f4`) is the
modbus dialect's default; `generic` (`drivers.chamber.modbus_map`) is a map described
register by register, matching no controller until configured. A configuration table
names its preset with `preset = "..."` (default: watlow-f4).
"""

from __future__ import annotations

from typing import Any, Mapping, Union

from drivers.chamber.modbus_map import GENERIC, ChamberMapError, ChamberRegisterMap
from drivers.chamber.watlow_f4 import PRESET as WATLOW_F4
from drivers.chamber.watlow_f4 import WatlowF4Map

#: a map the modbus client and the simulator serve
ChamberMap = Union[ChamberRegisterMap, WatlowF4Map]
PRESETS = (WATLOW_F4, GENERIC)
DEFAULT_PRESET = WATLOW_F4


def preset_map(name: str) -> ChamberMap:
    """The shipped map called `name` (ChamberMapError naming the presets for another)."""
    if name == WATLOW_F4:
        return WatlowF4Map()
    if name == GENERIC:
        return ChamberRegisterMap()
    raise ChamberMapError(f"no register map preset {name!r} (presets: {', '.join(PRESETS)})")


def default_map() -> ChamberMap:
    """The modbus dialect's map when none is configured: the Watlow F4P's."""
    return preset_map(DEFAULT_PRESET)


def chamber_map_from_dict(d: Mapping[str, Any], source: str = "<dict>") -> ChamberMap:
    """A map from a configuration table: `preset` ("watlow-f4", the default, or "generic") and its keys;
    ChamberMapError naming `source` and the key otherwise."""
    preset = d.get("preset", DEFAULT_PRESET) if isinstance(d, Mapping) else DEFAULT_PRESET
    if preset == GENERIC:
        return ChamberRegisterMap.from_dict(d, source)
    if preset == WATLOW_F4:
        return WatlowF4Map.from_dict(d, source)
    raise ChamberMapError(f"{source}: preset: no register map preset {preset!r} (presets: {', '.join(PRESETS)})")


__all__ = ["ChamberMap", "DEFAULT_PRESET", "PRESETS", "chamber_map_from_dict", "default_map", "preset_map"]
