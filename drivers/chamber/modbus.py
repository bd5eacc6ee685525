"""Chamber client for the Modbus dialect, TCP or RTU (register map in drivers/chamber/modbus_map.py).

URLs as for the turntable: `modbus+tcp://host[:port][?unit=N]`,
`modbus+rtu:///dev/ttyUSB0?baud=9600&parity=N&unit=N`. The request machinery (retries,
one reconnect, bounded replies) is `drivers.modbus_link`'s, raising the chamber's errors:
no reply -> `ChamberTimeout`; garbage or a bad CRC -> `ChamberProtocolError` /
`ChamberChecksumError`; an exception reply -> `ChamberCommandError(code)`; a lost link
-> `ChamberConnectionError`. docs/hardware/chamber.md documents registers and scaling.

The map (default: the Watlow F4P's, `drivers.chamber.watlow_f4`) says what to write for each
command and how to read the state; a map whose scaling lives in the controller (the
F4P's decimal point and degF/degC) is read once per connection, before anything else.
"""

from __future__ import annotations

from drivers.chamber.base import Chamber, ChamberLimits, ChamberState
from drivers.chamber.presets import ChamberMap, default_map
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import CHAMBER_LINK_ERRORS
from drivers.modbus_link import ModbusRequests


class ModbusChamber(ModbusRequests, Chamber):
    """A chamber controller spoken to over Modbus TCP or RTU with a register map (`drivers.chamber.presets`)."""

    dialect = "modbus"
    link_errors = CHAMBER_LINK_ERRORS

    def __init__(self, url: str, register_map: ChamberMap | None = None, limits: ChamberLimits | None = None,
                 clock: Clock = SYSTEM_CLOCK, timeout_s: float = 0.5, retries: int = 2):
        Chamber.__init__(self, limits, clock)
        #: the map as configured; `map` is it with the controller's settings once connected
        self.configured_map: ChamberMap = register_map if register_map is not None else default_map()
        self.map: ChamberMap = self.configured_map
        self.supports_ramp = self.map.has_ramp
        self._setup_link(url, self.map.unit, timeout_s, retries)

    def _open(self) -> None:
        self._connect_link()
        try:
            reads = self.configured_map.settings_reads
            blocks = [self._read(start, count, f"read settings ({count} registers at {start})")
                      for start, count in reads]
            self.map = self.configured_map.configure(blocks)
        except BaseException:
            self._close_link()          # a connection that failed half-way leaves nothing open
            raise

    def _close(self) -> None:
        self._close_link()

    def set_setpoint(self, setpoint_c: float, ramp_c_per_min: float | None = None) -> None:
        # the bench's limits first (a clearer refusal), then what the registers or the controller's own
        # limits cannot carry: both before anything is sent
        self.limits.check_setpoint(float(setpoint_c))
        if ramp_c_per_min:
            self.limits.check_ramp(float(ramp_c_per_min))
        self.map.check_demand(float(setpoint_c), None if ramp_c_per_min is None else float(ramp_c_per_min))
        super().set_setpoint(setpoint_c, ramp_c_per_min)

    def stop_caveat(self) -> str:
        return self.map.stop_caveat

    def _send(self, writes: list[tuple[int, int, str]]) -> None:
        for address, word, what in writes:
            self._write_single(address, word, what)

    def _set_setpoint(self, setpoint_c: float) -> None:
        self._send(self.map.setpoint_writes(setpoint_c))

    def _set_ramp(self, ramp_c_per_min: float) -> None:
        self._send(self.map.ramp_writes(ramp_c_per_min))

    def _command(self, name: str) -> None:
        self._send(self.map.command_writes(name))

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
