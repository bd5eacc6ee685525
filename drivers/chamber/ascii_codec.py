"""The chamber's ASCII line dialect: a pure codec (no I/O), both directions (client and simulator).

One command per line, CR LF terminated, one reply line each (docs/hardware/chamber.md):

    MON?            -> 23.4,25.0,2.0,RUN,0          temperature, setpoint, ramp, mode, alarm count[, codes]
    TEMP?           -> 23.4,25.0                    temperature, setpoint (degC)
    TEMP,S25.0      -> OK:TEMP,S25.0                setpoint, degC
    RAMP?           -> 2.0                          degC/min (0.0 = no ramp: steps)
    RAMP,2.0        -> OK:RAMP,2.0
    MODE?           -> RUN | STOP
    MODE,RUN        -> OK:MODE,RUN                  (MODE,STOP stops temperature control)
    ALARM?          -> 0 | 2,1,3                    count, then the codes
    ALARM,CLEAR     -> OK:ALARM,CLEAR

A refused or unreadable command is answered `NA:<reason>` (`NA:OUT OF RANGE`); the client
raises it as `ChamberCommandError`. Alarm codes: 1 over-temperature, 2 under-temperature,
3 door open, 4 sensor fault, 5 equipment fault; any other code is reported by number.
Temperatures go out with one decimal (the controllers' resolution).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from drivers.chamber.base import ChamberAlarms, ChamberState
from drivers.errors import ChamberCommandError, ChamberProtocolError, quote_bytes

TERMINATOR = b"\r\n"
#: the longest reply line a client accepts (a MON? reply with every alarm code fits easily)
MAX_REPLY = 256
MAX_ALARM_CODES = 32

ALARM_CODES = {1: ChamberAlarms.OVER_TEMPERATURE, 2: ChamberAlarms.UNDER_TEMPERATURE, 3: ChamberAlarms.DOOR_OPEN,
               4: ChamberAlarms.SENSOR_FAULT, 5: ChamberAlarms.EQUIPMENT_FAULT}
MODES = ("RUN", "STOP")

# The reasons of NA: replies the simulator gives (a controller may give others; the client quotes any).
NA_COMMAND = "COMMAND ERR"          # not a command of the dialect
NA_PARAMETER = "PARAMETER ERR"      # a value that is not a number or not allowed
NA_RANGE = "OUT OF RANGE"           # beyond the controller's own setpoint or ramp range
NA_ALARM = "ALARM ACTIVE"           # run refused while an alarm is latched

_NUMBER = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?")

# requests: the text before the value -> request name
QUERIES = ("MON?", "TEMP?", "RAMP?", "MODE?", "ALARM?")


@dataclass(frozen=True)
class ChamberRequest:
    """A parsed request line (for the simulator): `name` is a query, 'TEMP,S', 'RAMP', 'MODE' or 'ALARM,CLEAR'."""

    name: str
    value: float | str | None = None


# -- client side: encoding requests ---------------------------------------------------

def format_temperature(value_c: float) -> str:
    """One decimal, no exponent: '25.0', '-40.0'."""
    if not math.isfinite(value_c):
        raise ValueError(f"temperature must be finite, got {value_c}")
    text = f"{value_c:.1f}"
    return "0.0" if text == "-0.0" else text


def encode_set_setpoint(setpoint_c: float) -> bytes:
    return f"TEMP,S{format_temperature(setpoint_c)}".encode("ascii")


def encode_set_ramp(ramp_c_per_min: float) -> bytes:
    return f"RAMP,{format_temperature(ramp_c_per_min)}".encode("ascii")


def encode_mode(run: bool) -> bytes:
    return b"MODE,RUN" if run else b"MODE,STOP"


CLEAR_ALARMS = b"ALARM,CLEAR"
MONITOR = b"MON?"


# -- client side: decoding replies ------------------------------------------------------

def _text(line: bytes) -> str:
    if len(line) > MAX_REPLY:
        raise ChamberProtocolError(f"reply line of {len(line)} bytes is longer than any reply of the dialect: "
                                   f"{quote_bytes(line)}", line)
    try:
        text = line.decode("ascii")
    except UnicodeDecodeError as exc:
        raise ChamberProtocolError(f"non-ASCII reply {quote_bytes(line)}", line) from exc
    if any(not c.isprintable() for c in text):
        raise ChamberProtocolError(f"control characters in reply {quote_bytes(line)}", line)
    return text.strip()


def _refused(text: str, line: bytes) -> None:
    if text.startswith("NA:"):
        reason = text[3:].strip() or "no reason given"
        raise ChamberCommandError(f"chamber refused: {reason}")


def _number(field: str, what: str, line: bytes) -> float:
    field = field.strip()
    if not _NUMBER.fullmatch(field):
        raise ChamberProtocolError(f"{what} {field!r} is not a number in reply {quote_bytes(line)}", line)
    value = float(field)
    if not math.isfinite(value):     # the pattern admits no inf or nan, but 1e999 overflows to inf
        raise ChamberProtocolError(f"{what} {field!r} is not finite in reply {quote_bytes(line)}", line)
    return value


def decode_ack(line: bytes, request: bytes) -> None:
    """The reply to a command: `OK:<the command>`; `NA:...` -> ChamberCommandError; else ChamberProtocolError."""
    text = _text(line)
    _refused(text, line)
    expected = "OK:" + request.decode("ascii")
    if text != expected:
        raise ChamberProtocolError(f"expected {expected!r} in reply to {request!r}, got {quote_bytes(line)}", line)


def _alarms(fields: list[str], line: bytes) -> tuple[ChamberAlarms, str]:
    count = _number(fields[0], "alarm count", line)
    if count != int(count) or not 0 <= count <= MAX_ALARM_CODES:
        raise ChamberProtocolError(f"alarm count {fields[0]!r} is not 0-{MAX_ALARM_CODES} in reply "
                                   f"{quote_bytes(line)}", line)
    codes = fields[1:]
    if len(codes) != int(count):
        raise ChamberProtocolError(f"alarm count {int(count)} but {len(codes)} codes in reply {quote_bytes(line)}",
                                   line)
    alarms, unknown = ChamberAlarms(0), []
    for field in codes:
        code = _number(field, "alarm code", line)
        if code != int(code) or code < 0:
            raise ChamberProtocolError(f"alarm code {field!r} is not a whole number in reply {quote_bytes(line)}",
                                       line)
        flag = ALARM_CODES.get(int(code))
        if flag is None:
            unknown.append(f"alarm code {int(code)}")
        else:
            alarms |= flag
    return alarms, ", ".join(unknown)


def decode_monitor(line: bytes, time_s: float = 0.0) -> ChamberState:
    """`MON?` reply -> ChamberState."""
    text = _text(line)
    _refused(text, line)
    fields = text.split(",")
    if len(fields) < 5:
        raise ChamberProtocolError(f"MON? reply needs temperature,setpoint,ramp,mode,alarm count: "
                                   f"{quote_bytes(line)}", line)
    temperature = _number(fields[0], "temperature", line)
    setpoint = _number(fields[1], "setpoint", line)
    ramp = _number(fields[2], "ramp rate", line)
    if ramp < 0:
        raise ChamberProtocolError(f"negative ramp rate in reply {quote_bytes(line)}", line)
    mode = fields[3].strip()
    if mode not in MODES:
        raise ChamberProtocolError(f"mode {mode!r} is not RUN or STOP in reply {quote_bytes(line)}", line)
    alarms, text_of_unknown = _alarms(fields[4:], line)
    return ChamberState(time_s, temperature, setpoint, ramp, mode == "RUN", alarms, text_of_unknown)


def decode_temperature(line: bytes) -> tuple[float, float]:
    """`TEMP?` reply -> (temperature, setpoint), degC."""
    text = _text(line)
    _refused(text, line)
    fields = text.split(",")
    if len(fields) != 2:
        raise ChamberProtocolError(f"TEMP? reply needs temperature,setpoint: {quote_bytes(line)}", line)
    return _number(fields[0], "temperature", line), _number(fields[1], "setpoint", line)


def decode_alarms(line: bytes) -> tuple[ChamberAlarms, str]:
    """`ALARM?` reply -> (alarm flags, text naming codes the dialect does not define)."""
    text = _text(line)
    _refused(text, line)
    return _alarms(text.split(","), line)


# -- simulator side ------------------------------------------------------------------------

class RequestError(ValueError):
    """A request line the dialect cannot read; `reason` is the NA: reply's text."""

    def __init__(self, message: str, reason: str = NA_COMMAND):
        super().__init__(message)
        self.reason = reason


def parse_request(line: bytes) -> ChamberRequest:
    """A request line -> ChamberRequest; RequestError (its NA: reason) when it is not one."""
    try:
        text = line.decode("ascii").strip().upper()
    except UnicodeDecodeError:
        raise RequestError("not ASCII") from None
    if text in QUERIES:
        return ChamberRequest(text)
    if text == "ALARM,CLEAR":
        return ChamberRequest(text)
    if text.startswith("MODE,"):
        mode = text[5:].strip()
        if mode not in MODES:
            raise RequestError(f"mode {mode!r}", NA_PARAMETER)
        return ChamberRequest("MODE", mode)
    for name, prefix in (("TEMP,S", "TEMP,S"), ("RAMP", "RAMP,")):
        if text.startswith(prefix):
            field = text[len(prefix):].strip()
            if not _NUMBER.fullmatch(field):
                raise RequestError(f"{name} value {field!r}", NA_PARAMETER)
            return ChamberRequest(name, float(field))
    raise RequestError(f"unknown command {text[:40]!r}")


def format_ok(line: bytes) -> bytes:
    """`OK:<the command as sent>` + CR LF."""
    return b"OK:" + line.strip() + TERMINATOR


def format_na(reason: str) -> bytes:
    return f"NA:{reason}".encode("ascii") + TERMINATOR


def alarm_codes(alarms: ChamberAlarms) -> list[int]:
    return [code for code, flag in ALARM_CODES.items() if alarms & flag]


def format_alarm_fields(alarms: ChamberAlarms) -> str:
    codes = alarm_codes(alarms)
    return ",".join([str(len(codes)), *map(str, codes)])


def format_monitor(state: ChamberState) -> bytes:
    ramp = 0.0 if state.ramp_c_per_min is None else state.ramp_c_per_min
    fields = [format_temperature(state.temperature_c), format_temperature(state.setpoint_c), format_temperature(ramp),
              "RUN" if state.running else "STOP", format_alarm_fields(state.alarms)]
    return ",".join(fields).encode("ascii") + TERMINATOR
