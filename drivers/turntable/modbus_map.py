"""The Modbus dialect's pure codec: a register map, value encodings, state decoding, reply checks.

No I/O here. `RegisterMap` says where every quantity lives (0-based holding-register
addresses, as they go on the wire), how 32-bit values are encoded (scaled int32 or
float32, word order) and what the status bits, mode codes, command codes and fault
codes mean. The client (`drivers.turntable.modbus`) and the simulator serve the same
map, so both directions live here. docs/hardware/modbus.md documents the default map.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field, replace
from typing import Any, Iterable, Mapping, Sequence

from drivers.errors import (
    DeviceConfigError,
    TurntableLimitError,
    TurntableProtocolError,
)
from drivers.turntable.base import FRAMES, AxisMode, AxisState, AxisStatus, TableState

MAX_READ_REGISTERS = 125          # Modbus limit for one read (function 3)

ENCODINGS = ("int32", "float32")
WORD_ORDERS = ("big", "little")
STATUS_FLAGS = ("enabled", "moving", "in_position", "fault", "estop", "limit")
COMMANDS = ("enable", "disable", "reset", "stop", "abort")
MODES = ("off", "position", "rate")
#: the code tables of a map: (field, the names of its entries, the highest value an entry may have)
CODE_TABLES = (("status_bits", STATUS_FLAGS, 15), ("command_codes", COMMANDS, 65535), ("mode_codes", MODES, 65535))
# Per-axis registers (three addresses each) and single registers; width in 16-bit words.
AXIS_REGISTERS = {"status": 1, "mode": 1, "actual_position": 2, "actual_rate": 2, "move_rate": 2,
                  "demand_position": 2, "demand_rate": 2}
SINGLE_REGISTERS = {"fault_code": 1, "watchdog": 1, "command": 1, "command_axes": 1}
# What one state read must cover (the client reads their span in a single request).
STATE_REGISTERS = ("status", "mode", "actual_position", "actual_rate", "fault_code")
READ_ONLY_REGISTERS = ("status", "actual_position", "actual_rate", "fault_code")

DEFAULT_FAULT_TEXT = {1: "emergency stop", 2: "limit switch tripped", 3: "servo amplifier fault",
                      4: "Modbus watchdog expired"}


class RegisterMapError(DeviceConfigError):
    """A register map (configuration) that cannot describe a controller; the message names the key."""


@dataclass(frozen=True)
class RegisterMap:
    """Where a three-axis controller keeps its quantities, and how it encodes them.

    Addresses are 0-based holding registers (function 3 reads, 6/16 writes). Per-axis
    registers are (outer, middle, inner). 32-bit values take two consecutive registers,
    `word_order` "big" = high word first. `int32` values are counts of `angle_scale_deg`
    (positions) or `rate_scale_dps` (rates); `float32` values are degrees and deg/s.
    `watchdog_s` = 0 disables the watchdog.
    """

    unit: int = 1
    encoding: str = "int32"
    angle_scale_deg: float = 1e-4
    rate_scale_dps: float = 1e-4
    word_order: str = "big"
    watchdog_s: float = 2.0
    status: tuple[int, int, int] = (0, 1, 2)
    fault_code: int = 3
    mode: tuple[int, int, int] = (4, 5, 6)
    watchdog: int = 7
    actual_position: tuple[int, int, int] = (8, 10, 12)
    actual_rate: tuple[int, int, int] = (14, 16, 18)
    command: int = 20
    command_axes: int = 21
    move_rate: tuple[int, int, int] = (22, 26, 30)
    demand_position: tuple[int, int, int] = (24, 28, 32)
    demand_rate: tuple[int, int, int] = (34, 36, 38)
    # Bit positions of ENABLED, MOVING, IN_POSITION, FAULT, ESTOP, LIMIT in the status word.
    status_bits: tuple[int, int, int, int, int, int] = (0, 1, 2, 3, 4, 5)
    # Command register codes for enable, disable, reset, stop, abort.
    command_codes: tuple[int, int, int, int, int] = (1, 2, 3, 4, 5)
    # Mode register codes for off, position, rate.
    mode_codes: tuple[int, int, int] = (0, 1, 2)
    fault_texts: tuple[tuple[int, str], ...] = tuple(sorted(DEFAULT_FAULT_TEXT.items()))
    source: str = field(default="<default>", compare=False)

    def __post_init__(self) -> None:
        self._validate()

    # -- construction ---------------------------------------------------------------
    @classmethod
    def default(cls) -> "RegisterMap":
        """The documented default map (docs/hardware/modbus.md)."""
        return cls()

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "<dict>") -> "RegisterMap":
        """Build a map from configuration (a TOML table); missing keys keep the default's value.

        Raises `RegisterMapError` naming `source` and the offending key.
        """
        if not isinstance(d, Mapping):
            raise RegisterMapError(f"{source}: a register map must be a table, got {type(d).__name__}")
        known = {"unit", "encoding", "angle_scale_deg", "rate_scale_dps", "word_order", "watchdog_s",
                 "registers", "status_bits", "command_codes", "mode_codes", "fault_codes"}
        map_no_unknown(d, known, source, "")
        kw: dict[str, Any] = {"source": source}
        if "unit" in d:
            kw["unit"] = map_int(d["unit"], source, "unit", 0, 255)
        for key in ("encoding", "word_order"):
            if key in d:
                if not isinstance(d[key], str):
                    raise RegisterMapError(f"{source}: {key} must be a string, got {d[key]!r}")
                kw[key] = d[key].strip().lower()
        for key in ("angle_scale_deg", "rate_scale_dps", "watchdog_s"):
            if key in d:
                kw[key] = map_number(d[key], source, key)
        if "registers" in d:
            regs = map_table(d["registers"], source, "registers")
            map_no_unknown(regs, set(AXIS_REGISTERS) | set(SINGLE_REGISTERS), source, "registers.")
            for name, value in regs.items():
                if name in AXIS_REGISTERS:
                    kw[name] = _axis_addresses(value, source, f"registers.{name}")
                else:
                    kw[name] = map_int(value, source, f"registers.{name}", 0, 65535)
        kw.update(map_code_tables(d, cls, source, CODE_TABLES))
        if "fault_codes" in d:
            table = map_table(d["fault_codes"], source, "fault_codes")
            texts = []
            for code, text in table.items():
                try:
                    number = int(str(code), 0)
                except ValueError:
                    raise RegisterMapError(f"{source}: fault_codes.{code}: a fault code must be a number") from None
                if not 1 <= number <= 65535:
                    raise RegisterMapError(f"{source}: fault_codes.{code}: must be 1-65535")
                if not isinstance(text, str) or not text.strip():
                    raise RegisterMapError(f"{source}: fault_codes.{code}: the text must be a non-empty string")
                texts.append((number, text.strip()))
            kw["fault_texts"] = tuple(sorted(texts))
        try:
            return cls(**kw)
        except RegisterMapError:
            raise
        except (TypeError, ValueError) as exc:    # pragma: no cover - every field is checked above
            raise RegisterMapError(f"{source}: {exc}") from exc

    def to_dict(self) -> dict[str, Any]:
        """The map as a TOML-shaped table that `from_dict` reads back."""
        return {
            "unit": self.unit, "encoding": self.encoding, "angle_scale_deg": self.angle_scale_deg,
            "rate_scale_dps": self.rate_scale_dps, "word_order": self.word_order, "watchdog_s": self.watchdog_s,
            "registers": {name: (list(getattr(self, name)) if name in AXIS_REGISTERS else getattr(self, name))
                          for name in (*AXIS_REGISTERS, *SINGLE_REGISTERS)},
            "status_bits": dict(zip(STATUS_FLAGS, self.status_bits)),
            "command_codes": dict(zip(COMMANDS, self.command_codes)),
            "mode_codes": dict(zip(MODES, self.mode_codes)),
            "fault_codes": {str(code): text for code, text in self.fault_texts},
        }

    def with_changes(self, **changes: Any) -> "RegisterMap":
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)

    # -- validation ---------------------------------------------------------------
    def _validate(self) -> None:
        src = self.source
        map_int(self.unit, src, "unit", 0, 255)
        if self.encoding not in ENCODINGS:
            raise RegisterMapError(f"{src}: encoding must be one of {ENCODINGS}, got {self.encoding!r}")
        if self.word_order not in WORD_ORDERS:
            raise RegisterMapError(f"{src}: word_order must be one of {WORD_ORDERS}, got {self.word_order!r}")
        for key in ("angle_scale_deg", "rate_scale_dps"):
            value = map_number(getattr(self, key), src, key)
            if not value > 0:
                raise RegisterMapError(f"{src}: {key} must be positive, got {value}")
        watchdog = map_number(self.watchdog_s, src, "watchdog_s")
        if watchdog < 0:
            raise RegisterMapError(f"{src}: watchdog_s must be >= 0 (0 disables), got {watchdog}")
        owner: dict[int, str] = {}
        for name, width in (*AXIS_REGISTERS.items(), *SINGLE_REGISTERS.items()):
            value = getattr(self, name)
            addresses = _axis_addresses(value, src, f"registers.{name}") if name in AXIS_REGISTERS else (
                (map_int(value, src, f"registers.{name}", 0, 65535),))
            for k, address in enumerate(addresses):
                label = f"registers.{name}" + (f"[{k}] ({FRAMES[k]})" if name in AXIS_REGISTERS else "")
                if address + width - 1 > 65535:
                    raise RegisterMapError(f"{src}: {label}: a 32-bit value at {address} runs past 65535")
                for a in range(address, address + width):
                    if a in owner:
                        raise RegisterMapError(f"{src}: {label} at {address} overlaps {owner[a]} (register {a})")
                    owner[a] = label
        start, count = self.state_span
        if count > MAX_READ_REGISTERS:
            raise RegisterMapError(
                f"{src}: the state registers ({', '.join(STATE_REGISTERS)}) span {count} registers from {start}; "
                f"one Modbus read covers at most {MAX_READ_REGISTERS}")
        check_code_tables(self, src, CODE_TABLES)

    # -- layout -------------------------------------------------------------------
    def addresses(self, name: str) -> tuple[int, ...]:
        """The first register of each value called `name` (three for per-axis registers)."""
        value = getattr(self, name)
        return tuple(value) if name in AXIS_REGISTERS else (value,)

    def width(self, name: str) -> int:
        return AXIS_REGISTERS.get(name) or SINGLE_REGISTERS[name]

    @property
    def state_span(self) -> tuple[int, int]:
        """(first address, count) of the one read that returns the whole state."""
        lo, hi = 65536, -1
        for name in STATE_REGISTERS:
            for address in self.addresses(name):
                lo, hi = min(lo, address), max(hi, address + self.width(name) - 1)
        return lo, hi - lo + 1

    def register_names(self) -> dict[int, tuple[str, int, int]]:
        """address -> (name, axis index or -1, word index) for every register the map uses."""
        out = {}
        for name in (*AXIS_REGISTERS, *SINGLE_REGISTERS):
            for k, address in enumerate(self.addresses(name)):
                for w in range(self.width(name)):
                    out[address + w] = (name, k if name in AXIS_REGISTERS else -1, w)
        return out

    @property
    def fault_text_map(self) -> dict[int, str]:
        return dict(self.fault_texts)

    # -- values ---------------------------------------------------------------------
    def _scale(self, kind: str) -> float:
        if kind == "angle":
            return self.angle_scale_deg
        if kind == "rate":
            return self.rate_scale_dps
        raise ValueError(f"kind must be 'angle' or 'rate', got {kind!r}")

    def encode_value(self, value: float, kind: str = "angle") -> list[int]:
        """A position (deg, kind 'angle') or rate (deg/s, kind 'rate') -> two registers.

        Raises `TurntableLimitError` for a value the encoding cannot carry (non-finite,
        beyond int32 counts or float32 range).
        """
        scale = self._scale(kind)
        value = float(value)
        if not math.isfinite(value):
            raise TurntableLimitError(f"{kind} {value} cannot be sent: not finite")
        if self.encoding == "int32":
            counts = round(value / scale)
            if not -2**31 <= counts < 2**31:
                raise TurntableLimitError(f"{kind} {value} is beyond the int32 register range "
                                          f"(+-{2**31 * scale:g} at {scale:g} per count)")
            raw = struct.pack(">i", counts)
        else:
            try:
                raw = struct.pack(">f", value)
            except OverflowError as exc:
                raise TurntableLimitError(f"{kind} {value} is beyond the float32 range") from exc
        words = [int.from_bytes(raw[0:2], "big"), int.from_bytes(raw[2:4], "big")]
        return words if self.word_order == "big" else words[::-1]

    def decode_value(self, registers: Sequence[int], kind: str = "angle") -> float:
        """Two registers -> position (deg) or rate (deg/s); `TurntableProtocolError` if malformed."""
        scale = self._scale(kind)
        words = check_registers(registers, 2, f"a 32-bit {kind}")
        if self.word_order == "little":
            words = words[::-1]
        raw = words[0].to_bytes(2, "big") + words[1].to_bytes(2, "big")
        if self.encoding == "int32":
            return struct.unpack(">i", raw)[0] * scale
        value = struct.unpack(">f", raw)[0]
        if not math.isfinite(value):
            raise TurntableProtocolError(f"float32 {kind} registers {list(registers)} are not a finite number",
                                         raw)
        return float(value)

    # -- status, modes, commands -----------------------------------------------------
    def encode_status(self, status: AxisStatus) -> int:
        word = 0
        for flag, bit in zip(_FLAGS, self.status_bits):
            if status & flag:
                word |= 1 << bit
        return word

    def decode_status(self, word: int) -> AxisStatus:
        status = AxisStatus(0)
        for flag, bit in zip(_FLAGS, self.status_bits):
            if word >> bit & 1:
                status |= flag
        return status

    def mode_code(self, mode: AxisMode) -> int:
        return self.mode_codes[MODES.index(AxisMode(mode).value)]

    def decode_mode(self, code: int) -> AxisMode:
        if code not in self.mode_codes:
            raise TurntableProtocolError(f"mode register value {code} is not a mode code "
                                         f"({dict(zip(MODES, self.mode_codes))})")
        return AxisMode(MODES[self.mode_codes.index(code)])

    def command_code(self, command: str) -> int:
        return command_code(COMMANDS, self.command_codes, command)

    def decode_command(self, code: int) -> str:
        """Command register value -> 'enable' ... 'abort' (ValueError for an unknown code)."""
        return decode_command(COMMANDS, self.command_codes, code)

    def fault_text(self, code: int) -> str:
        if code == 0:
            return ""
        text = self.fault_text_map.get(code)
        return f"fault code {code}" + (f" ({text})" if text else "")

    # -- the whole state --------------------------------------------------------------
    def decode_state(self, block: Sequence[int], time_s: float = 0.0) -> TableState:
        """The registers of `state_span` (in order) -> TableState; `TurntableProtocolError` if malformed."""
        start, count = self.state_span
        words = check_registers(block, count, "the state block")

        def at(address: int, n: int = 1) -> list[int]:
            return words[address - start:address - start + n]

        axes = []
        for k in range(3):
            angle = self.decode_value(at(self.actual_position[k], 2), "angle")
            rate = self.decode_value(at(self.actual_rate[k], 2), "rate")
            mode = self.decode_mode(at(self.mode[k])[0])
            axes.append(AxisState(angle, rate, mode, self.decode_status(at(self.status[k])[0])))
        return TableState(time_s, (axes[0], axes[1], axes[2]), self.fault_text(at(self.fault_code)[0]))

    def encode_state(self, state: TableState, fault_code: int = 0) -> dict[int, int]:
        """TableState -> {address: register} for every state register (what a controller serves)."""
        out: dict[int, int] = {self.fault_code: int(fault_code) & 0xFFFF}
        for k, axis in enumerate(state.axes):
            out[self.status[k]] = self.encode_status(axis.status)
            out[self.mode[k]] = self.mode_code(axis.mode)
            for name, value, kind in (("actual_position", axis.angle_deg, "angle"),
                                      ("actual_rate", axis.rate_dps, "rate")):
                address = getattr(self, name)[k]
                out[address], out[address + 1] = self.encode_value(value, kind)
        return out

    def state_block(self, state: TableState, fault_code: int = 0, fill: Mapping[int, int] | None = None) -> list[int]:
        """The registers of `state_span` for `state` (gaps from `fill`, else 0)."""
        start, count = self.state_span
        values = self.encode_state(state, fault_code)
        fill = fill or {}
        return [values.get(a, fill.get(a, 0)) for a in range(start, start + count)]


_FLAGS = (AxisStatus.ENABLED, AxisStatus.MOVING, AxisStatus.IN_POSITION, AxisStatus.FAULT, AxisStatus.ESTOP,
          AxisStatus.LIMIT)


def axis_mask(frames: Iterable[int]) -> int:
    """Frames (0-2) -> command_axes bit mask (bit 0 outer, bit 1 middle, bit 2 inner)."""
    mask = 0
    for k in frames:
        mask |= 1 << k
    return mask


def mask_axes(mask: int) -> list[int]:
    """command_axes bit mask -> frames; 0 means all three. ValueError for bits beyond 2."""
    if not 0 <= mask <= 7:
        raise ValueError(f"axis mask {mask:#x} has bits beyond the three axes")
    return [0, 1, 2] if mask == 0 else [k for k in range(3) if mask >> k & 1]


def contiguous_runs(values: Mapping[int, int]) -> list[tuple[int, list[int]]]:
    """{address: register} -> [(first address, [registers...]), ...] of consecutive addresses."""
    runs: list[tuple[int, list[int]]] = []
    for address in sorted(values):
        if runs and runs[-1][0] + len(runs[-1][1]) == address:
            runs[-1][1].append(values[address])
        else:
            runs.append((address, [values[address]]))
    return runs


# -- helpers (also the chamber's register map's) ------------------------------------------
def check_registers(registers: Sequence[int], count: int, what: str) -> list[int]:
    try:
        words = list(registers)
    except TypeError as exc:
        raise TurntableProtocolError(f"{what}: expected {count} registers, got {registers!r}") from exc
    if len(words) != count:
        raise TurntableProtocolError(f"{what}: expected {count} registers, got {len(words)}")
    for w in words:
        if isinstance(w, bool) or not isinstance(w, int) or not 0 <= w <= 0xFFFF:
            raise TurntableProtocolError(f"{what}: {w!r} is not a 16-bit register value")
    return words


def map_no_unknown(d: Mapping[str, Any], known: set[str], source: str, prefix: str) -> None:
    for key in d:
        if key not in known:
            raise RegisterMapError(f"{source}: unknown key {prefix}{key} (known: {', '.join(sorted(known))})")


def map_table(value: Any, source: str, key: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise RegisterMapError(f"{source}: {key} must be a table, got {value!r}")
    return value


def map_int(value: Any, source: str, key: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise RegisterMapError(f"{source}: {key} must be an integer, got {value!r}")
    if not lo <= value <= hi:
        raise RegisterMapError(f"{source}: {key} must be {lo}-{hi}, got {value}")
    return value


def check_code_tables(codes: Any, source: str, tables: Sequence[tuple[str, Sequence[str], int]]) -> None:
    """Each `(key, names, highest)` table of `codes` (a register map's status bits, command codes, ...): one
    integer 0..highest per name, all distinct; command codes never 0 (a command register reads 0 when idle)."""
    for key, names, hi in tables:
        values = getattr(codes, key)
        if not isinstance(values, tuple) or len(values) != len(names):
            raise RegisterMapError(f"{source}: {key} needs {len(names)} entries ({', '.join(names)})")
        for name, value in zip(names, values):
            map_int(value, source, f"{key}.{name}", 0, hi)
        if len(set(values)) != len(values):
            raise RegisterMapError(f"{source}: {key} must be distinct, got {dict(zip(names, values))}")
    if 0 in getattr(codes, "command_codes", ()):
        raise RegisterMapError(f"{source}: command_codes: 0 means 'no command' and cannot be a command code")


def map_code_tables(d: Mapping[str, Any], defaults: Any, source: str,
                    tables: Sequence[tuple[str, Sequence[str], int]]) -> dict[str, tuple[int, ...]]:
    """The code tables (`check_code_tables`'s `tables`) that configuration `d` gives, as field -> tuple, each
    entry it leaves out kept from `defaults` (the map class: its defaults)."""
    out = {}
    for key, names, hi in tables:
        if key in d:
            table = map_table(d[key], source, key)
            map_no_unknown(table, set(names), source, f"{key}.")
            current = list(getattr(defaults, key))
            for i, name in enumerate(names):
                if name in table:
                    current[i] = map_int(table[name], source, f"{key}.{name}", 0, hi)
            out[key] = tuple(current)
    return out


def command_code(commands: Sequence[str], codes: Sequence[int], command: str) -> int:
    """The code of `command` (one of `commands`) in the register map's `codes`; ValueError for another."""
    if command not in commands:
        raise ValueError(f"command must be one of {tuple(commands)}, got {command!r}")
    return codes[list(commands).index(command)]


def decode_command(commands: Sequence[str], codes: Sequence[int], code: int) -> str:
    """Command register value -> its name in `commands` (ValueError for a code not in `codes`)."""
    if code not in codes:
        raise ValueError(f"command code {code} is not one of {dict(zip(commands, codes))}")
    return commands[list(codes).index(code)]


def map_number(value: Any, source: str, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RegisterMapError(f"{source}: {key} must be a finite number, got {value!r}")
    return float(value)


def _axis_addresses(value: Any, source: str, key: str) -> tuple[int, int, int]:
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 3:
        raise RegisterMapError(f"{source}: {key} must be three addresses (outer, middle, inner), got {value!r}")
    outer, middle, inner = (map_int(v, source, f"{key}[{k}]", 0, 65535) for k, v in enumerate(value))
    return outer, middle, inner


__all__ = ["RegisterMap", "RegisterMapError", "axis_mask", "mask_axes",
           "contiguous_runs", "MAX_READ_REGISTERS", "check_code_tables",
           "check_registers", "map_int", "map_number", "map_table", "map_no_unknown", "CODE_TABLES", "command_code",
           "decode_command", "map_code_tables"]

