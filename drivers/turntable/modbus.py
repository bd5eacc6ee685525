"""Modbus TCP / RTU turntable client over pymodbus's sync clients (register map in modbus_map).

URLs: `modbus+tcp://host[:port][?unit=N]` (port 502 by default) and
`modbus+rtu:///dev/ttyUSB0?baud=115200&parity=E&unit=N` (also bytesize, stopbits).
docs/hardware/modbus.md documents the dialect: registers, encodings, commands, errors.

The request machinery (drivers.modbus_link, shared with the chamber) maps failures onto
drivers.errors: no reply -> retry, then `TurntableTimeout`; a reply
that does not decode (garbage, bad CRC, malformed MBAP) -> retry, then
`TurntableProtocolError`/`TurntableChecksumError`; a Modbus exception reply ->
`TurntableCommandError(code)` at once (the controller refused); a lost link ->
reconnect and resend once, then `TurntableConnectionError`. A reply that grows past
`MAX_REPLY_BYTES` (64 KiB; a Modbus reply is at most 260 bytes) without decoding -> the
link is closed (the next request reconnects) and `TurntableProtocolError` at once: a
peer streaming garbage costs a bounded buffer and a short message.
"""

from __future__ import annotations

import threading
from typing import Sequence

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import TURNTABLE_LINK_ERRORS, DeviceError
from drivers.modbus_link import DEFAULT_TCP_PORT, ModbusRequests, parse_modbus_url
from drivers.turntable.base import AxisMode, TableState, Turntable, TurntableLimits
from drivers.turntable.modbus_map import RegisterMap, axis_mask, contiguous_runs

__all__ = ["DEFAULT_TCP_PORT", "ModbusTurntable", "parse_modbus_url"]


class ModbusTurntable(ModbusRequests, Turntable):
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
    link_errors = TURNTABLE_LINK_ERRORS

    def __init__(self, url: str, register_map: RegisterMap | None = None, limits: TurntableLimits | None = None,
                 clock: Clock = SYSTEM_CLOCK, timeout_s: float = 0.5, retries: int = 2,
                 watchdog_refresh_s: float | None = None, release_watchdog: bool = True):
        Turntable.__init__(self, limits, clock)
        self.map = register_map if register_map is not None else RegisterMap.default()
        self._setup_link(url, self.map.unit, timeout_s, retries)
        period = self.map.watchdog_s
        self.watchdog_refresh_s = (max(period / 4, 0.02) if watchdog_refresh_s is None else float(watchdog_refresh_s))
        self.watchdog_error: DeviceError | None = None
        self.release_watchdog = release_watchdog
        self._watchdog_value = 0
        self._watchdog_stop = threading.Event()
        self._watchdog_thread: threading.Thread | None = None

    # -- link -------------------------------------------------------------------------
    def _open(self) -> None:
        if self._client is not None:
            return
        self._connect_link()
        assert self._client is not None
        if self.map.watchdog_s > 0:
            try:
                self._refresh_watchdog()
            except DeviceError:
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
                except DeviceError:
                    pass      # best effort: the link may be what failed; the watchdog then trips, which is safe
            self._client.close()
            self._client = None

    def _stop_watchdog(self) -> None:
        self._watchdog_stop.set()
        thread = self._watchdog_thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=(self.retries + 2) * self.timeout_s + 1.0)
            self._watchdog_thread = None

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
            except DeviceError as exc:
                self.watchdog_error = exc
            finally:
                self._lock.release()

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
