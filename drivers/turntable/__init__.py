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
    TABLE_STATE_UNKNOWN,
    AxisLimits,
    AxisMode,
    AxisState,
    AxisStatus,
    StopOutcome,
    StopResult,
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
    "acutrol": "drivers.turntable.acutrol:AcutrolTurntable",
}


_DIALECTS: Dialects[Turntable] = Dialects("turntable", DIALECTS, TurntableConfigError)
#: dialect_class(dialect): the client class (TurntableConfigError naming the known ones for another);
#: check_url_dialect(url, dialect): TurntableConfigError when the URL cannot carry the dialect (Modbus URLs:
#: modbus only);
#: open_turntable(url, dialect=None, **options): an unconnected driver (`modbus+...` URLs imply 'modbus'), `options`
#: going to the dialect's constructor (limits, clock, timeout_s, retries, ...)
dialect_class, check_url_dialect, open_turntable = _DIALECTS.dialect_class, _DIALECTS.check_url_dialect, _DIALECTS.open


__all__ = ["ALL_FRAMES", "DIALECTS", "FRAMES", "MODBUS_SCHEMES", "TABLE_STATE_UNKNOWN", "AxisLimits", "AxisMode",
           "AxisState", "AxisStatus", "StopOutcome", "StopResult", "TableState", "Turntable", "TurntableLimits",
           "check_url_dialect", "dialect_class", "frame_index", "open_turntable"]
