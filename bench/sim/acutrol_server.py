"""The simulated controller served in the ACUTROL3000 Command Language (docs/hardware/acutrol.md).

`AcutrolSimHandler(controller)` is a `LineServer` handler: one program message (a line) in,
one framed response out (error code, length, text, NUL; `framing="tcp"`, the TCP port and the
RS-232 device server), or, with `framing="gpib"`, the IEEE-488 way: text answers to queries
only, LF terminated, errors left on the error queue. The units of a message run in order on
the `SimController`; the first refused unit ends the message (what came before it has run).
Every read of one message answers from one controller frame (one instant of the table).

ACL keeps demands apart from modes (TM-8004 4.3, 4.7): a demand is stored, and moves the table
when its axis is servoed in the matching mode; a position demand made in another mode is taken
up by the next Mode:Position, otherwise entering position mode holds the axis where it comes to
rest. Off mode holds zero rate with the servo on. A latched interlock fault (limit switch
string, amplifier acknowledge, master interlock: the fault console's `limit`, `fault`, `estop`)
opens the servo, freezes the interlock state at `Fault` and refuses Interlock:Close until
Interlock:Reset (TM-9385A 3.2, 5.1).

Wire faults (`controller.faults`, tcp framing), once per response: timeout (executed, nothing sent), garbage
(junk instead of the frame), checksum (ACL has none: the error code's top byte is corrupted, so
the frame cannot be read), exception (not executed, answered with `exception_code` mapped below),
late (sent just before the next response).
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass
from typing import Callable

from bench.model.units import DEG
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
from bench.sim.serve import LineServer, held_first, reply_with_fault, serve_lines
from drivers.turntable import acutrol_codec as ac
from drivers.turntable.base import AxisMode, AxisStatus

SIM_TO_ACL = {ERR_SYNTAX: ac.NOT_RECOGNIZED, ERR_ARGUMENT: ac.OUT_OF_RANGE, ERR_NOT_ENABLED: ac.NOT_SERVOED,
              ERR_WRONG_MODE: ac.OUT_OF_RANGE, ERR_LIMIT: ac.OUT_OF_RANGE, ERR_FAULT: ac.INTERLOCK_FAULT}
IDN = "turntable-bench,ACUTROL3000-SIM,0,1.0"
ERROR_QUEUE_LENGTH = 32
GARBAGE = b"\xa5Z#?garbage\xfe\x00"
CONTINUOUS_TRAVEL_DEG = 1.0e6     # the absolute position limits a continuous axis reports
TRACKING_ERROR_TRIP_DEG = 10.0

# status register bits (TM-8004 appendix B)
INTLK_PA_ACK = 1 << 6           # A(n)INTLK: power amplifier acknowledge lost (an amplifier fault)
INTLK_LIMIT_STRING = 1 << 7     # A(n)INTLK: INTLK1, the limit switch string (TM-9385A 3.2.2)
INTLK_MASTER = 1 << 9           # A(n)INTLK: master interlock (the emergency stop)
STATE_SERVOED = 1 << 4          # A(n)STATE
STATE_HW_ABORT = 1 << 7
STATE_LATCHED = 1 << 8
DYN_HIGH_LIMIT = 1 << 6         # A(n)DYN
DYN_LOW_LIMIT = 1 << 7
DYN_POSITION_COMPLETE = 1 << 8
DYN_RATE_COMPLETE = 1 << 9
STB_SI, STB_MSS, STB_EQ = 1 << 0, 1 << 6, 1 << 7


def acl_error_code(sim_code: int) -> int:
    """A SimCommandError code -> the ACL error number (docs/hardware/acutrol.md, "Errors")."""
    return SIM_TO_ACL.get(sim_code, ac.NOT_AVAILABLE)


@dataclass
class _AxisAcl:
    """What ACL keeps per axis beside the servo: the profiler mode, the demands, the working limits."""

    mode: str = "Off"
    position_demand_deg: float = 0.0
    position_pending: bool = False       # a position demand made outside position mode, for the next Mode:Position
    rate_demand_dps: float = 0.0
    last_delta_deg: float = 0.0


@dataclass(frozen=True)
class _Frame:
    """One instant of one axis, for every read of a message."""

    angle_deg: float
    rate_dps: float
    accel_dps2: float
    status: AxisStatus


class AcutrolSimHandler:
    """`(line: bytes) -> bytes | None`: the ACL face of a SimController (thread-safe: TCP and pty may share it)."""

    def __init__(self, controller: SimController, framing: str = "tcp", idn: str = IDN):
        if framing not in ("tcp", "gpib"):
            raise ValueError(f"framing must be 'tcp' or 'gpib', got {framing!r}")
        self.controller, self.framing, self.idn = controller, framing, idn
        self.errors: deque[str] = deque()
        self._lock = threading.Lock()
        ctl = controller
        self.axes = [_AxisAcl(position_demand_deg=ctl.axis_state(k).angle_deg) for k in range(3)]
        self.absolute = [self._factory_limits(k) for k in range(3)]
        # working limits per (mode, axis): rate, acceleration, high and low position
        self.rate_limit = {(m, k): self.absolute[k].rate_dps for m in ac.MODE_NAMES for k in range(3)}
        self.accel_limit = {(m, k): self.absolute[k].accel_dps2 for m in ac.MODE_NAMES for k in range(3)}
        self.high_limit = {(m, k): self.absolute[k].pos_hi_deg for m in ac.MODE_NAMES for k in range(3)}
        self.low_limit = {(m, k): self.absolute[k].pos_lo_deg for m in ac.MODE_NAMES for k in range(3)}

    def _factory_limits(self, k: int) -> ac.AbsoluteLimits:
        lim = self.controller.limits[k]
        low = -CONTINUOUS_TRAVEL_DEG if lim.min_deg is None else lim.min_deg
        high = CONTINUOUS_TRAVEL_DEG if lim.max_deg is None else lim.max_deg
        # the simulated table has no jerk limit: it reports a hundred times its acceleration limit
        return ac.AbsoluteLimits(lim.max_rate_dps, lim.max_accel_dps2, 100.0 * lim.max_accel_dps2, low, high,
                                 1.2 * lim.max_rate_dps)

    # -- the handler ------------------------------------------------------------------------------------------
    def __call__(self, line: bytes) -> bytes | None:
        return held_first(self.controller.faults, lambda: self._faulty_reply(line))

    def _faulty_reply(self, line: bytes) -> bytes | None:
        if self.framing == "gpib":
            return self.respond(line)
        return reply_with_fault(
            self.controller.faults, lambda: self.respond(line) or b"", garbage=GARBAGE, corrupt=_corrupt_code,
            exception_reply=lambda code: ac.frame_response(acl_error_code(code), "injected fault"))

    def respond(self, line: bytes) -> bytes | None:
        """Run one program message; its response in this handler's framing (None: nothing to send)."""
        with self._lock, self.controller.lock:
            code, text, queries = self._run(line)
        if self.framing == "tcp":
            return ac.frame_response(code, text)
        return (text + "\n").encode("ascii") if code == ac.NO_ERROR and queries else None

    def _run(self, line: bytes) -> tuple[int, str, int]:
        """(error code, response text, number of queries answered)."""
        units, refused = ac.parse_message(line)
        responses: list[str] = []
        frame: list[_Frame] | None = None
        for unit in units:
            try:
                if unit.query:
                    frame = frame or self._frame()
                    responses.append(self._query(unit, frame))
                else:
                    self._command(unit)
                    frame = None           # a read after a command sees what it did
            except ac.AclError as exc:
                refused = ac.AclError(exc.code, exc.detail, exc.unit or unit.name)
                break
            except SimCommandError as exc:
                refused = ac.AclError(acl_error_code(exc.code), str(exc), unit.name)
                break
        if refused is not None:
            self._push_error(refused)
            return refused.code, str(refused), 0
        return ac.NO_ERROR, ";".join(responses), len(responses)

    def _push_error(self, error: ac.AclError) -> None:
        # ';' separates responses and '"' ends the entry's string: neither may stand in its text
        entry = f'{error.code},"{str(error).replace(";", ",").replace(chr(34), chr(39))}"'
        if len(self.errors) >= ERROR_QUEUE_LENGTH:
            self.errors.popleft()          # the oldest goes: the newest says what the host just did
        self.errors.append(entry)

    # -- one instant of the table ------------------------------------------------------------------------------
    def _frame(self) -> list[_Frame]:
        ctl = self.controller
        t = ctl.now()
        out = []
        for k in range(3):
            theta, rate, accel = ctl.table.axis_at(t, k)
            out.append(_Frame(theta / DEG, rate / DEG, accel / DEG, ctl.axis_state(k, t).status))
        return out

    def _interlock_bits(self, k: int, frame: list[_Frame]) -> int:
        status = frame[k].status
        return ((INTLK_PA_ACK if status & AxisStatus.FAULT else 0) | (INTLK_LIMIT_STRING if status & AxisStatus.LIMIT
                else 0) | (INTLK_MASTER if status & AxisStatus.ESTOP else 0))

    def _dynamic_bits(self, k: int, frame: list[_Frame]) -> int:
        axis, acl = frame[k], self.axes[k]
        bits = 0
        if axis.angle_deg >= self.high_limit[(acl.mode, k)]:
            bits |= DYN_HIGH_LIMIT
        if axis.angle_deg <= self.low_limit[(acl.mode, k)]:
            bits |= DYN_LOW_LIMIT
        if axis.status & AxisStatus.ENABLED:
            if acl.mode == "Position" and axis.status & AxisStatus.IN_POSITION:
                bits |= DYN_POSITION_COMPLETE
            if acl.mode in ("Rate", "Off") and axis.accel_dps2 == 0.0:
                bits |= DYN_RATE_COMPLETE
        return bits

    def _register(self, name: str, frame: list[_Frame]) -> int:
        for k in range(3):
            n = f"A{k + 1}"
            if name == n + "INTLK":
                return self._interlock_bits(k, frame)
            if name in (n + "SWFLT", n + "SWFAULT", n + "ERR"):
                return 0                     # no software-detected faults in the simulation
            if name == n + "DYN":
                return self._dynamic_bits(k, frame)
            if name == n + "STATE":
                latched = self._interlock_bits(k, frame) != 0
                return ((STATE_SERVOED if frame[k].status & AxisStatus.ENABLED else 0)
                        | (STATE_HW_ABORT | STATE_LATCHED if latched else 0))
        if name == "G1INTLK":
            bits = 0
            for k in range(3):
                if frame[k].status & AxisStatus.LIMIT:
                    bits |= 1 << (4 * k)          # axis k's INTLK1
            return bits | (1 << 15 if any(f.status & AxisStatus.ESTOP for f in frame) else 0)
        if name == "SI":
            bits = 1 if self._register("G1INTLK", frame) else 0
            for k in range(3):
                bits |= (1 << (2 + 2 * k)) if self._interlock_bits(k, frame) else 0
            return bits
        if name in ("ACP", "SUP", "RI", "G2INTLK"):    # no ACP procedure errors, supervisor or interface faults
            return 0
        raise ac.AclError(ac.OUT_OF_RANGE, f"no status register {name}")

    def _status_byte(self, frame: list[_Frame]) -> int:
        # an interlock fault alone reads 65 (summary and SI), the manual's example and what a real client tests for
        stb = (STB_SI if self._register("SI", frame) else 0) | (STB_EQ if self.errors else 0)
        return stb | (STB_MSS if stb else 0)

    # -- queries -----------------------------------------------------------------------------------------------
    def _query(self, unit: ac.Unit, frame: list[_Frame]) -> str:
        path, args = unit.path, unit.args
        k = args[0] - 1 if args and isinstance(args[0], int) else 0
        reads: dict[tuple[str, ...], Callable[[], str]] = {
            ("READ", "POSITION"): lambda: ac.format_number(frame[k].angle_deg),
            ("READ", "RATE"): lambda: ac.format_number(frame[k].rate_dps),
            ("READ", "ACCELERATION"): lambda: ac.format_number(frame[k].accel_dps2),
            ("DEMAND", "POSITION"): lambda: ac.format_number(self.axes[k].position_demand_deg),
            ("DEMAND", "RATE"): lambda: ac.format_number(self.axes[k].rate_demand_dps),
            ("DEMAND", "DELTAPOSITION"): lambda: ac.format_number(self.axes[k].last_delta_deg),
            ("MODE",): lambda: self.axes[k].mode,
            ("INTERLOCK",): lambda: self._interlock_state(k, frame),
            ("INTERLOCK", "CONTROL"): lambda: self._interlock_state(k, frame),
            ("*IDN",): lambda: self.idn,
            ("*STB",): lambda: str(self._status_byte(frame)),
            ("STATUS", "STB"): lambda: str(self._status_byte(frame)),
            ("QUERY", "SYSTEM"): lambda: "3,1,2,3",
        }
        if path in reads:
            return reads[path]()
        if path == ("LIMIT", "ABSOLUTE"):
            lim = self.absolute[k]
            return ",".join(ac.format_number(v) for v in (lim.rate_dps, lim.accel_dps2, lim.jerk_dps3, lim.pos_lo_deg,
                                                           lim.pos_hi_deg, lim.velocity_trip_dps or 0.0,
                                                           TRACKING_ERROR_TRIP_DEG))
        if path[0] == "LIMIT":
            mode, axis = args[0], args[1]
            assert isinstance(mode, str) and isinstance(axis, int)
            return ac.format_number(self._working_limits(path[1])[(mode, axis - 1)])
        if path == ("QUERY", "ERROR"):
            code = args[0]
            assert isinstance(code, int)
            return ac.ERROR_TEXT.get(code, "Unknown error code")
        if path == ("STATUS", "CSR"):
            assert isinstance(args[0], str)
            value = self._register(args[0], frame)
            if len(args) > 1:
                bit = args[1]
                assert isinstance(bit, int)
                if not 0 <= bit <= 15:
                    raise ac.AclError(ac.OUT_OF_RANGE, f"no bit {bit} (0-15)")
                return str(value >> bit & 1)
            return str(value)
        if path == ("STATUS", "MSG"):
            return self._messages(args)
        raise ac.AclError(ac.NOT_AVAILABLE, f"{unit.name} is not offered")

    def _interlock_state(self, k: int, frame: list[_Frame]) -> str:
        if self._interlock_bits(k, frame):
            return "Fault"
        return "Close" if frame[k].status & AxisStatus.ENABLED else "Open"

    def _messages(self, args: tuple[object, ...]) -> str:
        queue, count = args[0], args[1] if len(args) > 1 else 1
        if queue != "QERROR":
            return ""                        # the other message queues: none kept (the manual: not implemented)
        n = len(self.errors) if count == "ALL" else count
        assert isinstance(n, int)
        return ";".join(self.errors.popleft() for _ in range(min(n, len(self.errors))))

    def _working_limits(self, name: str) -> dict[tuple[str, int], float]:
        return {"RATE": self.rate_limit, "ACCELERATION": self.accel_limit, "HIGHPOSITION": self.high_limit,
                "LOWPOSITION": self.low_limit}[name]

    # -- commands ----------------------------------------------------------------------------------------------
    def _command(self, unit: ac.Unit) -> None:
        path, args = unit.path, unit.args
        if path == ("INTERLOCK", "RESET"):
            for k in range(3):
                self.controller.reset(k)
        elif path in (("INTERLOCK", "CLOSE"), ("INTERLOCK", "OPEN")):
            for k in _axes(args[0]):
                self._close(k) if path[1] == "CLOSE" else self.controller.disable(k)
        elif path[0] == "MODE":
            mode = path[1].title() if len(path) > 1 else args[1]
            assert isinstance(mode, str)
            if mode not in ac.AXIS_MODE:
                raise ac.AclError(ac.NOT_AVAILABLE, f"{mode} mode is not simulated")
            for k in _axes(args[0]):
                self._set_mode(k, mode)
        elif path[0] == "DEMAND":
            axis, value = args
            assert isinstance(axis, int) and isinstance(value, float)
            self._demand(path[1], axis - 1, value)
        elif path[0] == "LIMIT":
            mode, axis, value = args
            assert isinstance(mode, str) and isinstance(axis, int) and isinstance(value, float)
            self._set_limit(path[1], mode, axis - 1, value)
        elif path in (("*CLS",), ("STATUS", "MSGCLR")):
            if path == ("*CLS",) or args[0] in ("QERROR", "ALL"):
                self.errors.clear()
        else:
            raise ac.AclError(ac.NOT_AVAILABLE, f"{unit.name} is not offered")

    def _servoed(self, k: int) -> bool:
        return self.controller.axis_state(k).enabled

    def _close(self, k: int) -> None:
        """Interlock:Close: servo on, holding where the axis is, then the axis's mode applies."""
        was_servoed = self._servoed(k)
        self.controller.enable(k)
        if not was_servoed:
            acl = self.axes[k]
            acl.position_demand_deg, acl.position_pending = self.controller.axis_state(k).angle_deg, False
            if acl.mode != "Position":
                self._apply_rate_mode(k)

    def _apply_rate_mode(self, k: int) -> None:
        """Rate mode at its demand, or Off: zero rate, reached at the mode's acceleration limit (4.6.8)."""
        ctl, acl = self.controller, self.axes[k]
        ctl.set_mode(k, AxisMode.RATE)
        mode = "Rate" if acl.mode == "Rate" else "Off"
        ctl.demand_rate(k, acl.rate_demand_dps if mode == "Rate" else 0.0, self.accel_limit[(mode, k)])

    def _set_mode(self, k: int, mode: str) -> None:
        acl = self.axes[k]
        previous, acl.mode = acl.mode, mode
        if not self._servoed(k):
            return
        if mode != "Position":
            self._apply_rate_mode(k)
            return
        if previous != "Position":
            self.controller.set_mode(k, AxisMode.POSITION)     # comes to rest and holds there
            rest = self.controller.table.axis_at(self.controller.now() + 3600.0, k)[0] / DEG
            if acl.position_pending:
                self._move(k, acl.position_demand_deg)
            else:
                acl.position_demand_deg = rest
        acl.position_pending = False

    def _demand(self, name: str, k: int, value: float) -> None:
        acl = self.axes[k]
        if name == "RATE":
            limit = self.rate_limit[("Rate", k)]
            if abs(value) > limit:
                raise ac.AclError(ac.OUT_OF_RANGE, f"rate {value} beyond the rate limit {limit}")
            acl.rate_demand_dps = value
            if acl.mode == "Rate" and self._servoed(k):
                self.controller.demand_rate(k, value, self.accel_limit[("Rate", k)])
            return
        target = value if name == "POSITION" else acl.position_demand_deg + value
        low, high = self.low_limit[("Position", k)], self.high_limit[("Position", k)]
        if not low <= target <= high:
            raise ac.AclError(ac.OUT_OF_RANGE, f"position {target} outside the position limits [{low}, {high}]")
        if name == "DELTAPOSITION":
            acl.last_delta_deg = value
        acl.position_demand_deg = target
        if acl.mode == "Position" and self._servoed(k):
            self._move(k, target)
            acl.position_pending = False
        else:
            acl.position_pending = True

    def _move(self, k: int, target_deg: float) -> None:
        """A profiled move at the position mode's rate and acceleration limits (4.7.4)."""
        self.controller.demand_position(k, target_deg, self.rate_limit[("Position", k)],
                                        self.accel_limit[("Position", k)])

    def _set_limit(self, name: str, mode: str, k: int, value: float) -> None:
        absolute = self.absolute[k]
        if name in ("RATE", "ACCELERATION"):
            ceiling = absolute.rate_dps if name == "RATE" else absolute.accel_dps2
            if not 0.0 < value <= ceiling:
                raise ac.AclError(ac.OUT_OF_RANGE, f"{name.lower()} limit {value} outside (0, {ceiling}]")
        elif name == "HIGHPOSITION":
            if not self.low_limit[(mode, k)] < value <= absolute.pos_hi_deg:
                raise ac.AclError(ac.OUT_OF_RANGE, f"high position limit {value} outside "
                                                   f"({self.low_limit[(mode, k)]}, {absolute.pos_hi_deg}]")
        elif not absolute.pos_lo_deg <= value < self.high_limit[(mode, k)]:
            raise ac.AclError(ac.OUT_OF_RANGE, f"low position limit {value} outside "
                                               f"[{absolute.pos_lo_deg}, {self.high_limit[(mode, k)]})")
        self._working_limits(name)[(mode, k)] = value


def _axes(arg: object) -> range | tuple[int]:
    """An <axis|ALL> argument -> the axis indices (0-2) it names."""
    if arg == "ALL":
        return range(3)
    assert isinstance(arg, int)
    return (arg - 1,)


def _corrupt_code(frame: bytes) -> bytes:
    """A `checksum` fault: the error code's most significant byte corrupted (the frame cannot be read)."""
    body = bytearray(frame)
    body[3] ^= 0x40
    return bytes(body)


def serve_acutrol(controller: SimController, tcp: bool = True, pty: bool = False, port: int = 0,
                  framing: str = "tcp") -> tuple[LineServer, dict[str, str]]:
    """Serve `controller` in ACL; returns the server (close it) and its URLs ({'tcp': 'tcp://127.0.0.1:port',
    'pty': '/dev/pts/N'} as requested)."""
    return serve_lines(AcutrolSimHandler(controller, framing), tcp, pty, port)
