"""Chamber client for the Modbus dialect, TCP or RTU (register map in drivers/chamber/modbus_map.py).

URLs as for the turntable: `modbus+tcp://host[:port][?unit=N]`,
`modbus+rtu:///dev/ttyUSB0?baud=9600&parity=N&unit=N`. The request machinery (retries,
one reconnect, bounded replies) is `drivers.modbus_link`'s, raising the chamber's errors:
no reply -> `ChamberTimeout`; garbage or a bad CRC -> `ChamberProtocolError` /
`ChamberChecksumError`; an exception reply -> `ChamberCommandError(code)`; a lost link
-> `ChamberConnectionError`. drivers/CHAMBER.md documents registers and scaling.
"""

from __future__ import annotations

from drivers.chamber.base import Chamber, ChamberLimits, ChamberState
from drivers.chamber.modbus_map import ChamberRegisterMap
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import CHAMBER_LINK_ERRORS
from drivers.modbus_link import ModbusRequests


class ModbusChamber(ModbusRequests, Chamber):
    """A chamber controller spoken to over Modbus TCP or RTU with a `ChamberRegisterMap`."""

    dialect = "modbus"
    link_errors = CHAMBER_LINK_ERRORS

    def __init__(self, url: str, register_map: ChamberRegisterMap | None = None, limits: ChamberLimits | None = None,
                 clock: Clock = SYSTEM_CLOCK, timeout_s: float = 0.5, retries: int = 2):
        Chamber.__init__(self, limits, clock)
        self.map = register_map if register_map is not None else ChamberRegisterMap.default()
        self.supports_ramp = self.map.has_ramp
        self._setup_link(url, self.map.unit, timeout_s, retries)

    def _open(self) -> None:
        self._connect_link()

    def _close(self) -> None:
        self._close_link()

    def set_setpoint(self, setpoint_c: float, ramp_c_per_min: float | None = None) -> None:
        # a value the int16 registers cannot carry fails before anything is sent
        self.map.encode_temperature(float(setpoint_c))
        if ramp_c_per_min is not None and self.map.has_ramp:
            self.map.encode_ramp(float(ramp_c_per_min))
        super().set_setpoint(setpoint_c, ramp_c_per_min)

    def _set_setpoint(self, setpoint_c: float) -> None:
        self._write_single(self.map.setpoint, self.map.encode_temperature(setpoint_c),
                           f"setpoint {setpoint_c:g} degC")

    def _set_ramp(self, ramp_c_per_min: float) -> None:
        self._write_single(self.map.ramp_rate, self.map.encode_ramp(ramp_c_per_min),
                           f"ramp rate {ramp_c_per_min:g} degC/min")

    def _command(self, name: str) -> None:
        code = self.map.command_code(name)
        self._write_single(self.map.command, code, f"{name} (command {code})")

    def _run(self) -> None:
        self._command("run")

    def _stop(self) -> None:
        self._command("stop")

    def _clear_alarms(self) -> None:
        self._command("clear_alarms")

    def _read_state(self) -> ChamberState:
        blocks = [self._read(start, count, f"read state ({count} registers at {start})")
                  for start, count in self.map.state_reads]
        return self.map.decode_state(blocks, self.clock.now())
