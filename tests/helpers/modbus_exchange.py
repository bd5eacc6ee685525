"""Expected-exchange peer for Modbus client tests (pymodbus owns its socket/serial port).

`ModbusExchange(script)` listens on 127.0.0.1 (`start_tcp()` -> url) or a pty
(`start_pty()` -> url). Each script step `(request_hex, reply_hex_or_None)` must be the
next bytes the client sends, exactly; the reply (None = silence) goes back; a third item
is a late reply, sent `LATE_AFTER_S` after the reply (a slow controller answering a retry's
timed-out attempt as well). `DROP`
closes the connection (the next step is served on a new one); `GONE` closes the
connection and the listener. `assert_done()` (also on leaving the `with` block)
fails on a mismatch, on leftover steps and on any byte the script did not expect.
Hex strings may contain spaces.
"""

from __future__ import annotations

import os
import select
import socket
import threading
import time
import tty

DROP = "drop"
GONE = "gone"
LATE_AFTER_S = 0.1


def hexbytes(text: str | bytes | None) -> bytes | None:
    if text is None or isinstance(text, bytes):
        return text
    return bytes.fromhex(text)


class ModbusExchange:
    def __init__(self, script: list, step_timeout_s: float = 2.0):
        self.script = [s if s in (DROP, GONE) else tuple(hexbytes(x) for x in s) for s in script]
        self.step_timeout_s = step_timeout_s
        self.received: list[bytes] = []
        self.errors: list[str] = []
        self.extra = bytearray()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closers: list = []
        self._done = threading.Event()

    # -- TCP --------------------------------------------------------------------------
    def start_tcp(self) -> str:
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", 0))
        listener.listen(4)
        listener.settimeout(0.05)
        self._closers.append(listener.close)
        host, port = listener.getsockname()
        self._thread = threading.Thread(target=self._serve_tcp, args=(listener,), daemon=True)
        self._thread.start()
        return f"modbus+tcp://{host}:{port}"

    def _accept(self, listener: socket.socket) -> socket.socket | None:
        deadline = time.monotonic() + self.step_timeout_s * 3
        while not self._stop.is_set() and time.monotonic() < deadline:
            try:
                conn, _ = listener.accept()
            except (socket.timeout, TimeoutError):
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._closers.append(conn.close)
            return conn
        return None

    def _serve_tcp(self, listener: socket.socket) -> None:
        conn = self._accept(listener)

        def read(n: int, timeout_s: float) -> bytes:
            conn.settimeout(timeout_s)
            try:
                return conn.recv(n)
            except (socket.timeout, TimeoutError):
                return b""
            except OSError:
                return b""

        for step in self.script:
            if conn is None:
                self.errors.append("the client never connected")
                break
            if step in (DROP, GONE):
                if step == GONE:        # listener first, so a reconnect cannot land in its backlog
                    listener.close()
                    conn.close()
                    conn = None
                    break
                conn.close()
                conn = self._accept(listener)
                continue
            if not self._exchange(step, read, conn.sendall):
                break
        self._done.set()
        if conn is not None:
            self._drain(read)

    # -- pty ----------------------------------------------------------------------------
    def start_pty(self, options: str = "baud=115200") -> str:
        master, slave = os.openpty()
        tty.setraw(slave)
        self._closers += [lambda: os.close(slave), lambda: os.close(master)]
        path = os.ttyname(slave)

        def read(n: int, timeout_s: float) -> bytes:
            ready, _, _ = select.select([master], [], [], timeout_s)
            if not ready:
                return b""
            try:
                return os.read(master, n)
            except OSError:
                return b""

        def serve() -> None:
            for step in self.script:
                if step in (DROP, GONE):
                    self.errors.append("DROP/GONE are TCP-only steps")
                    break
                if not self._exchange(step, read, lambda data: os.write(master, data)):
                    break
            self._done.set()
            self._drain(read)

        self._thread = threading.Thread(target=serve, daemon=True)
        self._thread.start()
        return f"modbus+rtu://{path}?{options}"

    # -- shared ---------------------------------------------------------------------------
    def _exchange(self, step, read, write) -> bool:
        expected, reply, *late = step
        got = bytearray()
        deadline = time.monotonic() + self.step_timeout_s
        while len(got) < len(expected) and not self._stop.is_set():
            left = deadline - time.monotonic()
            if left <= 0:
                break
            got += read(len(expected) - len(got), min(left, 0.05))
        self.received.append(bytes(got))
        if bytes(got) != expected:
            self.errors.append(f"step {len(self.received)}: received {bytes(got).hex(' ')!r}, "
                               f"expected {expected.hex(' ')!r}")
            return False
        if reply:
            write(reply)
        for extra in late:
            self._stop.wait(LATE_AFTER_S)
            write(extra)
        return True

    def _drain(self, read) -> None:
        while not self._stop.is_set():
            data = read(4096, 0.05)
            if data:
                self.extra += data

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for close in reversed(self._closers):
            try:
                close()
            except OSError:
                pass
        self._closers.clear()

    def assert_done(self) -> None:
        self.close()
        assert not self.errors, "; ".join(self.errors)
        steps = [s for s in self.script if s not in (DROP, GONE)]
        assert len(self.received) == len(steps), (
            f"{len(steps) - len(self.received)} exchange(s) left over; received {[r.hex(' ') for r in self.received]}")
        assert not self.extra, f"unexpected bytes after the script: {bytes(self.extra).hex(' ')}"

    def __enter__(self) -> "ModbusExchange":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.assert_done()
            return
        self.close()
        if self.errors:     # the client's error is a symptom; the mismatch is the cause
            raise AssertionError("; ".join(self.errors)) from exc
