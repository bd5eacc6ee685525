"""The Watlow Series F4P's own Modbus registers for a chamber: a pure codec (no I/O).

Facts from the Watlow Series F4P User's Manual (chapter 9, "Communications": the registers
sorted by number and alphabetically; chapter 6 for ranges), in our words. Register numbers
are the manual's relative numbers, which are the 0-based addresses on the wire (the
manual's 40001-based absolute number minus 40001). docs/hardware/chamber.md tabulates them.

- Values are signed 16-bit integers with input 1's decimal places implied: register 606
  (0 to 3) says how many, so 234 reads 23.4 at one decimal and 2.34 at two. Temperatures
  are in the unit register 901 selects (0 degF, 1 degC); the bench converts to degC.
- Run/stop: the F4P is a set-point controller without profiles; its closed-loop switch is
  the auto/manual mode (200: 1 auto, 2 manual). The bench runs = auto, stops = manual;
  the power manual mode may hold is bounded by 452/453 (read at connect, `stop_caveat`).
- The ramp is the controller's ramp to set point: 1100 mode (0 off, 1 at startup, 2 at
  startup or a set point change), 1101 rate (1 to 999 counts, input 1's decimals),
  1102 its time base (0 per minute, 1 per hour).
- Alarms: 102 and 106 (alarm outputs 1 and 2: 0 off, 1 high, 2 low), 101 (input 1 error,
  0 none, 1 to 6 a named error), 210 (input 1 open loop, 0 off, 1 on); cleared by writing
  311, 312 and 331.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

from drivers.chamber.base import ChamberAlarms, ChamberLimits, ChamberState
from drivers.chamber.modbus_map import ChamberMapError, grouped_reads, read_words, signed_word
from drivers.errors import ChamberLimitError, ChamberProtocolError
from drivers.turntable.modbus_map import RegisterMapError, map_int, map_no_unknown, map_table

PRESET = "watlow-f4"

#: role -> the F4P's relative register number (manual chapter 9; the section each comes from in the docstring)
REGISTERS: dict[str, int] = {
    "process_value": 100,       # Input 1 Value (Status), read only
    "input_error": 101,         # Input 1 Error (Status): 0 none, 1-6 an error
    "alarm_1": 102,             # Alarm 1 (Status): 0 off, 1 high, 2 low
    "alarm_2": 106,             # Alarm 2 (Status): same enumeration
    "mode": 200,                # Auto/Manual Mode (Status): 1 auto, 2 manual
    "open_loop": 210,           # Input 1 Open Loop (Status): 0 off, 1 on
    "setpoint": 300,            # Set Point 1 (Main Page)
    "clear_input_error": 311,   # Clear Error Input 1 (key press simulation): write any value
    "clear_alarm_1": 312,       # Clear Alarm 1 (key press simulation): write any value
    "clear_alarm_2": 331,       # Clear Alarm 2 (key press simulation): write any value
    "max_transfer_heat": 452,   # Maximum Transfer Heat (System): 0-1000 tenths of % held on the switch to manual
    "max_transfer_cool": 453,   # Maximum Transfer Cool (System): -1000-0 tenths of %
    "setpoint_low_limit": 602,  # Set Point Low Limit, Analog Input 1
    "setpoint_high_limit": 603,  # Set Point High Limit, Analog Input 1
    "decimal": 606,             # Decimal, Analog Input 1: 0-3 decimal places
    "units": 901,               # degF or degC (System): 0 degF, 1 degC
    "ramp_mode": 1100,          # Ramp to Set Point Mode: 0 off, 1 startup, 2 startup or change
    "ramp_rate": 1101,          # Ramp to Set Point Rate: 1-999 counts at input 1's decimals
    "ramp_scale": 1102,         # Ramp to Set Point Scale: 0 per minute, 1 per hour
}
READ_ONLY = ("process_value", "input_error", "alarm_1", "alarm_2", "open_loop")
#: what one state poll reads, and what the connection reads once (the settings that scale the values)
STATE = ("process_value", "input_error", "alarm_1", "alarm_2", "mode", "open_loop", "setpoint", "ramp_mode",
         "ramp_rate", "ramp_scale")
SETTINGS = ("max_transfer_heat", "max_transfer_cool", "setpoint_low_limit", "setpoint_high_limit", "decimal",
            "units")

MODE_AUTO, MODE_MANUAL = 1, 2
ALARM_OFF, ALARM_HIGH, ALARM_LOW = 0, 1, 2
RAMP_OFF, RAMP_ON_CHANGE = 0, 2
PER_MINUTE, PER_HOUR = 0, 1
RAMP_COUNTS = (1, 999)
#: the largest relative error a ramp rate may take from its rounding to counts (else it is refused)
RAMP_TOLERANCE = 0.05
UNITS_F, UNITS_C = 0, 1
#: Input 1 Error's enumeration (0 is none)
INPUT_ERRORS = {1: "A/D underflow", 2: "sensor under range", 3: "sensor over range", 4: "A/D overflow",
                5: "A/D timeout", 6: "open loop"}

#: every register number in the manual's numerical list (chapter 9), as inclusive ranges
F4P_REGISTERS: tuple[tuple[int, int], ...] = (
    (0, 5), (8, 10), (16, 17), (20, 21), (25, 25), (100, 103), (106, 107), (200, 201), (210, 210), (213, 213),
    (225, 225), (237, 237), (298, 305), (307, 309), (311, 316), (321, 322), (327, 327), (330, 334), (343, 343),
    (346, 346), (349, 349), (352, 353), (365, 365), (371, 372), (452, 454), (500, 505), (507, 507), (509, 515),
    (517, 517), (520, 525), (527, 527), (530, 535), (537, 537), (540, 545), (547, 547), (550, 557), (559, 565),
    (567, 567), (570, 575), (577, 577), (580, 585), (587, 587), (590, 595), (597, 597), (600, 608), (610, 618),
    (620, 628), (680, 685), (693, 695), (700, 712), (714, 729), (731, 733), (836, 837), (844, 844), (880, 885),
    (900, 901), (903, 904), (1060, 1067), (1100, 1102), (1140, 1141), (1300, 1300), (1302, 1303), (1306, 1308),
    (1315, 1319), (1330, 1333), (1400, 1415), (1500, 1501), (1504, 1506), (1513, 1515), (1531, 1532),
    (1601, 1613), (1624, 1627), (1629, 1632), (1910, 1919), (1922, 1923), (1925, 1927), (1951, 1951),
    (1961, 1964), (2600, 2605), (2607, 2607), (2610, 2615), (2617, 2617), (2620, 2625), (2627, 2627),
    (2630, 2635), (2637, 2637), (2640, 2645), (2647, 2647), (2650, 2655), (2657, 2657), (2660, 2665),
    (2667, 2667), (2670, 2675), (2677, 2677), (2680, 2685), (2687, 2687), (2690, 2695), (2697, 2697),
    (3000, 3006), (3010, 3016), (3020, 3026), (3030, 3036), (3050, 3053), (3060, 3063), (3070, 3078),
    (3200, 3219), (4501, 4517), (4521, 4537), (4541, 4557), (4561, 4577), (4581, 4597), (4601, 4617),
    (4621, 4637), (4641, 4657), (4661, 4677), (4681, 4697), (4701, 4717), (4721, 4737), (4741, 4757),
    (4761, 4777), (4781, 4797), (4801, 4817), (5506, 5574))
ABSOLUTE_OFFSET = 40001


def is_f4p_register(number: int) -> bool:
    """Whether `number` (relative) is in the F4P manual's register list."""
    return any(low <= number <= high for low, high in F4P_REGISTERS)


@dataclass(frozen=True)
class WatlowF4Map:
    """The F4P's registers (`REGISTERS`, overridable one by one with other F4P registers) and, once read from
    the controller (`configure`), the settings that scale its values: input 1's decimals, degF or degC and
    the set point limits."""

    unit: int = 1
    registers: Mapping[str, int] = field(default_factory=lambda: dict(REGISTERS))
    decimals: int | None = None             # None: not read yet (the client reads it at connect)
    fahrenheit: bool = False
    setpoint_limits_c: tuple[float, float] | None = None
    #: the most heat and cool power (%) manual mode may hold (Maximum Transfer Heat / Cool); None: not read
    transfer_power_pct: tuple[float, float] | None = None
    source: str = field(default="<watlow-f4>", compare=False)

    preset = PRESET
    has_ramp = True

    def __post_init__(self) -> None:
        try:
            map_int(self.unit, self.source, "unit", 0, 255)
            owner: dict[int, str] = {}
            for name, number in self.registers.items():
                if name not in REGISTERS:
                    raise RegisterMapError(f"{self.source}: unknown key registers.{name}")
                check_f4p_register(number, self.source, f"registers.{name}")
                if number in owner:
                    raise RegisterMapError(f"{self.source}: registers.{name}: {number} overlaps "
                                           f"registers.{owner[number]}")
                owner[number] = name
            if set(self.registers) != set(REGISTERS):
                raise RegisterMapError(f"{self.source}: registers must name every role ({', '.join(REGISTERS)})")
        except RegisterMapError as exc:
            raise ChamberMapError(str(exc)) from exc
        if self.decimals is not None and self.decimals not in range(4):
            raise ChamberProtocolError(f"input 1 decimal register holds {self.decimals} (0-3)")

    # -- configuration --------------------------------------------------------------
    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "<dict>") -> "WatlowF4Map":
        """`preset = "watlow-f4"`, `unit`, and `[registers]` overrides (each an F4P register, relative number)."""
        try:
            if not isinstance(d, Mapping):
                raise RegisterMapError(f"{source}: a register map must be a table, got {type(d).__name__}")
            map_no_unknown(d, {"preset", "unit", "registers"}, source, "")
            kw: dict[str, Any] = {"source": source}
            if "unit" in d:
                kw["unit"] = map_int(d["unit"], source, "unit", 0, 255)
            if "registers" in d:
                regs = map_table(d["registers"], source, "registers")
                map_no_unknown(regs, set(REGISTERS), source, "registers.")
                kw["registers"] = {**REGISTERS, **{name: map_int(value, source, f"registers.{name}", 0, 65535)
                                                   for name, value in regs.items()}}
        except RegisterMapError as exc:
            raise ChamberMapError(str(exc)) from exc
        return cls(**kw)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"preset": PRESET, "unit": self.unit}
        changed = {name: number for name, number in self.registers.items() if REGISTERS[name] != number}
        if changed:
            out["registers"] = changed
        return out

    def register_names(self) -> dict[int, str]:
        return {number: name for name, number in self.registers.items()}

    # -- the connection's settings ---------------------------------------------------------
    @property
    def settings_reads(self) -> list[tuple[int, int]]:
        return grouped_reads(self.registers[name] for name in SETTINGS)

    def configure(self, blocks: Sequence[Sequence[int]]) -> "WatlowF4Map":
        """This map with the controller's settings (the blocks of `settings_reads`)."""
        words = read_words(self.settings_reads, blocks, "settings")
        decimals, units = words[self.registers["decimal"]], words[self.registers["units"]]
        if units not in (UNITS_F, UNITS_C):
            raise ChamberProtocolError(f"the degF/degC register {self.registers['units']} holds {units} (0 or 1)")
        scaled = replace(self, decimals=decimals, fahrenheit=units == UNITS_F)
        low, high = (scaled.decode_temperature(words[self.registers[name]])
                     for name in ("setpoint_low_limit", "setpoint_high_limit"))
        heat, cool = (signed_word(words[self.registers[name]]) / 10.0
                      for name in ("max_transfer_heat", "max_transfer_cool"))
        return replace(scaled, setpoint_limits_c=(low, high), transfer_power_pct=(heat, cool))

    @property
    def stop_caveat(self) -> str:
        """What stopping (manual mode) may leave on: '' when the controller transfers 0 % heat and cool."""
        if not self.transfer_power_pct or self.transfer_power_pct == (0.0, 0.0):
            return ""
        heat, cool = self.transfer_power_pct
        return (f"manual mode may hold up to {heat:g} % heat and {cool:g} % cool power: the F4P's Maximum Transfer "
                f"Heat/Cool, registers {self.registers['max_transfer_heat']}/{self.registers['max_transfer_cool']}")

    def settings_image(self, limits: ChamberLimits) -> dict[int, int]:
        """What a controller with these settings serves in the settings registers (the simulator)."""
        r = self.registers
        return {r["max_transfer_heat"]: 0, r["max_transfer_cool"]: 0,      # manual mode: outputs off
                r["decimal"]: self._decimals(), r["units"]: UNITS_F if self.fahrenheit else UNITS_C,
                r["setpoint_low_limit"]: self.encode_temperature(limits.min_setpoint_c),
                r["setpoint_high_limit"]: self.encode_temperature(limits.max_setpoint_c)}

    # -- values ------------------------------------------------------------------------------
    def _decimals(self) -> int:
        if self.decimals is None:
            raise ChamberProtocolError("the F4P's decimal setting has not been read (connect first)")
        return self.decimals

    def _to_display(self, value_c: float) -> float:
        return value_c * 9.0 / 5.0 + 32.0 if self.fahrenheit else value_c

    def encode_temperature(self, value_c: float) -> int:
        """degC -> one register: counts of 10**-decimals in the controller's unit, signed 16-bit."""
        if not math.isfinite(value_c):
            raise ChamberLimitError(f"temperature {value_c} cannot be sent: not finite")
        counts = round(self._to_display(value_c) * 10 ** self._decimals())
        if not -0x8000 <= counts <= 0x7FFF:
            raise ChamberLimitError(f"temperature {value_c:g} degC is beyond the int16 register at "
                                    f"{self._decimals()} decimals")
        return counts & 0xFFFF

    def decode_temperature(self, word: int) -> float:
        value = signed_word(word) / 10 ** self._decimals()
        return (value - 32.0) * 5.0 / 9.0 if self.fahrenheit else value

    def ramp_words(self, ramp_c_per_min: float) -> tuple[int, int]:
        """degC/min (> 0) -> (rate counts, time base): of per minute and per hour, the one whose 1-999 counts
        carry the rate most closely (per minute on a tie); ChamberLimitError if neither comes within
        RAMP_TOLERANCE of it."""
        exact = ramp_c_per_min * (9.0 / 5.0 if self.fahrenheit else 1.0) * 10 ** self._decimals()
        fits = [(abs(round(counts) - counts) / counts, scale, round(counts))
                for scale, counts in ((PER_MINUTE, exact), (PER_HOUR, exact * 60.0))
                if RAMP_COUNTS[0] <= round(counts) <= RAMP_COUNTS[1]
                and abs(round(counts) - counts) <= RAMP_TOLERANCE * counts]
        if not fits:
            raise ChamberLimitError(f"ramp rate {ramp_c_per_min:g} degC/min does not fit the F4P's 1-999 counts "
                                    f"per minute or per hour at {self._decimals()} decimals (within "
                                    f"{RAMP_TOLERANCE:.0%})")
        _, scale, counts = min(fits)
        return counts, scale

    def decode_ramp(self, mode: int, counts: int, scale: int) -> float:
        """The ramp registers -> degC/min (0: ramping off)."""
        if mode == RAMP_OFF:
            return 0.0
        if mode not in (1, 2) or scale not in (PER_MINUTE, PER_HOUR):
            raise ChamberProtocolError(f"ramp to set point registers hold mode {mode}, scale {scale}")
        rate = signed_word(counts) / 10 ** self._decimals() / (60.0 if scale == PER_HOUR else 1.0)
        return rate * 5.0 / 9.0 if self.fahrenheit else rate

    # -- what the client sends -----------------------------------------------------------------
    def check_demand(self, setpoint_c: float, ramp_c_per_min: float | None) -> None:
        """ChamberLimitError, before anything is sent, for a demand the controller would refuse."""
        self.encode_temperature(setpoint_c)
        if self.setpoint_limits_c is not None:
            low, high = self.setpoint_limits_c
            if not low - 1e-9 <= setpoint_c <= high + 1e-9:
                raise ChamberLimitError(f"setpoint {setpoint_c:g} degC is outside the F4P's set point limits "
                                        f"[{low:g}, {high:g}] degC (registers {self.registers['setpoint_low_limit']}"
                                        f", {self.registers['setpoint_high_limit']})")
        if ramp_c_per_min:
            self.ramp_words(ramp_c_per_min)

    def setpoint_writes(self, setpoint_c: float) -> list[tuple[int, int, str]]:
        return [(self.registers["setpoint"], self.encode_temperature(setpoint_c), f"set point 1 {setpoint_c:g} degC")]

    def ramp_writes(self, ramp_c_per_min: float) -> list[tuple[int, int, str]]:
        r = self.registers
        if ramp_c_per_min == 0:
            return [(r["ramp_mode"], RAMP_OFF, "ramp to set point off")]
        counts, scale = self.ramp_words(ramp_c_per_min)
        what = f"ramp {ramp_c_per_min:g} degC/min"
        # the time base and the rate first, so the ramp is switched on at the new rate
        return [(r["ramp_scale"], scale, what), (r["ramp_rate"], counts, what), (r["ramp_mode"], RAMP_ON_CHANGE, what)]

    def command_writes(self, command: str) -> list[tuple[int, int, str]]:
        r = self.registers
        if command == "run":
            return [(r["mode"], MODE_AUTO, "auto mode (run)")]
        if command == "stop":
            return [(r["mode"], MODE_MANUAL, "manual mode (stop)")]
        if command == "clear_alarms":
            return [(r[name], 1, name.replace("_", " ")) for name in ("clear_input_error", "clear_alarm_1",
                                                                         "clear_alarm_2")]
        raise ValueError(f"unknown chamber command {command!r}")

    # -- the state ---------------------------------------------------------------------------------
    @property
    def state_reads(self) -> list[tuple[int, int]]:
        return grouped_reads(self.registers[name] for name in STATE)

    def decode_alarms(self, words: Mapping[str, int]) -> tuple[ChamberAlarms, str]:
        alarms, unknown = ChamberAlarms(0), []
        for name in ("alarm_1", "alarm_2"):
            value = words[name]
            if value == ALARM_HIGH:
                alarms |= ChamberAlarms.OVER_TEMPERATURE
            elif value == ALARM_LOW:
                alarms |= ChamberAlarms.UNDER_TEMPERATURE
            elif value != ALARM_OFF:
                unknown.append(f"{name.replace('_', ' ')} status {value}")
        error = words["input_error"]
        if error:
            alarms |= ChamberAlarms.SENSOR_FAULT
            if error not in INPUT_ERRORS:
                unknown.append(f"input 1 error {error}")
        if words["open_loop"]:
            alarms |= ChamberAlarms.EQUIPMENT_FAULT
        return alarms, ", ".join(unknown)

    def decode_state(self, blocks: Sequence[Sequence[int]], time_s: float = 0.0) -> ChamberState:
        by_address = read_words(self.state_reads, blocks, "state")
        words = {name: by_address[self.registers[name]] for name in STATE}
        if words["mode"] not in (MODE_AUTO, MODE_MANUAL):
            raise ChamberProtocolError(f"the auto/manual register {self.registers['mode']} holds {words['mode']} "
                                       "(1 auto, 2 manual)")
        alarms, unknown = self.decode_alarms(words)
        return ChamberState(time_s, self.decode_temperature(words["process_value"]),
                            self.decode_temperature(words["setpoint"]),
                            self.decode_ramp(words["ramp_mode"], words["ramp_rate"], words["ramp_scale"]),
                            words["mode"] == MODE_AUTO, alarms, unknown)

    def encode_state(self, state: ChamberState) -> dict[int, int]:
        """The state registers of a controller in `state` (the simulator; ramp registers excepted: they hold what
        was written)."""
        r, a = self.registers, state.alarms
        alarm_1 = ALARM_HIGH if a & ChamberAlarms.OVER_TEMPERATURE else (
            ALARM_LOW if a & ChamberAlarms.UNDER_TEMPERATURE else ALARM_OFF)
        alarm_2 = ALARM_LOW if a & ChamberAlarms.OVER_TEMPERATURE and a & ChamberAlarms.UNDER_TEMPERATURE \
            else ALARM_OFF
        return {r["process_value"]: self.encode_temperature(state.temperature_c),
                r["setpoint"]: self.encode_temperature(state.setpoint_c),
                r["mode"]: MODE_AUTO if state.running else MODE_MANUAL,
                r["alarm_1"]: alarm_1, r["alarm_2"]: alarm_2,
                r["input_error"]: 3 if a & ChamberAlarms.SENSOR_FAULT else 0,      # sensor over range
                r["open_loop"]: 1 if a & ChamberAlarms.EQUIPMENT_FAULT else 0}


def check_f4p_register(number: Any, source: str, key: str) -> int:
    """`number` if it is one of the F4P's registers (relative); a RegisterMapError naming `key` otherwise."""
    number = map_int(number, source, key, 0, 65535)
    if not is_f4p_register(number):
        hint = ""
        if ABSOLUTE_OFFSET <= number and is_f4p_register(number - ABSOLUTE_OFFSET):
            hint = f"; {number} looks 40001-based: give the relative number {number - ABSOLUTE_OFFSET}"
        raise RegisterMapError(f"{source}: {key}: the Watlow F4P has no register {number} "
                               f"(its manual's chapter 9 lists them{hint})")
    return number


__all__ = ["F4P_REGISTERS", "INPUT_ERRORS", "PRESET", "REGISTERS", "WatlowF4Map", "check_f4p_register",
           "is_f4p_register"]
