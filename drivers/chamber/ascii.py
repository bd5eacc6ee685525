"""Chamber client for the ASCII line dialect (docs/hardware/chamber.md, codec in ascii_codec).

Each command is one line answered by `OK:<command>` or `NA:<reason>`; the state poll is one
`MON?`. Retries, late replies and reconnects are `drivers.line_link`'s; every command of
the dialect is idempotent (absolute setpoint and ramp, mode, alarm acknowledge), so a
retry that resends one is safe.
"""

from __future__ import annotations

from drivers.chamber import ascii_codec as codec
from drivers.chamber.base import Chamber, ChamberLimits, ChamberState
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import CHAMBER_LINK_ERRORS
from drivers.line_link import LineRequests
from drivers.transport import ByteTransport


class AsciiChamber(LineRequests, Chamber):
    """A chamber controller speaking the ASCII dialect over serial or TCP."""

    dialect = "ascii"
    link_errors = CHAMBER_LINK_ERRORS

    def __init__(self, transport: ByteTransport | str, limits: ChamberLimits | None = None,
                 clock: Clock = SYSTEM_CLOCK, timeout_s: float = 0.5, retries: int = 2):
        Chamber.__init__(self, limits, clock)
        self._setup_link(transport, timeout_s, retries)

    def _command(self, request: bytes) -> None:
        self._transact(request, lambda line: codec.decode_ack(line, request))

    def _set_setpoint(self, setpoint_c: float) -> None:
        self._command(codec.encode_set_setpoint(setpoint_c))

    def _set_ramp(self, ramp_c_per_min: float) -> None:
        self._command(codec.encode_set_ramp(ramp_c_per_min))

    def _run(self) -> None:
        self._command(codec.encode_mode(True))

    def _stop(self) -> None:
        self._command(codec.encode_mode(False))

    def _clear_alarms(self) -> None:
        self._command(codec.CLEAR_ALARMS)

    def _read_state(self) -> ChamberState:
        return self._transact(codec.MONITOR, lambda line: codec.decode_monitor(line, self.clock.now()))

    def read_temperature(self) -> tuple[float, float]:
        """`TEMP?`: (chamber temperature, setpoint), degC."""
        with self._lock:
            return self._transact(b"TEMP?", codec.decode_temperature)
