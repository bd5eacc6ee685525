"""Pure codec of the ACUTROL3000 Command Language (ACL, Acutronic TM-8004); docs/hardware/acutrol.md is its page.

Both ways, no I/O. The controller side parses a program message into units (`parse_message`)
and formats responses (`frame_response`, `format_number`); the client side encodes units
(`unit`) and decodes responses (`frame_size`, `parse_framed`, `split_responses`, `decode_*`).

Syntax (TM-8004 ch. 2): a unit is a header of colon-separated mnemonics, optionally a `?`,
then white space and comma-separated arguments. A header that starts with `:` starts at the
root; one without continues in the subsystem of the unit before it (`:Mode:Position 1;Rate 2`),
and the first unit of a message starts at the root whatever it begins with. Mnemonics match
case-insensitively as their long form, any unique leading part of it (`Dem`, `Pos`, `Delta`),
the one-letter forms the manual prints where a letter is shared (`:I:C` is Interlock:Close,
`:L:A` Limit:Acceleration) and the manual's own abbreviations (`HPOS`, `LPOS`, `VTR`).

Responses on the TCP port and through an RS-232 device server are framed (TM-8004 ch. 2,
TM-9374A 3.4.2): every program message gets one response, a 32-bit error code and a 32-bit
text length, least significant byte first (TM-8004 2.4), then the text and a NUL. Several
query responses in one message are joined by `;`.
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass

from drivers.errors import TurntableProtocolError, quote_bytes
from drivers.turntable.base import AxisMode
from drivers.turntable.program import split_program_units

# -- error codes (the manual lists none: its error table is "TBD"; these numbers are ours) ---------------------

NO_ERROR = 0
NOT_RECOGNIZED = 1       # a mnemonic that is not in the tree, or not under the current subsystem
SYNTAX_ERROR = 2         # misplaced ';' or ':', comma after the header, white space in a header, bad character
OUT_OF_RANGE = 3         # the manual's "PARAMETER OUT OF RANGE": bad axis, mode, register or value
PARAMETER_COUNT = 4      # too few or too many arguments
INVALID_NUMBER = 5       # an argument that is not <NRf> (binary #-blocks included: not supported)
NOT_AVAILABLE = 6        # a command of the language this controller does not offer (factory limits, synthesis ...)
INTERLOCK_FAULT = 7      # a latched interlock fault refuses Interlock:Close until Interlock:Reset
NOT_SERVOED = 8          # the manual's "Servo Not Enabled" (A(n)ERR bit 2)
ERROR_TEXT = {
    NO_ERROR: "No error", NOT_RECOGNIZED: "Command not recognized", SYNTAX_ERROR: "Syntax error",
    OUT_OF_RANGE: "Parameter out of range", PARAMETER_COUNT: "Wrong number of parameters",
    INVALID_NUMBER: "Invalid numeric data", NOT_AVAILABLE: "Command not available",
    INTERLOCK_FAULT: "Interlock fault latched", NOT_SERVOED: "Servo not enabled",
}

MAX_MESSAGE = 32768      # TM-8004 2.5: characters in one message, either way
HEADER = struct.Struct("<iI")

# -- the command tree --------------------------------------------------------------------------------------------

#: children of each node by long name; every real root subsystem is listed so that a prefix is unique only
#: when it is unique on the controller (the ones the bench does not use answer NOT_AVAILABLE)
TREE: dict[tuple[str, ...], tuple[str, ...]] = {
    (): ("ACQUIRE", "CONFIGURE", "DEMAND", "INTERFACE", "INTERLOCK", "LIMIT", "MODE", "PLAYBACK", "QUERY", "READ",
         "STATUS", "SYSTEM", "UTILITY"),
    ("DEMAND",): ("ACCELERATION", "DELTAPOSITION", "INPUTVARIABLE", "OSCILLATOR", "POSITION", "RATE",
                  "SHORTVECTOR", "VECTOR", "WORLDCOORDS"),
    ("INTERLOCK",): ("CLOSE", "CONFIGURE", "CONTROL", "LOGIC", "OPEN", "RESET"),
    ("LIMIT",): ("ABSOLUTE", "ACCELERATION", "BEMF", "GLOBAL", "HIGHPOSITION", "LOWPOSITION", "RATE",
                 "VELOCITYTRIP"),
    ("MODE",): ("ARATE", "HOME", "OFF", "POSITION", "RATE", "SYNTHESIS", "TRACK"),
    ("QUERY",): ("ERROR", "SYSTEM", "VARNUM"),
    ("READ",): ("ACCELERATION", "LOGDATA", "POSITION", "RATE", "SHORTVECTOR", "VARIABLE", "VECTOR", "WORLDCOORDS"),
    ("STATUS",): ("CSR", "ECP", "ESE", "ESR", "MIS", "MSG", "MSGCLR", "STB", "SUPERVISOR", "TFR"),
}
#: one-letter and other forms the manual prints that a unique-prefix rule would not give (or would give otherwise)
ALIASES: dict[tuple[str, ...], dict[str, str]] = {
    (): {"D": "DEMAND", "I": "INTERLOCK", "INT": "INTERLOCK", "L": "LIMIT", "M": "MODE", "R": "READ", "Q": "QUERY",
         "STAT": "STATUS", "SYST": "SYSTEM"},
    ("DEMAND",): {"A": "ACCELERATION", "D": "DELTAPOSITION", "P": "POSITION", "R": "RATE"},
    ("INTERLOCK",): {"C": "CLOSE", "O": "OPEN", "R": "RESET"},
    ("LIMIT",): {"A": "ACCELERATION", "H": "HIGHPOSITION", "L": "LOWPOSITION", "R": "RATE", "V": "VELOCITYTRIP",
                 "HPOS": "HIGHPOSITION", "LPOS": "LOWPOSITION", "VTR": "VELOCITYTRIP", "VTRIP": "VELOCITYTRIP",
                 "ABS": "ABSOLUTE"},
    ("MODE",): {"A": "ARATE", "O": "OFF", "P": "POSITION", "R": "RATE", "S": "SYNTHESIS", "T": "TRACK"},
    ("READ",): {"A": "ACCELERATION", "P": "POSITION", "R": "RATE"},
}
#: modes of the Mode command and the <mode> argument of the Limit commands; one letter each (TM-8004 4.6)
MODE_NAMES = ("Position", "Rate", "Arate", "Synthesis", "Track", "Abort", "Off")
MODE_LETTERS = {"A": "Abort", "O": "Off", "P": "Position", "R": "Rate", "S": "Synthesis", "T": "Track"}
AXIS_MODE = {"Position": AxisMode.POSITION, "Rate": AxisMode.RATE, "Off": AxisMode.OFF}
INTERLOCK_STATES = ("Close", "Open", "Fault")

# argument kinds: "axis" (1-3), "axes" (1-3 or ALL), "mode" (a MODE_NAMES member), "nrf" (a number), "code" (NR1 >= 0),
# "name" (a register or queue mnemonic), "count" (NR1 or ALL)


@dataclass(frozen=True)
class Spec:
    """What one header accepts: argument kinds of its command and of its query (None: no such form);
    `optional` kinds may be left off the end; `query_mark_optional`: reads answer with or without `?`."""

    command: tuple[str, ...] | None = None
    query: tuple[str, ...] | None = None
    optional: int = 0
    query_mark_optional: bool = False


SPECS: dict[tuple[str, ...], Spec] = {
    ("DEMAND", "POSITION"): Spec(("axis", "nrf"), ("axis",)),
    ("DEMAND", "RATE"): Spec(("axis", "nrf"), ("axis",)),
    ("DEMAND", "DELTAPOSITION"): Spec(("axis", "nrf"), ("axis",)),
    ("INTERLOCK",): Spec(None, ("axis",)),
    ("INTERLOCK", "CLOSE"): Spec(("axes",)),
    ("INTERLOCK", "OPEN"): Spec(("axes",)),
    ("INTERLOCK", "RESET"): Spec(()),
    ("INTERLOCK", "CONTROL"): Spec(None, ("axis",)),
    ("LIMIT", "ABSOLUTE"): Spec(None, ("axis",)),
    ("LIMIT", "RATE"): Spec(("mode", "axis", "nrf"), ("mode", "axis")),
    ("LIMIT", "ACCELERATION"): Spec(("mode", "axis", "nrf"), ("mode", "axis")),
    ("LIMIT", "HIGHPOSITION"): Spec(("mode", "axis", "nrf"), ("mode", "axis")),
    ("LIMIT", "LOWPOSITION"): Spec(("mode", "axis", "nrf"), ("mode", "axis")),
    ("MODE",): Spec(("axes", "mode"), ("axis",)),
    ("MODE", "POSITION"): Spec(("axes",)),
    ("MODE", "RATE"): Spec(("axes",)),
    ("MODE", "OFF"): Spec(("axes",)),
    ("QUERY", "ERROR"): Spec(None, ("code",)),
    ("QUERY", "SYSTEM"): Spec(None, ()),
    ("READ", "POSITION"): Spec(None, ("axis",), query_mark_optional=True),
    ("READ", "RATE"): Spec(None, ("axis",), query_mark_optional=True),
    ("READ", "ACCELERATION"): Spec(None, ("axis",), query_mark_optional=True),
    ("STATUS", "STB"): Spec(None, ()),
    ("STATUS", "CSR"): Spec(None, ("name", "code"), optional=1),
    ("STATUS", "MSG"): Spec(None, ("name", "count"), optional=1),
    ("STATUS", "MSGCLR"): Spec(("name",)),
    ("*IDN",): Spec(None, ()),
    ("*STB",): Spec(None, ()),
    ("*CLS",): Spec(()),
}

# -- parsing a program message (controller side) -----------------------------------------------------------------


class AclError(Exception):
    """A unit the controller refuses: `code` is the error number, `unit` the text of the unit at fault."""

    def __init__(self, code: int, detail: str, unit: str = ""):
        super().__init__(f"{ERROR_TEXT[code]}: {detail}")
        self.code, self.detail, self.unit = code, detail, unit


@dataclass(frozen=True)
class Unit:
    """One parsed program unit: `path` of long names ('DEMAND', 'POSITION'), `query`, and the checked arguments
    (axis numbers 1-3 or 'ALL', mode names from MODE_NAMES, floats, ints, upper-case names)."""

    path: tuple[str, ...]
    query: bool
    args: tuple[object, ...] = ()

    @property
    def name(self) -> str:
        return ":".join(self.path) + ("?" if self.query else "")


_NRF = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:\s*[eE]\s*[+-]?\s*\d+)?")
_DIGITS = re.compile(r"\d{1,9}")
_MNEMONIC = re.compile(r"[A-Za-z][A-Za-z0-9]*")
_HEADER_CHARS = re.compile(r"[A-Za-z0-9:*?]+")


def resolve(node: tuple[str, ...], word: str) -> str | None:
    """The long name `word` stands for under `node`, or None: the whole name, the manual's forms, else a
    leading part that fits exactly one child."""
    upper = word.upper()
    children = TREE.get(node, ())
    if upper in children:
        return upper
    alias = ALIASES.get(node, {}).get(upper)
    if alias is not None:
        return alias
    fits = [child for child in children if child.startswith(upper)]
    return fits[0] if len(fits) == 1 else None


def resolve_mode(text: str) -> str | None:
    """A <mode> argument -> its MODE_NAMES member: the manual's letter, or a leading part fitting one name."""
    word = text.strip()
    if word.upper() in MODE_LETTERS:
        return MODE_LETTERS[word.upper()]
    fits = [name for name in MODE_NAMES if name.upper().startswith(word.upper())] if word else []
    return fits[0] if len(fits) == 1 else None


def _split_units(message: str) -> list[str]:
    units, unterminated = split_program_units(message)
    if unterminated:
        raise AclError(SYNTAX_ERROR, "unterminated string", message)
    return units


def _argument(kind: str, text: str, unit: str) -> object:
    field = text.strip()
    if kind in ("axis", "axes"):
        if kind == "axes" and field.upper() == "ALL":
            return "ALL"
        if field.upper() == "ALL":
            raise AclError(OUT_OF_RANGE, "ALL is for commands, a query names one axis", unit)
        if not _DIGITS.fullmatch(field):
            raise AclError(OUT_OF_RANGE, f"axis {quote_bytes(field)} is not an axis number", unit)
        if not 1 <= int(field) <= 3:
            raise AclError(OUT_OF_RANGE, f"no axis {int(field)} (axes 1-3)", unit)
        return int(field)
    if kind == "mode":
        mode = resolve_mode(field)
        if mode is None:
            raise AclError(OUT_OF_RANGE, f"{quote_bytes(field)} is not a mode ({', '.join(MODE_NAMES)})", unit)
        return mode
    if kind == "nrf":
        if field.startswith("#"):
            raise AclError(INVALID_NUMBER, "binary block data is not supported", unit)
        if not _NRF.fullmatch(field):
            raise AclError(INVALID_NUMBER, f"{quote_bytes(field)} is not a decimal number", unit)
        value = float(re.sub(r"\s+", "", field))
        if not math.isfinite(value):
            raise AclError(INVALID_NUMBER, f"{quote_bytes(field)} is out of range", unit)
        return value
    if kind == "code":
        if not re.fullmatch(r"[+-]?\d{1,9}", field):
            raise AclError(INVALID_NUMBER, f"{quote_bytes(field)} is not an integer", unit)
        return int(field)
    if kind == "count":
        if field.upper() == "ALL":
            return "ALL"
        if not _DIGITS.fullmatch(field):
            raise AclError(INVALID_NUMBER, f"{quote_bytes(field)} is not a count", unit)
        return int(field)
    if not _MNEMONIC.fullmatch(field):                       # "name"
        raise AclError(OUT_OF_RANGE, f"{quote_bytes(field)} is not a register or queue name", unit)
    return field.upper()


def parse_unit(text: str, node: tuple[str, ...], first: bool) -> tuple[Unit, tuple[str, ...]]:
    """One unit -> (the unit, the subsystem the next unit continues in). `node` is the current subsystem,
    `first` whether the unit opens the message (then it starts at the root). AclError when refused."""
    stripped = text.strip()
    if not stripped:
        raise AclError(SYNTAX_ERROR, "empty command between ';'", text)
    head, _, rest = stripped.partition(" ")
    head, rest = head.strip(), rest.strip()
    if "\t" in head:
        head, _, tail = head.partition("\t")
        rest = (tail + " " + rest).strip()
    if "," in head:
        raise AclError(SYNTAX_ERROR, "a comma between the command and its data", text)
    if not _HEADER_CHARS.fullmatch(head):
        raise AclError(SYNTAX_ERROR, f"character not allowed in {quote_bytes(head)}", text)
    query = head.endswith("?")
    words_text = head[:-1] if query else head
    if "?" in words_text:
        raise AclError(SYNTAX_ERROR, f"'?' inside the header {quote_bytes(head)}", text)
    if words_text.startswith("*"):
        path: tuple[str, ...] = (words_text.upper(),)
        next_node = node
    else:
        absolute = words_text.startswith(":")
        words = (words_text[1:] if absolute else words_text).split(":")
        if any(not w for w in words):
            raise AclError(SYNTAX_ERROR, f"empty mnemonic in {quote_bytes(head)}", text)
        start = () if absolute or first else node
        path = start
        for word in words:
            if not _MNEMONIC.fullmatch(word):
                raise AclError(NOT_RECOGNIZED, f"{quote_bytes(word)} is not a mnemonic", text)
            child = resolve(path, word)
            if child is None:
                where = ":".join(path) or "the root"
                raise AclError(NOT_RECOGNIZED, f"{quote_bytes(word)} is not a command under {where}", text)
            path = path + (child,)
        next_node = path[:-1]       # the last colon before the last mnemonic (TM-8004 2.3)
    spec = SPECS.get(path)
    if spec is None:
        if path in TREE and not query:
            raise AclError(SYNTAX_ERROR, f"{':'.join(path)} is a subsystem, not a command (misplaced ';'?)", text)
        raise AclError(NOT_AVAILABLE, f"{':'.join(path) + ('?' if query else '')} is not offered", text)
    kinds = spec.query if query else spec.command
    if kinds is None and not query and spec.query_mark_optional:
        query, kinds = True, spec.query
    if kinds is None:
        form = "query" if query else "command"
        raise AclError(NOT_AVAILABLE, f"{':'.join(path)} has no {form} form", text)
    fields = rest.split(",") if rest else []
    if not len(kinds) - spec.optional <= len(fields) <= len(kinds):
        raise AclError(PARAMETER_COUNT, f"{':'.join(path)}{'?' if query else ''} takes {len(kinds)} "
                                        f"argument(s), got {len(fields)}", text)
    args = tuple(_argument(kind, field, text) for kind, field in zip(kinds, fields))
    return Unit(path, query, args), next_node


def strip_terminator(message: bytes) -> bytes:
    """A program message without its <END>: the manual allows a CR, a LF or both after the last byte."""
    for end in (b"\r\n", b"\n", b"\r"):
        if message.endswith(end):
            return message[:-len(end)]
    return message


def parse_message(message: bytes) -> tuple[list[Unit], AclError | None]:
    """A program message -> the units before the first refused one, and that refusal (None when all parse).
    The controller executes nothing after a refused unit."""
    body = strip_terminator(message)
    if len(body) > MAX_MESSAGE:
        return [], AclError(SYNTAX_ERROR, f"message of {len(body)} characters (at most {MAX_MESSAGE})")
    if any(not 0x20 <= b <= 0x7E and b != 0x09 for b in body):
        return [], AclError(SYNTAX_ERROR, "a character outside printable ASCII", quote_bytes(body))
    text = body.decode("ascii")
    units: list[Unit] = []
    try:
        node: tuple[str, ...] = ()
        parts = _split_units(text)
        if len(parts) > 1 and not parts[-1].strip():
            parts.pop()          # a ';' before <END> (the manual's own examples end so)
        for k, part in enumerate(parts):
            parsed, node = parse_unit(part, node, first=k == 0)
            units.append(parsed)
    except AclError as exc:
        return units, exc
    return units, None


# -- numbers ----------------------------------------------------------------------------------------------------

def format_number(value: float, decimals: int = 6) -> str:
    """<NR2>: a sign only when negative, digits, a decimal point, `decimals` digits; never an exponent."""
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"cannot send a non-finite number ({value})")
    text = f"{value:.{decimals}f}"
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def decode_number(field: str, what: str, raw: bytes | None = None) -> float:
    """A numeric response (<NR1>, <NR2> or <NR3>) -> float; anything else -> TurntableProtocolError."""
    text = field.strip()
    if not _NRF.fullmatch(text) or " " in text:
        raise TurntableProtocolError(f"{what}: {quote_bytes(text)} is not a number", raw)
    return float(text)


# -- framing ----------------------------------------------------------------------------------------------------

def frame_response(code: int, text: str = "") -> bytes:
    """A framed response: error code, text length, the text, NUL."""
    body = text.encode("ascii", "replace")
    return HEADER.pack(code, len(body)) + body + b"\0"


@dataclass(frozen=True)
class Response:
    """A controller's framed response: its error code and its text (the query responses, or the error text)."""

    code: int
    text: str


def frame_size(head: bytes) -> int | None:
    """The whole frame's size in bytes from its first 8 (None: not a plausible header, the bytes are garbage)."""
    code, length = HEADER.unpack(head[:HEADER.size])
    if length > MAX_MESSAGE or not -(1 << 24) < code < 1 << 24:
        return None
    return HEADER.size + length + 1


def parse_framed(frame: bytes) -> Response:
    """A whole framed response -> Response; a frame that breaks the rules -> TurntableProtocolError.

    The length is taken as the text's; a controller counting the NUL as well is accepted (the frame then
    ends in the NUL the length covers)."""
    if len(frame) < HEADER.size + 1:
        raise TurntableProtocolError(f"response of {len(frame)} bytes is shorter than a frame", frame)
    code, length = HEADER.unpack(frame[:HEADER.size])
    body = frame[HEADER.size:]
    if len(body) == length and length and body[-1:] == b"\0":       # the length counted the NUL
        text_bytes = body[:-1]
    elif len(body) == length + 1 and body[-1:] == b"\0":
        text_bytes = body[:-1]
    else:
        raise TurntableProtocolError(f"response frame says {length} text bytes but carries {len(body)} bytes "
                                     "or lacks its closing NUL", frame)
    if any(not 0x20 <= b <= 0x7E and b not in (0x09, 0x0A, 0x0D) for b in text_bytes):
        raise TurntableProtocolError("response text is not printable ASCII", frame)
    return Response(code, text_bytes.decode("ascii").rstrip("\r\n"))


def split_responses(text: str, count: int, what: str, raw: bytes | None = None) -> list[str]:
    """The `count` query responses of one message (joined by ';') -> their texts."""
    fields = text.split(";") if text or count != 1 else [text]     # one empty response is a response
    if len(fields) != count:
        raise TurntableProtocolError(f"{what}: expected {count} response(s), got {len(fields)}", raw)
    return [f.strip() for f in fields]


# -- decoding single responses (client side) ---------------------------------------------------------------------

def decode_mode(field: str, raw: bytes | None = None) -> str:
    """A mode response: the manual prints one letter (`P`), a real client compares the word (`Position`);
    both (any case, any leading part fitting one mode) -> its MODE_NAMES member."""
    mode = resolve_mode(field) if field.strip() else None
    if mode is None or (len(field.strip()) > 1 and not mode.upper().startswith(field.strip().upper())):
        raise TurntableProtocolError(f"{quote_bytes(field)} is not a mode ({', '.join(MODE_NAMES)})", raw)
    return mode


def decode_interlock(field: str, raw: bytes | None = None) -> str:
    """An interlock state: Close, Open or Fault (one letter or the word, any case)."""
    word = field.strip().upper()
    for state in INTERLOCK_STATES:
        if word and state.upper().startswith(word):
            return state
    raise TurntableProtocolError(f"{quote_bytes(field)} is not an interlock state (Close, Open, Fault)", raw)


def decode_register(field: str, what: str, raw: bytes | None = None) -> int:
    """A status register in <NR1> (0..65535)."""
    text = field.strip()
    if not re.fullmatch(r"\+?\d{1,5}", text) or int(text) > 0xFFFF:
        raise TurntableProtocolError(f"{what}: {quote_bytes(text)} is not a 16-bit register value", raw)
    return int(text)


@dataclass(frozen=True)
class AbsoluteLimits:
    """`:Limit:Absolute? n`: the factory limits of one axis (deg, deg/s, deg/s^2, deg/s^3)."""

    rate_dps: float
    accel_dps2: float
    jerk_dps3: float
    pos_lo_deg: float
    pos_hi_deg: float
    velocity_trip_dps: float | None = None


def decode_absolute_limits(text: str, raw: bytes | None = None) -> AbsoluteLimits:
    """rate,acc,jerk,pos_lo,pos_hi[,vtrip[,tracking error trip]]: the manual lists seven fields, a real client
    prints six; five to seven are accepted."""
    fields = [f.strip() for f in text.split(",")]
    if not 5 <= len(fields) <= 7:
        raise TurntableProtocolError(f"absolute limits: expected 5-7 fields, got {len(fields)}", raw)
    values = [decode_number(f, "absolute limit", raw) for f in fields]
    rate, accel, jerk, low, high = values[:5]
    limits = AbsoluteLimits(rate, accel, jerk, low, high, values[5] if len(values) > 5 else None)
    if not (limits.rate_dps > 0 and limits.accel_dps2 > 0 and limits.pos_lo_deg < limits.pos_hi_deg):
        raise TurntableProtocolError(f"absolute limits make no sense: {quote_bytes(text)}", raw)
    return limits


# -- encoding requests (client side) -----------------------------------------------------------------------------

SHORT = {  # the 3-4 letter forms the client sends (the manual's upper-case parts)
    "DEMAND": "DEM", "POSITION": "POS", "RATE": "RATE", "DELTAPOSITION": "DEL", "INTERLOCK": "INT", "CLOSE": "CLOS",
    "OPEN": "OPEN", "RESET": "RES", "LIMIT": "LIM", "ABSOLUTE": "ABS", "ACCELERATION": "ACC", "MODE": "MODE",
    "OFF": "OFF", "READ": "READ", "STATUS": "STAT", "STB": "STB", "CSR": "CSR", "MSG": "MSG", "MSGCLR": "MSGCLR",
    "QUERY": "QUER", "ERROR": "ERR", "HIGHPOSITION": "HPOS", "LOWPOSITION": "LPOS",
}


def unit(path: str, *args: object, query: bool = False, long_form: bool = False) -> str:
    """One program unit: unit('DEMAND:POSITION', 1, 10.5) -> ':DEM:POS 1,10.500000'."""
    if path.startswith("*"):
        return path.upper() + ("?" if query else "")
    words = path.split(":")
    for k in range(len(words)):
        node = tuple(words[:k])
        if words[k] not in TREE.get(node, ()):
            raise ValueError(f"{path!r} is not in the ACL tree")
    head = ":" + ":".join(words if long_form else [SHORT[w] for w in words]) + ("?" if query else "")
    texts = [format_number(a) if isinstance(a, float) else str(a) for a in args]
    return head + (" " + ",".join(texts) if texts else "")


def message(*units: str) -> bytes:
    """Units joined into one program message (no terminator)."""
    return ";".join(units).encode("ascii")


__all__ = ["AbsoluteLimits", "AclError", "Response", "Spec", "Unit", "decode_absolute_limits", "decode_interlock",
           "decode_mode", "decode_number", "decode_register", "format_number", "frame_response", "message",
           "frame_size", "parse_framed", "parse_message", "resolve", "resolve_mode", "split_responses", "unit"]
