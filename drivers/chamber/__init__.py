"""Thermal chambers: the common interface and one codec/client pair per dialect.

Dialects load lazily by name (`open_chamber(url, "ascii")`), so importing the interface
does not import pymodbus. docs/hardware/chamber.md documents both dialects.
"""

from __future__ import annotations

from drivers.chamber.base import ALARM_NAMES, Chamber, ChamberAlarms, ChamberLimits, ChamberState
from drivers.dialects import Dialects
from drivers.errors import ChamberConfigError

#: dialect name -> "module:class"
DIALECTS = {
    "ascii": "drivers.chamber.ascii:AsciiChamber",
    "modbus": "drivers.chamber.modbus:ModbusChamber",
}


_DIALECTS: Dialects[Chamber] = Dialects("chamber", DIALECTS, ChamberConfigError)
#: dialect_class(dialect): the client class (ChamberConfigError naming the known ones for another);
#: check_url_dialect(url, dialect): ChamberConfigError when the URL cannot carry the dialect (Modbus URLs:
#: modbus only);
#: open_chamber(url, dialect=None, **options): an unconnected driver (`modbus+...` URLs imply 'modbus'), `options`
#: going to the dialect's constructor (limits, clock, timeout_s, retries, register_map for modbus)
dialect_class, check_url_dialect, open_chamber = _DIALECTS.dialect_class, _DIALECTS.check_url_dialect, _DIALECTS.open


__all__ = ["ALARM_NAMES", "DIALECTS", "Chamber", "ChamberAlarms", "ChamberLimits", "ChamberState",
           "check_url_dialect", "dialect_class", "open_chamber"]
