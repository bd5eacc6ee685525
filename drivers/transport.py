"""Byte transports chosen by URL, and a line channel over them.

`open_transport(url)`:
- `tcp://host:port` -> a TCP socket;
- anything else -> pyserial's `serial_for_url`: a device path (`/dev/ttyUSB0`, a pty
  such as `/dev/pts/5`), `socket://host:port`, `loop://`, `rfc2217://host:port`,
  with `?baud=N` (also `baudrate=`), `parity=N|E|O`, `bytesize=` and `stopbits=` query
  options applied to real serial ports. (`modbus+tcp://` and `modbus+rtu://` belong to
  the Modbus client, which hands them to pymodbus.)

Transports raise the builtin `ConnectionError` (lost or refused link) and return b''
from `read` on a timeout; clients translate those into their device's errors. A URL or
option they cannot use raises `TurntableConfigError` (also a `ValueError`) at once.

What a client reads while waiting for one reply is bounded, so a peer that streams
garbage ends in a protocol error, not in a growing buffer: a line is at most
`LineChannel.max_line` bytes (4096), `discard_input` drops at most `MAX_REPLY_BYTES`,
and the Modbus client gives up on a reply after `MAX_REPLY_BYTES` (64 KiB).
"""

from __future__ import annotations

import socket
import time
from typing import Protocol
from urllib.parse import parse_qs, urlsplit

import serial

from drivers.errors import TurntableConfigError

#: the most bytes a client takes in while waiting for one reply (or drops before a retry)
MAX_REPLY_BYTES = 64 * 1024


class ByteTransport(Protocol):
    url: str

    def open(self) -> None: ...

    def close(self) -> None: ...

    @property
    def is_open(self) -> bool: ...

    def write(self, data: bytes) -> None: ...

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        """Up to `max_bytes` that arrive within `timeout_s` (b'' on timeout)."""

    def discard_input(self) -> None:
        """Drop whatever has been received and not read (before a retry)."""


SERIAL_OPTIONS = {"baud": "baudrate", "baudrate": "baudrate", "parity": "parity", "bytesize": "bytesize",
                  "stopbits": "stopbits"}


def serial_settings(query: str) -> dict:
    """`baud=115200&parity=E` -> pyserial keyword arguments.

    TurntableConfigError (a ValueError) on an unknown or bad option.
    """
    out: dict = {}
    for key, values in parse_qs(query, keep_blank_values=True).items():
        if key not in SERIAL_OPTIONS:
            raise TurntableConfigError(f"unknown serial option {key!r} (known: {', '.join(sorted(SERIAL_OPTIONS))})")
        value = values[-1]
        name = SERIAL_OPTIONS[key]
        try:
            out[name] = value.upper() if name == "parity" else (float(value) if name == "stopbits" else int(value))
        except ValueError as exc:
            raise TurntableConfigError(f"serial option {key}={value!r} is not a number") from exc
        if name == "parity" and out[name] not in ("N", "E", "O", "M", "S"):
            raise TurntableConfigError(f"serial option parity={value!r} must be N, E or O")
    return out


class TcpTransport:
    """A TCP client socket (`tcp://host:port`)."""

    def __init__(self, url: str, connect_timeout_s: float = 3.0):
        parts = urlsplit(url)
        if parts.scheme != "tcp" or not parts.hostname or parts.port is None:
            raise TurntableConfigError(f"expected tcp://host:port, got {url!r}")
        self.url, self.host, self.port = url, parts.hostname, parts.port
        self.connect_timeout_s = connect_timeout_s
        self._sock: socket.socket | None = None

    @property
    def is_open(self) -> bool:
        return self._sock is not None

    def open(self) -> None:
        self.close()
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout_s)
        except OSError as exc:
            raise ConnectionError(f"cannot connect to {self.url}: {exc}") from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock

    def close(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None

    def _require(self) -> socket.socket:
        if self._sock is None:
            raise ConnectionError(f"{self.url} is not open")
        return self._sock

    def write(self, data: bytes) -> None:
        sock = self._require()
        try:
            sock.settimeout(self.connect_timeout_s)
            sock.sendall(data)
        except OSError as exc:
            self.close()
            raise ConnectionError(f"write to {self.url} failed: {exc}") from exc

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        sock = self._require()
        try:
            sock.settimeout(max(timeout_s, 1e-4))
            data = sock.recv(max_bytes)
        except (socket.timeout, TimeoutError):
            return b""
        except OSError as exc:
            self.close()
            raise ConnectionError(f"read from {self.url} failed: {exc}") from exc
        if not data:
            self.close()
            raise ConnectionError(f"{self.url} closed the connection")
        return data

    def discard_input(self) -> None:
        """Drop what has arrived, at most MAX_REPLY_BYTES: a peer streaming without pause cannot hold us here."""
        sock = self._require()
        sock.setblocking(False)
        try:
            dropped = 0
            while dropped < MAX_REPLY_BYTES:
                chunk = sock.recv(4096)
                if not chunk:
                    break
                dropped += len(chunk)
        except (BlockingIOError, InterruptedError):
            pass
        except OSError as exc:
            self.close()
            raise ConnectionError(f"{self.url}: {exc}") from exc
        finally:
            if self._sock is not None:
                sock.setblocking(True)


class SerialTransport:
    """Anything pyserial's `serial_for_url` opens: device paths, ptys, socket://, loop://, rfc2217://."""

    def __init__(self, url: str, **settings):
        self.url = url
        base, _, query = url.partition("?")
        self.settings = {**serial_settings(query), **settings}
        self._base = base
        self._port: serial.SerialBase | None = None

    @property
    def is_open(self) -> bool:
        return self._port is not None and self._port.is_open

    def open(self) -> None:
        self.close()
        try:
            self._port = serial.serial_for_url(self._base, timeout=0.1, write_timeout=2.0, **self.settings)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise ConnectionError(f"cannot open {self.url}: {exc}") from exc

    def close(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except (serial.SerialException, OSError):
                pass
            self._port = None

    def _require(self) -> serial.SerialBase:
        if self._port is None:
            raise ConnectionError(f"{self.url} is not open")
        return self._port

    def write(self, data: bytes) -> None:
        port = self._require()
        try:
            port.write(data)
            port.flush()
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise ConnectionError(f"write to {self.url} failed: {exc}") from exc

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        port = self._require()
        try:
            port.timeout = max(timeout_s, 0.0)
            first = port.read(1)
            if not first:
                return b""
            waiting = port.in_waiting
            return first + (port.read(min(waiting, max_bytes - 1)) if waiting and max_bytes > 1 else b"")
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise ConnectionError(f"read from {self.url} failed: {exc}") from exc

    def discard_input(self) -> None:
        port = self._require()
        try:
            port.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise ConnectionError(f"{self.url}: {exc}") from exc


#: URL schemes of the Modbus dialect (and of no other); pymodbus opens those, not this module
MODBUS_SCHEMES = ("modbus+tcp://", "modbus+rtu://")


def open_transport(url: str) -> ByteTransport:
    """An unopened transport for `url` (see the module docstring); TurntableConfigError (a ValueError) on a bad URL."""
    if not url:
        raise TurntableConfigError("empty transport URL")
    if url.startswith("tcp://"):
        return TcpTransport(url)
    if url.startswith(MODBUS_SCHEMES):
        raise TurntableConfigError(f"{url!r} is a Modbus URL: use the modbus dialect")
    return SerialTransport(url)


class LineChannel:
    """Request/reply lines over a byte transport, with a receive buffer kept between reads.

    `read_line` returns one line without its terminator; CR, LF and CRLF all end a line
    (an empty line between CR and LF is skipped). Time is measured with
    `time.monotonic` because it bounds real I/O waits, whatever clock the caller uses.
    """

    def __init__(self, transport: ByteTransport, max_line: int = 4096):
        self.transport = transport
        self.max_line = max_line
        self._buffer = bytearray()

    def write_line(self, line: bytes, terminator: bytes = b"\r\n") -> None:
        self.transport.write(line + terminator)

    def discard_input(self) -> None:
        self._buffer.clear()
        self.transport.discard_input()

    def read_line(self, timeout_s: float) -> bytes | None:
        """The next line, or None if none completes within `timeout_s`.

        A run of more than `max_line` bytes without a terminator is returned as it is
        (the codec then rejects it) so that garbage cannot grow the buffer forever.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            line = self._take_line()
            if line is not None:
                return line
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            self._buffer += self.transport.read(4096, remaining)

    def _take_line(self) -> bytes | None:
        while self._buffer[:1] in (b"\r", b"\n"):
            del self._buffer[:1]
        ends = [i for i in (self._buffer.find(b"\r"), self._buffer.find(b"\n")) if i >= 0]
        if ends:
            i = min(ends)
            line = bytes(self._buffer[:i])
            del self._buffer[:i + 1]
            return line
        if len(self._buffer) > self.max_line:
            line = bytes(self._buffer[:self.max_line])
            del self._buffer[:self.max_line]
            return line
        return None
