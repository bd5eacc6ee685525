"""Step records: what a compiled calibration plan is made of (procedures are data).

A plan compiles (`bench.plan.compiler.compile_plan`) to a flat tuple of these small frozen
records; the sequencer executes them one by one. Angles in `target_*` fields are the
controller's absolute angles (multi-turn, chosen nearest to where the table is);
`angles_deg`/`start_deg` are the schedule's nominal angles in [0, 360). Every step
belongs to one *unit*: the label of the observation it serves ("P03" = the third
position of the position schedule as listed, "R02" = the second rotation). A unit is
complete when its observation step (`DwellStep` or `TurnStep`) has finished; resume
skips complete units and redoes the moves of the rest.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal, Union

from bench.model.kinematics import FRAMES
from schedules.loader import Direction, Frame


@dataclass(frozen=True, kw_only=True)
class MoveStep:
    """Move all three axes to absolute angles at `rate_dps` and wait until in position."""

    index: int
    unit: str
    target_deg: tuple[float, float, float]
    rate_dps: float
    estimated_s: float
    kind: Literal["move"] = "move"


@dataclass(frozen=True, kw_only=True)
class SettleStep:
    """Stay at rest for `duration_s` (data recorded, not used by the solver)."""

    index: int
    unit: str
    duration_s: float
    estimated_s: float
    kind: Literal["settle"] = "settle"


@dataclass(frozen=True, kw_only=True)
class DwellStep:
    """Record the IMU at rest for `dwell_s`: one position observation."""

    index: int
    unit: str                                # also the observation label, e.g. "P03"
    schedule: str                            # schedule name, e.g. "optimal-24"
    schedule_index: int                      # 0-based index in the schedule as listed
    angles_deg: tuple[float, float, float]   # nominal schedule angles
    target_deg: tuple[float, float, float]   # absolute controller angles (where the table is)
    dwell_s: float
    estimated_s: float
    kind: Literal["dwell"] = "dwell"


@dataclass(frozen=True, kw_only=True)
class TurnStep:
    """Rest `rest_s`, turn one frame N whole revolutions rest to rest, rest `rest_s`: one rotation observation.

    CCW (a positive right-handed rotation about the frame axis) *decreases* the
    controller angle by 360*N deg (docs/explanation/model.md#frame-rotations): `end_deg` says where it ends.
    """

    index: int
    unit: str                                # also the observation label, e.g. "R02"
    schedule: str
    schedule_index: int
    start_deg: tuple[float, float, float]    # nominal initial state
    target_deg: tuple[float, float, float]   # absolute controller angles at the start
    frame: Frame
    direction: Direction
    revolutions: int
    rate_dps: float
    accel_dps2: float
    rest_s: float
    estimated_s: float
    kind: Literal["turn"] = "turn"

    @property
    def frame_index(self) -> int:
        return FRAMES.index(self.frame)

    @property
    def end_deg(self) -> tuple[float, float, float]:
        end = list(self.target_deg)
        end[self.frame_index] += (-360.0 if self.direction == "ccw" else 360.0) * self.revolutions
        return end[0], end[1], end[2]


@dataclass(frozen=True, kw_only=True)
class SetTemperatureStep:
    """Send the chamber to `setpoint_c` (at `ramp_c_per_min`; None: the controller's ramp) and run it.

    `temperature_index` is the 1-based block of a thermal plan: the calibration units of the
    block are labelled with its prefix (`thermal_prefix`), e.g. "T2-P03".
    """

    index: int
    unit: str                                # "T2": the block's own unit
    temperature_index: int
    setpoint_c: float
    ramp_c_per_min: float | None
    estimated_s: float
    kind: Literal["set_temperature"] = "set_temperature"


@dataclass(frozen=True, kw_only=True)
class SoakStep:
    """Wait until the IMU's temperature is steady: the chamber air within `chamber_tolerance_c` of the
    setpoint, then the IMU's temperature rate below `rate_c_per_min` for `stable_s`; at most `max_soak_s`
    (then `SoakTimeout`, a fault). The decision is on the IMU's own temperature, never the chamber's."""

    index: int
    unit: str
    temperature_index: int
    setpoint_c: float
    rate_c_per_min: float
    stable_s: float
    max_soak_s: float
    chamber_tolerance_c: float
    rate_window_s: float
    estimated_s: float
    kind: Literal["soak"] = "soak"


Step = Union[MoveStep, SettleStep, DwellStep, TurnStep, SetTemperatureStep, SoakStep]
#: what a step is (each step class's `kind`)
StepKind = Literal["move", "settle", "dwell", "turn", "set_temperature", "soak"]
OBSERVATION_KINDS: tuple[StepKind, ...] = ("dwell", "turn")
#: step kinds that drive the thermal chamber
CHAMBER_KINDS: tuple[StepKind, ...] = ("set_temperature", "soak")


def thermal_prefix(temperature_index: int) -> str:
    """The unit label of block k of a thermal plan ("T2"); its calibration units are "T2-P03", "T2-R01"."""
    return f"T{temperature_index}"


#: the digits of a temperature block's number in a unit label ("T12-P03")
MAX_BLOCK_DIGITS = 6


def thermal_block(unit: str) -> int | None:
    """The 1-based temperature block of a unit label ("T2-P03" and "T2" -> 2), None outside a thermal plan."""
    head = unit.split("-", 1)[0]
    # ASCII digits only ("T²" is no block: str.isdigit takes it) and a few of them (a label from a log is hostile)
    if 2 <= len(head) <= 1 + MAX_BLOCK_DIGITS and head[0] == "T" and head[1:].isascii() and head[1:].isdigit():
        return int(head[1:])
    return None


def step_to_dict(step: Step) -> dict:
    """JSON-able description of a step (for events, logs and --dry-run)."""
    out = {k: (list(v) if isinstance(v, tuple) else v) for k, v in step.__dict__.items()}
    if isinstance(step, TurnStep):
        out["end_deg"] = list(step.end_deg)
    return out


_STEP_TYPES = {cls.__dataclass_fields__["kind"].default: cls
               for cls in (MoveStep, SettleStep, DwellStep, TurnStep, SetTemperatureStep, SoakStep)}


def step_from_dict(d: dict) -> Step:
    """Inverse of `step_to_dict` (ValueError/KeyError/TypeError on a malformed dict)."""
    if not isinstance(d, dict):
        raise TypeError(f"a step must be an object, got {type(d).__name__}")
    cls: type[Step] | None = _STEP_TYPES.get(d.get("kind"))
    if cls is None:
        raise ValueError(f"unknown step kind {d.get('kind')!r}")
    names = [f.name for f in dataclasses.fields(cls)]
    missing = [n for n in names if n not in d and n != "kind"]
    if missing:
        raise KeyError(f"{d.get('kind')} step lacks {', '.join(missing)}")
    values: dict[str, Any] = {n: tuple(d[n]) if isinstance(d[n], list) else d[n] for n in names if n in d}
    return cls(**values)
