"""The drivers' errors: one tree under `DeviceError`, for the turntable, the thermal chamber and the IMU over CAN.

    DeviceError                              any driver error: what a boundary (CLI, TUI) catches
    ├── DeviceTimeout (TimeoutError)         no (complete) reply within the timeout, after the retries
    │     TurntableTimeout, ChamberTimeout, ImuTimeout
    ├── DeviceConnectionError (ConnectionError)   the link could not be opened, or was lost and not regained
    │     TurntableConnectionError, ChamberConnectionError, ImuConnectionError
    ├── DeviceProtocolError  .raw            a reply (or frame) that does not follow the protocol
    │   │ TurntableProtocolError (> ScpiRequestError, MnRequestError), ChamberProtocolError, ImuFrameError
    │   └── DeviceChecksumError              a framed reply whose checksum/CRC does not match
    │         TurntableChecksumError (> MnChecksumError), ChamberChecksumError
    ├── DeviceCommandError  .code            the controller understood a request and refused it
    │     TurntableCommandError, ChamberCommandError
    ├── DeviceFault  .state                  the device reports a fault
    │     TurntableFault (> TurntableEStop), ChamberAlarm
    ├── DeviceLimitError (ValueError)        a demand outside the configured limits; nothing sent
    │     TurntableLimitError, ChamberLimitError
    └── DeviceConfigError (ValueError)       a URL, dialect, option, limit, register map or DBC the driver cannot use
          TurntableConfigError, ChamberConfigError (> ChamberMapError), ImuConfigError,
          RegisterMapError (a Modbus register map, drivers.turntable.modbus_map)

Code catches the kinds (`DeviceError`, `DeviceTimeout`, ...). The device-named classes under each
kind are what a driver raises, for their names: a boundary prints an error as
`TurntableTimeout: ...` and a run records a fault's error by that name, so they stay as users
and old logs know them. Caught by name are only `TurntableEStop` (an abort instead of a stop),
the codecs' request errors (what a simulator replies) and `RegisterMapError` (restated as a
`ChamberMapError` for a chamber's map).

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


class DeviceError(Exception):
    """Base of every device driver error (turntable, thermal chamber, IMU)."""


class DeviceTimeout(DeviceError, TimeoutError):
    """No (complete) reply within the timeout, after the configured retries."""


class DeviceConnectionError(DeviceError, ConnectionError):
    """The link to the device could not be opened or was lost and not regained."""


class DeviceProtocolError(DeviceError):
    """A reply that does not follow the protocol: garbage, wrong echo, malformed fields, an undecodable frame.

    `raw` holds the offending bytes (or None when not applicable).
    """

    def __init__(self, message: str, raw: bytes | None = None):
        super().__init__(message)
        self.raw = raw


class DeviceChecksumError(DeviceProtocolError):
    """A framed reply whose checksum/CRC does not match its content."""


class DeviceCommandError(DeviceError):
    """The controller understood the request and refused it (error reply, Modbus exception).

    `code` is the controller's error or exception code when it gives one.
    """

    def __init__(self, message: str, code: int | None = None):
        super().__init__(message)
        self.code = code


class DeviceFault(DeviceError):
    """The device reports a fault (servo fault, limit trip, chamber alarm); `state` is the last state read."""

    def __init__(self, message: str, state=None):
        super().__init__(message)
        self.state = state


class DeviceLimitError(DeviceError, ValueError):
    """A demand outside the configured limits; raised before anything is sent."""


class DeviceConfigError(DeviceError, ValueError):
    """A URL, dialect, option, limit, register map or DBC the driver cannot use; raised before anything is sent."""


# The device-named leaves (see the module docstring: their names are printed and recorded).
class TurntableTimeout(DeviceTimeout):
    """The turntable controller did not answer."""


class TurntableConnectionError(DeviceConnectionError):
    """The link to the turntable controller could not be opened or was lost."""


class TurntableProtocolError(DeviceProtocolError):
    """A turntable reply that does not follow the dialect."""


class TurntableChecksumError(TurntableProtocolError, DeviceChecksumError):
    """A framed turntable reply whose checksum/CRC does not match its content."""


class TurntableCommandError(DeviceCommandError):
    """The turntable controller refused a request."""


class TurntableFault(DeviceFault):
    """The turntable controller reports a fault (servo fault, limit trip); `state` is the last TableState read."""


class TurntableEStop(TurntableFault):
    """The emergency stop is active: the table is not under servo control."""


class TurntableLimitError(DeviceLimitError):
    """A table demand outside the configured limits; raised before anything is sent."""


class TurntableConfigError(DeviceConfigError):
    """A URL, dialect, option or limit the turntable driver cannot use; raised before anything is sent."""


class ChamberTimeout(DeviceTimeout):
    """The chamber controller did not answer."""


class ChamberConnectionError(DeviceConnectionError):
    """The link to the chamber controller could not be opened or was lost."""


class ChamberProtocolError(DeviceProtocolError):
    """A chamber reply that does not follow the dialect."""


class ChamberChecksumError(ChamberProtocolError, DeviceChecksumError):
    """A framed chamber reply (Modbus RTU) whose CRC does not match its content."""


class ChamberCommandError(DeviceCommandError):
    """The chamber controller refused a request (an `NA:` reply, a Modbus exception)."""


class ChamberAlarm(DeviceFault):
    """The chamber reports an alarm (over-temperature, door open, ...); `state` is the last ChamberState read."""


class ChamberLimitError(DeviceLimitError):
    """A setpoint or ramp rate outside the configured limits; raised before anything is sent."""


class ChamberConfigError(DeviceConfigError):
    """A URL, dialect, register map, option or limit the chamber driver cannot use; raised before anything is sent."""


class ImuTimeout(DeviceTimeout):
    """No IMU frame within the timeout."""


class ImuConnectionError(DeviceConnectionError):
    """The CAN bus could not be opened, or failed while in use."""


class ImuConfigError(DeviceConfigError):
    """A DBC file or signal mapping that cannot describe an IMU sample."""


class ImuFrameError(DeviceProtocolError):
    """A CAN frame that cannot be decoded (wrong length, bad CRC, unknown id) where one is required."""


@dataclass(frozen=True)
class LinkErrors:
    """The device-named errors the shared request machinery (drivers.line_link, drivers.modbus_link) raises for
    one device, so the turntable and the chamber share one retry/reconnect logic and keep their errors' names."""

    timeout: type[DeviceTimeout]
    connection: type[DeviceConnectionError]
    protocol: type[DeviceProtocolError]
    checksum: type[DeviceChecksumError]     # a subclass of `protocol`
    command: type[DeviceCommandError]
    config: type[DeviceConfigError]


TURNTABLE_LINK_ERRORS = LinkErrors(TurntableTimeout, TurntableConnectionError, TurntableProtocolError,
                                   TurntableChecksumError, TurntableCommandError, TurntableConfigError)
CHAMBER_LINK_ERRORS = LinkErrors(ChamberTimeout, ChamberConnectionError, ChamberProtocolError, ChamberChecksumError,
                                 ChamberCommandError, ChamberConfigError)
