"""The simulated controller served in the SCPI-like dialect (docs/hardware/scpi.md).

`ScpiSimHandler(controller)` is a `LineServer` handler: it parses a request line with
the pure codec, executes each program unit on the `SimController` in order and answers
the line's queries in one reply (no queries -> no reply, as in SCPI). A command that
fails puts an entry on the error queue (read with `:SYST:ERR?`); a query that fails
answers with its error entry in place of its data. `serve_scpi` starts a `LineServer`
on TCP 127.0.0.1 and/or a pty.

Wire faults (`controller.faults`), taken once per reply:
- timeout: the line is executed, the reply is swallowed;
- garbage: the line is executed, the reply is junk bytes + CR LF;
- checksum: plain SCPI has no checksum; the reply is corrupted instead, the top bit of
  one character flipped as a parity error on a serial line would, which the client's
  codec rejects as a non-ASCII reply (a corruption that stayed a valid character would
  go unnoticed on a real plain-SCPI link);
- exception: the line is not executed and the reply is the error entry of
  `faults.exception_code` (a SimCommandError code, mapped as below);
- late: the line is executed, the reply is sent just before the reply to the next line.
"""

from __future__ import annotations

import threading
from collections import deque

from bench.sim.controller import (
    ERR_ARGUMENT,
    ERR_FAULT,
    ERR_LIMIT,
    ERR_NOT_ENABLED,
    ERR_SYNTAX,
    ERR_WRONG_MODE,
    SimCommandError,
    SimController,
)
from bench.sim.serve import LineServer, flip_parity, held_first, reply_with_fault, serve_lines
from drivers.turntable import scpi_codec as sc
from drivers.turntable.base import AxisMode

SIM_TO_SCPI = {  # SimCommandError code -> SCPI error number (docs/hardware/scpi.md, "Errors")
    ERR_SYNTAX: sc.SYNTAX_ERROR,
    ERR_ARGUMENT: sc.ILLEGAL_PARAMETER_VALUE,
    ERR_NOT_ENABLED: sc.INTERLOCK_OPEN,
    ERR_WRONG_MODE: sc.SETTINGS_CONFLICT,
    ERR_LIMIT: sc.DATA_OUT_OF_RANGE,
    ERR_FAULT: sc.FAULT_LATCHED,
}
ERROR_QUEUE_LENGTH = 16
GARBAGE = b"\xa5Z#?\x00garbage\xfe"
IDN = "turntable-bench,SCPI-SIM,0,1.0"

_MODES = {"MODE:POSITION": AxisMode.POSITION, "MODE:RATE": AxisMode.RATE, "MODE:OFF": AxisMode.OFF}


def scpi_error_code(sim_code: int) -> int:
    """A SimCommandError code -> its SCPI error number (unknown codes -> -200 Execution error)."""
    return SIM_TO_SCPI.get(sim_code, sc.EXECUTION_ERROR)


class ScpiSimHandler:
    """Serves a SimController in the SCPI-like dialect: `handler(line) -> reply bytes | None`.

    One error queue for the whole controller (as on an instrument with several
    interfaces); thread-safe, so a TCP client and a pty client may share it.
    """

    def __init__(self, controller: SimController, idn: str = IDN):
        self.controller = controller
        self.idn = idn
        self.errors: deque[str] = deque()
        # Position-mode move rate per axis set by :L:R (None = the controller's maximum).
        self.move_rate_dps: list[float | None] = [None, None, None]
        self._lock = threading.Lock()

    def _push_error(self, code: int, detail: str) -> None:
        if len(self.errors) >= ERROR_QUEUE_LENGTH:
            self.errors[-1] = sc.format_error(sc.QUEUE_OVERFLOW)
            return
        self.errors.append(sc.format_error(code, detail))

    def __call__(self, line: bytes) -> bytes | None:
        return held_first(self.controller.faults, lambda: self._reply(line))

    def _reply(self, line: bytes) -> bytes | None:
        units = sc.parse_program(line)
        if not any(u.query for u in units):
            with self._lock:
                self._run(units)
            return None
        def run() -> bytes:
            with self._lock:
                return sc.format_reply(self._run(units))

        return reply_with_fault(
            self.controller.faults, run, garbage=GARBAGE + b"\r\n", corrupt=flip_parity,
            exception_reply=lambda code: sc.format_reply([sc.format_error(scpi_error_code(code), "injected")]))

    def _run(self, units: list[sc.ScpiRequest | sc.ScpiRequestError]) -> list[str]:
        responses = []
        for unit in units:
            if isinstance(unit, sc.ScpiRequestError):
                entry = (unit.code, str(unit))
            else:
                try:
                    response = self._execute(unit)
                    if unit.query and response is None:     # every query the codec knows answers or raises
                        raise SimCommandError(f"{unit.name} not implemented", ERR_SYNTAX)
                except SimCommandError as exc:
                    entry = (scpi_error_code(exc.code), str(exc))
                else:
                    if unit.query and response is not None:
                        responses.append(response)
                    continue
            if unit.query:
                responses.append(sc.format_error(*entry))
            else:
                self._push_error(*entry)
        return responses

    def _execute(self, request: sc.ScpiRequest) -> str | None:
        """Run one request on the controller; a query's response text (None for a command)."""
        ctl, name, values = self.controller, request.name, request.values
        if name in _MODES:
            ctl.set_mode(_axis(request), _MODES[name])
        elif name == "DEMAND:POSITION":
            k = _axis(request)
            rate = values[1] if len(values) > 1 else self.move_rate_dps[k]
            ctl.demand_position(k, values[0], rate)
        elif name == "DEMAND:RATE":
            ctl.demand_rate(_axis(request), values[0])
        elif name == "LIMIT:RATE":
            k = _axis(request)
            if not values[0] > 0:       # an illegal value (-224), as for :D:P; above the maximum: a limit (-222)
                raise SimCommandError(f"move rate must be positive, got {values[0]} deg/s", ERR_ARGUMENT)
            if values[0] > ctl.limits[k].max_rate_dps:
                raise SimCommandError(f"move rate {values[0]} deg/s outside (0, {ctl.limits[k].max_rate_dps}]",
                                      ERR_LIMIT)
            self.move_rate_dps[k] = values[0]
        elif name == "LIMIT:RATE?":
            k = _axis(request)
            rate = self.move_rate_dps[k]
            return sc.format_number(ctl.limits[k].max_rate_dps if rate is None else rate)
        elif name == "INTERLOCK:CLOSE":
            ctl.enable(_axis(request))
        elif name == "INTERLOCK:OPEN":
            ctl.disable(_axis(request))
        elif name == "INTERLOCK:RESET":
            ctl.reset(_axis(request))
        elif name == "STOP":
            ctl.stop()
        elif name == "ABORT":
            ctl.abort()
        elif name == "READ:ALL?":
            return sc.format_state(ctl.state())
        elif name.startswith("READ:") and request.frame is not None:
            axis = ctl.axis_state(request.frame)
            return {"READ:POSITION?": lambda: sc.format_number(axis.angle_deg),
                    "READ:RATE?": lambda: sc.format_number(axis.rate_dps),
                    "READ:MODE?": lambda: str(sc.MODE_CODES[axis.mode]),
                    "READ:STATUS?": lambda: str(sc.status_word(axis.status))}[name]()
        elif name == "READ:FAULT?":
            return sc.format_string(ctl.fault_text)
        elif name == "SYSTEM:ERROR?":
            return self.errors.popleft() if self.errors else sc.format_error(sc.NO_ERROR)
        elif name == "*IDN?":
            return self.idn
        elif name == "*CLS":
            self.errors.clear()
        else:  # a command in the codec's table that this simulator does not implement
            raise SimCommandError(f"{name} not implemented", ERR_SYNTAX)
        return None


def _axis(request: sc.ScpiRequest) -> int:
    """The axis (0-2) of a per-axis command; the codec gives every one an axis."""
    if request.frame is None:
        raise SimCommandError(f"{request.name} needs an axis", ERR_SYNTAX)
    return request.frame


def serve_scpi(controller: SimController, tcp: bool = True, pty: bool = False,
               port: int = 0) -> tuple[LineServer, dict[str, str]]:
    """Serve `controller` in the SCPI dialect; returns the server (close it) and its URLs
    ({'tcp': 'tcp://127.0.0.1:port', 'pty': '/dev/pts/N'} as requested)."""
    return serve_lines(ScpiSimHandler(controller), tcp, pty, port)
