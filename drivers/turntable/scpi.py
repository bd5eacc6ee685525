"""Turntable client for the generic SCPI-like dialect (this project's own; it matches no controller).

Every command goes out as `<command>[;<command>...];:SYST:ERR?` so that one reply
confirms it (SCPI commands say nothing by themselves): `0,"No error"` or the error
entry, raised as `TurntableCommandError(code)`. A line carrying several commands (all
axes enabled or moved at once) that gets an error reply has the rest of the error
queue read out, so every refusal is reported and the queue is left empty. The state
poll is one query, `:R:A?`. On every (re)connect the client sends `*CLS` (no reply) so
that errors left from an earlier session are not taken for its own.

Retries (see LineTurntable) resend a whole line; every command of the dialect is
idempotent (absolute positions, rates, modes, interlock states, stop, abort).
"""

from __future__ import annotations

from typing import Sequence

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import DeviceCommandError, DeviceError, TurntableCommandError, TurntableConnectionError
from drivers.transport import ByteTransport
from drivers.turntable import scpi_codec as sc
from drivers.turntable.base import AxisMode, AxisStatus, TableState, TurntableLimits, frame_index
from drivers.turntable.line_client import LineTurntable

_MODE_COMMANDS = {AxisMode.POSITION: "MODE:POSITION", AxisMode.RATE: "MODE:RATE", AxisMode.OFF: "MODE:OFF"}
MAX_DRAIN = 16   # error-queue entries read after an error reply (the queue length of the controller)


class ScpiTurntable(LineTurntable):
    """A turntable controller speaking the SCPI-like dialect over serial or TCP.

    `long_form=True` sends long headers (`:DEMAND:POSITION`) for controllers or
    logs that want them; replies are the same either way.
    """

    dialect = "scpi"

    def __init__(self, transport: ByteTransport | str, limits: TurntableLimits | None = None,
                 clock: Clock = SYSTEM_CLOCK, timeout_s: float = 0.5, retries: int = 2, long_form: bool = False):
        super().__init__(transport, limits, clock, timeout_s, retries)
        self.long_form = long_form

    def _unit(self, name: str, frame: int | None = None, *values: float) -> bytes:
        return sc.encode(name, frame, *values, long_form=self.long_form)

    def _command(self, *units: bytes) -> None:
        """Send commands on one line with the error query; raise every error they caused."""
        try:
            self._transact(sc.confirmed(*units, long_form=self.long_form), sc.decode_confirmation)
        except DeviceCommandError as first:
            if len(units) == 1:
                raise
            entries = [str(first)]
            for _ in range(MAX_DRAIN):
                try:
                    code, text = self._transact(self._unit("SYSTEM:ERROR?"), sc.decode_error)
                except DeviceError as exc:   # the refusal is the error to report, not the failed read-out
                    entries.append(f"(error queue not read: {exc})")
                    break
                if code == sc.NO_ERROR:
                    break
                entries.append(f"SCPI controller error {code}: {sc.error_text(text)}")
            raise TurntableCommandError("; ".join(entries), first.code) from first

    # -- LineTurntable / Turntable ------------------------------------------------------
    def _open(self) -> None:
        super()._open()
        try:
            self.channel.write_line(sc.encode("*CLS"), self.terminator)
        except ConnectionError as exc:
            self.transport.close()
            raise TurntableConnectionError(f"{self.dialect}: {exc}") from exc

    def _enable(self, frames: Sequence[int]) -> None:
        if frames:
            self._command(*(self._unit("INTERLOCK:CLOSE", k) for k in frames))

    def _disable(self, frames: Sequence[int]) -> None:
        if frames:
            self._command(*(self._unit("INTERLOCK:OPEN", k) for k in frames))

    def _reset_faults(self, frames: Sequence[int]) -> None:
        if frames:
            self._command(*(self._unit("INTERLOCK:RESET", k) for k in frames))

    def _set_mode(self, frame: int, mode: AxisMode) -> None:
        self._command(self._unit(_MODE_COMMANDS[mode], frame))

    def _demand_positions(self, targets: dict[int, float], rate_dps: dict[int, float]) -> None:
        self._command(*(self._unit("DEMAND:POSITION", k, angle, rate_dps[k]) for k, angle in targets.items()))

    def _demand_rate(self, frame: int, rate_dps: float) -> None:
        self._command(self._unit("DEMAND:RATE", frame, rate_dps))

    def _stop(self) -> None:
        self._command(self._unit("STOP"))

    def _abort(self) -> None:
        self._command(self._unit("ABORT"))

    def _read_state(self) -> TableState:
        return self._transact(self._unit("READ:ALL?"), lambda line: sc.decode_state(line, self.clock.now()))

    # -- single-value queries (diagnostics; the state poll is read_state) -----------------
    def identify(self) -> str:
        """The controller's `*IDN?` reply: maker,model,serial,firmware."""
        with self._lock:
            return self._transact(self._unit("*IDN?"), sc.decode_idn)

    def read_position(self, frame: int | str) -> float:
        """`:R:P? n`: one frame's angle, deg."""
        with self._lock:
            return self._transact(self._unit("READ:POSITION?", frame_index(frame)),
                                  lambda line: sc.decode_number(line, "position"))

    def read_rate(self, frame: int | str) -> float:
        """`:R:R? n`: one frame's rate, deg/s."""
        with self._lock:
            return self._transact(self._unit("READ:RATE?", frame_index(frame)),
                                  lambda line: sc.decode_number(line, "rate"))

    def read_status(self, frame: int | str) -> AxisStatus:
        """`:R:S? n`: one frame's status bits."""
        with self._lock:
            return self._transact(self._unit("READ:STATUS?", frame_index(frame)), sc.decode_status)

    def read_error(self) -> tuple[int, str]:
        """`:SYST:ERR?`: the oldest error-queue entry, (0, 'No error') when empty."""
        with self._lock:
            return self._transact(self._unit("SYSTEM:ERROR?"), sc.decode_error)
