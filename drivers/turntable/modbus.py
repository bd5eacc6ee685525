"""Modbus TCP / RTU turntable client over pymodbus's sync clients (register map in modbus_map).

URLs: `modbus+tcp://host[:port][?unit=N]` (port 502 by default) and
`modbus+rtu:///dev/ttyUSB0?baud=115200&parity=E&unit=N` (also bytesize, stopbits).
drivers/MODBUS.md documents the dialect: registers, encodings, commands, errors.

Failures map onto drivers.errors: no reply -> retry, then `TurntableTimeout`; a reply
that does not decode (garbage, bad CRC, malformed MBAP) -> retry, then
`TurntableProtocolError`/`TurntableChecksumError`; a Modbus exception reply ->
`TurntableCommandError(code)` at once (the controller refused); a lost link ->
reconnect and resend once, then `TurntableConnectionError`. A reply that grows past
`MAX_REPLY_BYTES` (64 KiB; a Modbus reply is at most 260 bytes) without decoding -> the
link is closed (the next request reconnects) and `TurntableProtocolError` at once: a
peer streaming garbage costs a bounded buffer and a short message.
"""

from __future__ import annotations

import logging
import threading
from typing import Callable, Sequence
from urllib.parse import parse_qs, urlencode, urlsplit

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import (
    TurntableCommandError,
    TurntableConfigError,
    TurntableConnectionError,
    TurntableError,
    TurntableProtocolError,
    TurntableTimeout,
    quote_bytes,
)
from drivers.transport import MAX_REPLY_BYTES, serial_settings
from drivers.turntable.base import AxisMode, TableState, Turntable, TurntableLimits
from drivers.turntable.modbus_map import (
    RegisterMap,
    axis_mask,
    contiguous_runs,
    exception_name,
    explain_bad_reply,
)

# pymodbus logs every timeout at ERROR; without a handler Python would print those to
# stderr. The application's own logging configuration still receives them.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

DEFAULT_TCP_PORT = 502


class _ReplyTooLong(Exception):
    """Raised through pymodbus from the packet trace: a reply past MAX_REPLY_BYTES that has not decoded."""


def parse_modbus_url(url: str) -> tuple[str, dict, int | None]:
    """`modbus+tcp://...` / `modbus+rtu://...` -> (framing 'tcp'|'rtu', pymodbus client kwargs, unit or None).

    TurntableConfigError (a ValueError) naming what is wrong for any other form.
    """
    parts = urlsplit(url)
    query = parse_qs(parts.query, keep_blank_values=True)
    unit = None
    if "unit" in query:
        text = query.pop("unit")[-1]
        try:
            unit = int(text)
        except ValueError:
            raise TurntableConfigError(f"{url}: unit={text!r} is not a number") from None
        if not 0 <= unit <= 255:
            raise TurntableConfigError(f"{url}: unit must be 0-255, got {unit}")
    if parts.scheme == "modbus+tcp":
        if query:
            raise TurntableConfigError(f"{url}: unknown option(s) {', '.join(sorted(query))} (modbus+tcp takes unit=)")
        try:
            port = parts.port
        except ValueError as exc:
            raise TurntableConfigError(f"{url}: bad port") from exc
        if not parts.hostname:
            raise TurntableConfigError(f"expected modbus+tcp://host:port, got {url!r}")
        return "tcp", {"host": parts.hostname, "port": port or DEFAULT_TCP_PORT}, unit
    if parts.scheme == "modbus+rtu":
        path = (parts.netloc + parts.path) if parts.netloc else parts.path
        if not path:
            raise TurntableConfigError(f"expected modbus+rtu:///dev/ttyX?baud=N, got {url!r}")
        try:
            settings = serial_settings(urlencode({k: v[-1] for k, v in query.items()}))
        except ValueError as exc:
            raise TurntableConfigError(f"{url}: {exc}") from exc
        kwargs = {"port": path, "baudrate": 19200, "parity": "N", "bytesize": 8, "stopbits": 1}
        kwargs.update(settings)
        return "rtu", kwargs, unit
    raise TurntableConfigError(f"not a Modbus URL (modbus+tcp://host:port or modbus+rtu:///dev/path): {url!r}")


class ModbusTurntable(Turntable):
    """A three-axis controller spoken to over Modbus TCP or RTU with a `RegisterMap`.

    `timeout_s` is the reply timeout of one attempt (real seconds); a request is tried
    `retries + 1` times. With a watchdog in the map, a small thread writes an
    incrementing watchdog value every `watchdog_refresh_s` (default a quarter of the
    map's period) while connected; a failing refresh is kept in `watchdog_error`. Closing
    the link releases the watchdog (writes 0, which disarms it) unless `release_watchdog`
    is False: a command that ends on purpose must not leave the table to fault 2 s later,
    while a client that dies without closing still trips it.
    """

    dialect = "modbus"

    def __init__(self, url: str, register_map: RegisterMap | None = None, limits: TurntableLimits | None = None,
                 clock: Clock = SYSTEM_CLOCK, timeout_s: float = 0.5, retries: int = 2,
                 watchdog_refresh_s: float | None = None, release_watchdog: bool = True):
        super().__init__(limits, clock)
        if not timeout_s > 0:
            raise TurntableConfigError(f"timeout_s must be positive, got {timeout_s}")
        if not (isinstance(retries, int) and retries >= 0):
            raise TurntableConfigError(f"retries must be a non-negative integer, got {retries!r}")
        self.url = url
        self.map = register_map if register_map is not None else RegisterMap.default()
        self.framing, self._client_kwargs, url_unit = parse_modbus_url(url)
        self.unit = self.map.unit if url_unit is None else url_unit
        self.timeout_s = float(timeout_s)
        self.retries = retries
        period = self.map.watchdog_s
        self.watchdog_refresh_s = (max(period / 4, 0.02) if watchdog_refresh_s is None else float(watchdog_refresh_s))
        self.watchdog_error: TurntableError | None = None
        self.release_watchdog = release_watchdog
        self.reconnects = 0
        self._client: ModbusTcpClient | ModbusSerialClient | None = None
        self._watchdog_value = 0
        self._watchdog_stop = threading.Event()
        self._watchdog_thread: threading.Thread | None = None
        self._rx = b""
        self._tx = b""

    # -- link -------------------------------------------------------------------------
    def _make_client(self):
        common = {"timeout": self.timeout_s, "retries": 0, "trace_packet": self._trace_packet}
        if self.framing == "tcp":
            kw = dict(self._client_kwargs)
            return ModbusTcpClient(kw.pop("host"), **kw, **common)
        kw = dict(self._client_kwargs)
        return ModbusSerialClient(kw.pop("port"), **kw, **common)

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

    def _open(self) -> None:
        if self._client is not None:
            return
        client = self._make_client()
        if not client.connect():
            client.close()
            raise TurntableConnectionError(f"cannot connect to {self.url}")
        self._client = client
        if self.map.watchdog_s > 0:
            try:
                self._refresh_watchdog()
            except TurntableError:
                self._client.close()
                self._client = None
                raise
            self._watchdog_stop.clear()
            self._watchdog_thread = threading.Thread(target=self._watchdog_loop, daemon=True,
                                                     name="modbus-watchdog")
            self._watchdog_thread.start()

    def close(self) -> None:
        # Stop the watchdog thread before taking the lock it also takes.
        self._stop_watchdog()
        super().close()

    def _close(self) -> None:
        self._stop_watchdog()
        if self._client is not None:
            if self.release_watchdog and self.map.watchdog_s > 0 and self._watchdog_value:
                try:
                    self._write_single(self.map.watchdog, 0, "watchdog release")
                except TurntableError:
                    pass      # best effort: the link may be what failed; the watchdog then trips, which is safe
            self._client.close()
            self._client = None

    def _stop_watchdog(self) -> None:
        self._watchdog_stop.set()
        thread = self._watchdog_thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=(self.retries + 2) * self.timeout_s + 1.0)
            self._watchdog_thread = None

    def _reconnect(self, what: str, cause: Exception) -> None:
        assert self._client is not None
        self._client.close()
        self.reconnects += 1
        if not self._client.connect():
            raise TurntableConnectionError(f"{what}: link to {self.url} lost ({cause}) and reconnecting failed") \
                from cause

    # -- watchdog ---------------------------------------------------------------------
    def _refresh_watchdog(self) -> None:
        self._watchdog_value = self._watchdog_value % 0xFFFF + 1     # 1..65535, never 0
        self._write_single(self.map.watchdog, self._watchdog_value, "watchdog refresh")

    def _watchdog_loop(self) -> None:
        interval = self.watchdog_refresh_s
        while not self._watchdog_stop.wait(interval):
            if not self._lock.acquire(timeout=interval):
                continue
            try:
                if self._watchdog_stop.is_set() or self._client is None:
                    return
                self._refresh_watchdog()
                self.watchdog_error = None
            except TurntableError as exc:
                self.watchdog_error = exc
            finally:
                self._lock.release()

    # -- requests -----------------------------------------------------------------------
    def _request(self, what: str, function_code: int, call: Callable):
        """One request with retries on silence or an undecodable reply, one reconnect on a lost link."""
        if self._client is None:
            raise TurntableConnectionError(f"{what}: not connected to {self.url} (call connect() first)")
        failure: tuple[TurntableError, Exception] | None = None
        reconnected = False
        attempt = 0
        while attempt <= self.retries:
            self._rx = self._tx = b""
            try:
                response = call(self._client)
            except (ConnectionException, OSError) as exc:
                if reconnected:
                    raise TurntableConnectionError(f"{what}: link to {self.url} lost and not regained: {exc}") \
                        from exc
                reconnected = True
                self._reconnect(what, exc)
                continue
            except ModbusIOException as exc:
                failure = (self._no_reply(what, function_code), exc)
                attempt += 1
                continue
            except _ReplyTooLong:
                self._client.close()        # the rest of the stream goes with the link; the next request reconnects
                raise TurntableProtocolError(
                    f"{what}: no Modbus reply in more than {MAX_REPLY_BYTES:,} bytes from {self.url} (garbage?): "
                    f"{quote_bytes(self._rx, hex_dump=True)}", self._rx) from None
            except ModbusException as exc:
                raise TurntableProtocolError(f"{what}: {exc}", self._rx or None) from exc
            if response is None:        # pragma: no cover - only with no_response_expected
                raise TurntableProtocolError(f"{what}: no response object from pymodbus")
            if response.isError():
                code = getattr(response, "exception_code", None)
                raise TurntableCommandError(
                    f"{what}: Modbus exception {code} ({exception_name(code)}) from {self.url}", code)
            if response.function_code != function_code:
                raise TurntableProtocolError(
                    f"{what}: reply has function code {response.function_code}, expected {function_code}",
                    self._rx or None)
            return response
        # retries >= 0 (checked in __init__), so the loop ran and only ends after a recorded failure
        assert failure is not None
        error, cause = failure
        raise error from cause

    def _no_reply(self, what: str, function_code: int) -> TurntableError:
        attempts = self.retries + 1
        if not self._rx:
            return TurntableTimeout(f"{what}: no reply from {self.url} within {self.timeout_s} s "
                                    f"({attempts} attempt{'s' if attempts > 1 else ''})")
        tid = int.from_bytes(self._tx[0:2], "big") if self.framing == "tcp" and len(self._tx) >= 2 else None
        error = explain_bad_reply(self._rx, self.framing, self.unit, function_code, tid)
        return type(error)(f"{what}: {error} ({attempts} attempt{'s' if attempts > 1 else ''})", error.raw)

    def _read(self, address: int, count: int, what: str) -> list[int]:
        response = self._request(what, 3, lambda c: c.read_holding_registers(address, count=count,
                                                                              device_id=self.unit))
        registers = list(response.registers)
        if len(registers) != count:
            raise TurntableProtocolError(f"{what}: asked for {count} registers, got {len(registers)}",
                                         self._rx or None)
        return registers

    def _write_single(self, address: int, value: int, what: str) -> None:
        self._request(what, 6, lambda c: c.write_register(address, value, device_id=self.unit))

    def _write(self, address: int, values: Sequence[int], what: str) -> None:
        if len(values) == 1:
            self._write_single(address, values[0], what)
            return
        self._request(what, 16, lambda c: c.write_registers(address, list(values), device_id=self.unit))

    def _command(self, name: str, frames: Sequence[int]) -> None:
        code, mask = self.map.command_code(name), axis_mask(frames)
        what = f"{name} (command {code}, axes {mask:#05b})"
        cmd, axes = self.map.command, self.map.command_axes
        if axes == cmd + 1:
            self._write(cmd, [code, mask], what)
        elif axes == cmd - 1:
            self._write(axes, [mask, code], what)
        else:           # the axis mask first: writing the command register executes it
            self._write_single(axes, mask, what)
            self._write_single(cmd, code, what)

    # -- the dialect ----------------------------------------------------------------------
    def move_to(self, angles_deg: Sequence[float | None], rate_dps: float | Sequence[float] | None = None) -> None:
        # A target the register encoding cannot carry must fail before the mode writes go out.
        for angle in angles_deg:
            if angle is not None:
                self.map.encode_value(float(angle), "angle")
        super().move_to(angles_deg, rate_dps)

    def _enable(self, frames: Sequence[int]) -> None:
        self._command("enable", frames)

    def _disable(self, frames: Sequence[int]) -> None:
        self._command("disable", frames)

    def _reset_faults(self, frames: Sequence[int]) -> None:
        self._command("reset", frames)

    def _set_mode(self, frame: int, mode: AxisMode) -> None:
        code = self.map.mode_code(mode)
        self._write_single(self.map.mode[frame], code, f"set mode {mode.value} on axis {frame + 1}")

    def _demand_positions(self, targets: dict[int, float], rate_dps: dict[int, float]) -> None:
        values: dict[int, int] = {}
        triggers: set[int] = set()
        for k, angle in targets.items():
            for name, value, kind in (("move_rate", rate_dps[k], "rate"), ("demand_position", angle, "angle")):
                address = getattr(self.map, name)[k]
                values[address], values[address + 1] = self.map.encode_value(value, kind)
            triggers.update((self.map.demand_position[k], self.map.demand_position[k] + 1))
        what = "move to " + ", ".join(f"axis {k + 1} {a:g} deg at {rate_dps[k]:g} deg/s" for k, a in targets.items())
        # Writing a demand position starts the move, so runs holding only move rates go first.
        runs = sorted(contiguous_runs(values), key=lambda run: any(
            a in triggers for a in range(run[0], run[0] + len(run[1]))))
        for address, registers in runs:
            self._write(address, registers, what)

    def _demand_rate(self, frame: int, rate_dps: float) -> None:
        registers = self.map.encode_value(rate_dps, "rate")
        self._write(self.map.demand_rate[frame], registers, f"rate {rate_dps:g} deg/s on axis {frame + 1}")

    def _stop(self) -> None:
        self._command("stop", (0, 1, 2))

    def _abort(self) -> None:
        self._command("abort", (0, 1, 2))

    def _read_state(self) -> TableState:
        start, count = self.map.state_span
        registers = self._read(start, count, f"read state ({count} registers at {start})")
        return self.map.decode_state(registers, self.clock.now())
