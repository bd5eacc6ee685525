"""The `$MN` checksum-framed dialect: a pure codec (bytes <-> typed messages), no I/O.

A frame is `$<body>*<CS>` where CS is the sum of the body bytes (everything between
`$` and `*`) modulo 256, as two upper-case hex digits, and the body is
`<prefix><CMD>[,<field>...]`: prefix `MN` for a request, `AS` for a reply, CMD three
upper-case letters. Requests and replies both ways, so the simulator serves exactly
what the client parses. docs/hardware/mn.md is the dialect page (commands, replies, error
codes, status bits). Frames here carry no terminator; the line layer adds CR LF.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import ClassVar, Sequence, Union

from drivers.errors import TurntableChecksumError, TurntableCommandError, TurntableProtocolError, quote_bytes
from drivers.turntable.base import FRAMES, AxisMode, AxisState, AxisStatus, TableState

REQUEST_PREFIX = "MN"
REPLY_PREFIX = "AS"
TERMINATOR = b"\r\n"
MAX_FRAME = 512          # longer than any frame of the dialect; caps work on garbage

# Error codes of `$AS<CMD>,ERR,<code>` replies (1-6 are the simulator's ERR_* codes).
ERR_SYNTAX = 1        # not a frame of the dialect, or an unknown command
ERR_ARGUMENT = 2      # wrong field count, bad axis number or value
ERR_NOT_ENABLED = 3   # axis servo off
ERR_WRONG_MODE = 4    # demand does not match the axis mode
ERR_LIMIT = 5         # beyond the controller's travel or rate limits
ERR_FAULT = 6         # a fault or e-stop is latched; reset first
ERR_CHECKSUM = 7      # the request's checksum did not match; nothing was executed
ERROR_TEXT = {
    ERR_SYNTAX: "syntax error or unknown command",
    ERR_ARGUMENT: "bad argument",
    ERR_NOT_ENABLED: "axis not enabled",
    ERR_WRONG_MODE: "axis in the wrong mode",
    ERR_LIMIT: "beyond the controller's limits",
    ERR_FAULT: "fault or e-stop latched, reset first",
    ERR_CHECKSUM: "request checksum error",
}
UNREADABLE_CMD = "ERR"   # the CMD a controller echoes when it cannot read the request's

# Status word bits of the STA reply -> the common AxisStatus (bits 6-15 reserved, ignored).
STATUS_BITS = {
    0x0001: AxisStatus.ENABLED,
    0x0002: AxisStatus.IN_POSITION,
    0x0004: AxisStatus.MOVING,
    0x0010: AxisStatus.FAULT,
    0x0020: AxisStatus.LIMIT,
    0x0080: AxisStatus.ESTOP,
}
MODE_LETTERS = {AxisMode.POSITION: "P", AxisMode.RATE: "R", AxisMode.OFF: "O"}
_MODE_BY_LETTER = {v: k for k, v in MODE_LETTERS.items()}

_HEX2 = re.compile(rb"[0-9A-F]{2}")
_ANY_CASE_HEX2 = re.compile(rb"[0-9A-Fa-f]{2}")
_CMD = re.compile(r"[A-Z]{3}")
_STATUS = re.compile(r"[0-9A-F]{4}")
_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)")
_FIELD_FORBIDDEN = set(",*$")


class MnChecksumError(TurntableChecksumError):
    """A frame whose checksum digits (`got`) differ from the sum of its body (`expected`)."""

    def __init__(self, message: str, raw: bytes | None, expected: int, got: int):
        super().__init__(message, raw)
        self.expected, self.got = expected, got


class MnRequestError(TurntableProtocolError):
    """A request the controller must refuse; `code` is the ERR_* code to reply with."""

    def __init__(self, message: str, raw: bytes | None = None, code: int = ERR_ARGUMENT):
        super().__init__(message, raw)
        self.code = code


@dataclass(frozen=True)
class Frame:
    prefix: str                 # "MN" (request) or "AS" (reply)
    cmd: str                    # three upper-case letters
    fields: tuple[str, ...]     # comma-separated fields after the command ('' = empty field)


# -- frames ---------------------------------------------------------------------------
def checksum(body: bytes) -> int:
    """Sum of the bytes between `$` and `*`, modulo 256."""
    return sum(body) & 0xFF


def format_angle(angle_deg: float) -> str:
    """Angles go on the wire with 6 decimals (absolute degrees, never wrapped)."""
    return f"{float(angle_deg) + 0.0:.6f}"   # + 0.0 turns -0.0 into 0.0


def format_rate(rate_dps: float) -> str:
    """Rates: 6 decimals with trailing zeros dropped (`10`, `-2.5`)."""
    text = format_angle(rate_dps).rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _field_text(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        raise ValueError(f"a frame field cannot be a bool ({value!r})")
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"a frame field must be finite, got {value}")
        return format_angle(value)
    text = str(value)
    bad = [c for c in text if c in _FIELD_FORBIDDEN or not " " <= c <= "~"]
    if bad:
        raise ValueError(f"frame field {text!r} contains {bad[0]!r} (only printable ASCII without , * $)")
    return text


def sanitize_text(text: str) -> str:
    """Free text (a fault message) made fit for one field: no `, * $`, printable ASCII only."""
    out = "".join(c if " " <= c <= "~" else "?" for c in text)
    return out.replace(",", ";").replace("*", "x").replace("$", "S")[:200]


def encode_frame(prefix: bytes | str, cmd: str, args: Sequence = ()) -> bytes:
    """`$<prefix><cmd>[,<args>...]*<CS>` without terminator. Args: str, int, float (6 decimals), None (empty)."""
    prefix = prefix.decode("ascii") if isinstance(prefix, bytes) else prefix
    if prefix not in (REQUEST_PREFIX, REPLY_PREFIX):
        raise ValueError(f"prefix must be {REQUEST_PREFIX!r} or {REPLY_PREFIX!r}, got {prefix!r}")
    if not _CMD.fullmatch(cmd):
        raise ValueError(f"command must be three upper-case letters, got {cmd!r}")
    fields = [_field_text(a) for a in args]
    body = (prefix + cmd + "".join("," + f for f in fields)).encode("ascii")
    return b"$" + body + b"*" + f"{checksum(body):02X}".encode("ascii")


def decode_frame(line: bytes) -> Frame:
    """Check framing, checksum and body syntax of one line (a trailing CR/LF is allowed)."""
    raw = bytes(line)
    text = raw.rstrip(b"\r\n")
    if not text:
        raise TurntableProtocolError("empty line where a $ frame was expected", raw)
    if len(text) > MAX_FRAME:
        raise TurntableProtocolError(f"line of {len(text)} bytes is longer than any frame ({MAX_FRAME})", raw)
    for i, byte in enumerate(text):
        if not 0x20 <= byte <= 0x7E:
            raise TurntableProtocolError(f"byte 0x{byte:02X} at offset {i} is not printable ASCII", raw)
    if text[:1] != b"$":
        raise TurntableProtocolError(f"frame must start with '$', got {quote_bytes(text, 12)}", raw)
    star = text.rfind(b"*")
    if star < 0:
        raise TurntableProtocolError("no '*' before the checksum", raw)
    digits = text[star + 1:]
    if not _HEX2.fullmatch(digits):
        message = f"checksum must be two upper-case hex digits after '*', got {quote_bytes(digits)}"
        if _ANY_CASE_HEX2.fullmatch(digits):
            # a checksum in lower case is a checksum error (a controller answers ERR 7, command echoed)
            raise MnChecksumError(message, raw, checksum(text[1:star]), int(digits, 16))
        raise TurntableProtocolError(message, raw)
    body = text[1:star]
    for stray in (b"$", b"*"):
        if stray in body:
            raise TurntableProtocolError(f"stray {stray.decode()!r} inside the frame at offset "
                                         f"{body.index(stray) + 1}", raw)
    expected, got = checksum(body), int(digits, 16)
    if expected != got:
        raise MnChecksumError(f"checksum mismatch: frame carries {got:02X}, its content sums to {expected:02X}",
                              raw, expected, got)
    body_text = body.decode("ascii")
    prefix, cmd, rest = body_text[:2], body_text[2:5], body_text[5:]
    if prefix not in (REQUEST_PREFIX, REPLY_PREFIX):
        raise TurntableProtocolError(f"frame prefix must be {REQUEST_PREFIX} or {REPLY_PREFIX}, got {prefix!r}", raw)
    if not _CMD.fullmatch(cmd):
        raise TurntableProtocolError(f"command must be three upper-case letters, got {cmd!r}", raw)
    if rest and rest[0] != ",":
        raise TurntableProtocolError(f"expected ',' after command {cmd}, got {quote_bytes(rest, 8)}", raw)
    return Frame(prefix, cmd, tuple(rest[1:].split(",")) if rest else ())


# -- field parsers (error type chosen by the caller: requests -> MnRequestError) -------------
def _number(text: str, what: str) -> float:
    if not _NUMBER.fullmatch(text):
        raise ValueError(f"{what} must be a decimal number, got {quote_bytes(text)}")
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{what} {quote_bytes(text)} is out of range")
    return value


def _axis(text: str) -> int:
    if text not in ("1", "2", "3"):
        raise ValueError(f"axis must be 1, 2 or 3 (outer, middle, inner), got {quote_bytes(text)}")
    return int(text) - 1


def _mode(text: str) -> AxisMode:
    try:
        return _MODE_BY_LETTER[text]
    except KeyError:
        raise ValueError(f"mode must be P, R or O, got {quote_bytes(text)}") from None


def status_word(status: AxisStatus) -> int:
    """AxisStatus -> the dialect's status word."""
    return sum(bit for bit, flag in STATUS_BITS.items() if status & flag)


def axis_status(word: int) -> AxisStatus:
    """The dialect's status word -> AxisStatus (reserved bits ignored)."""
    status = AxisStatus(0)
    for bit, flag in STATUS_BITS.items():
        if word & bit:
            status |= flag
    return status


# -- requests -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Check:
    """Link check (`$MNCHK,1`): the controller at station 1 replies OK."""
    cmd: ClassVar[str] = "CHK"
    station: int = 1


@dataclass(frozen=True)
class Enable:
    cmd: ClassVar[str] = "ENA"
    axes: tuple[int, ...]       # frame indexes 0-2 (1-3 on the wire)


@dataclass(frozen=True)
class Disable:
    cmd: ClassVar[str] = "DIS"
    axes: tuple[int, ...]


@dataclass(frozen=True)
class Reset:
    cmd: ClassVar[str] = "RST"
    axes: tuple[int, ...]


@dataclass(frozen=True)
class SetMode:
    cmd: ClassVar[str] = "MOD"
    axis: int
    mode: AxisMode


@dataclass(frozen=True)
class MovePositions:
    """Absolute targets (deg) and move rates (deg/s) for outer, middle, inner; None = leave alone."""
    cmd: ClassVar[str] = "POS"
    targets_deg: tuple[float | None, float | None, float | None]
    rates_dps: tuple[float | None, float | None, float | None] = (None, None, None)


@dataclass(frozen=True)
class SetRate:
    cmd: ClassVar[str] = "RAT"
    axis: int
    rate_dps: float


@dataclass(frozen=True)
class Stop:
    cmd: ClassVar[str] = "STP"


@dataclass(frozen=True)
class Abort:
    cmd: ClassVar[str] = "ABT"


@dataclass(frozen=True)
class ReadState:
    cmd: ClassVar[str] = "STA"


Request = Union[Check, Enable, Disable, Reset, SetMode, MovePositions, SetRate, Stop, Abort, ReadState]
_AXIS_LIST: dict[str, type[Enable | Disable | Reset]] = {"ENA": Enable, "DIS": Disable, "RST": Reset}
_NO_FIELDS: dict[str, type[Stop | Abort | ReadState]] = {"STP": Stop, "ABT": Abort, "STA": ReadState}
COMMANDS = ("CHK", "ENA", "DIS", "RST", "MOD", "POS", "RAT", "STP", "ABT", "STA")


def _wire_axes(axes: Sequence[int]) -> list[str]:
    if not axes or len(set(axes)) != len(axes) or any(a not in (0, 1, 2) for a in axes):
        raise ValueError(f"need one to three distinct frame indexes 0-2, got {axes!r}")
    return [str(a + 1) for a in axes]


def encode_request(request: Request) -> bytes:
    """A typed request -> its `$MN` frame (no terminator); ValueError on values the dialect cannot carry."""
    args: Sequence[int | str]
    if isinstance(request, Check):
        if not 1 <= request.station <= 99:
            raise ValueError(f"station must be 1-99, got {request.station}")
        args = [request.station]
    elif isinstance(request, (Enable, Disable, Reset)):
        args = _wire_axes(request.axes)
    elif isinstance(request, SetMode):
        args = _wire_axes([request.axis]) + [MODE_LETTERS[AxisMode(request.mode)]]
    elif isinstance(request, MovePositions):
        if len(request.targets_deg) != 3 or len(request.rates_dps) != 3:
            raise ValueError("POS needs three targets and three rates (None to leave a frame alone)")
        if all(t is None for t in request.targets_deg):
            raise ValueError("POS needs at least one target")
        for v in (*request.targets_deg, *request.rates_dps):
            if v is not None and not math.isfinite(v):
                raise ValueError(f"POS values must be finite, got {v}")
        targets = ["" if t is None else format_angle(t) for t in request.targets_deg]
        args = targets + ["" if r is None else format_rate(r) for r in request.rates_dps]
    elif isinstance(request, SetRate):
        if not math.isfinite(request.rate_dps):
            raise ValueError(f"rate must be finite, got {request.rate_dps}")
        args = _wire_axes([request.axis]) + [format_rate(request.rate_dps)]
    elif isinstance(request, (Stop, Abort, ReadState)):
        args = []
    else:
        raise TypeError(f"not a $MN request: {request!r}")
    return encode_frame(REQUEST_PREFIX, request.cmd, args)


def decode_request(line: bytes) -> Request:
    """A `$MN` request line -> typed request (controller side).

    Raises MnChecksumError (reply ERR_CHECKSUM), MnRequestError (its `code`), or
    TurntableProtocolError for an unreadable frame (reply ERR_SYNTAX).
    """
    frame = decode_frame(line)
    raw = bytes(line)
    if frame.prefix != REQUEST_PREFIX:
        raise MnRequestError(f"a request must start with ${REQUEST_PREFIX}, got ${frame.prefix}", raw, ERR_SYNTAX)
    cmd, fields = frame.cmd, frame.fields
    if cmd not in COMMANDS:
        raise MnRequestError(f"unknown command {cmd!r} (known: {', '.join(COMMANDS)})", raw, ERR_SYNTAX)
    counts = {"CHK": (1, 1), "MOD": (2, 2), "POS": (6, 6), "RAT": (2, 2), "ENA": (1, 3), "DIS": (1, 3),
              "RST": (1, 3), "STP": (0, 0), "ABT": (0, 0), "STA": (0, 0)}
    low, high = counts[cmd]
    if not low <= len(fields) <= high:
        want = str(low) if low == high else f"{low}-{high}"
        raise MnRequestError(f"{cmd} takes {want} fields, got {len(fields)}", raw)
    try:
        if cmd == "CHK":
            if not (fields[0].isdigit() and len(fields[0]) <= 2 and int(fields[0]) >= 1):
                raise ValueError(f"CHK station must be 1-99, got {quote_bytes(fields[0])}")
            return Check(int(fields[0]))
        if cmd in _AXIS_LIST:
            axes = tuple(_axis(f) for f in fields)
            if len(set(axes)) != len(axes):
                raise ValueError(f"axis listed twice in {quote_bytes(','.join(fields))}")
            return _AXIS_LIST[cmd](axes)
        if cmd == "MOD":
            return SetMode(_axis(fields[0]), _mode(fields[1]))
        if cmd == "POS":
            # exactly six fields (checked above): three targets, then three rates
            t0, t1, t2 = (None if f == "" else _number(f, f"{FRAMES[k]} target") for k, f in enumerate(fields[:3]))
            r0, r1, r2 = (None if f == "" else _number(f, f"{FRAMES[k]} move rate") for k, f in enumerate(fields[3:]))
            targets, rates = (t0, t1, t2), (r0, r1, r2)
            if all(t is None for t in targets):
                raise ValueError("POS needs at least one target")
            return MovePositions(targets, rates)
        if cmd == "RAT":
            return SetRate(_axis(fields[0]), _number(fields[1], "rate"))
        return _NO_FIELDS[cmd]()
    except ValueError as exc:
        raise MnRequestError(f"{cmd}: {exc}", raw, ERR_ARGUMENT) from exc


# -- replies ---------------------------------------------------------------------------------
def encode_ok(cmd: str, fields: Sequence = ()) -> bytes:
    """`$AS<cmd>,<fields...>,OK*CS` (no terminator)."""
    return encode_frame(REPLY_PREFIX, cmd, [*fields, "OK"])


def encode_error(cmd: str, code: int) -> bytes:
    """`$AS<cmd>,ERR,<code>*CS` (no terminator)."""
    if not (isinstance(code, int) and 0 <= code <= 999):
        raise ValueError(f"error code must be 0-999, got {code!r}")
    return encode_frame(REPLY_PREFIX, cmd, ["ERR", code])


def encode_state(state: TableState) -> bytes:
    """The STA reply for a table state: per axis angle, rate, mode, status word; then fault text."""
    fields: list[str] = []
    for axis in state.axes:
        fields += [format_angle(axis.angle_deg), format_angle(axis.rate_dps), MODE_LETTERS[axis.mode],
                   f"{status_word(axis.status):04X}"]
    return encode_ok("STA", [*fields, sanitize_text(state.fault_text)])


STATE_FIELDS = 13


def decode_reply(line: bytes, cmd: str, n_fields: int = 0) -> tuple[str, ...]:
    """Check that `line` is the OK reply to `cmd` with `n_fields` data fields; return them.

    An error reply raises TurntableCommandError(code); an error reply saying the request
    was unreadable or failed its checksum raises TurntableProtocolError /
    TurntableChecksumError (the line was corrupted on the way: worth a retry); a reply
    to another command (stale or mismatched) raises TurntableProtocolError.
    """
    frame = decode_frame(line)
    raw = bytes(line)
    if frame.prefix != REPLY_PREFIX:
        raise TurntableProtocolError(f"expected a ${REPLY_PREFIX} reply to {cmd}, got a ${frame.prefix} frame", raw)
    fields = frame.fields
    is_error = len(fields) >= 1 and fields[0] == "ERR"
    code = None
    if is_error:
        if len(fields) != 2 or not (fields[1].isdigit() and len(fields[1]) <= 3):
            raise TurntableProtocolError(f"error reply must be ERR,<code 0-999>, got {quote_bytes(','.join(fields))}",
                                         raw)
        code = int(fields[1])
        if code == ERR_CHECKSUM:
            raise TurntableChecksumError(f"controller saw a checksum error in the {cmd} request", raw)
        if frame.cmd == UNREADABLE_CMD:
            raise TurntableProtocolError(f"controller could not read the {cmd} request "
                                         f"(error {code}: {ERROR_TEXT.get(code, 'unknown code')})", raw)
    if frame.cmd != cmd:
        raise TurntableProtocolError(f"reply to {frame.cmd} where a reply to {cmd} was expected "
                                     "(stale or mismatched reply)", raw)
    if is_error:
        assert code is not None  # set with is_error above
        raise TurntableCommandError(f"controller refused {cmd}: error {code} "
                                    f"({ERROR_TEXT.get(code, 'unknown code')})", code)
    if not fields or fields[-1] != "OK":
        raise TurntableProtocolError(f"{cmd} reply does not end in OK or carry ERR,<code>", raw)
    data = fields[:-1]
    if len(data) != n_fields:
        raise TurntableProtocolError(f"{cmd} reply has {len(data)} data fields, expected {n_fields}", raw)
    return data


def decode_state(fields: Sequence[str], time_s: float, raw: bytes | None = None) -> TableState:
    """The data fields of an STA reply -> TableState (TurntableProtocolError names a bad field)."""
    if len(fields) != STATE_FIELDS:
        raise TurntableProtocolError(f"STA reply has {len(fields)} data fields, expected {STATE_FIELDS}", raw)
    axes = []
    for k in range(3):
        angle, rate, mode, word = fields[4 * k:4 * k + 4]
        try:
            angle_deg = _number(angle, f"{FRAMES[k]} angle")
            rate_dps = _number(rate, f"{FRAMES[k]} rate")
            axis_mode = _mode(mode)
            if not _STATUS.fullmatch(word):
                raise ValueError(f"{FRAMES[k]} status word must be four upper-case hex digits, got {quote_bytes(word)}")
        except ValueError as exc:
            raise TurntableProtocolError(f"STA reply: {exc}", raw) from exc
        axes.append(AxisState(angle_deg, rate_dps, axis_mode, axis_status(int(word, 16))))
    return TableState(time_s, (axes[0], axes[1], axes[2]), fields[12])
