"""Client for `$MN` checksum-framed turntable controllers (serial or TCP); see docs/hardware/mn.md.

Every interface call is one request frame and one `$AS` reply; a move of all three
frames is one POS command and a state poll is one STA round trip. Retries, timeouts
and reconnects are `LineTurntable`'s; the wire format is `mn_codec`'s.
"""

from __future__ import annotations

from typing import Sequence

from drivers.turntable import mn_codec as codec
from drivers.turntable.base import AxisMode, TableState
from drivers.turntable.line_client import LineTurntable


class MnTurntable(LineTurntable):
    """A `$MN` controller over a transport URL (`/dev/ttyUSB0?baud=115200`, `tcp://host:port`, ...).

    `connect()` opens the link and checks it with `$MNCHK,1` (station 1 answers OK).
    """

    dialect = "mn"

    def connect(self) -> "MnTurntable":
        with self._lock:
            self._open()
            try:
                self.check_link()
            except BaseException:
                self._close()
                raise
        return self

    def check_link(self) -> None:
        """`$MNCHK,1` -> `$ASCHK,OK`: the controller is there and speaks the dialect."""
        with self._lock:
            self._command(codec.Check())

    def _command(self, request: codec.Request, n_fields: int = 0) -> tuple[str, ...]:
        return self._transact(codec.encode_request(request),
                              lambda line: codec.decode_reply(line, request.cmd, n_fields))

    def _enable(self, frames: Sequence[int]) -> None:
        if frames:
            self._command(codec.Enable(tuple(dict.fromkeys(frames))))

    def _disable(self, frames: Sequence[int]) -> None:
        if frames:
            self._command(codec.Disable(tuple(dict.fromkeys(frames))))

    def _reset_faults(self, frames: Sequence[int]) -> None:
        if frames:
            self._command(codec.Reset(tuple(dict.fromkeys(frames))))

    def _set_mode(self, frame: int, mode: AxisMode) -> None:
        self._command(codec.SetMode(frame, mode))

    def _demand_positions(self, targets: dict[int, float], rate_dps: dict[int, float]) -> None:
        def rate(k: int) -> float | None:
            return rate_dps.get(k) if k in targets else None

        self._command(codec.MovePositions((targets.get(0), targets.get(1), targets.get(2)),
                                          (rate(0), rate(1), rate(2))))

    def _demand_rate(self, frame: int, rate_dps: float) -> None:
        self._command(codec.SetRate(frame, rate_dps))

    def _stop(self) -> None:
        self._command(codec.Stop())

    def _abort(self) -> None:
        self._command(codec.Abort())

    def _read_state(self) -> TableState:
        def parse(line: bytes) -> TableState:
            fields = codec.decode_reply(line, "STA", codec.STATE_FIELDS)
            return codec.decode_state(fields, self.clock.now(), line)
        return self._transact(codec.encode_request(codec.ReadState()), parse)
