"""Modbus TCP / RTU request machinery over pymodbus's sync clients, shared by the turntable and the chamber.

URLs: `modbus+tcp://host[:port][?unit=N]` (port 502 by default) and
`modbus+rtu:///dev/ttyUSB0?baud=115200&parity=E&unit=N` (also bytesize, stopbits).

Failures map onto the device's own errors (`link_errors`, a `drivers.errors.LinkErrors`):
no reply -> retry, then `timeout`; a reply that does not decode (garbage, bad CRC,
malformed MBAP) -> retry, then `protocol`/`checksum`; on RTU, a controller that was only
slow answers the attempts that timed out as well: after the reply, the replies still owed
are read and dropped (each the length of the one received, waited for at most about
`timeout_s`), or the next request would read one of them as its answer: nothing on RTU
tells them apart, a state one poll old (on TCP pymodbus skips a reply whose transaction
id is not the request's); a Modbus exception reply ->
`command(code)` at once (the controller refused); a lost link -> reconnect and resend
once, then `connection`. A reply that grows past `MAX_REPLY_BYTES` (64 KiB; a Modbus
reply is at most 260 bytes) without decoding -> the link is closed (the next request
reconnects) and `protocol` at once: a peer streaming garbage costs a bounded buffer and
a short message.
"""

from __future__ import annotations

import logging
from typing import Callable, Sequence
from urllib.parse import parse_qs, urlencode, urlsplit

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from drivers.errors import TURNTABLE_LINK_ERRORS, DeviceChecksumError, LinkErrors, quote_bytes
from drivers.modbus_frames import exception_name, explain_bad_reply
from drivers.transport import MAX_REPLY_BYTES, serial_settings

# pymodbus logs every timeout at ERROR; without a handler Python would print those to
# stderr. The application's own logging configuration still receives them.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

DEFAULT_TCP_PORT = 502


class _ReplyTooLong(Exception):
    """Raised through pymodbus from the packet trace: a reply past MAX_REPLY_BYTES that has not decoded."""


def parse_modbus_url(url: str, errors: LinkErrors = TURNTABLE_LINK_ERRORS) -> tuple[str, dict, int | None]:
    """`modbus+tcp://...` / `modbus+rtu://...` -> (framing 'tcp'|'rtu', pymodbus client kwargs, unit or None).

    `errors.config` (a ValueError) naming what is wrong for any other form.
    """
    bad = errors.config
    parts = urlsplit(url)
    query = parse_qs(parts.query, keep_blank_values=True)
    unit = None
    if "unit" in query:
        text = query.pop("unit")[-1]
        try:
            unit = int(text)
        except ValueError:
            raise bad(f"{url}: unit={text!r} is not a number") from None
        if not 0 <= unit <= 255:
            raise bad(f"{url}: unit must be 0-255, got {unit}")
    if parts.scheme == "modbus+tcp":
        if query:
            raise bad(f"{url}: unknown option(s) {', '.join(sorted(query))} (modbus+tcp takes unit=)")
        try:
            port = parts.port
        except ValueError as exc:
            raise bad(f"{url}: bad port") from exc
        if not parts.hostname:
            raise bad(f"expected modbus+tcp://host:port, got {url!r}")
        return "tcp", {"host": parts.hostname, "port": port or DEFAULT_TCP_PORT}, unit
    if parts.scheme == "modbus+rtu":
        path = (parts.netloc + parts.path) if parts.netloc else parts.path
        if not path:
            raise bad(f"expected modbus+rtu:///dev/ttyX?baud=N, got {url!r}")
        try:
            settings = serial_settings(urlencode({k: v[-1] for k, v in query.items()}))
        except ValueError as exc:
            raise bad(f"{url}: {exc}") from exc
        kwargs = {"port": path, "baudrate": 19200, "parity": "N", "bytesize": 8, "stopbits": 1}
        kwargs.update(settings)
        return "rtu", kwargs, unit
    raise bad(f"not a Modbus URL (modbus+tcp://host:port or modbus+rtu:///dev/path): {url!r}")


class ModbusRequests:
    """Holding-register reads and writes with retries and one reconnect (a mixin of the Modbus clients).

    `_setup_link(url, unit, timeout_s, retries)` parses the URL; `_connect_link()` /
    `_close_link()` open and close pymodbus's client; `_read`, `_write_single` and
    `_write` are the requests.
    """

    link_errors: LinkErrors

    def _setup_link(self, url: str, unit: int, timeout_s: float, retries: int) -> None:
        if not timeout_s > 0:
            raise self.link_errors.config(f"timeout_s must be positive, got {timeout_s}")
        if not (isinstance(retries, int) and retries >= 0):
            raise self.link_errors.config(f"retries must be a non-negative integer, got {retries!r}")
        self.url = url
        self.framing, self._client_kwargs, url_unit = parse_modbus_url(url, self.link_errors)
        self.unit = unit if url_unit is None else url_unit
        self.timeout_s = float(timeout_s)
        self.retries = retries
        self.reconnects = 0
        self.late_replies = 0     # replies to timed-out attempts, read and dropped
        self._client: ModbusTcpClient | ModbusSerialClient | None = None
        self._rx = b""
        self._tx = b""

    # -- link -------------------------------------------------------------------------
    def _make_client(self) -> ModbusTcpClient | ModbusSerialClient:
        kw = dict(self._client_kwargs)
        if self.framing == "tcp":
            return ModbusTcpClient(kw.pop("host"), **kw, timeout=self.timeout_s, retries=0,
                                   trace_packet=self._trace_packet)
        return ModbusSerialClient(kw.pop("port"), **kw, timeout=self.timeout_s, retries=0,
                                  trace_packet=self._trace_packet)

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        # Keep what went out and what came back, to say why a reply did not decode.
        # pymodbus hands over everything received for the reply so far (one more read each time):
        # stop it there once it passes MAX_REPLY_BYTES.
        if sending:
            self._tx = bytes(data)
        else:
            self._rx = bytes(data)
            if len(data) > MAX_REPLY_BYTES:
                raise _ReplyTooLong()
        return data

    def _connect_link(self) -> None:
        """Open the client (nothing if open); `connection` error when it cannot connect."""
        if self._client is not None:
            return
        client = self._make_client()
        if not client.connect():
            client.close()
            raise self.link_errors.connection(f"cannot connect to {self.url}")
        self._client = client

    def _close_link(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

    def _reconnect(self, what: str, cause: Exception) -> None:
        assert self._client is not None
        self._client.close()
        self.reconnects += 1
        if not self._client.connect():
            raise self.link_errors.connection(
                f"{what}: link to {self.url} lost ({cause}) and reconnecting failed") from cause

    # -- requests -----------------------------------------------------------------------
    def _request(self, what: str, function_code: int, call: Callable):
        """One request with retries on silence or an undecodable reply, one reconnect on a lost link."""
        errors = self.link_errors
        if self._client is None:
            raise errors.connection(f"{what}: not connected to {self.url} (call connect() first)")
        failure: tuple[Exception, Exception] | None = None
        reconnected = False
        attempt = 0
        unanswered = 0      # attempts that timed out in silence: a slow controller still owes their replies
        while attempt <= self.retries:
            self._rx = self._tx = b""
            try:
                response = call(self._client)
            except (ConnectionException, OSError) as exc:
                if reconnected:
                    raise errors.connection(f"{what}: link to {self.url} lost and not regained: {exc}") from exc
                reconnected = True
                self._reconnect(what, exc)
                continue
            except ModbusIOException as exc:
                unanswered += not self._rx
                failure = (self._no_reply(what, function_code), exc)
                attempt += 1
                continue
            except _ReplyTooLong:
                self._client.close()        # the rest of the stream goes with the link; the next request reconnects
                raise errors.protocol(
                    f"{what}: no Modbus reply in more than {MAX_REPLY_BYTES:,} bytes from {self.url} (garbage?): "
                    f"{quote_bytes(self._rx, hex_dump=True)}", self._rx) from None
            except ModbusException as exc:
                raise errors.protocol(f"{what}: {exc}", self._rx or None) from exc
            if response is None:        # pragma: no cover - only with no_response_expected
                raise errors.protocol(f"{what}: no response object from pymodbus", None)
            if unanswered and self.framing == "rtu":     # an exception reply is owed as often as any other
                self._drop_late_replies(unanswered, response)
            if response.isError():
                code = getattr(response, "exception_code", None)
                raise errors.command(
                    f"{what}: Modbus exception {code} ({exception_name(code)}) from {self.url}", code)
            if response.function_code != function_code:
                raise errors.protocol(
                    f"{what}: reply has function code {response.function_code}, expected {function_code}",
                    self._rx or None)
            return response
        # retries >= 0 (checked in _setup_link), so the loop ran and only ends after a recorded failure
        assert failure is not None
        error, cause = failure
        raise error from cause

    def _drop_late_replies(self, owed: int, response) -> None:
        """Read and drop up to `owed` replies of the received one's length, each waited for at most
        about `timeout_s` (a request lost on the way is never answered: its wait ends the drain)."""
        assert self._client is not None
        frame = len(self._client.framer.buildFrame(response))
        # bytes read with the reply beyond its frame were dropped with it (pymodbus keeps no rest)
        ahead = max(0, len(self._rx) - frame)
        for _ in range(owed):
            if ahead >= frame:
                ahead -= frame
                self.late_replies += 1
                continue
            try:
                got = len(self._client.recv(frame - ahead))
            except (ConnectionException, OSError):
                return              # the next request finds the link gone and reconnects
            if got < frame - ahead:
                return
            ahead = 0
            self.late_replies += 1

    def _no_reply(self, what: str, function_code: int) -> Exception:
        errors = self.link_errors
        attempts = self.retries + 1
        if not self._rx:
            return errors.timeout(f"{what}: no reply from {self.url} within {self.timeout_s} s "
                                  f"({attempts} attempt{'s' if attempts > 1 else ''})")
        tid = int.from_bytes(self._tx[0:2], "big") if self.framing == "tcp" and len(self._tx) >= 2 else None
        error = explain_bad_reply(self._rx, self.framing, self.unit, function_code, tid)
        kind = errors.checksum if isinstance(error, DeviceChecksumError) else errors.protocol
        return kind(f"{what}: {error} ({attempts} attempt{'s' if attempts > 1 else ''})", error.raw)

    def _read(self, address: int, count: int, what: str) -> list[int]:
        response = self._request(what, 3, lambda c: c.read_holding_registers(address, count=count,
                                                                              device_id=self.unit))
        registers = list(response.registers)
        if len(registers) != count:
            raise self.link_errors.protocol(f"{what}: asked for {count} registers, got {len(registers)}",
                                            self._rx or None)
        return registers

    def _write_single(self, address: int, value: int, what: str) -> None:
        self._request(what, 6, lambda c: c.write_register(address, value, device_id=self.unit))

    def _write(self, address: int, values: Sequence[int], what: str) -> None:
        if len(values) == 1:
            self._write_single(address, values[0], what)
            return
        self._request(what, 16, lambda c: c.write_registers(address, list(values), device_id=self.unit))
