"""Turntable controllers: the common interface and one codec/client pair per dialect.

Dialects load lazily by name (`open_turntable(url, "scpi")`), so importing the
interface does not import pymodbus.
"""

from __future__ import annotations

import importlib
from typing import Callable

from drivers.errors import TurntableConfigError
from drivers.transport import MODBUS_SCHEMES
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


def check_url_dialect(url: str, dialect: str, *, dialect_label: str = "the dialect") -> None:
    """TurntableConfigError when `url` cannot carry `dialect`: Modbus URLs are for the modbus dialect only.

    `dialect_label` names the dialect's source in the message (e.g. "table.dialect").
    """
    is_modbus_url = url.startswith(MODBUS_SCHEMES)
    if dialect.lower() == "modbus" and not is_modbus_url:
        raise TurntableConfigError(f"the modbus dialect needs a modbus+tcp:// or modbus+rtu:// url, got {url!r}")
    if dialect.lower() != "modbus" and is_modbus_url:
        raise TurntableConfigError(f"{url!r} is a Modbus url but {dialect_label} is {dialect!r}")


def open_turntable(url: str, dialect: str | None = None, **options) -> Turntable:
    """An unconnected driver for `url` in `dialect` (`modbus+...` URLs imply 'modbus').

    `options` go to the dialect's constructor (limits, clock, timeout_s, retries, ...).
    """
    if dialect is None:
        if not url.startswith(MODBUS_SCHEMES):
            raise TurntableConfigError(f"say which dialect {url!r} speaks (known: {', '.join(DIALECTS)})")
        dialect = "modbus"
    check_url_dialect(url, dialect)
    # Each dialect's constructor takes the URL (or transport) first: not Turntable.__init__'s signature.
    make: Callable[..., Turntable] = dialect_class(dialect)
    return make(url, **options)


__all__ = ["ALL_FRAMES", "DIALECTS", "FRAMES", "AxisLimits", "AxisMode", "AxisState", "AxisStatus", "TableState",
           "Turntable", "TurntableLimits", "MODBUS_SCHEMES", "check_url_dialect", "dialect_class", "frame_index",
           "open_turntable"]
