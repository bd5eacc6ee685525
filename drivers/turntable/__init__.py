"""Turntable controllers: the common interface and one codec/client pair per dialect.

Dialects load lazily by name (`open_turntable(url, "scpi")`), so importing the
interface does not import pymodbus.
"""

from __future__ import annotations

import importlib
from typing import Callable

from drivers.errors import TurntableConfigError
from drivers.turntable.base import (
    ALL_FRAMES,
    FRAMES,
    AxisLimits,
    AxisMode,
    AxisState,
    AxisStatus,
    TableState,
    Turntable,
    TurntableLimits,
    frame_index,
)

#: dialect name -> "module:class"
DIALECTS = {
    "scpi": "drivers.turntable.scpi:ScpiTurntable",
    "mn": "drivers.turntable.mn:MnTurntable",
    "modbus": "drivers.turntable.modbus:ModbusTurntable",
}


def dialect_class(dialect: str) -> type[Turntable]:
    """The client class of a dialect; TurntableConfigError (a ValueError) naming the known ones otherwise."""
    try:
        module, _, name = DIALECTS[dialect.lower()].partition(":")
    except (KeyError, AttributeError):
        raise TurntableConfigError(f"unknown turntable dialect {dialect!r} (known: {', '.join(DIALECTS)})") from None
    return getattr(importlib.import_module(module), name)


def open_turntable(url: str, dialect: str | None = None, **options) -> Turntable:
    """An unconnected driver for `url` in `dialect` (`modbus+...` URLs imply 'modbus').

    `options` go to the dialect's constructor (limits, clock, timeout_s, retries, ...).
    """
    if dialect is None:
        if not url.startswith(("modbus+tcp://", "modbus+rtu://")):
            raise TurntableConfigError(f"say which dialect {url!r} speaks (known: {', '.join(DIALECTS)})")
        dialect = "modbus"
    if dialect.lower() == "modbus" and not url.startswith(("modbus+tcp://", "modbus+rtu://")):
        raise TurntableConfigError(f"the modbus dialect needs a modbus+tcp:// or modbus+rtu:// URL, got {url!r}")
    if dialect.lower() != "modbus" and url.startswith(("modbus+tcp://", "modbus+rtu://")):
        raise TurntableConfigError(f"{url!r} is a Modbus URL but the dialect is {dialect!r}")
    # Each dialect's constructor takes the URL (or transport) first: not Turntable.__init__'s signature.
    make: Callable[..., Turntable] = dialect_class(dialect)
    return make(url, **options)


__all__ = ["ALL_FRAMES", "DIALECTS", "FRAMES", "AxisLimits", "AxisMode", "AxisState", "AxisStatus", "TableState",
           "Turntable", "TurntableLimits", "dialect_class", "frame_index", "open_turntable"]
