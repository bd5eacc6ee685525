"""Serve a `SimController` as a Modbus controller: pymodbus TCP server on 127.0.0.1, RTU over a pty.

Registers follow a `RegisterMap` (docs/hardware/modbus.md). Reads are computed from the
controller's live state; writes execute as controller commands. A refused command
(`SimCommandError`) becomes an exception reply:

- ERR_ARGUMENT, ERR_LIMIT -> 03 illegal data value
- ERR_NOT_ENABLED, ERR_WRONG_MODE, ERR_FAULT -> 04 server device failure
- an unknown command/mode code or a non-finite value -> 03 illegal data value
- a write to a read-only register, an address outside the map, or a write that
  covers only one word of a 32-bit value -> 02 illegal data address

Faults on demand come from `controller.faults` (one per request): timeout = no reply,
garbage = junk bytes instead of the reply, checksum = a corrupted CRC (RTU) or a
malformed MBAP length field (TCP), exception = exception code `faults.exception_code`
instead of executing. The fault code register reads 1 e-stop, 2 limit, 3 servo fault,
4 watchdog expired (the default map's codes), 0 otherwise.

The serving machinery (event loop, TCP listeners, RTU ptys, wire faults, connection cap)
is `bench.sim.modbus_serving.ModbusServing`'s, shared with the simulated chamber.
"""

from __future__ import annotations

import asyncio

from pymodbus.constants import ExcCodes
from pymodbus.simulator import SimDevice

from bench.sim.controller import (
    ERR_ARGUMENT,
    ERR_FAULT,
    ERR_LIMIT,
    ERR_NOT_ENABLED,
    ERR_SYNTAX,
    ERR_WRONG_MODE,
    SimCommandError,
    SimController,
)
from bench.sim.modbus_serving import GARBAGE, ModbusServing, Refused
from bench.sim.serve import IDLE_TIMEOUT_S, MAX_CONNECTIONS
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import DeviceError
from drivers.turntable.base import AxisStatus, TableState
from drivers.turntable.modbus_map import READ_ONLY_REGISTERS, RegisterMap, mask_axes

# Fault code register values the simulator serves.
FAULT_NONE, FAULT_ESTOP, FAULT_LIMIT, FAULT_SERVO, FAULT_WATCHDOG = 0, 1, 2, 3, 4

EXCEPTION_FOR_ERROR = {
    ERR_SYNTAX: ExcCodes.ILLEGAL_FUNCTION,
    ERR_ARGUMENT: ExcCodes.ILLEGAL_VALUE,
    ERR_LIMIT: ExcCodes.ILLEGAL_VALUE,
    ERR_NOT_ENABLED: ExcCodes.DEVICE_FAILURE,
    ERR_WRONG_MODE: ExcCodes.DEVICE_FAILURE,
    ERR_FAULT: ExcCodes.DEVICE_FAILURE,
}

__all__ = ["EXCEPTION_FOR_ERROR", "FAULT_ESTOP", "FAULT_LIMIT", "FAULT_NONE", "FAULT_SERVO", "FAULT_WATCHDOG",
           "GARBAGE", "ModbusSimServer"]


class ModbusSimServer(ModbusServing):
    """The simulated controller as a Modbus server (any number of TCP listeners and RTU ptys).

    `wall_clock` times the watchdog: it guards the link, so it runs on real time even
    when the controller runs on a simulated clock. `max_connections` caps the TCP
    connections each listener serves at once (the excess is accepted and closed at once).
    """

    device_errors = (DeviceError,)

    def __init__(self, controller: SimController, register_map: RegisterMap | None = None,
                 wall_clock: Clock = SYSTEM_CLOCK, watchdog_poll_s: float = 0.02,
                 max_connections: int = MAX_CONNECTIONS, idle_timeout_s: float = IDLE_TIMEOUT_S):
        super().__init__(max_connections, idle_timeout_s)
        self.controller = controller
        self.wire_faults = controller.faults
        self.map = register_map if register_map is not None else RegisterMap.default()
        self.wall_clock = wall_clock
        self.watchdog_poll_s = watchdog_poll_s
        self.watchdog_tripped = False
        self._names = self.map.register_names()
        self._image = {address: 0 for address in self._names}
        self._watchdog_armed = False
        self._watchdog_at = 0.0
        self._device = self._build_device()

    # -- the register space -----------------------------------------------------------
    def _build_device(self) -> SimDevice:
        read_only = {a for a, (name, _, _) in self._names.items() if name in READ_ONLY_REGISTERS}
        return self._register_device(self.map.unit, self._names, lambda address: address in read_only)

    def _read_image(self) -> dict[int, int]:
        self._refresh_state()
        return self._image

    def _fault_code(self, state: TableState) -> int:
        if self.controller.estop:
            return FAULT_ESTOP
        if self.watchdog_tripped:
            return FAULT_WATCHDOG
        if any(a.status & AxisStatus.LIMIT for a in state.axes):
            return FAULT_LIMIT
        if any(a.status & AxisStatus.FAULT for a in state.axes):
            return FAULT_SERVO
        return FAULT_NONE

    def _refresh_state(self) -> None:
        state = self.controller.state()
        self._image.update(self.map.encode_state(state, self._fault_code(state)))

    def _write(self, address: int, values: list[int]) -> None:
        """Store a write and execute what it commands (all under the lock)."""
        m = self.map
        written = {address + i: v for i, v in enumerate(values)}
        touched: dict[tuple[str, int], set[int]] = {}
        for a in written:
            if a in self._names:
                name, k, word = self._names[a]
                touched.setdefault((name, k), set()).add(word)
        for (name, _k), words in touched.items():
            if len(words) != m.width(name):
                raise Refused(ExcCodes.ILLEGAL_ADDRESS, f"write covers one word of 32-bit {name}")
        image = dict(self._image)
        image.update(written)

        def value(name: str, k: int, kind: str) -> float:
            a = getattr(m, name)[k]
            try:
                return m.decode_value([image[a], image[a + 1]], kind)
            except DeviceError as exc:
                raise Refused(ExcCodes.ILLEGAL_VALUE, str(exc)) from exc

        try:
            if ("watchdog", -1) in touched:
                # any other value arms (and feeds) it; 0 releases it (a client closing on purpose)
                self._watchdog_armed = m.watchdog_s > 0 and image[m.watchdog] != 0
                self._watchdog_at = self.wall_clock.now()
            if ("command", -1) in touched:
                try:
                    command = m.decode_command(image[m.command])
                    axes = mask_axes(image[m.command_axes])
                except ValueError as exc:
                    raise Refused(ExcCodes.ILLEGAL_VALUE, str(exc)) from exc
                self._execute(command, axes)
            for k in range(3):
                if ("mode", k) in touched:
                    try:
                        mode = m.decode_mode(image[m.mode[k]])
                    except DeviceError as exc:
                        raise Refused(ExcCodes.ILLEGAL_VALUE, str(exc)) from exc
                    self.controller.set_mode(k, mode)
            for k in range(3):
                if ("demand_position", k) in touched:
                    self.controller.demand_position(k, value("demand_position", k, "angle"),
                                                    value("move_rate", k, "rate"))
            for k in range(3):
                if ("demand_rate", k) in touched:
                    self.controller.demand_rate(k, value("demand_rate", k, "rate"))
        except SimCommandError as exc:
            raise Refused(EXCEPTION_FOR_ERROR.get(exc.code, ExcCodes.DEVICE_FAILURE), str(exc)) from exc
        self._image.update(written)

    def _execute(self, command: str, axes: list[int]) -> None:
        c = self.controller
        if command == "stop":
            c.stop()
        elif command == "abort":
            c.abort()
        else:
            for k in axes:
                {"enable": c.enable, "disable": c.disable, "reset": c.reset}[command](k)
            if command == "reset":
                self.watchdog_tripped = False

    # -- watchdog -------------------------------------------------------------------------
    def check_watchdog(self) -> bool:
        """Trip the watchdog fault if it is armed and not refreshed in time; True if it tripped now."""
        with self._lock:
            if not (self._watchdog_armed and self.map.watchdog_s > 0):
                return False
            if self.wall_clock.now() - self._watchdog_at <= self.map.watchdog_s:
                return False
            self._watchdog_armed = False
            self.watchdog_tripped = True
            for k in range(3):
                self.controller.trip_fault(k, "Modbus watchdog expired")
            return True

    async def _watchdog_loop(self) -> None:
        while True:
            await asyncio.sleep(self.watchdog_poll_s)
            self.check_watchdog()

    def _on_loop_started(self) -> None:
        self._call(self._start_watchdog())

    async def _start_watchdog(self) -> None:
        self._watchdog_task = asyncio.get_running_loop().create_task(self._watchdog_loop())
