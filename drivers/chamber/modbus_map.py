"""The chamber's generic Modbus map: a pure codec (no I/O): register map, scaled int16 values, state decoding.

`ChamberRegisterMap` (preset "generic") says where a controller keeps its quantities
(0-based holding registers as they go on the wire), their scale (signed int16 counts of
`temperature_scale_c`, default 0.1 degC) and what the status bits, alarm bits and command
codes mean. Its default numbers are this project's own and match no controller: they
are for a controller described register by register in a configuration. The shipped
map of a real controller is `drivers.chamber.watlow_f4` (the default). The client
(`drivers.chamber.modbus`) and the simulator serve the same map; docs/hardware/chamber.md
documents both. Configuration is read with the turntable map's checks
(`drivers.turntable.modbus_map`), its errors named for the chamber.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Iterable, Mapping, Sequence

from drivers.chamber.base import ChamberAlarms, ChamberState
from drivers.errors import (
    ChamberConfigError,
    ChamberLimitError,
    ChamberProtocolError,
    DeviceProtocolError,
)
from drivers.turntable.modbus_map import (
    MAX_READ_REGISTERS,
    RegisterMapError,
    check_code_tables,
    check_registers,
    command_code,
    decode_command,
    map_code_tables,
    map_int,
    map_no_unknown,
    map_number,
    map_table,
)

REGISTERS = ("process_value", "setpoint", "ramp_rate", "status", "alarms", "command")
READ_ONLY = ("process_value", "status", "alarms")
#: what one state poll reads
STATE_REGISTERS = ("process_value", "setpoint", "ramp_rate", "status", "alarms")
STATUS_BITS = ("running",)
ALARM_BITS = ("over_temperature", "under_temperature", "door_open", "sensor_fault", "equipment_fault")
COMMANDS = ("run", "stop", "clear_alarms")
#: the code tables of a map (field, entry names, highest value), as `check_code_tables` takes them
CODE_TABLES = (("status_bits", STATUS_BITS, 15), ("alarm_bits", ALARM_BITS, 15), ("command_codes", COMMANDS, 65535))
_ALARM_FLAGS = (ChamberAlarms.OVER_TEMPERATURE, ChamberAlarms.UNDER_TEMPERATURE, ChamberAlarms.DOOR_OPEN,
                ChamberAlarms.SENSOR_FAULT, ChamberAlarms.EQUIPMENT_FAULT)
#: registers closer than this are read in one request (the few unused ones between them are read too)
MAX_GAP = 8
NO_REGISTER = -1
GENERIC = "generic"


class ChamberMapError(ChamberConfigError):
    """A chamber register map (configuration) that cannot describe a controller; the message names the key."""


@dataclass(frozen=True)
class ChamberRegisterMap:
    """Where a chamber controller keeps its quantities and how it encodes them.

    Temperatures (process value, setpoint) are signed int16 counts of `temperature_scale_c`
    degC; the ramp rate is counts of `ramp_scale_c_per_min` degC/min (0 = no ramp).
    `ramp_rate` = -1: the controller has no ramp register.
    """

    unit: int = 1
    temperature_scale_c: float = 0.1
    ramp_scale_c_per_min: float = 0.1
    process_value: int = 100
    alarms: int = 102
    status: int = 103
    command: int = 200
    setpoint: int = 300
    ramp_rate: int = 301
    # bit positions of RUNNING in the status word
    status_bits: tuple[int] = (0,)
    # bit positions of over/under temperature, door open, sensor fault, equipment fault in the alarm word
    alarm_bits: tuple[int, int, int, int, int] = (0, 1, 2, 3, 4)
    # command register codes for run, stop, clear_alarms
    command_codes: tuple[int, int, int] = (1, 2, 3)
    source: str = field(default="<generic>", compare=False)

    preset: ClassVar[str] = "generic"

    def __post_init__(self) -> None:
        try:
            self._validate()
        except RegisterMapError as exc:
            raise ChamberMapError(str(exc)) from exc

    @classmethod
    def default(cls) -> "ChamberRegisterMap":
        """The generic map's documented numbers (docs/hardware/chamber.md; the dialect's default is the F4P's map)."""
        return cls()

    @property
    def has_ramp(self) -> bool:
        return self.ramp_rate != NO_REGISTER

    # -- configuration --------------------------------------------------------------
    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "<dict>") -> "ChamberRegisterMap":
        """A map from configuration (a TOML table); missing keys keep the default's value.

        Raises `ChamberMapError` naming `source` and the offending key.
        """
        try:
            return cls._from_dict(d, source)
        except RegisterMapError as exc:
            raise ChamberMapError(str(exc)) from exc

    @classmethod
    def _from_dict(cls, d: Mapping[str, Any], source: str) -> "ChamberRegisterMap":
        if not isinstance(d, Mapping):
            raise RegisterMapError(f"{source}: a register map must be a table, got {type(d).__name__}")
        map_no_unknown(d, {"preset", "unit", "temperature_scale_c", "ramp_scale_c_per_min", "registers", "status_bits",
                           "alarm_bits", "command_codes"}, source, "")
        if d.get("preset", GENERIC) != GENERIC:
            raise RegisterMapError(f"{source}: preset: this is the {GENERIC!r} map, got {d['preset']!r}")
        kw: dict[str, Any] = {"source": source}
        if "unit" in d:
            kw["unit"] = map_int(d["unit"], source, "unit", 0, 255)
        for key in ("temperature_scale_c", "ramp_scale_c_per_min"):
            if key in d:
                kw[key] = map_number(d[key], source, key)
        if "registers" in d:
            regs = map_table(d["registers"], source, "registers")
            map_no_unknown(regs, set(REGISTERS), source, "registers.")
            for name, value in regs.items():
                kw[name] = map_int(value, source, f"registers.{name}", NO_REGISTER if name == "ramp_rate" else 0,
                                   65535)
        kw.update(map_code_tables(d, cls, source, CODE_TABLES))
        return cls(**kw)

    def to_dict(self) -> dict[str, Any]:
        """The map as a TOML-shaped table that `from_dict` reads back."""
        return {"preset": GENERIC, "unit": self.unit, "temperature_scale_c": self.temperature_scale_c,
                "ramp_scale_c_per_min": self.ramp_scale_c_per_min,
                "registers": {name: getattr(self, name) for name in REGISTERS},
                "status_bits": dict(zip(STATUS_BITS, self.status_bits)),
                "alarm_bits": dict(zip(ALARM_BITS, self.alarm_bits)),
                "command_codes": dict(zip(COMMANDS, self.command_codes))}

    def _validate(self) -> None:
        src = self.source
        map_int(self.unit, src, "unit", 0, 255)
        for key in ("temperature_scale_c", "ramp_scale_c_per_min"):
            if not map_number(getattr(self, key), src, key) > 0:
                raise RegisterMapError(f"{src}: {key} must be positive, got {getattr(self, key)}")
        owner: dict[int, str] = {}
        for name in REGISTERS:
            address = map_int(getattr(self, name), src, f"registers.{name}",
                              NO_REGISTER if name == "ramp_rate" else 0, 65535)
            if address == NO_REGISTER:
                continue
            if address in owner:
                raise RegisterMapError(f"{src}: registers.{name} at {address} overlaps registers.{owner[address]}")
            owner[address] = name
        check_code_tables(self, src, CODE_TABLES)

    # -- layout -----------------------------------------------------------------------
    def register_names(self) -> dict[int, str]:
        """address -> name for every register the map uses."""
        return {getattr(self, name): name for name in REGISTERS if getattr(self, name) != NO_REGISTER}

    @property
    def state_reads(self) -> list[tuple[int, int]]:
        """(first address, count) of the reads that cover the state registers (`grouped_reads`)."""
        return grouped_reads(getattr(self, n) for n in STATE_REGISTERS if getattr(self, n) != NO_REGISTER)

    #: the generic map has no settings to read at connect (`WatlowF4Map` has)
    settings_reads: ClassVar[tuple[tuple[int, int], ...]] = ()
    #: what stopping may leave on (nothing the generic map knows of)
    stop_caveat: ClassVar[str] = ""

    def configure(self, blocks: Sequence[Sequence[int]]) -> "ChamberRegisterMap":
        return self

    # -- values -------------------------------------------------------------------------
    def _encode(self, value: float, scale: float, what: str, unit: str, low: int = -0x8000) -> int:
        if not math.isfinite(value):
            raise ChamberLimitError(f"{what} {value} cannot be sent: not finite")
        counts = round(value / scale)
        if not low <= counts <= 0x7FFF:
            raise ChamberLimitError(f"{what} {value:g} {unit} is beyond the int16 register range "
                                    f"[{low * scale:g}, {0x7FFF * scale:g}] {unit} at {scale:g} per count")
        return counts & 0xFFFF

    def encode_temperature(self, value_c: float) -> int:
        """degC -> one register (signed int16 counts); ChamberLimitError when it cannot carry the value."""
        return self._encode(value_c, self.temperature_scale_c, "temperature", "degC")

    def decode_temperature(self, word: int) -> float:
        return signed_word(word) * self.temperature_scale_c

    def encode_ramp(self, ramp_c_per_min: float) -> int:
        return self._encode(ramp_c_per_min, self.ramp_scale_c_per_min, "ramp rate", "degC/min", low=0)

    def decode_ramp(self, word: int) -> float:
        counts = signed_word(word)
        if counts < 0:
            raise ChamberProtocolError(f"ramp rate register holds {counts} (negative)")
        return counts * self.ramp_scale_c_per_min

    def encode_alarms(self, alarms: ChamberAlarms) -> int:
        return sum(1 << bit for flag, bit in zip(_ALARM_FLAGS, self.alarm_bits) if alarms & flag)

    def decode_alarms(self, word: int) -> tuple[ChamberAlarms, str]:
        """Alarm word -> (flags, text naming bits the map does not define)."""
        alarms = ChamberAlarms(0)
        for flag, bit in zip(_ALARM_FLAGS, self.alarm_bits):
            if word >> bit & 1:
                alarms |= flag
        unknown = [bit for bit in range(16) if word >> bit & 1 and bit not in self.alarm_bits]
        return alarms, (", ".join(f"alarm bit {bit}" for bit in unknown))

    def encode_status(self, running: bool) -> int:
        return (1 << self.status_bits[0]) if running else 0

    def decode_status(self, word: int) -> bool:
        return bool(word >> self.status_bits[0] & 1)

    # -- what the client sends ---------------------------------------------------------------
    def check_demand(self, setpoint_c: float, ramp_c_per_min: float | None) -> None:
        """ChamberLimitError, before anything is sent, for a value the int16 registers cannot carry."""
        self.encode_temperature(setpoint_c)
        if ramp_c_per_min is not None and self.has_ramp:
            self.encode_ramp(ramp_c_per_min)

    def setpoint_writes(self, setpoint_c: float) -> list[tuple[int, int, str]]:
        return [(self.setpoint, self.encode_temperature(setpoint_c), f"setpoint {setpoint_c:g} degC")]

    def ramp_writes(self, ramp_c_per_min: float) -> list[tuple[int, int, str]]:
        return [(self.ramp_rate, self.encode_ramp(ramp_c_per_min), f"ramp rate {ramp_c_per_min:g} degC/min")]

    def command_writes(self, command: str) -> list[tuple[int, int, str]]:
        code = self.command_code(command)
        return [(self.command, code, f"{command} (command {code})")]

    def command_code(self, command: str) -> int:
        return command_code(COMMANDS, self.command_codes, command)

    def decode_command(self, code: int) -> str:
        """Command register value -> 'run', 'stop' or 'clear_alarms' (ValueError for an unknown code)."""
        return decode_command(COMMANDS, self.command_codes, code)

    # -- the whole state -------------------------------------------------------------------
    def decode_state(self, blocks: Sequence[Sequence[int]], time_s: float = 0.0) -> ChamberState:
        """The registers of `state_reads` (one list per read, in order) -> ChamberState;
        ChamberProtocolError if malformed."""
        words = read_words(self.state_reads, blocks, "state")
        alarms, unknown = self.decode_alarms(words[self.alarms])
        ramp = self.decode_ramp(words[self.ramp_rate]) if self.has_ramp else None
        return ChamberState(time_s, self.decode_temperature(words[self.process_value]),
                            self.decode_temperature(words[self.setpoint]), ramp,
                            self.decode_status(words[self.status]), alarms, unknown)

    def encode_state(self, state: ChamberState) -> dict[int, int]:
        """ChamberState -> {address: register} for every state register (what a controller serves)."""
        out = {self.process_value: self.encode_temperature(state.temperature_c),
               self.setpoint: self.encode_temperature(state.setpoint_c),
               self.status: self.encode_status(state.running), self.alarms: self.encode_alarms(state.alarms)}
        if self.has_ramp:
            out[self.ramp_rate] = self.encode_ramp(state.ramp_c_per_min or 0.0)
        return out


def grouped_reads(addresses: Iterable[int]) -> list[tuple[int, int]]:
    """(first address, count) of the reads that cover `addresses`: registers at most MAX_GAP apart share a
    read, and no read covers more than one Modbus read may."""
    reads: list[tuple[int, int]] = []
    for address in sorted(set(addresses)):
        if reads:
            start, count = reads[-1]
            if address - (start + count - 1) <= MAX_GAP and address - start < MAX_READ_REGISTERS:
                reads[-1] = (start, address - start + 1)
                continue
        reads.append((address, 1))
    return reads


def read_words(reads: Sequence[tuple[int, int]], blocks: Sequence[Sequence[int]], what: str) -> dict[int, int]:
    """address -> register of the blocks read by `reads` (one list per read, in order); ChamberProtocolError
    if malformed."""
    if len(blocks) != len(reads):
        raise ChamberProtocolError(f"the {what} needs {len(reads)} register blocks, got {len(blocks)}")
    words: dict[int, int] = {}
    for (start, count), block in zip(reads, blocks):
        try:
            checked = check_registers(block, count, f"the {what} block at {start}")
        except DeviceProtocolError as exc:       # the shared check's wording, under the chamber's name
            raise ChamberProtocolError(str(exc)) from exc
        words.update({start + i: w for i, w in enumerate(checked)})
    return words


def signed_word(word: int) -> int:
    if isinstance(word, bool) or not isinstance(word, int) or not 0 <= word <= 0xFFFF:
        raise ChamberProtocolError(f"{word!r} is not a 16-bit register value")
    return word - 0x10000 if word & 0x8000 else word


__all__ = ["ALARM_BITS", "COMMANDS", "ChamberMapError", "ChamberRegisterMap", "GENERIC", "MAX_GAP", "NO_REGISTER",
           "READ_ONLY", "REGISTERS", "STATE_REGISTERS", "STATUS_BITS", "grouped_reads", "read_words", "signed_word"]
