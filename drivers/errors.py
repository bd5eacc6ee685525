"""The drivers' exception trees: one for the turntable, one for the thermal chamber, one for the IMU over CAN.

Every driver error is raised `from` the low-level cause (socket error, serial error,
pymodbus exception) so a traceback shows both what the bench tried and what failed.
"""

from __future__ import annotations

from dataclasses import dataclass

#: how much of a peer's data an error message quotes: the first this many bytes (characters), then the length
QUOTE_LIMIT = 64


def quote_bytes(raw: bytes | bytearray | memoryview | str, limit: int = QUOTE_LIMIT, *, hex_dump: bool = False) -> str:
    """Data from the wire as an error message shows it: whole up to `limit` bytes, else its start and its length.

    Every error message in drivers/ that quotes what a peer sent goes through here, so a
    peer streaming garbage cannot make a message of megabytes. `quote_bytes(b'OK')` is
    `b'OK'` (its repr); 41.5 MB of junk is `b'\\xde\\xad...'... (41,500,000 bytes)` (the first
    `limit` bytes). `hex_dump=True` gives hex pairs instead (`de ad be ef`, or
    `de ad ... ... (41,500,000 bytes)`). A `str` (text already decoded from the wire) is
    quoted the same way, counted in characters.
    """
    if isinstance(raw, str):
        if len(raw) <= limit:
            return repr(raw)
        return f"{raw[:limit]!r}... ({len(raw):,} characters)"
    data = bytes(raw[:limit])
    total = len(raw)
    text = data.hex(" ") if hex_dump else repr(data)
    if total <= limit:
        return text
    return f"{text} ... ({total:,} bytes)" if hex_dump else f"{text}... ({total:,} bytes)"


# What some errors carry besides their message, the same in every device family's tree (mixins, not roots:
# each tree's base is its family's error).
class _CarriesRaw(Exception):
    """`raw`: the offending bytes (or None when not applicable)."""

    def __init__(self, message: str, raw: bytes | None = None):
        super().__init__(message)
        self.raw = raw


class _CarriesCode(Exception):
    """`code`: the controller's error or exception code (or None when it gives none)."""

    def __init__(self, message: str, code: int | None = None):
        super().__init__(message)
        self.code = code


class _CarriesState(Exception):
    """`state`: the last state read (or None)."""

    def __init__(self, message: str, state=None):
        super().__init__(message)
        self.state = state


class TurntableError(Exception):
    """Base of every turntable driver error."""


class TurntableTimeout(TurntableError, TimeoutError):
    """No (complete) reply within the timeout, after the configured retries."""


class TurntableConnectionError(TurntableError, ConnectionError):
    """The link to the controller could not be opened or was lost and not regained."""


class TurntableProtocolError(TurntableError, _CarriesRaw):
    """A reply that does not follow the dialect: garbage, wrong echo, malformed fields.

    `raw` holds the offending bytes (or None when not applicable).
    """


class TurntableChecksumError(TurntableProtocolError):
    """A framed reply whose checksum/CRC does not match its content."""


class TurntableCommandError(TurntableError, _CarriesCode):
    """The controller understood the request and refused it (error reply, Modbus exception).

    `code` is the controller's error or exception code when it gives one.
    """


class TurntableFault(TurntableError, _CarriesState):
    """The controller reports a fault (servo fault, limit trip); `state` is the last TableState read."""


class TurntableEStop(TurntableFault):
    """The emergency stop is active: the table is not under servo control."""


class TurntableLimitError(TurntableError, ValueError):
    """A demand outside the configured limits; raised before anything is sent."""


class TurntableConfigError(TurntableError, ValueError):
    """A URL, dialect, option or limit the driver cannot use; raised before anything is sent."""


class ChamberError(Exception):
    """Base of every thermal-chamber driver error."""


class ChamberTimeout(ChamberError, TimeoutError):
    """No (complete) reply within the timeout, after the configured retries."""


class ChamberConnectionError(ChamberError, ConnectionError):
    """The link to the chamber controller could not be opened or was lost and not regained."""


class ChamberProtocolError(ChamberError, _CarriesRaw):
    """A reply that does not follow the dialect; `raw` holds the offending bytes (or None)."""


class ChamberChecksumError(ChamberProtocolError):
    """A framed reply (Modbus RTU) whose CRC does not match its content."""


class ChamberCommandError(ChamberError, _CarriesCode):
    """The controller understood the request and refused it (an `NA:` reply, a Modbus exception); `code`
    is the controller's code when it gives one."""


class ChamberAlarm(ChamberError, _CarriesState):
    """The controller reports an alarm (over-temperature, door open, ...); `state` is the last ChamberState read."""


class ChamberLimitError(ChamberError, ValueError):
    """A setpoint or ramp rate outside the configured limits; raised before anything is sent."""


class ChamberConfigError(ChamberError, ValueError):
    """A URL, dialect, register map, option or limit the chamber driver cannot use; raised before anything is sent."""


@dataclass(frozen=True)
class LinkErrors:
    """The error classes the shared request machinery (drivers.line_link, drivers.modbus_link) raises for one
    device family, so the turntable and the chamber share one retry/reconnect logic and keep their own trees."""

    timeout: type[Exception]
    connection: type[Exception]
    protocol: type[Exception]      # takes (message, raw)
    checksum: type[Exception]      # takes (message, raw); a subclass of `protocol`
    command: type[Exception]       # takes (message, code)
    config: type[Exception]
    base: type[Exception]


TURNTABLE_LINK_ERRORS = LinkErrors(TurntableTimeout, TurntableConnectionError, TurntableProtocolError,
                                   TurntableChecksumError, TurntableCommandError, TurntableConfigError, TurntableError)
CHAMBER_LINK_ERRORS = LinkErrors(ChamberTimeout, ChamberConnectionError, ChamberProtocolError, ChamberChecksumError,
                                 ChamberCommandError, ChamberConfigError, ChamberError)


class ImuError(Exception):
    """Base of every IMU (CAN) driver error."""


class ImuTimeout(ImuError, TimeoutError):
    """No IMU frame within the timeout."""


class ImuConnectionError(ImuError, ConnectionError):
    """The CAN bus could not be opened, or failed while in use."""


class ImuConfigError(ImuError, ValueError):
    """A DBC file or signal mapping that cannot describe an IMU sample."""


class ImuFrameError(ImuError):
    """A CAN frame that cannot be decoded (wrong length, bad CRC, unknown id) where one is required."""
