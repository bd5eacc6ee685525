"""The simulated chamber behind the Watlow F4P's registers (`drivers.chamber.watlow_f4`).

What a write does, as the F4P's manual describes each register: Set Point 1 sets the
setpoint; Auto/Manual Mode 1 runs (closed loop) and 2 stops; the ramp to set point's
mode, rate and time base together give the ramp (mode off: steps); writing any value to
Clear Error Input 1, Clear Alarm 1 or Clear Alarm 2 clears the latched alarms (the
simulator clears them all on any of the three). The settings registers (decimal point,
degF/degC, set point limits) hold the simulated controller's settings and are not
writable here. Refusals use the exception codes the manual lists: 02 illegal data
address (a register not served or read only), 03 illegal data value (a value out of
range, and run while an alarm is latched).
"""

from __future__ import annotations

from dataclasses import replace

from pymodbus.constants import ExcCodes

from bench.sim.chamber import SimChamber
from bench.sim.modbus_serving import Refused
from drivers.chamber.base import ChamberLimits
from drivers.chamber.watlow_f4 import (
    MODE_AUTO,
    MODE_MANUAL,
    PER_HOUR,
    RAMP_COUNTS,
    RAMP_OFF,
    READ_ONLY,
    SETTINGS,
    WatlowF4Map,
)

#: the simulated F4P's input 1 decimal places when its map does not say
SIM_DECIMALS = 1


class WatlowF4Face:
    """The F4P's registers over a SimChamber: `image()` for reads, `write(address, value)` for writes."""

    def __init__(self, chamber: SimChamber, register_map: WatlowF4Map):
        self.chamber = chamber
        self.map = register_map if register_map.decimals is not None else replace(register_map,
                                                                                   decimals=SIM_DECIMALS)
        p = chamber.physics
        self._settings = self.map.settings_image(ChamberLimits(p.min_setpoint_c, p.max_setpoint_c))
        r = self.map.registers
        # the ramp registers hold what was written (the chamber holds the ramp they mean)
        self._ramp = {r["ramp_mode"]: RAMP_OFF, r["ramp_rate"]: 10 ** (self.map.decimals or 0), r["ramp_scale"]: 0}
        self._unwritable = {r[name] for name in (*READ_ONLY, *SETTINGS)}

    def read_only(self, address: int) -> bool:
        return address in self._unwritable or address not in self.map.register_names()

    def image(self) -> dict[int, int]:
        return {**self._settings, **self._ramp, **self.map.encode_state(self.chamber.state())}

    def write(self, address: int, value: int) -> None:
        r, c, name = self.map.registers, self.chamber, self.map.register_names().get(address)
        if name is None or address in self._unwritable:
            raise Refused(ExcCodes.ILLEGAL_ADDRESS, f"register {address} ({name or 'not served'}) is not writable")
        if name == "setpoint":
            c.set_setpoint(self.map.decode_temperature(value))
        elif name == "mode":
            if value not in (MODE_AUTO, MODE_MANUAL):
                raise Refused(ExcCodes.ILLEGAL_VALUE, f"auto/manual mode {value} (1 auto, 2 manual)")
            (c.run if value == MODE_AUTO else c.stop)()
        elif name in ("clear_input_error", "clear_alarm_1", "clear_alarm_2"):
            c.clear_alarms()
        else:
            allowed = {"ramp_mode": range(3), "ramp_rate": range(RAMP_COUNTS[0], RAMP_COUNTS[1] + 1),
                       "ramp_scale": range(PER_HOUR + 1)}[name]
            if value not in allowed:
                raise Refused(ExcCodes.ILLEGAL_VALUE, f"{name.replace('_', ' ')} {value} is out of range")
            ramp = {**self._ramp, address: value}
            c.set_ramp(self.map.decode_ramp(ramp[r["ramp_mode"]], ramp[r["ramp_rate"]], ramp[r["ramp_scale"]]))
            self._ramp = ramp


__all__ = ["SIM_DECIMALS", "WatlowF4Face"]
