"""IMU frame layouts: a DBC (read with cantools) + a signal mapping, compiled once.

cantools only reads the DBC; its per-frame decode is far too slow for the hot path.
`ImuLayout` compiles every mapped signal into plain numbers (byte window, shift, mask,
sign, factor, offset) that the decoders apply with numpy (`drivers.imu.rules`).
Supported signals: integer (not float, not multiplexed), Intel or Motorola, whose bits
lie within 8 consecutive bytes (any signal of <= 57 bits, or a byte-aligned one of up to
64 bits); the counter is unsigned with factor 1, offset 0, the same width in every
message; the CRC (optional) is an unsigned byte-aligned 8-bit signal holding
CRC-8/SAE-J1850 over the id and every other data byte (`drivers.imu.crc`).
Anything else raises `ImuConfigError` naming the signal.
"""

from __future__ import annotations

import dataclasses
import functools
import operator
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntFlag
from pathlib import Path
from typing import Literal

import cantools

from drivers.errors import ImuConfigError

#: The per-sample columns every layout fills, in this order.
CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")
COLUMNS = CHANNELS + ("temperature", "status")
TEMPERATURE_COLUMN, STATUS_COLUMN = 6, 7
#: Added to the arbitration id of a 29-bit frame wherever ids are keys (live feed, bulk arrays).
EXTENDED_ID_FLAG = 1 << 31



class ImuStatus(IntFlag):
    """The shipped layouts' status bits (docs/hardware/can.md); 0 = healthy."""

    GYRO_FAULT = 1 << 0
    ACC_FAULT = 1 << 1
    TEMPERATURE_RANGE = 1 << 2
    OVER_RANGE = 1 << 3           # an output saturated in this sample
    INITIALISING = 1 << 4         # outputs not yet valid


#: The status bits that make a sample unusable for a calibration (a fault, a saturated output, outputs not yet
#: valid); an IMU whose status means otherwise says which of its bits do in `[imu.signals] status_invalid`.
STATUS_INVALID = ImuStatus.GYRO_FAULT | ImuStatus.ACC_FAULT | ImuStatus.OVER_RANGE | ImuStatus.INITIALISING


class SbgImuStatus(IntFlag):
    """sbg-ecan's IMU status bits (SBG's IMU_STATUS): each set = healthy."""

    COM_OK = 1 << 0
    BUILT_IN_TEST_OK = 1 << 1
    ACCEL_X_OK = 1 << 2
    ACCEL_Y_OK = 1 << 3
    ACCEL_Z_OK = 1 << 4
    GYRO_X_OK = 1 << 5
    GYRO_Y_OK = 1 << 6
    GYRO_Z_OK = 1 << 7
    ACCELS_IN_RANGE = 1 << 8
    GYROS_IN_RANGE = 1 << 9


#: sbg-ecan's status word with every health bit set (0x03FF); a sample lacking any is unusable.
SBG_STATUS_HEALTHY = int(functools.reduce(operator.or_, SbgImuStatus))
#: sbg-ecan's "accelerometers / gyroscopes within range" bits: a sender whose output saturates clears them.
SBG_ACCELS_IN_RANGE, SBG_GYROS_IN_RANGE = int(SbgImuStatus.ACCELS_IN_RANGE), int(SbgImuStatus.GYROS_IN_RANGE)


def describe_status(bits: int, invalid: int = STATUS_INVALID, required: int = 0) -> str:
    """Unusable status bits (set invalid ones, cleared required ones) in words: the shipped names where the bits
    are the shipped layouts' or sbg-ecan's, else in hex."""
    if required:
        if required == SBG_STATUS_HEALTHY and not invalid:
            return ", ".join(f"{str(flag.name).lower().replace('_', '-')} clear" for flag in SbgImuStatus
                             if bits & flag)
        return f"status bits {bits:#06x}"
    if invalid == STATUS_INVALID:
        names = [str(flag.name).lower().replace("_", "-") for flag in ImuStatus if bits & flag]
        return ", ".join(names)
    return f"status bits {bits:#06x}"


DBC_DIR = Path(__file__).resolve().parent
DEFAULT_DBC = DBC_DIR / "sim_imu.dbc"
DEFAULT_FD_DBC = DBC_DIR / "sim_imu_fd.dbc"
DEFAULT_PACKED_DBC = DBC_DIR / "sim_imu_packed.dbc"
SBG_ECAN_DBC = DBC_DIR / "sbg_ecan.dbc"


@dataclass(frozen=True)
class ImuFrameSpec:
    """Which DBC signals carry an IMU sample.

    `channels`: gyro_x..acc_z -> "MESSAGE.Signal". `counter` / `crc`: the signal name in
    every mapped message, or a per-message {message: signal} table (`crc` None or a
    message missing from the table: that message has no CRC). `temperature` (degC) and
    `status` are optional "MESSAGE.Signal" strings; `status_invalid`: the status bits that
    make a sample unusable (the shipped layouts' `STATUS_INVALID` unless told); `status_required`:
    the bits that must be set in a usable sample (an IMU whose status bits mean "healthy").
    Every message named here is part of every sample.

    `time_stamp` ("MESSAGE.Signal", unsigned, microseconds) instead of a counter: a layout
    without a sample counter (sbg-ecan). That message opens a sample and the others follow
    it; the channels are then rates and accelerations (per second), not increments.
    """

    channels: Mapping[str, str]
    counter: str | Mapping[str, str] | None = "Counter"
    crc: str | Mapping[str, str] | None = "CRC"
    temperature: str | None = None
    status: str | None = None
    status_invalid: int = STATUS_INVALID
    time_stamp: str | None = None
    status_required: int = 0

    @classmethod
    def from_dict(cls, config: Mapping) -> "ImuFrameSpec":
        """From a TOML-shaped table: gyro_x..acc_z, temperature, status, status_invalid, counter, crc keys.

        `crc = ""` means no CRC; anything else malformed raises `ImuConfigError`.
        """
        if not isinstance(config, Mapping):
            raise ImuConfigError(f"the IMU signal mapping must be a table, got {type(config).__name__}")
        known = set(CHANNELS) | {"temperature", "status", "status_invalid", "status_required", "counter", "crc",
                                 "time_stamp"}
        unknown = sorted(str(k) for k in config if k not in known)
        if unknown:
            raise ImuConfigError(f"unknown key(s) in the IMU signal mapping: {', '.join(unknown)} "
                                 f"(known: {', '.join(sorted(known))})")
        missing = [c for c in CHANNELS if c not in config]
        if missing:
            raise ImuConfigError(f"the IMU signal mapping lacks {', '.join(missing)}")
        time_stamp = config.get("time_stamp")
        crc = config.get("crc", None if time_stamp else "CRC")
        counter = config.get("counter", None if time_stamp else "Counter")
        if time_stamp is not None and counter is not None:
            raise ImuConfigError("give a counter or a time_stamp signal, not both")
        invalid = config.get("status_invalid", 0 if time_stamp else int(STATUS_INVALID))
        required = config.get("status_required", 0)
        for key, bits in (("status_invalid", invalid), ("status_required", required)):
            if type(bits) is not int or not 0 <= bits <= 0xFFFF_FFFF:
                raise ImuConfigError(f"{key} must be a whole number of status bits (0 to 0xFFFFFFFF; 0: none), "
                                     f"got {bits!r}")
        return cls(channels={c: config[c] for c in CHANNELS}, counter=counter,
                   crc=crc if crc != "" else None, temperature=config.get("temperature"),
                   status=config.get("status"), status_invalid=invalid, time_stamp=time_stamp,
                   status_required=required)


#: The mapping of the shipped classic layout (drivers/imu/sim_imu.dbc).
DEFAULT_SPEC = ImuFrameSpec(
    channels={"gyro_x": "IMU_GYRO_X.GyroX", "gyro_y": "IMU_GYRO_Y.GyroY", "gyro_z": "IMU_GYRO_Z.GyroZ",
              "acc_x": "IMU_ACC_X.AccX", "acc_y": "IMU_ACC_Y.AccY", "acc_z": "IMU_ACC_Z.AccZ"},
    temperature="IMU_AUX.Temperature", status="IMU_AUX.Status")
#: The mapping of the shipped CAN FD layout (drivers/imu/sim_imu_fd.dbc).
DEFAULT_FD_SPEC = ImuFrameSpec(
    channels={c: f"IMU_SAMPLE_FD.{n}" for c, n in zip(CHANNELS, ("GyroX", "GyroY", "GyroZ", "AccX", "AccY", "AccZ"))},
    temperature="IMU_SAMPLE_FD.Temperature", status="IMU_SAMPLE_FD.Status")
#: The mapping of the shipped packed classic layout (drivers/imu/sim_imu_packed.dbc): 3 frames per sample.
DEFAULT_PACKED_SPEC = ImuFrameSpec(
    channels={"gyro_x": "IMU_PACK_A.GyroX", "gyro_y": "IMU_PACK_A.GyroY", "gyro_z": "IMU_PACK_B.GyroZ",
              "acc_x": "IMU_PACK_B.AccX", "acc_y": "IMU_PACK_C.AccY", "acc_z": "IMU_PACK_C.AccZ"},
    temperature="IMU_PACK_B.Temperature", status="IMU_PACK_A.Status")
#: The mapping of the sbg-ecan layout (drivers/imu/sbg_ecan.dbc): SBG Systems' published IMU messages.
SBG_ECAN_SPEC = ImuFrameSpec(
    channels={"gyro_x": "IMU_GYRO.GyroX", "gyro_y": "IMU_GYRO.GyroY", "gyro_z": "IMU_GYRO.GyroZ",
              "acc_x": "IMU_ACCEL.AccelX", "acc_y": "IMU_ACCEL.AccelY", "acc_z": "IMU_ACCEL.AccelZ"},
    counter=None, crc=None, temperature="IMU_INFO.Temperature", status="IMU_INFO.ImuStatus", status_invalid=0,
    time_stamp="IMU_INFO.TimeStamp", status_required=SBG_STATUS_HEALTHY)

#: The shipped layouts by the name `[imu] layout` gives them: (DBC file, signal mapping, what it is).
SHIPPED_LAYOUTS: dict[str, tuple[Path, ImuFrameSpec, str]] = {
    "classic": (DEFAULT_DBC, DEFAULT_SPEC, "7 classic frames per sample, 1/256-count resolution"),
    "packed": (DEFAULT_PACKED_DBC, DEFAULT_PACKED_SPEC,
               "3 classic frames per sample, whole counts (for rates up to 2 kHz on a 1 Mbit/s bus)"),
    "fd": (DEFAULT_FD_DBC, DEFAULT_FD_SPEC, "one 64-byte CAN FD frame per sample"),
    "sbg-ecan": (SBG_ECAN_DBC, SBG_ECAN_SPEC, "SBG Systems' CAN IMU messages (IMU_INFO, IMU_ACCEL, IMU_GYRO): "
                 "rates in 0.001 rad/s, accelerations in 0.01 m/s^2, a microsecond time stamp"),
}


def shipped_layout_name(imu: Mapping) -> str | None:
    """The shipped layout an `[imu]` table (as TOML reads it) names: its `layout`, else "fd" or "classic"
    by its `fd` flag; None when it names its own `dbc` (and no `layout`) or an unknown layout."""
    name = imu.get("layout")
    if name is None:
        return None if imu.get("dbc") else ("fd" if imu.get("fd") is True else "classic")
    return name if name in SHIPPED_LAYOUTS else None


def spec_of(imu: Mapping) -> ImuFrameSpec:
    """The signal mapping of an `[imu]` table: its `[imu.signals]`, else its shipped layout's (classic when it
    names none). Raises `ImuConfigError` for a malformed `[imu.signals]`."""
    signals = imu.get("signals")
    if signals:
        return ImuFrameSpec.from_dict(signals)
    return SHIPPED_LAYOUTS[shipped_layout_name(imu) or ("fd" if imu.get("fd") is True else "classic")][1]


@dataclass(frozen=True)
class SignalLayout:
    """One integer signal, compiled.

    Live path: `(v >> shift) & mask` on the frame read as one int, little-endian for
    Intel signals, big-endian for Motorola (`big_endian`). Bulk path: the 1..8 bytes
    `first_byte..last_byte` gathered into a uint64 (in the signal's byte order), then
    `>> window_shift`, masked, sign-extended. Physical value = raw * scale + offset.
    """

    name: str
    length: int
    signed: bool
    big_endian: bool
    shift: int
    first_byte: int
    last_byte: int
    window_shift: int
    scale: float = 1.0
    offset: float = 0.0

    @property
    def mask(self) -> int:
        return (1 << self.length) - 1

    def raw(self, data: bytes) -> int:
        """The raw (sign-extended) value of this signal in one frame's data."""
        order: Literal["big", "little"] = "big" if self.big_endian else "little"
        v = int.from_bytes(data, order)
        x = (v >> self.shift) & self.mask
        if self.signed and x >> (self.length - 1):
            x -= 1 << self.length
        return x

    def insert(self, data: bytearray, raw: int) -> None:
        """Write `raw` (range already checked) into `data` in place."""
        order: Literal["big", "little"] = "big" if self.big_endian else "little"
        v = int.from_bytes(data, order)
        v = (v & ~(self.mask << self.shift)) | ((raw & self.mask) << self.shift)
        data[:] = v.to_bytes(len(data), order)


def _compile_signal(msg, sig, where: str) -> SignalLayout:
    n = msg.length
    label = f"signal {sig.name} of {msg.name}{where}"
    if sig.is_float:
        raise ImuConfigError(f"{label} is a float signal; only integer signals are supported")
    if sig.multiplexer_ids or sig.is_multiplexer:
        raise ImuConfigError(f"{label} is multiplexed; multiplexed IMU messages are not supported")
    length = int(sig.length)
    if not 1 <= length <= 64:
        raise ImuConfigError(f"{label} has {length} bits")
    if length == 64 and not sig.is_signed:
        raise ImuConfigError(f"{label} is an unsigned 64-bit signal; at most 63 bits unsigned are supported")
    start = int(sig.start)
    if sig.byte_order == "little_endian":
        lsb = start
        if lsb + length > 8 * n:
            raise ImuConfigError(f"{label} runs past the end of its {n}-byte message")
        first, last = lsb // 8, (lsb + length - 1) // 8
        shift, window_shift, big = lsb, lsb - 8 * first, False
    else:
        msb_be = 8 * (n - 1 - start // 8) + start % 8   # bit index in the frame read big-endian
        lsb_be = msb_be - length + 1
        if lsb_be < 0 or start // 8 >= n:
            raise ImuConfigError(f"{label} runs past the end of its {n}-byte message")
        first, last = start // 8, n - 1 - lsb_be // 8
        shift, window_shift, big = lsb_be, lsb_be % 8, True
    if last - first + 1 > 8:
        raise ImuConfigError(f"{label} spans {last - first + 1} bytes; signals must lie within 8 consecutive bytes")
    return SignalLayout(sig.name, length, bool(sig.is_signed), big, shift, first, last, window_shift,
                        float(sig.scale), float(sig.offset))


@dataclass(frozen=True)
class MessageLayout:
    """One message of a sample: its id, length, counter, CRC byte and value signals."""

    name: str
    frame_id: int
    is_extended_id: bool
    is_fd: bool
    length: int
    counter: SignalLayout
    crc_byte: int | None
    values: tuple[tuple[int, SignalLayout], ...]   # (column index in COLUMNS, signal)

    @property
    def key(self) -> int:
        """The id as ids are keyed in this package (`EXTENDED_ID_FLAG` set for 29-bit ids)."""
        return self.frame_id | (EXTENDED_ID_FLAG if self.is_extended_id else 0)


#: The width of the sample number a time-stamped layout's frames carry once numbered (`ImuLayout.numbered`).
SAMPLE_NUMBER_BITS = 62


def _sample_number_slot(length: int) -> SignalLayout:
    """Where a numbered frame of a `length`-byte message carries its sample number: 8 bytes after its data."""
    return SignalLayout("(sample number)", SAMPLE_NUMBER_BITS, False, False, 8 * length, length, length + 7, 0)


@dataclass(frozen=True)
class TimeStampRule:
    """A layout without a sample counter: `signal` of the first message, a time stamp in `unit_s`, opens
    each sample; the other messages belong to the sample whose time stamp came before them."""

    signal: SignalLayout
    unit_s: float = 1e-6


@dataclass(frozen=True)
class ImuLayout:
    """A compiled IMU layout: the messages of one sample and the column scales.

    A time-stamped layout (`time_stamp` set: no counter in the frames, channels in units per second) is
    decoded through `drivers.imu.numbering`, which gives every frame its sample number; its messages'
    `counter` is where a numbered frame carries it (after the frame's own bytes).
    """

    messages: tuple[MessageLayout, ...]
    counter_bits: int
    scale: tuple[float, ...]       # per column of COLUMNS
    offset: tuple[float, ...]
    has_column: tuple[bool, ...]
    source: str = ""
    dbc_text: str = field(default="", repr=False)
    #: the status bits that make a sample unusable (`ImuFrameSpec.status_invalid`; 0 without a status signal)
    status_invalid: int = 0
    #: the status bits a usable sample has set (`ImuFrameSpec.status_required`; 0 without a status signal)
    status_required: int = 0
    #: the time stamp that stands in for a counter; None: the frames carry a counter
    time_stamp: TimeStampRule | None = None

    @property
    def output_step(self) -> tuple[float, ...] | None:
        """The six channels' output resolution per second (rad/s, m/s^2 for sbg-ecan) of a time-stamped layout,
        which rounds each sample on its own; None for a counter layout, whose increments sum exactly to one
        step."""
        return None if self.time_stamp is None else tuple(abs(v) for v in self.scale[:6])

    def healthy_status(self) -> int:
        """The status word of a sample with nothing to report (what a sender sends unless told)."""
        return self.status_required

    def numbered(self, rate_hz: float) -> "ImuLayout":
        """The layout of this time-stamped layout's frames once numbered: each frame 8 bytes longer (its sample
        number), the channels scaled to increments per sample (per-second values / `rate_hz`)."""
        if self.time_stamp is None:
            raise ImuConfigError("only a time-stamped layout is numbered")
        messages = tuple(dataclasses.replace(m, length=m.length + 8) for m in self.messages)
        scale = tuple(v / rate_hz if c < 6 else v for c, v in enumerate(self.scale))
        offset = tuple(v / rate_hz if c < 6 else v for c, v in enumerate(self.offset))
        return dataclasses.replace(self, messages=messages, scale=scale, offset=offset, time_stamp=None)

    @property
    def keys(self) -> tuple[int, ...]:
        return tuple(m.key for m in self.messages)

    def with_id_offset(self, offset: int) -> "ImuLayout":
        """This layout with `offset` added to every message's arbitration id (several IMUs of one layout on one
        bus, each configured to send at its own ids); ImuConfigError when an id leaves its range."""
        if offset == 0:
            return self
        messages = []
        for m in self.messages:
            frame_id, top = m.frame_id + offset, (0x1FFFFFFF if m.is_extended_id else 0x7FF)
            if not 0 <= frame_id <= top:
                raise ImuConfigError(f"message {m.name}: id {m.frame_id:#x} + {offset} = {frame_id:#x} is outside "
                                     f"0..{top:#x} ({'29' if m.is_extended_id else '11'}-bit ids)")
            messages.append(dataclasses.replace(m, frame_id=frame_id))
        return dataclasses.replace(self, messages=tuple(messages))

    def message(self, key: int) -> MessageLayout:
        for m in self.messages:
            if m.key == key:
                return m
        raise KeyError(key)

    @classmethod
    def from_dbc(cls, dbc: str | Path | "cantools.database.can.Database", spec: ImuFrameSpec) -> "ImuLayout":
        """Compile `spec` against a DBC file path (or a loaded cantools database)."""
        if isinstance(dbc, (str, Path)):
            path = Path(dbc)
            try:
                text = path.read_text(encoding="utf-8", errors="replace")
            except OSError as exc:
                raise ImuConfigError(f"cannot read the DBC file {str(path)!r}: {exc}") from exc
            return cls.from_dbc_string(text, spec, source=str(path))
        return _compile(dbc, spec, source="<database>", text="")

    @classmethod
    def from_dbc_string(cls, text: str, spec: ImuFrameSpec, source: str = "<string>") -> "ImuLayout":
        """Compile `spec` against DBC text."""
        try:
            db = cantools.database.load_string(text, database_format="dbc")
        except Exception as exc:  # cantools raises many types on malformed input
            raise ImuConfigError(f"{source} is not a readable DBC file: {exc}") from exc
        return _compile(db, spec, source=source, text=text)


def _split_ref(ref, what: str) -> tuple[str, str]:
    if not isinstance(ref, str) or ref.count(".") != 1 or not all(ref.split(".")):
        raise ImuConfigError(f"{what} must be 'MESSAGE.Signal', got {ref!r}")
    message, signal = ref.split(".")
    return message, signal


def _compile(db, spec: ImuFrameSpec, source: str, text: str) -> ImuLayout:
    if not isinstance(spec, ImuFrameSpec):
        raise ImuConfigError(f"expected an ImuFrameSpec, got {type(spec).__name__}")
    refs: list[tuple[int, str, str]] = []
    for column, name in enumerate(COLUMNS):
        ref = spec.channels.get(name) if column < 6 else (spec.temperature if name == "temperature" else spec.status)
        if ref is None:
            if column < 6:
                raise ImuConfigError(f"the IMU signal mapping lacks {name}")
            continue
        refs.append((column, *_split_ref(ref, name)))
    seen: dict[tuple[str, str], str] = {}
    for column, m, s in refs:
        if (m, s) in seen:
            raise ImuConfigError(f"{COLUMNS[column]} and {seen[(m, s)]} both map to {m}.{s}")
        seen[(m, s)] = COLUMNS[column]
    names = list(dict.fromkeys(m for _, m, _ in refs))   # message order: first use
    if spec.time_stamp is not None:   # its message is part of every sample even if it carries no other signal
        names = list(dict.fromkeys(names + [_split_ref(spec.time_stamp, "time_stamp")[0]]))
    by_name = {}
    for name in names:
        try:
            by_name[name] = db.get_message_by_name(name)
        except KeyError:
            raise ImuConfigError(f"{source} has no message {name!r}") from None

    def per_message(value, what: str, required: bool) -> dict[str, str | None]:
        if value is None:
            if required:
                raise ImuConfigError(f"the IMU signal mapping needs a {what} signal")
            return {n: None for n in names}
        if isinstance(value, str):
            return {n: value for n in names}
        if isinstance(value, Mapping):
            if required and any(n not in value for n in names):
                raise ImuConfigError(f"no {what} signal given for message(s) "
                                     f"{', '.join(n for n in names if n not in value)}")
            return {n: value.get(n) for n in names}
        raise ImuConfigError(f"{what} must be a signal name or a table of them, got {value!r}")

    stamped = spec.time_stamp is not None
    time_stamp = None
    if stamped:
        if spec.counter is not None:
            raise ImuConfigError("give a counter or a time_stamp signal, not both")
        ts_message, ts_signal = _split_ref(spec.time_stamp, "time_stamp")
        names.sort(key=lambda n: (n != ts_message, by_name[n].frame_id))   # the time stamp opens a sample
    counters = per_message(spec.counter, "counter", not stamped)
    crcs = per_message(spec.crc, "CRC", False)

    def signal(msg, sig_name: str | None, what: str):  # None (no name given) fails the lookup like a wrong name
        try:
            return msg.get_signal_by_name(sig_name)
        except KeyError:
            raise ImuConfigError(f"message {msg.name} in {source} has no {what} signal {sig_name!r}") from None

    messages, counter_bits = [], None
    scale, offset, has = [1.0] * len(COLUMNS), [0.0] * len(COLUMNS), [False] * len(COLUMNS)
    for name in names:
        msg = by_name[name]
        if msg.length < 1 or msg.length > 64:
            raise ImuConfigError(f"message {name} has length {msg.length}")
        if stamped:
            counter = _sample_number_slot(int(msg.length))
            if name == ts_message:
                ts = _compile_signal(msg, signal(msg, ts_signal, "time_stamp"), " (time_stamp)")
                if ts.signed or ts.scale != 1.0 or ts.offset != 0.0 or ts.length > 62:
                    raise ImuConfigError(f"time_stamp signal {ts.name} of {name} must be unsigned, at most 62 "
                                         f"bits, factor 1 (microseconds), offset 0")
                time_stamp = TimeStampRule(ts)
        else:
            counter = _compile_signal(msg, signal(msg, counters[name], "counter"), " (counter)")
        if counter.signed or counter.scale != 1.0 or counter.offset != 0.0 or counter.length > 62:
            raise ImuConfigError(f"counter signal {counter.name} of {name} must be unsigned, at most 62 bits, "
                                 f"factor 1, offset 0")
        if counter_bits is None:
            counter_bits = counter.length
        elif counter.length != counter_bits:
            raise ImuConfigError(f"counter signal {counter.name} of {name} has {counter.length} bits, "
                                 f"others have {counter_bits}; all counters must have one width")
        crc_byte = None
        if crcs[name] is not None:
            crc = _compile_signal(msg, signal(msg, crcs[name], "CRC"), " (CRC)")
            if (crc.length != 8 or crc.signed or crc.first_byte != crc.last_byte or crc.window_shift != 0
                    or crc.scale != 1.0 or crc.offset != 0.0):
                raise ImuConfigError(f"CRC signal {crc.name} of {name} must be one whole unsigned byte, factor 1")
            crc_byte = crc.first_byte
        values = []
        for column, m, s in refs:
            if m != name:
                continue
            sig = _compile_signal(msg, signal(msg, s, COLUMNS[column]), f" ({COLUMNS[column]})")
            values.append((column, sig))
            scale[column], offset[column], has[column] = sig.scale, sig.offset, True
        messages.append(MessageLayout(name, int(msg.frame_id), bool(msg.is_extended_frame), bool(msg.is_fd),
                                      int(msg.length), counter, crc_byte, tuple(values)))
    keys = [m.key for m in messages]
    if len(set(keys)) != len(keys):
        raise ImuConfigError("two mapped messages share one arbitration id")
    assert counter_bits is not None  # the six channels are required, so at least one message was compiled
    return ImuLayout(tuple(messages), int(counter_bits), tuple(scale), tuple(offset), tuple(has), source, text,
                     status_invalid=int(spec.status_invalid) if spec.status else 0,
                     status_required=int(spec.status_required) if spec.status else 0, time_stamp=time_stamp)


@functools.lru_cache(maxsize=None)
def default_layout() -> ImuLayout:
    """The shipped classic layout of the simulated IMU (7 frames per sample)."""
    return ImuLayout.from_dbc(DEFAULT_DBC, DEFAULT_SPEC)


@functools.lru_cache(maxsize=None)
def default_packed_layout() -> ImuLayout:
    """The shipped packed classic layout of the simulated IMU (3 frames per sample)."""
    return ImuLayout.from_dbc(DEFAULT_PACKED_DBC, DEFAULT_PACKED_SPEC)


def shipped_layout(name: str) -> ImuLayout:
    """The compiled shipped layout `name` (a key of `SHIPPED_LAYOUTS`)."""
    return {"classic": default_layout, "packed": default_packed_layout, "fd": default_fd_layout,
            "sbg-ecan": sbg_ecan_layout}[name]()


@functools.lru_cache(maxsize=None)
def sbg_ecan_layout() -> ImuLayout:
    """The sbg-ecan layout: SBG Systems' IMU_INFO, IMU_ACCEL, IMU_GYRO messages at their default ids."""
    return ImuLayout.from_dbc(SBG_ECAN_DBC, SBG_ECAN_SPEC)


@functools.lru_cache(maxsize=None)
def default_fd_layout() -> ImuLayout:
    """The shipped CAN FD layout of the simulated IMU (one 64-byte frame per sample)."""
    return ImuLayout.from_dbc(DEFAULT_FD_DBC, DEFAULT_FD_SPEC)
