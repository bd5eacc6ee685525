"""Thermal chambers: the common interface and one codec/client pair per dialect.

Dialects load lazily by name (`open_chamber(url, "ascii")`), so importing the interface
does not import pymodbus. drivers/CHAMBER.md documents both dialects.
"""

from __future__ import annotations

import importlib
from typing import Callable

from drivers.chamber.base import ALARM_NAMES, Chamber, ChamberAlarms, ChamberLimits, ChamberState
from drivers.errors import ChamberConfigError
from drivers.transport import MODBUS_SCHEMES

#: dialect name -> "module:class"
DIALECTS = {
    "ascii": "drivers.chamber.ascii:AsciiChamber",
    "modbus": "drivers.chamber.modbus:ModbusChamber",
}


def dialect_class(dialect: str) -> type[Chamber]:
    """The client class of a dialect; ChamberConfigError (a ValueError) naming the known ones otherwise."""
    try:
        module, _, name = DIALECTS[dialect.lower()].partition(":")
    except (KeyError, AttributeError):
        raise ChamberConfigError(f"unknown chamber dialect {dialect!r} (known: {', '.join(DIALECTS)})") from None
    return getattr(importlib.import_module(module), name)


def check_url_dialect(url: str, dialect: str, *, dialect_label: str = "the dialect") -> None:
    """ChamberConfigError when `url` cannot carry `dialect`: Modbus URLs are for the modbus dialect only."""
    is_modbus_url = url.startswith(MODBUS_SCHEMES)
    if dialect.lower() == "modbus" and not is_modbus_url:
        raise ChamberConfigError(f"the modbus dialect needs a modbus+tcp:// or modbus+rtu:// url, got {url!r}")
    if dialect.lower() != "modbus" and is_modbus_url:
        raise ChamberConfigError(f"{url!r} is a Modbus url but {dialect_label} is {dialect!r}")


def open_chamber(url: str, dialect: str | None = None, **options) -> Chamber:
    """An unconnected driver for `url` in `dialect` (`modbus+...` URLs imply 'modbus').

    `options` go to the dialect's constructor (limits, clock, timeout_s, retries, register_map for modbus).
    """
    if dialect is None:
        if not url.startswith(MODBUS_SCHEMES):
            raise ChamberConfigError(f"say which dialect {url!r} speaks (known: {', '.join(DIALECTS)})")
        dialect = "modbus"
    check_url_dialect(url, dialect)
    # Each dialect's constructor takes the URL (or transport) first: not Chamber.__init__'s signature.
    make: Callable[..., Chamber] = dialect_class(dialect)
    return make(url, **options)


__all__ = ["ALARM_NAMES", "DIALECTS", "Chamber", "ChamberAlarms", "ChamberLimits", "ChamberState",
           "check_url_dialect", "dialect_class", "open_chamber"]
