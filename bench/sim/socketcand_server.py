"""A simulated socketcand (CAN over TCP, linux-can/socketcand) serving one bus (`can0`, or as named) on 127.0.0.1.

python-can opens it with its own client, `can.Bus(interface="socketcand", host=..., port=...,
channel="can0")`. The protocol (socketcand's doc/protocol.md) is ASCII, every element in
angle brackets:

    server: < hi >                       on connect
    client: < open can0 >                server: < ok >   (< error ... > for another bus)
    client: < rawmode >                  server: < ok >   then every frame on the bus:
    server: < frame 123 1700000000.123456 0011223344556677 >
            (id: 3 hex digits for 11 bits, 8 for 29 bits; seconds.microseconds; data hex)
    client: < send 123 8 0 11 22 33 44 55 66 77 >    a frame to transmit (accepted, no reply)
    client: < echo >                     server: < echo >
    anything else (bcmmode, controlmode, isotpmode, ...)  server: < error ... >

python-can's client reads each handshake reply with one `recv` and compares it whole, so
frames start flowing `RAW_START_DELAY_S` after the rawmode `< ok >`: they must not arrive
in the same read. CAN FD frames are not carried (python-can's client reads `< frame >` only):
`encode_frame` refuses one. `SocketcandSession` is the pure state machine; `SocketcandServer`
serves sessions on TCP, one thread per connection, and survives clients that come and go.
"""

from __future__ import annotations

import select
import socket
import threading
import time
from collections.abc import Iterable

import can

from bench.sim.serve import IDLE_TIMEOUT_S, ClosedOnExit, check_idle_timeout, longest_idle, tcp_listener

BUS = "can0"
HI = b"< hi >"
OK = b"< ok >"
#: python-can's client reads the rawmode `< ok >` with one recv: frames wait this long after it
RAW_START_DELAY_S = 0.2
MAX_ELEMENT = 256                       # longer than any command: junk is discarded
#: output queued for one slow client before its frames are dropped (and counted)
MAX_PENDING_BYTES = 4 * 1024 * 1024
MAX_CONNECTIONS = 8
#: python-can's client reads up to this many bytes at a time (and warns when an element is cut)
CLIENT_READ = 1024


class SocketcandError(ValueError):
    """A frame socketcand (as python-can reads it) cannot carry."""


def encode_frame(msg: can.Message, timestamp_s: float) -> bytes:
    """One frame in raw mode: `< frame ID SEC.USEC DATA >`."""
    if msg.is_fd:
        raise SocketcandError("python-can's socketcand client reads classic CAN frames only, not CAN FD: "
                              "use a classic (fd = false) layout")
    can_id = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    seconds = int(timestamp_s)
    micros = int(round((timestamp_s - seconds) * 1e6))
    if micros >= 1_000_000:
        seconds, micros = seconds + 1, micros - 1_000_000
    return f"< frame {can_id} {seconds}.{micros:06d} {bytes(msg.data).hex().upper()} >".encode("ascii")


def split_elements(buffer: bytearray) -> list[str]:
    """Pop every complete `< ... >` element off the front of `buffer`, as their inner words joined by
    one space; bytes outside elements and overlong or non-ASCII elements are discarded."""
    out: list[str] = []
    while True:
        start = buffer.find(b"<")
        if start < 0:
            buffer.clear()
            return out
        del buffer[:start]
        end = buffer.find(b">")
        if end < 0:
            if len(buffer) > MAX_ELEMENT:
                buffer.clear()
            return out
        element = bytes(buffer[1:end])
        del buffer[:end + 1]
        try:
            out.append(" ".join(element.decode("ascii").split()))
        except UnicodeDecodeError:
            continue


class SocketcandSession:
    """One client's state: `handle(command)` -> reply bytes (possibly empty); `raw` once in raw mode."""

    def __init__(self, bus: str = BUS):
        self.bus = bus
        self.opened = False
        self.raw = False
        self.sent: list[str] = []           # frames the client asked to send (kept for tests, bounded)

    def handle(self, command: str) -> bytes:
        words = command.split()
        if not words:
            return b"< error empty command >"
        verb = words[0]
        if verb == "open":
            if len(words) != 2 or words[1] != self.bus:
                return f"< error no such bus; this server has {self.bus} >".encode("ascii")
            self.opened = True
            return OK
        if verb == "echo":
            return b"< echo >"
        if not self.opened:
            return b"< error open a bus first >"
        if verb == "rawmode":
            self.raw = True
            return OK
        if verb == "send":
            if not self._valid_send(words[1:]):
                return b"< error malformed send >"
            if len(self.sent) < 1000:
                self.sent.append(command)
            return b""
        return f"< error {verb} is not served here (raw mode only) >".encode("ascii", "replace")

    @staticmethod
    def _valid_send(args: list[str]) -> bool:
        try:
            can_id, dlc, data = int(args[0], 16), int(args[1], 16), [int(b, 16) for b in args[2:]]
        except (IndexError, ValueError):
            return False
        return 0 <= can_id < (1 << 29) and 0 <= dlc <= 8 and len(data) == dlc and all(0 <= b < 256 for b in data)


class _Connection:
    def __init__(self, sock: socket.socket, bus: str):
        self.sock = sock
        self.session = SocketcandSession(bus)
        self.pending = bytearray()
        self.evicted = False                    # closed to make room for a new client
        self.raw_from: float | None = None      # monotonic time frames start flowing
        #: monotonic time of the last bytes from the client or taken by it (a raw-mode reader only reads)
        self.last_active = time.monotonic()


class SocketcandServer(ClosedOnExit):
    """socketcand on TCP until `close()`; `send(messages)` hands bus frames to every client in raw mode.

    Connections as `bench.sim.serve.LineServer`'s: a client that neither sends nor takes a byte for
    `idle_timeout_s` is closed, and a new client beyond `max_connections` closes the longest idle one."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, max_connections: int = MAX_CONNECTIONS,
                 idle_timeout_s: float = IDLE_TIMEOUT_S, bus: str = BUS):
        self.bus = bus                # the bus a client opens (`< open BUS >`)
        self.idle_timeout_s = check_idle_timeout(idle_timeout_s)
        self.evicted = 0              # connections closed to make room for a new one
        self.timed_out = 0            # connections closed for being idle too long
        self.frames_sent = 0          # frames queued to clients (one per client in raw mode)
        self.frames_dropped = 0       # not queued: a client's output was full
        self.clients = 0              # connections accepted so far
        self.peak_pending = 0         # the longest a client's output queue has been, bytes
        self.max_connections = max_connections
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._connections: dict[int, _Connection] = {}
        self._threads: list[threading.Thread] = []
        self._listener = sock = tcp_listener(host, port, backlog=8)
        self.host, self.port = sock.getsockname()[:2]
        self._spawn(self._accept_loop, "accept")

    def _spawn(self, target, name: str, *args) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True, name=f"sim-socketcand-{name}")
        with self._lock:
            self._threads = [t for t in self._threads if t.is_alive()] + [thread]
        thread.start()

    @property
    def connections(self) -> int:
        with self._lock:
            return len(self._connections)

    def send(self, messages: Iterable[can.Message]) -> None:
        """Frames on the bus, stamped with the wall clock as socketcand stamps what it receives."""
        now = time.time()
        mono = time.monotonic()
        with self._lock:
            targets = [c for c in self._connections.values() if c.raw_from is not None and mono >= c.raw_from]
            if not targets:
                return
            frames = [encode_frame(m, now) for m in messages]
            data = b"".join(frames)
            for conn in targets:
                if len(conn.pending) + len(data) > MAX_PENDING_BYTES:
                    self.frames_dropped += len(frames)
                else:
                    conn.pending += data
                    self.frames_sent += len(frames)
                    self.peak_pending = max(self.peak_pending, len(conn.pending))

    def _accept_loop(self) -> None:
        key = 0
        while not self._stop.is_set():
            try:
                sock, _ = self._listener.accept()
            except (socket.timeout, TimeoutError):
                continue
            except OSError:
                if self._stop.is_set():
                    return
                self._stop.wait(0.05)
                continue
            with self._lock:
                if len(self._connections) >= self.max_connections:     # room for the new one: the longest idle goes
                    victim = longest_idle({k: c.last_active for k, c in self._connections.items()})
                    if victim is not None:
                        self._connections.pop(victim).evicted = True
                        self.evicted += 1
            try:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sock.setblocking(False)
                key += 1
                conn = _Connection(sock, self.bus)
                with self._lock:
                    self._connections[key] = conn
                    self.clients += 1
                self._spawn(self._serve, f"{key}", key, conn)
            except Exception:  # noqa: BLE001 - one connection's failure must not end the accept loop
                with self._lock:
                    self._connections.pop(key, None)
                sock.close()

    def _serve(self, key: int, conn: _Connection) -> None:
        try:
            self._converse(conn)
        finally:
            with self._lock:
                self._connections.pop(key, None)
            conn.sock.close()

    def _converse(self, conn: _Connection) -> None:
        sock = conn.sock
        with self._lock:
            conn.pending += HI
        buffer = bytearray()
        while not self._stop.is_set():
            with self._lock:
                want_write = bool(conn.pending)
                if conn.evicted:
                    return
                if time.monotonic() - conn.last_active > self.idle_timeout_s:
                    self.timed_out += 1
                    return
            readable, writable, _ = select.select([sock], [sock] if want_write else [], [], 0.01)
            if readable:
                try:
                    data: bytes | None = sock.recv(4096)
                except BlockingIOError:
                    data = None
                except OSError:
                    return
                if data == b"":
                    return                       # the client went away
                if data:
                    conn.last_active = time.monotonic()
                    buffer += data
                    for command in split_elements(buffer):
                        reply = conn.session.handle(command)
                        with self._lock:
                            conn.pending += reply
                            if conn.session.raw and conn.raw_from is None:
                                conn.raw_from = time.monotonic() + RAW_START_DELAY_S
            if writable:
                with self._lock:
                    # whole elements, at most what python-can's client reads at once: it warns about a cut one
                    chunk = bytes(conn.pending[:CLIENT_READ])
                    end = chunk.rfind(b">") + 1
                    chunk = chunk[:end] if end else chunk
                try:
                    written = sock.send(chunk)
                except BlockingIOError:
                    written = 0
                except OSError:
                    return
                with self._lock:
                    del conn.pending[:written]
                    if written:
                        conn.last_active = time.monotonic()

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            threads = list(self._threads)
        for thread in threads:
            thread.join(timeout=2.0)
        self._listener.close()


__all__ = ["SocketcandError", "SocketcandServer", "SocketcandSession", "encode_frame", "split_elements"]
