"""Serve a `SimController` as a Modbus controller: pymodbus TCP server on 127.0.0.1, RTU over a pty.

Registers follow a `RegisterMap` (drivers/MODBUS.md). Reads are computed from the
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

pymodbus's server is asyncio-based: it runs on an event loop in one dedicated thread;
the RTU server sits on one pty of a pair bridged by a thread to a second pty whose
path clients open. `close()` stops everything and joins the threads.

Connections cost no thread here and pymodbus forgets each one when it ends, but their
number is capped like the line servers' (`bench.sim.serve.MAX_CONNECTIONS` per TCP
listener): one more is accepted and closed at once, so idle clients cannot use up the
process's file descriptors.
"""

from __future__ import annotations

import asyncio
import logging
import os
import select
import threading
import tty

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType
from pymodbus.pdu import ExceptionResponse
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

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
from bench.sim.serve import MAX_CONNECTIONS
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import TurntableError
from drivers.turntable.base import AxisStatus, TableState
from drivers.turntable.modbus_map import READ_ONLY_REGISTERS, RegisterMap, mask_axes

# pymodbus logs refused requests at ERROR; keep them out of stderr unless logging is configured.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

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

GARBAGE = bytes.fromhex("de ad be ef 00 ff 13 37 42")


class _CloseAtOnce(asyncio.Protocol):
    """The protocol of a connection beyond the cap: closed as soon as it is made."""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        transport.close()


class _BoundedTcpServer(ModbusTcpServer):
    """pymodbus's TCP server serving at most `max_connections` connections at once."""

    def __init__(self, *args, max_connections: int = MAX_CONNECTIONS, **kwargs):
        super().__init__(*args, **kwargs)
        self.max_connections = max_connections
        self.refused = 0

    def handle_new_connection(self):
        # the listener's protocol factory; active_connections holds the live connections only
        if len(self.active_connections) >= self.max_connections:
            self.refused += 1
            return _CloseAtOnce()
        return super().handle_new_connection()


class _Refused(Exception):
    def __init__(self, code: ExcCodes, message: str):
        super().__init__(message)
        self.code = code


class ModbusSimServer:
    """The simulated controller as a Modbus server (any number of TCP listeners and RTU ptys).

    `wall_clock` times the watchdog: it guards the link, so it runs on real time even
    when the controller runs on a simulated clock. `max_connections` caps the TCP
    connections each listener serves at once (the excess is accepted and closed at once).
    """

    def __init__(self, controller: SimController, register_map: RegisterMap | None = None,
                 wall_clock: Clock = SYSTEM_CLOCK, watchdog_poll_s: float = 0.02,
                 max_connections: int = MAX_CONNECTIONS):
        if max_connections < 1:
            raise ValueError(f"max_connections must be at least 1, got {max_connections}")
        self.controller = controller
        self.max_connections = max_connections
        self.map = register_map if register_map is not None else RegisterMap.default()
        self.wall_clock = wall_clock
        self.watchdog_poll_s = watchdog_poll_s
        self.requests = 0
        self.last_refusal = ""
        self.watchdog_tripped = False
        self._names = self.map.register_names()
        self._image = {address: 0 for address in self._names}
        self._lock = threading.RLock()
        self._watchdog_armed = False
        self._watchdog_at = 0.0
        self._pending_wire_fault: str | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: threading.Thread | None = None
        self._servers: list = []
        self._tcp_servers: list = []
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._fds: list[int] = []
        self._device = self._build_device()

    # -- the register space -----------------------------------------------------------
    def _build_device(self) -> SimDevice:
        read_only = {a for a, (name, _, _) in self._names.items() if name in READ_ONLY_REGISTERS}
        lo, hi = min(self._names), max(self._names)
        blocks: list[SimData] = []
        start = lo
        for address in range(lo, hi + 2):
            if address == hi + 1 or (address > start and (address in read_only) != (start in read_only)):
                blocks.append(SimData(start, count=address - start, values=0, datatype=DataType.REGISTERS,
                                      readonly=start in read_only))
                start = address
        return SimDevice(self.map.unit, simdata=blocks, action=self._action)

    async def _action(self, function_code, start_address, address, count, registers, set_values):
        try:
            with self._lock:
                if set_values is not None:
                    self._write(address, [int(v) for v in set_values])
                    return None
                self._refresh_state()
                for i in range(count):
                    registers[address - start_address + i] = self._image.get(address + i, 0)
                return None
        except _Refused as exc:
            self.last_refusal = str(exc)
            return exc.code
        except (TurntableError, ValueError) as exc:
            self.last_refusal = str(exc)
            return ExcCodes.DEVICE_FAILURE

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
                raise _Refused(ExcCodes.ILLEGAL_ADDRESS, f"write covers one word of 32-bit {name}")
        image = dict(self._image)
        image.update(written)

        def value(name: str, k: int, kind: str) -> float:
            a = getattr(m, name)[k]
            try:
                return m.decode_value([image[a], image[a + 1]], kind)
            except TurntableError as exc:
                raise _Refused(ExcCodes.ILLEGAL_VALUE, str(exc)) from exc

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
                    raise _Refused(ExcCodes.ILLEGAL_VALUE, str(exc)) from exc
                self._execute(command, axes)
            for k in range(3):
                if ("mode", k) in touched:
                    try:
                        mode = m.decode_mode(image[m.mode[k]])
                    except TurntableError as exc:
                        raise _Refused(ExcCodes.ILLEGAL_VALUE, str(exc)) from exc
                    self.controller.set_mode(k, mode)
            for k in range(3):
                if ("demand_position", k) in touched:
                    self.controller.demand_position(k, value("demand_position", k, "angle"),
                                                    value("move_rate", k, "rate"))
            for k in range(3):
                if ("demand_rate", k) in touched:
                    self.controller.demand_rate(k, value("demand_rate", k, "rate"))
        except SimCommandError as exc:
            raise _Refused(EXCEPTION_FOR_ERROR.get(exc.code, ExcCodes.DEVICE_FAILURE), str(exc)) from exc
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

    # -- faults on demand -------------------------------------------------------------------
    def _trace_pdu(self, sending: bool, pdu):
        if sending:
            fault = getattr(pdu, "sim_wire_fault", None)
            if fault:
                self._pending_wire_fault = fault
            return pdu
        self.requests += 1
        fault = self.controller.faults.take()
        if fault is None:
            return pdu
        original = pdu.datastore_update
        code = self.controller.faults.exception_code

        async def faulty_update(context, device_id):
            if fault == "exception":
                return ExceptionResponse(pdu.function_code, code)
            response = await original(context, device_id)
            response.sim_wire_fault = fault        # applied to this reply's bytes in _trace_packet
            return response

        pdu.datastore_update = faulty_update
        return pdu

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        if not sending or self._pending_wire_fault is None:
            return data
        fault, self._pending_wire_fault = self._pending_wire_fault, None
        if fault == "timeout":
            return b""
        if fault == "garbage":
            return GARBAGE
        if fault == "checksum":
            if self._rtu_packet(data):
                return data[:-2] + bytes([data[-2] ^ 0x5A, data[-1]])
            length = int.from_bytes(data[4:6], "big") + 1      # MBAP length one beyond the PDU
            return data[:4] + length.to_bytes(2, "big") + data[6:]
        return data

    def _rtu_packet(self, data: bytes) -> bool:
        # An MBAP header has protocol id 0 in bytes 2-3; an RTU reply starts with the unit id.
        return not (len(data) >= 8 and data[2:4] == b"\0\0" and int.from_bytes(data[4:6], "big") == len(data) - 6)

    # -- event loop -------------------------------------------------------------------------
    def _ensure_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            loop = asyncio.new_event_loop()
            started = threading.Event()

            def run() -> None:
                asyncio.set_event_loop(loop)
                loop.call_soon(started.set)
                loop.run_forever()

            self._loop_thread = threading.Thread(target=run, daemon=True, name="modbus-sim-loop")
            self._loop_thread.start()
            started.wait(5.0)
            self._loop = loop
            self._call(self._start_watchdog())
        return self._loop

    async def _start_watchdog(self) -> None:
        self._watchdog_task = asyncio.get_running_loop().create_task(self._watchdog_loop())

    def _call(self, coro, timeout_s: float = 5.0):
        loop = self._loop
        if loop is None:        # every caller starts the loop first
            raise RuntimeError("the Modbus simulator's event loop is not running")
        return asyncio.run_coroutine_threadsafe(coro, loop).result(timeout_s)

    # -- TCP ---------------------------------------------------------------------------------
    def start_tcp(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        """Listen for Modbus TCP; returns the (host, port) bound (port 0 = any free port)."""
        self._ensure_loop()

        async def start():
            server = _BoundedTcpServer(self._device, address=(host, port), trace_packet=self._trace_packet,
                                       trace_pdu=self._trace_pdu, max_connections=self.max_connections)
            await server.serve_forever(background=True)
            return server

        server = self._call(start())
        self._servers.append(server)
        self._tcp_servers.append(server)
        return tuple(server.transport.sockets[0].getsockname()[:2])

    @property
    def connections(self) -> int:
        """How many Modbus TCP connections are being served now (over every TCP listener)."""
        async def count() -> int:
            return sum(len(server.active_connections) for server in self._tcp_servers)

        return self._call(count()) if self._loop is not None else 0

    @property
    def refused(self) -> int:
        """Connections closed at once because `max_connections` were being served."""
        return sum(server.refused for server in self._tcp_servers)

    def drop_connections(self) -> int:
        """Close every open TCP connection (a lost link, for tests); returns how many."""
        async def drop() -> int:
            count = 0
            for server in self._tcp_servers:
                for connection in list(server.active_connections.values()):
                    connection.close()
                    count += 1
            return count

        return self._call(drop()) if self._loop is not None else 0

    # -- RTU over a pty ----------------------------------------------------------------------
    def start_rtu_pty(self, baudrate: int = 115200, parity: str = "N") -> str:
        """Serve Modbus RTU on a pty; returns the path a client opens (with the same baud/parity)."""
        self._ensure_loop()
        server_master, server_slave = os.openpty()
        client_master, client_slave = os.openpty()
        for fd in (server_slave, client_slave):
            tty.setraw(fd)
        # Our own slave fds stay open so the masters never see EIO between clients.
        self._fds += [server_master, server_slave, client_master, client_slave]
        server_path, client_path = os.ttyname(server_slave), os.ttyname(client_slave)
        bridge = threading.Thread(target=self._bridge, args=(server_master, client_master), daemon=True,
                                  name="modbus-sim-pty-bridge")
        self._threads.append(bridge)
        bridge.start()

        async def start():
            server = ModbusSerialServer(self._device, framer=FramerType.RTU, port=server_path, baudrate=baudrate,
                                        parity=parity, trace_packet=self._trace_packet, trace_pdu=self._trace_pdu)
            await server.serve_forever(background=True)
            return server

        self._servers.append(self._call(start()))
        return client_path

    def _bridge(self, a: int, b: int) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([a, b], [], [], 0.05)
                for fd in ready:
                    data = os.read(fd, 4096)
                    os.write(b if fd == a else a, data)
            except OSError:
                return

    # -- lifetime ----------------------------------------------------------------------------
    def close(self) -> None:
        """Stop the servers, the event loop and the bridges; join every thread."""
        if self._loop is not None:
            loop, loop_thread = self._loop, self._loop_thread

            async def shutdown() -> None:
                for server in self._servers:
                    await server.shutdown()
                tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
                for task in tasks:
                    task.cancel()
                await asyncio.gather(*tasks, return_exceptions=True)

            try:
                self._call(shutdown())
            finally:
                loop.call_soon_threadsafe(loop.stop)
                if loop_thread is not None:
                    loop_thread.join(timeout=5.0)
                loop.close()
                self._loop = None
                self._servers.clear()
                self._tcp_servers.clear()
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        self._threads.clear()
        for fd in self._fds:
            try:
                os.close(fd)
            except OSError:
                pass
        self._fds.clear()

    def __enter__(self) -> "ModbusSimServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
