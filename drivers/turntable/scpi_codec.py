"""Pure codec of the generic SCPI-like turntable dialect (this project's own; it matches no controller).

Both ways, no I/O: the client builds request lines (`encode`, `confirmed`) and decodes
replies (`decode_*`); the simulator parses request lines (`parse_program`) and formats
replies (`format_*`). docs/hardware/scpi.md is the dialect page: keywords, commands, replies,
error numbers, status bits and an example session.

Headers follow SCPI: keywords separated by ':', matched case-insensitively in their long
form or their short form. This dialect's short forms are single letters (`:M:P` for
`:MODE:POSITION`), so the short form of each keyword is given by the `SHORT` table, not
by the upper-case letters of a mixed-case name. Several program units share a line,
separated by ';'; a unit whose header does not start with ':' continues from the
previous unit's subsystem (`:D:P 1,0.0;P 2,90.0`). Axes are numbered 1, 2, 3 (outer,
middle, inner) on the wire and 0, 1, 2 in the typed messages.
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass

from drivers.errors import QUOTE_LIMIT, DeviceProtocolError, TurntableCommandError, TurntableProtocolError, quote_bytes
from drivers.turntable.base import AxisMode, AxisState, AxisStatus, TableState
from drivers.turntable.program import split_program_units

# -- keywords and commands -------------------------------------------------------------

SHORT = {  # long form -> short form; the same keyword has the same short form everywhere
    "MODE": "M", "DEMAND": "D", "LIMIT": "L", "READ": "R", "INTERLOCK": "I", "STOP": "S",
    "ABORT": "A", "SYSTEM": "SYST", "POSITION": "P", "RATE": "R", "OFF": "O", "STATUS": "S",
    "FAULT": "F", "ALL": "A", "CLOSE": "C", "OPEN": "O", "RESET": "R", "ERROR": "ERR",
}


@dataclass(frozen=True)
class CommandSpec:
    """One header: `name` is its canonical long path ('DEMAND:POSITION', 'READ:ALL?')."""

    name: str
    axis: bool            # the first argument is an axis number 1-3
    min_values: int = 0   # numeric arguments after the axis
    max_values: int = 0

    @property
    def query(self) -> bool:
        return self.name.endswith("?")

    @property
    def path(self) -> tuple[str, ...]:
        return tuple(self.name.rstrip("?").split(":"))


COMMANDS = {spec.name: spec for spec in (
    CommandSpec("MODE:POSITION", axis=True),
    CommandSpec("MODE:RATE", axis=True),
    CommandSpec("MODE:OFF", axis=True),
    CommandSpec("DEMAND:POSITION", axis=True, min_values=1, max_values=2),   # angle deg [, move rate deg/s]
    CommandSpec("DEMAND:RATE", axis=True, min_values=1, max_values=1),       # signed rate deg/s
    CommandSpec("LIMIT:RATE", axis=True, min_values=1, max_values=1),        # position-mode move rate deg/s
    CommandSpec("LIMIT:RATE?", axis=True),
    CommandSpec("READ:POSITION?", axis=True),
    CommandSpec("READ:RATE?", axis=True),
    CommandSpec("READ:MODE?", axis=True),
    CommandSpec("READ:STATUS?", axis=True),
    CommandSpec("READ:FAULT?", axis=False),
    CommandSpec("READ:ALL?", axis=False),
    CommandSpec("INTERLOCK:CLOSE", axis=True),
    CommandSpec("INTERLOCK:OPEN", axis=True),
    CommandSpec("INTERLOCK:RESET", axis=True),
    CommandSpec("STOP", axis=False),
    CommandSpec("ABORT", axis=False),
    CommandSpec("SYSTEM:ERROR?", axis=False),
    CommandSpec("*IDN?", axis=False),
    CommandSpec("*CLS", axis=False),
)}

# Children of each node of the header tree (the root is ()).
_TREE: dict[tuple[str, ...], set[str]] = {}
for _spec in COMMANDS.values():
    if not _spec.name.startswith("*"):
        for _depth, _word in enumerate(_spec.path):
            _TREE.setdefault(_spec.path[:_depth], set()).add(_word)

# -- error numbers ---------------------------------------------------------------------

NO_ERROR = 0
SYNTAX_ERROR = -102
DATA_TYPE_ERROR = -104
PARAMETER_NOT_ALLOWED = -108
MISSING_PARAMETER = -109
UNDEFINED_HEADER = -113
EXECUTION_ERROR = -200
SETTINGS_CONFLICT = -221
DATA_OUT_OF_RANGE = -222
ILLEGAL_PARAMETER_VALUE = -224
QUEUE_OVERFLOW = -350
INTERLOCK_OPEN = 201
FAULT_LATCHED = 202

ERROR_TEXT = {
    NO_ERROR: "No error", SYNTAX_ERROR: "Syntax error", DATA_TYPE_ERROR: "Data type error",
    PARAMETER_NOT_ALLOWED: "Parameter not allowed", MISSING_PARAMETER: "Missing parameter",
    UNDEFINED_HEADER: "Undefined header", EXECUTION_ERROR: "Execution error",
    SETTINGS_CONFLICT: "Settings conflict", DATA_OUT_OF_RANGE: "Data out of range",
    ILLEGAL_PARAMETER_VALUE: "Illegal parameter value", QUEUE_OVERFLOW: "Queue overflow",
    INTERLOCK_OPEN: "Interlock open", FAULT_LATCHED: "Fault latched",
}

# -- status word and mode codes --------------------------------------------------------

STATUS_BITS = (  # (bit value on the wire, AxisStatus flag); bits 3 and 7-15 are reserved
    (0x01, AxisStatus.ENABLED),      # interlock closed (servo on)
    (0x02, AxisStatus.IN_POSITION),  # position mode, within the in-position window, at rest
    (0x04, AxisStatus.MOVING),
    (0x10, AxisStatus.FAULT),        # servo/amplifier fault latched
    (0x20, AxisStatus.LIMIT),        # travel/rate limit tripped
    (0x40, AxisStatus.ESTOP),        # emergency stop active
)
STATUS_WORD_MAX = 0xFFFF

MODE_CODES = {AxisMode.OFF: 0, AxisMode.POSITION: 1, AxisMode.RATE: 2}
_MODE_BY_CODE = {code: mode for mode, code in MODE_CODES.items()}


@functools.lru_cache(maxsize=256)
def status_word(status: AxisStatus) -> int:
    """AxisStatus -> the dialect's status word (remembered: every state poll asks for the same few)."""
    return sum(bit for bit, flag in STATUS_BITS if status & flag)


@functools.lru_cache(maxsize=256)
def status_from_word(word: int) -> AxisStatus:
    """The dialect's status word -> AxisStatus (reserved bits ignored; remembered like `status_word`)."""
    if not 0 <= word <= STATUS_WORD_MAX:
        raise TurntableProtocolError(f"status word {word} outside 0..{STATUS_WORD_MAX}")
    status = AxisStatus(0)
    for bit, flag in STATUS_BITS:
        if word & bit:
            status |= flag
    return status


# -- numbers ---------------------------------------------------------------------------

_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_INTEGER = re.compile(r"[+-]?\d+")


def format_number(value: float, decimals: int = 6) -> str:
    """Plain decimal with `decimals` places (1e-6 deg by default), trailing zeros trimmed: 90.0, -12.345679."""
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"cannot send a non-finite number ({value})")
    text = f"{value:.{decimals}f}".rstrip("0")
    text = text + "0" if text.endswith(".") else text
    return "0.0" if text == "-0.0" else text


def _number(field: str, what: str, raw: bytes | None = None) -> float:
    text = field.strip()
    if not _NUMBER.fullmatch(text):
        raise TurntableProtocolError(f"{what}: {quote_bytes(text)} is not a decimal number", raw)
    value = float(text)
    if not math.isfinite(value):
        raise TurntableProtocolError(f"{what}: {quote_bytes(text)} is out of range", raw)
    return value


def _integer(field: str, what: str, raw: bytes | None = None) -> int:
    text = field.strip()
    if not _INTEGER.fullmatch(text) or len(text) > 12:
        raise TurntableProtocolError(f"{what}: {quote_bytes(text)} is not an integer", raw)
    return int(text)


# -- client side: requests -------------------------------------------------------------

ERROR_QUERY = b":SYST:ERR?"


def header(name: str, long_form: bool = False) -> str:
    """The wire header of a command name: 'DEMAND:POSITION' -> ':D:P' (or ':DEMAND:POSITION')."""
    spec = COMMANDS[name]
    if name.startswith("*"):
        return name
    words = spec.path if long_form else tuple(SHORT[w] for w in spec.path)
    return ":" + ":".join(words) + ("?" if spec.query else "")


def encode(name: str, frame: int | None = None, *values: float, long_form: bool = False) -> bytes:
    """One program unit: encode('DEMAND:POSITION', 0, 90.0) -> b':D:P 1,90.0' (no terminator)."""
    spec = COMMANDS.get(name)
    if spec is None:
        raise ValueError(f"unknown SCPI command {name!r}")
    if spec.axis != (frame is not None) or not spec.min_values <= len(values) <= spec.max_values:
        raise ValueError(f"{name} takes {'an axis and ' if spec.axis else ''}"
                         f"{spec.min_values}-{spec.max_values} values, got {frame!r}, {values!r}")
    if frame is not None and (isinstance(frame, bool) or frame not in (0, 1, 2)):
        raise ValueError(f"frame must be 0-2, got {frame!r}")
    args = ([str(frame + 1)] if frame is not None else []) + [format_number(v) for v in values]
    return (header(name, long_form) + (" " + ",".join(args) if args else "")).encode("ascii")


def confirmed(*units: bytes, long_form: bool = False) -> bytes:
    """Commands joined on one line with the error query appended, so one reply confirms them all."""
    return b";".join(units + (encode("SYSTEM:ERROR?", long_form=long_form),))


# -- client side: replies --------------------------------------------------------------

_NOT_PRINTABLE = re.compile(rb"[^\x20-\x7e]")


def split_fields(line: bytes) -> list[str]:
    """A reply line -> its comma-separated fields (quoted strings kept quoted); malformed -> TurntableProtocolError."""
    bad = _NOT_PRINTABLE.search(line)
    if bad is not None:
        raise TurntableProtocolError(f"reply byte 0x{line[bad.start()]:02X} at {bad.start()} is not printable ASCII",
                                     line)
    text = line.decode("ascii").strip()
    if not text:
        raise TurntableProtocolError("empty reply", line)
    # up to the first quote the fields are plain: split at once (a reply is mostly numbers), the rest char by char
    i = text.find('"')
    i = len(text) if i < 0 else i
    if ";" in text[:i]:
        raise TurntableProtocolError("several responses where one was expected", line)
    *fields, last = text[:i].split(",")
    fields, current, quoted = [f.strip() for f in fields], [last], False
    while i < len(text):
        char = text[i]
        if quoted:
            if char == '"' and text[i + 1:i + 2] == '"':
                current.append('""')
                i += 1
            elif char == '"':
                quoted = False
                current.append(char)
            else:
                current.append(char)
        elif char == '"':
            quoted = True
            current.append(char)
        elif char == ",":
            fields.append("".join(current).strip())
            current = []
        elif char == ";":
            raise TurntableProtocolError("several responses where one was expected", line)
        else:
            current.append(char)
        i += 1
    if quoted:
        raise TurntableProtocolError("unterminated string in reply", line)
    fields.append("".join(current).strip())
    return fields


def _unquote(field: str, what: str, raw: bytes) -> str:
    if len(field) < 2 or field[0] != '"' or field[-1] != '"' or '"' in field[1:-1].replace('""', ""):
        raise TurntableProtocolError(f"{what}: expected a quoted string, got {quote_bytes(field)}", raw)
    return field[1:-1].replace('""', '"')


def _is_error_entry(fields: list[str]) -> bool:
    return (len(fields) == 2 and bool(_INTEGER.fullmatch(fields[0])) and len(fields[1]) >= 2
            and fields[1][0] == fields[1][-1] == '"')


def decode_error(line: bytes) -> tuple[int, str]:
    """An error-queue entry `-222,"Data out of range"` -> (-222, 'Data out of range')."""
    fields = split_fields(line)
    if len(fields) != 2:
        raise TurntableProtocolError(f"error entry: expected <code>,\"<text>\", got {len(fields)} fields", line)
    return _integer(fields[0], "error code", line), _unquote(fields[1], "error text", line)


def error_text(text: str) -> str:
    """A controller's error text as a message shows it: as sent up to QUOTE_LIMIT characters, else cut (quote_bytes)."""
    return text if len(text) <= QUOTE_LIMIT else quote_bytes(text)


def raise_for_error(code: int, text: str) -> None:
    """A non-zero error entry -> TurntableCommandError(code)."""
    if code != NO_ERROR:
        raise TurntableCommandError(f"SCPI controller error {code}: {error_text(text)}", code)


def decode_confirmation(line: bytes) -> None:
    """The reply to `<commands>;:SYST:ERR?`: `0,"No error"` -> None; an error -> TurntableCommandError."""
    raise_for_error(*decode_error(line))


def _query_fields(line: bytes, count: int, what: str) -> list[str]:
    """Fields of a query reply; the error entry a controller sends instead -> TurntableCommandError."""
    fields = split_fields(line)
    if count != 2 and _is_error_entry(fields):
        raise_for_error(*decode_error(line))
    if len(fields) != count:
        raise TurntableProtocolError(f"{what}: expected {count} field(s), got {len(fields)}", line)
    return fields


def decode_number(line: bytes, what: str = "number") -> float:
    """The reply to `:R:P? n`, `:R:R? n`, `:L:R? n`: one decimal number."""
    return _number(_query_fields(line, 1, what)[0], what, line)


def _mode(field: str, raw: bytes) -> AxisMode:
    code = _integer(field, "mode", raw)
    if code not in _MODE_BY_CODE:
        raise TurntableProtocolError(f"mode code {code} is not 0 (off), 1 (position) or 2 (rate)", raw)
    return _MODE_BY_CODE[code]


def _status(field: str, raw: bytes) -> AxisStatus:
    word = _integer(field, "status word", raw)
    try:
        return status_from_word(word)
    except DeviceProtocolError as exc:
        raise TurntableProtocolError(str(exc), raw) from exc


def decode_mode(line: bytes) -> AxisMode:
    """The reply to `:R:M? n`: 0 off, 1 position, 2 rate."""
    return _mode(_query_fields(line, 1, "mode")[0], line)


def decode_status(line: bytes) -> AxisStatus:
    """The reply to `:R:S? n`: the status word in decimal."""
    return _status(_query_fields(line, 1, "status")[0], line)


def decode_string(line: bytes) -> str:
    """The reply to `:R:F?`: one quoted string."""
    return _unquote(_query_fields(line, 1, "string")[0], "string", line)


def decode_idn(line: bytes) -> str:
    """The reply to `*IDN?`: four fields, maker,model,serial,firmware (returned as the whole line)."""
    fields = _query_fields(line, 4, "*IDN?")
    return ",".join(fields)


STATE_FIELDS = 13


def decode_state(line: bytes, time_s: float) -> TableState:
    """The reply to `:R:A?`: position, rate, mode, status of axes 1, 2, 3, then the fault text."""
    fields = _query_fields(line, STATE_FIELDS, "state (:R:A?)")
    axes = []
    for k in range(3):
        angle, rate, mode, status = fields[4 * k:4 * k + 4]
        axes.append(AxisState(_number(angle, f"axis {k + 1} position", line), _number(rate, f"axis {k + 1} rate", line),
                              _mode(mode, line), _status(status, line)))
    return TableState(time_s, (axes[0], axes[1], axes[2]), _unquote(fields[12], "fault text", line))


# -- server side: requests -------------------------------------------------------------

@dataclass(frozen=True)
class ScpiRequest:
    """One parsed program unit. `frame` is 0-2 (None when the command takes no axis)."""

    name: str
    frame: int | None = None
    values: tuple[float, ...] = ()

    @property
    def query(self) -> bool:
        return self.name.endswith("?")


class ScpiRequestError(TurntableProtocolError):
    """A program unit the controller cannot parse; `code` is the SCPI error number, `query`
    whether the unit was a query (then its error entry stands in for its response)."""

    def __init__(self, message: str, code: int, query: bool, raw: bytes | None = None):
        super().__init__(message, raw)
        self.code, self.query = code, query


_HEADER = re.compile(r"\s*(\*[A-Za-z]+\??|:?[A-Za-z]+(?::[A-Za-z]+)*\??)(?:\s+(.*?))?\s*", re.S)


def _resolve(words: list[str], start: tuple[str, ...]) -> tuple[str, ...] | None:
    path = start
    for word in words:
        upper = word.upper()
        match = [c for c in _TREE.get(path, ()) if upper in (c, SHORT[c])]
        if not match:
            return None
        path = path + (match[0],)
    return path


def parse_request(unit: str, path: tuple[str, ...] = ()) -> tuple[ScpiRequest, tuple[str, ...]]:
    """One program unit -> (request, the path the next unit continues from).

    `path` is the current subsystem ((), the root, at the start of a line). Anything
    wrong raises ScpiRequestError with the SCPI error number.
    """
    looks_query = "?" in unit.split(None, 1)[0] if unit.strip() else False
    bad = [c for c in unit if not " " <= c <= "~" and c != "\t"]
    if bad:
        raise ScpiRequestError(f"character {bad[0]!r} not allowed", SYNTAX_ERROR, looks_query)
    match = _HEADER.fullmatch(unit)
    if not match:
        raise ScpiRequestError(f"cannot parse {quote_bytes(unit.strip())}", SYNTAX_ERROR, looks_query)
    head, args = match.group(1), match.group(2)
    query = head.endswith("?")
    if head.startswith("*"):
        name, next_path = head.upper(), path
    else:
        words = head.rstrip("?").split(":")
        absolute = words[0] == ""
        resolved = _resolve(words[1:] if absolute else words, () if absolute else path)
        if resolved is None:
            raise ScpiRequestError(f"undefined header {quote_bytes(head)}", UNDEFINED_HEADER, query)
        name, next_path = ":".join(resolved) + ("?" if query else ""), resolved[:-1]
    spec = COMMANDS.get(name)
    if spec is None:
        raise ScpiRequestError(f"undefined header {quote_bytes(head)}", UNDEFINED_HEADER, query)
    fields = [] if args is None or args == "" else [f.strip() for f in args.split(",")]
    wanted_min = int(spec.axis) + spec.min_values
    wanted_max = int(spec.axis) + spec.max_values
    if len(fields) < wanted_min:
        raise ScpiRequestError(f"{name} needs {wanted_min} parameter(s)", MISSING_PARAMETER, query)
    if len(fields) > wanted_max:
        raise ScpiRequestError(f"{name} takes at most {wanted_max} parameter(s)", PARAMETER_NOT_ALLOWED, query)
    frame = None
    if spec.axis:
        axis_text = fields.pop(0)
        if not _INTEGER.fullmatch(axis_text) or len(axis_text) > 12:
            raise ScpiRequestError(f"axis {quote_bytes(axis_text)} is not an integer", DATA_TYPE_ERROR, query)
        if not 1 <= int(axis_text) <= 3:
            raise ScpiRequestError(f"axis {axis_text} is not 1, 2 or 3", DATA_OUT_OF_RANGE, query)
        frame = int(axis_text) - 1
    values = []
    for field in fields:
        if not _NUMBER.fullmatch(field):
            raise ScpiRequestError(f"{quote_bytes(field)} is not a number", DATA_TYPE_ERROR, query)
        value = float(field)
        if not math.isfinite(value):
            raise ScpiRequestError(f"{quote_bytes(field)} is out of range", DATA_OUT_OF_RANGE, query)
        values.append(value)
    return ScpiRequest(name, frame, tuple(values)), next_path


def split_units(line: bytes) -> list[str]:
    """A request line -> its program units (split at ';' outside quoted strings; empty units dropped)."""
    units, _ = split_program_units(line.decode("latin-1"))
    return [u for u in units if u.strip()]


def parse_program(line: bytes) -> list[ScpiRequest | ScpiRequestError]:
    """A whole request line -> one parsed request or one error per unit, in order (never raises)."""
    out: list[ScpiRequest | ScpiRequestError] = []
    path: tuple[str, ...] = ()
    for unit in split_units(line):
        try:
            request, path = parse_request(unit, path)
        except ScpiRequestError as exc:
            out.append(exc)
            continue
        out.append(request)
    return out


# -- server side: replies --------------------------------------------------------------

def format_string(text: str) -> str:
    """A quoted string response; quotes doubled, anything outside printable ASCII replaced by '?'."""
    clean = "".join(c if " " <= c <= "~" else "?" for c in text)
    return '"' + clean.replace('"', '""') + '"'


def format_error(code: int, detail: str = "") -> str:
    """An error-queue entry: -222,"Data out of range;outer position 400.0 outside travel"."""
    text = ERROR_TEXT.get(code, "Device-specific error")
    return f"{code},{format_string(text + (';' + detail if detail else ''))}"


def format_axis(axis: AxisState) -> str:
    return (f"{format_number(axis.angle_deg)},{format_number(axis.rate_dps)},"
            f"{MODE_CODES[axis.mode]},{status_word(axis.status)}")


def format_state(state: TableState) -> str:
    """The response to `:R:A?`."""
    return ",".join(format_axis(a) for a in state.axes) + "," + format_string(state.fault_text)


def format_reply(responses: list[str]) -> bytes:
    """The responses of one line's queries, ';'-separated, CR LF terminated."""
    return (";".join(responses) + "\r\n").encode("ascii")
