"""Serve a line-oriented simulated controller over TCP (127.0.0.1) or a pty.

A dialect gives a `handle(line) -> reply bytes | None` function (reply with its
terminator; None = say nothing, e.g. an injected timeout). `LineServer` reads CR/LF
terminated lines from each connection and writes the replies. Threads are daemons and
`close()` joins them, so tests leave nothing running.
"""

from __future__ import annotations

import os
import select
import socket
import threading
import tty
from typing import Callable

Handler = Callable[[bytes], "bytes | None"]
MAX_LINE = 4096


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


class LineServer:
    """Serves one handler on any number of TCP listeners and ptys until `close()`."""

    def __init__(self, handle: Handler):
        self.handle = handle
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._closers: list[Callable[[], None]] = []
        self._lock = threading.Lock()

    def _spawn(self, target, *args) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True, name=f"sim-{target.__name__}")
        with self._lock:
            self._threads.append(thread)
        thread.start()

    # -- TCP --------------------------------------------------------------------
    def listen_tcp(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        """Start listening; returns the (host, port) actually bound (port 0 = any free port)."""
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(8)
        sock.settimeout(0.1)
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
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.settimeout(0.1)
            self._closers.append(conn.close)
            self._spawn(self._tcp_loop, conn)

    def _tcp_loop(self, conn: socket.socket) -> None:
        buffer = bytearray()
        with conn:
            while not self._stop.is_set():
                try:
                    data = conn.recv(4096)
                except (socket.timeout, TimeoutError):
                    continue
                except OSError:
                    return
                if not data:
                    return
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
        for thread in threads:
            thread.join(timeout=2.0)
        for close in reversed(self._closers):
            try:
                close()
            except OSError:
                pass
        self._closers.clear()

    def __enter__(self) -> "LineServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
