"""Serve a line-oriented simulated controller over TCP (127.0.0.1) or a pty.

A dialect gives a `handle(line) -> reply bytes | None` function (reply with its
terminator; None = say nothing, e.g. an injected timeout). `LineServer` reads CR/LF
terminated lines from each connection and writes the replies. Threads are daemons and
`close()` joins them, so tests leave nothing running.

Connections are bounded: at most `MAX_CONNECTIONS` are served at once (one thread each),
and a connection is forgotten when it ends, so the server's bookkeeping does not grow with
the number of connections it has seen. Idle ones cannot lock a client out: a connection
that sends nothing for `idle_timeout_s` (`IDLE_TIMEOUT_S` unless told, `--idle-timeout-s`
on the command line) is closed, and when every slot is taken a new client is served and
the connection that has been silent the longest is closed to make room ("refuse the
oldest idle": a bench polling its simulator is never the longest silent one). The accept
loop outlives any per-connection failure (a socket option, a thread that cannot start, an accept error such as too many
open files): only `close()` ends it.
"""

from __future__ import annotations

import os
import select
import socket
import threading
import time
import tty
from collections.abc import Hashable, Mapping
from typing import TYPE_CHECKING, Callable, Self, TypeVar

if TYPE_CHECKING:
    from bench.sim.controller import WireFaults

Handler = Callable[[bytes], "bytes | None"]
#: the longest request line a simulated device reads (bytes); junk without a terminator is cut there
MAX_LINE = 4096
#: connections served at once per server (over all its TCP listeners); a new one beyond them closes the longest idle
MAX_CONNECTIONS = 32
#: a connection that sends nothing for this long is closed (s)
IDLE_TIMEOUT_S = 300.0


ConnectionKey = TypeVar("ConnectionKey", bound=Hashable)


def longest_idle(last_heard: Mapping[ConnectionKey, float]) -> ConnectionKey | None:
    """The key of the connection heard from the longest ago (None: none)."""
    return min(last_heard, key=last_heard.__getitem__) if last_heard else None


def check_idle_timeout(idle_timeout_s: float) -> float:
    """`idle_timeout_s` if it is a positive finite number of seconds, else ValueError."""
    if not (isinstance(idle_timeout_s, (int, float)) and 0 < idle_timeout_s < float("inf")):
        raise ValueError(f"idle_timeout_s must be a positive number of seconds, got {idle_timeout_s!r}")
    return float(idle_timeout_s)


class ClosedOnExit:
    """A server (or a world of them) that a `with` block closes (`close()`) when it ends."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def held_first(faults: WireFaults, respond: Callable[[], bytes | None]) -> bytes | None:
    """What a line handler sends: the replies a `late` fault held back, then `respond()`'s (None: nothing)."""
    held = faults.release()     # released before the reply is built: a `late` fault on it holds it back
    return (held + (respond() or b"")) or None


def reply_with_fault(faults: WireFaults, respond: Callable[[], bytes], *, exception_reply: Callable[[int], bytes],
                     garbage: bytes, corrupt: Callable[[bytes], bytes]) -> bytes | None:
    """One reply line (with its terminator) with the next wire fault of `faults` applied: exception ->
    `exception_reply(code)` and `respond` is not called (nothing executes); otherwise the request executes
    (`respond()`) and timeout -> nothing sent, late -> held for the next reply, garbage -> `garbage`,
    checksum -> `corrupt(reply)`."""
    fault = faults.take()
    if fault == "exception":
        return exception_reply(faults.exception_code)
    reply = respond()
    if fault == "timeout":
        return None
    if fault == "late":
        faults.hold(reply)
        return None
    if fault == "garbage":
        return garbage
    if fault == "checksum":
        return corrupt(reply)
    return reply


def flip_parity(reply: bytes, terminator: bytes = b"\r\n") -> bytes:
    """A `checksum` fault in a dialect without a checksum: one character's top bit flipped, as a parity error
    would (`reply` ends with `terminator`)."""
    body = bytearray(reply[:-len(terminator)])
    body[len(body) // 2] ^= 0x80
    return bytes(body) + terminator


def _split_lines(buffer: bytearray) -> list[bytes]:
    """Pop every complete line (CR, LF or CRLF terminated) off the front of `buffer`."""
    lines = []
    while True:
        ends = [i for i in (buffer.find(b"\r"), buffer.find(b"\n")) if i >= 0]
        if not ends:
            if len(buffer) > MAX_LINE:       # junk without a terminator: hand it on, bounded
                lines.append(bytes(buffer[:MAX_LINE]))
                del buffer[:MAX_LINE]
                continue
            return lines
        i = min(ends)
        line = bytes(buffer[:i])
        del buffer[:i + 1]
        if line:
            lines.append(line)


def tcp_listener(host: str, port: int, backlog: int) -> socket.socket:
    """A listening TCP socket on (host, port) (port 0 = any free port) whose accept() times out every 0.1 s,
    so that an accept loop sees its stop flag; OSError when it cannot be bound (nothing left open)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(backlog)
        sock.settimeout(0.1)
    except OSError:
        sock.close()
        raise
    return sock


class LineServer(ClosedOnExit):
    """Serves one handler on any number of TCP listeners and ptys until `close()`.

    At most `max_connections` TCP connections are served at once; a new one beyond them
    closes the longest idle; one silent for `idle_timeout_s` is closed. `connections` is how
    many are being served now.
    """

    def __init__(self, handle: Handler, max_connections: int = MAX_CONNECTIONS,
                 idle_timeout_s: float = IDLE_TIMEOUT_S):
        if max_connections < 1:
            raise ValueError(f"max_connections must be at least 1, got {max_connections}")
        self.handle = handle
        self.max_connections = max_connections
        self.idle_timeout_s = check_idle_timeout(idle_timeout_s)
        #: connections closed to make room for a new one (the longest idle), and for being idle too long
        self.evicted = 0
        self.timed_out = 0
        self._last_heard: dict[int, float] = {}             # live connections -> monotonic time of their last bytes
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []          # listeners and ptys: a few, for the server's life
        self._closers: list[Callable[[], None]] = []        # their sockets and file descriptors
        self._connections: dict[int, tuple[socket.socket, threading.Thread]] = {}   # live ones only
        self._next_id = 0
        self._lock = threading.Lock()
        self._thread_factory = threading.Thread

    @property
    def connections(self) -> int:
        """How many TCP connections are being served now."""
        with self._lock:
            return len(self._connections)

    def _spawn(self, target, *args) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True, name=f"sim-{target.__name__}")
        with self._lock:
            self._threads.append(thread)
        thread.start()

    # -- TCP --------------------------------------------------------------------
    def listen_tcp(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        """Start listening; returns the (host, port) actually bound (port 0 = any free port)."""
        sock = tcp_listener(host, port, backlog=16)
        self._closers.append(sock.close)
        self._spawn(self._accept_loop, sock)
        return sock.getsockname()[:2]

    def _accept_loop(self, sock: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = sock.accept()
            except (socket.timeout, TimeoutError):
                continue
            except OSError:
                if self._stop.is_set() or sock.fileno() < 0:
                    return                   # closed: the server is shutting down
                self._stop.wait(0.05)        # EMFILE, ENOBUFS, ECONNABORTED, ...: keep listening
                continue
            try:
                self._serve_connection(conn)
            except Exception:  # noqa: BLE001 - one connection's failure must not end the accept loop
                conn.close()

    def _serve_connection(self, conn: socket.socket) -> None:
        """Start a thread for `conn`; when `max_connections` are served, the longest idle one is closed first."""
        with self._lock:
            if len(self._connections) >= self.max_connections:
                victim = longest_idle(self._last_heard)
                if victim is not None:
                    old, _ = self._connections.pop(victim)
                    self._last_heard.pop(victim, None)
                    self.evicted += 1
                    _hang_up(old)           # its thread sees the end at its next receive
            key = self._next_id
            self._next_id += 1
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.settimeout(0.1)
            thread = self._thread_factory(target=self._tcp_loop, args=(key, conn), daemon=True,
                                          name=f"sim-connection-{key}")
            self._connections[key] = (conn, thread)
            self._last_heard[key] = time.monotonic()
        try:
            thread.start()
        except BaseException:
            with self._lock:
                self._connections.pop(key, None)
                self._last_heard.pop(key, None)
            raise

    def _tcp_loop(self, key: int, conn: socket.socket) -> None:
        try:
            self._converse(key, conn)
        finally:
            with self._lock:
                self._connections.pop(key, None)     # forgotten as soon as it ends
                self._last_heard.pop(key, None)
            conn.close()

    def _converse(self, key: int, conn: socket.socket) -> None:
        buffer = bytearray()
        heard = time.monotonic()
        while not self._stop.is_set():
            try:
                data = conn.recv(4096)
            except (socket.timeout, TimeoutError):
                if time.monotonic() - heard > self.idle_timeout_s:
                    with self._lock:
                        self.timed_out += 1
                    return                   # silent too long: closed
                continue
            except OSError:
                return
            if not data:
                return
            heard = time.monotonic()
            with self._lock:
                if key in self._last_heard:
                    self._last_heard[key] = heard
            buffer += data
            for line in _split_lines(buffer):
                reply = self.handle(line)
                if reply:
                    try:
                        conn.sendall(reply)
                    except OSError:
                        return

    # -- pty --------------------------------------------------------------------
    def open_pty(self) -> str:
        """Create a pty pair and serve on its master side; returns the path clients open."""
        master, slave = os.openpty()
        tty.setraw(slave)                 # no echo, no CR/LF translation
        path = os.ttyname(slave)
        # Keeping our own slave fd open means the master never sees EIO between clients.
        self._closers.append(lambda: os.close(slave))
        self._closers.append(lambda: os.close(master))
        self._spawn(self._pty_loop, master)
        return path

    def _pty_loop(self, master: int) -> None:
        buffer = bytearray()
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([master], [], [], 0.1)
                if not ready:
                    continue
                buffer += os.read(master, 4096)
            except OSError:
                return
            for line in _split_lines(buffer):
                reply = self.handle(line)
                if reply:
                    try:
                        os.write(master, reply)
                    except OSError:
                        return

    # -- lifetime ---------------------------------------------------------------
    def close(self) -> None:
        self._stop.set()
        with self._lock:
            threads = list(self._threads)
            connections = list(self._connections.values())
        for thread in threads:
            thread.join(timeout=2.0)
        for _conn, thread in connections:      # each sees the stop within its 0.1 s receive timeout
            thread.join(timeout=2.0)
        for close in reversed(self._closers):
            try:
                close()
            except OSError:
                pass
        self._closers.clear()


def _hang_up(conn: socket.socket) -> None:
    """End a connection another thread serves: its receive returns at once (the thread closes the socket)."""
    try:
        conn.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass


def serve_lines(handler, tcp: bool = True, pty: bool = False, port: int = 0,
                idle_timeout_s: float = IDLE_TIMEOUT_S) -> tuple[LineServer, dict[str, str]]:
    """Serve a line dialect's `handler` on loopback TCP and/or a pty; returns the server (close it) and its
    URLs ({'tcp': 'tcp://127.0.0.1:port', 'pty': '/dev/pts/N'} as requested)."""
    server = LineServer(handler, idle_timeout_s=idle_timeout_s)
    urls = {}
    try:
        if tcp:
            host, bound = server.listen_tcp("127.0.0.1", port)
            urls["tcp"] = f"tcp://{host}:{bound}"
        if pty:
            urls["pty"] = server.open_pty()
    except OSError:
        server.close()
        raise
    return server, urls
