"""Turntable controllers: the common interface and one codec/client pair per dialect.

Dialects load lazily by name (`open_turntable(url, "scpi")`), so importing the
interface does not import pymodbus.
"""

from __future__ import annotations

from drivers.dialects import Dialects
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


_DIALECTS: Dialects[Turntable] = Dialects("turntable", DIALECTS, TurntableConfigError)
#: the client class of a dialect (`TurntableConfigError` naming the known ones for another)
dialect_class = _DIALECTS.dialect_class
#: `TurntableConfigError` when a URL cannot carry a dialect: Modbus URLs are for the modbus dialect only
check_url_dialect = _DIALECTS.check_url_dialect
#: `open_turntable(url, dialect=None, **options)`: an unconnected driver (`modbus+...` URLs imply 'modbus');
#: `options` go to the dialect's constructor (limits, clock, timeout_s, retries, ...)
open_turntable = _DIALECTS.open


__all__ = ["ALL_FRAMES", "DIALECTS", "FRAMES", "AxisLimits", "AxisMode", "AxisState", "AxisStatus", "TableState",
           "Turntable", "TurntableLimits", "MODBUS_SCHEMES", "check_url_dialect", "dialect_class", "frame_index",
           "open_turntable"]
