"""Serving a simulated device as a Modbus controller: pymodbus TCP server on 127.0.0.1, RTU over a pty.

`ModbusServing` is the machinery the simulated table (`bench.sim.modbus_server`) and the
simulated chamber (`bench.sim.chamber_server`) share: a subclass builds the pymodbus
`SimDevice` (its register space and what reads and writes do) and names its `WireFaults`.

Over RTU a request to another unit id gets no reply and does nothing (a device on a shared line);
over TCP it is answered with exception 04 (pymodbus's simulator). Faults on demand come from
`wire_faults` (one per request to this device): timeout = no reply, garbage =
junk bytes instead of the reply, checksum = a corrupted CRC (RTU) or a malformed MBAP
length field (TCP), exception = exception code `faults.exception_code` instead of executing.

pymodbus's server is asyncio-based: it runs on an event loop in one dedicated thread;
the RTU server sits on one pty of a pair bridged by a thread to a second pty whose
path clients open. `close()` stops everything and joins the threads.

Connections cost no thread here and pymodbus forgets each one when it ends, but their
number is capped like the line servers' (`bench.sim.serve.MAX_CONNECTIONS` per TCP
listener) and idle ones are handled alike: a connection silent for `idle_timeout_s` is
closed, and a new one beyond the cap closes the longest idle, so idle clients can neither
use up the process's file descriptors nor lock a bench out.
"""

from __future__ import annotations

import asyncio
import logging
import os
import select
import threading
import time
import tty
from typing import Any, Callable, Iterable, Mapping

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType
from pymodbus.pdu import ExceptionResponse
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import DataType, SimData, SimDevice

from bench.sim.controller import WireFaults
from bench.sim.serve import IDLE_TIMEOUT_S, MAX_CONNECTIONS, ClosedOnExit, check_idle_timeout, longest_idle

# pymodbus logs refused requests at ERROR; keep them out of stderr unless logging is configured.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

GARBAGE = bytes.fromhex("de ad be ef 00 ff 13 37 42")


class _CloseAtOnce(asyncio.Protocol):
    """The protocol of a connection beyond the cap: closed as soon as it is made."""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        transport.close()


class _HeardHandler(ServerRequestHandler):
    """pymodbus's handler of one connection, telling its server each time bytes arrive (for the idle reaper)."""

    server: _BoundedTcpServer

    def data_received(self, data: bytes) -> None:
        self.server.heard(self.unique_id)
        super().data_received(data)


class _BoundedTcpServer(ModbusTcpServer):
    """pymodbus's TCP server serving at most `max_connections` connections at once; a new one beyond them closes
    the longest idle, and one silent for `idle_timeout_s` is closed (checked every `_REAP_PERIOD_S`)."""

    def __init__(self, *args, max_connections: int = MAX_CONNECTIONS, idle_timeout_s: float = IDLE_TIMEOUT_S,
                 **kwargs):
        super().__init__(*args, **kwargs)
        self.max_connections = max_connections
        self.idle_timeout_s = check_idle_timeout(idle_timeout_s)
        self.refused = 0
        self.evicted = 0
        self.timed_out = 0
        self._last_heard: dict[str, float] = {}     # connection id -> monotonic time of its last bytes
        self._reaper: asyncio.TimerHandle | None = None

    def handle_new_connection(self):
        # the listener's protocol factory (on the loop's thread); active_connections holds the live ones only
        if len(self.active_connections) >= self.max_connections:
            victim = longest_idle({uid: self._last_heard.get(uid, 0.0) for uid in self.active_connections})
            if victim is None:
                self.refused += 1
                return _CloseAtOnce()
            self.evicted += 1
            self._drop(victim)
        protocol = super().handle_new_connection()
        self.heard(protocol.unique_id)
        if self._reaper is None:
            self._reaper = self.loop.call_later(min(_REAP_PERIOD_S, self.idle_timeout_s), self._reap)
        return protocol

    def callback_new_connection(self) -> _HeardHandler:
        # pymodbus's factory of a connection's handler (as its own), with the handler that notes when it is heard
        return _HeardHandler(self, self.trace_packet, self.trace_pdu, self.trace_connect)

    def heard(self, uid: str) -> None:
        """Connection `uid` sent bytes (or was just made): it is not idle now."""
        self._last_heard[uid] = time.monotonic()

    def _drop(self, uid: str) -> None:
        self._last_heard.pop(uid, None)
        connection = self.active_connections.get(uid)
        if connection is not None:
            connection.close()

    def _reap(self) -> None:
        """Close the connections silent for `idle_timeout_s`; again in a while while any is open."""
        now = time.monotonic()
        for uid in list(self._last_heard):
            if uid not in self.active_connections:
                self._last_heard.pop(uid, None)          # it ended on its own
            elif now - self._last_heard[uid] > self.idle_timeout_s:
                self.timed_out += 1
                self._drop(uid)
        self._reaper = (self.loop.call_later(min(_REAP_PERIOD_S, self.idle_timeout_s), self._reap)
                        if self._last_heard else None)


#: how often a Modbus TCP listener looks for idle connections (s)
_REAP_PERIOD_S = 1.0


class Refused(Exception):
    """A request the simulated device refuses; `code` is the Modbus exception it answers with."""

    def __init__(self, code: ExcCodes, message: str):
        super().__init__(message)
        self.code = code


class ModbusServing(ClosedOnExit):
    """A simulated Modbus device on any number of TCP listeners and RTU ptys (see the module docstring).

    A subclass sets `self._device` (`_register_device`) and `wire_faults` in its constructor, and says what
    reads return (`_read_image`) and what writes do (`_write`, under `_lock`; `Refused` to refuse one).
    """

    wire_faults: WireFaults
    #: the device's own errors that a request may raise (besides `Refused` and ValueError) ...
    device_errors: tuple[type[Exception], ...] = ()
    #: ... and the exception a request that raises one of them (or a ValueError) answers with
    device_error_code = ExcCodes.DEVICE_FAILURE

    def __init__(self, max_connections: int = MAX_CONNECTIONS, idle_timeout_s: float = IDLE_TIMEOUT_S):
        if max_connections < 1:
            raise ValueError(f"max_connections must be at least 1, got {max_connections}")
        self.max_connections = max_connections
        self.idle_timeout_s = check_idle_timeout(idle_timeout_s)
        self.requests = 0
        #: why the last refused request was refused (for tests and the console)
        self.last_refusal = ""
        self._lock = threading.RLock()
        self._device: SimDevice | None = None
        self._pending_wire_fault: str | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: threading.Thread | None = None
        self._servers: list = []
        self._tcp_servers: list = []
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._fds: list[int] = []

    # -- the register space ----------------------------------------------------------------
    def _register_device(self, unit: int, addresses: Iterable[int], read_only: Callable[[int], bool]) -> SimDevice:
        """One register space from the lowest of `addresses` to the highest, so a read may span the unused
        registers between two (they read 0); a run of `read_only` registers refuses writes (02 illegal data
        address)."""
        used = sorted(addresses)
        lo, hi = used[0], used[-1]
        blocks: list[SimData] = []
        start = lo
        for address in range(lo, hi + 2):
            if address == hi + 1 or (address > start and read_only(address) != read_only(start)):
                blocks.append(SimData(start, count=address - start, values=0, datatype=DataType.REGISTERS,
                                      readonly=read_only(start)))
                start = address
        return SimDevice(unit, simdata=blocks, action=self._action)

    def _served_device(self) -> SimDevice:
        if self._device is None:        # every subclass registers its device in its constructor
            raise RuntimeError(f"{type(self).__name__} registered no Modbus device")
        return self._device

    def _read_image(self) -> Mapping[int, int]:
        """address -> register value of the device now (under `_lock`); an address not in it reads 0."""
        raise NotImplementedError

    def _write(self, address: int, values: list[int]) -> None:
        """Execute a write of `values` from `address` (under `_lock`); `Refused` to refuse it."""
        raise NotImplementedError

    async def _action(self, function_code, start_address, address, count, registers, set_values):
        # pymodbus's hook for every request: a write executes, a read is filled from the live image
        failures: tuple[type[Exception], ...] = (*self.device_errors, ValueError)
        try:
            with self._lock:
                if set_values is not None:
                    self._write(address, [int(v) for v in set_values])
                    return None
                image = self._read_image()
                for i in range(count):
                    registers[address - start_address + i] = image.get(address + i, 0)
                return None
        except Refused as exc:
            self.last_refusal = str(exc)
            return exc.code
        except failures as exc:
            self.last_refusal = str(exc)
            return self.device_error_code

    # -- faults on demand -------------------------------------------------------------------
    def _trace_pdu(self, sending: bool, pdu):
        if sending:
            fault = getattr(pdu, "sim_wire_fault", None)
            if fault:
                self._pending_wire_fault = fault
            return pdu
        self.requests += 1
        fault = self.wire_faults.take()
        if fault is None:
            return pdu
        original = pdu.datastore_update
        code = self.wire_faults.exception_code

        async def faulty_update(context, device_id):
            if fault == "exception":
                return ExceptionResponse(pdu.function_code, code)
            response = await original(context, device_id)
            response.sim_wire_fault = fault        # applied to this reply's bytes in _trace_packet
            return response

        pdu.datastore_update = faulty_update
        return pdu

    def _trace_rtu_pdu(self, sending: bool, pdu):
        """The RTU server's `_trace_pdu`: on a shared RTU line a device answers only its own unit id, so a request
        to another (or a broadcast, unit 0) neither acts nor counts and nothing goes back on the line (pymodbus's
        simulator would answer it from our device, or with exception 04)."""
        if sending or pdu.dev_id == self._served_device().id:
            return self._trace_pdu(sending, pdu)

        async def not_ours(context, device_id):
            response: Any = ExceptionResponse(pdu.function_code, ExcCodes.GATEWAY_NO_RESPONSE)
            response.sim_wire_fault = "timeout"      # _trace_packet sends nothing for it
            return response

        pdu.datastore_update = not_ours
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
            self._on_loop_started()
        return self._loop

    def _on_loop_started(self) -> None:
        """Called once the event loop runs (the table's watchdog starts here)."""

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
            server = _BoundedTcpServer(self._served_device(), address=(host, port), trace_packet=self._trace_packet,
                                       trace_pdu=self._trace_pdu, max_connections=self.max_connections,
                                       idle_timeout_s=self.idle_timeout_s)
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

    @property
    def evicted(self) -> int:
        """Connections closed to make room for a new one (the longest idle)."""
        return sum(server.evicted for server in self._tcp_servers)

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
            server = ModbusSerialServer(self._served_device(), framer=FramerType.RTU, port=server_path,
                                        baudrate=baudrate, parity=parity, trace_packet=self._trace_packet,
                                        trace_pdu=self._trace_rtu_pdu)
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
