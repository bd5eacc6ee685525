"""A thermal plan: the calibration schedules run at each chamber temperature, each block after a soak.

`compile_thermal_plan` compiles one block per temperature: a `SetTemperatureStep` (the
chamber to the setpoint), a `SoakStep` (wait for the IMU's temperature to settle), then
the calibration's own steps (`compile_plan`, from where the table is) with their units
prefixed by the block ("T2-P03"), so that one log holds every temperature's calibration
and each is told apart by its units. Procedures are data: the chamber steps are records
like the moves and dwells, and the sequencer runs them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from bench.plan.compiler import CompiledPlan, PlanError, PlanTiming, compile_plan
from bench.plan.steps import DwellStep, MoveStep, SetTemperatureStep, SoakStep, Step, TurnStep, thermal_prefix
from drivers.turntable.base import TurntableLimits
from schedules import Schedule

#: a chamber's air changes this fast without a ramp (for the estimate only), degC/min
NOMINAL_AIR_RATE_C_PER_MIN = 2.0
#: the temperature the chamber and the IMU are assumed to start at (for the estimate only), degC
START_C = 23.0


@dataclass(frozen=True)
class SoakCriterion:
    """When the IMU is soaked: the chamber air within `chamber_tolerance_c` of the setpoint, then the IMU's
    temperature rate (least-squares slope over `rate_window_s`) below `rate_c_per_min` for `stable_min`
    minutes; a soak longer than `max_soak_min` is a fault."""

    rate_c_per_min: float = 0.05
    stable_min: float = 10.0
    max_soak_min: float = 240.0
    chamber_tolerance_c: float = 1.0
    rate_window_s: float = 60.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise PlanError(f"soak {f.name} must be a positive number, got {value!r}")
        if self.stable_min * 60.0 > self.max_soak_min * 60.0:
            raise PlanError(f"soak stable_min {self.stable_min:g} exceeds max_soak_min {self.max_soak_min:g}")


@dataclass(frozen=True)
class ThermalPlan:
    """[plan] temperatures_c and its soak: the chamber setpoints in the order they are visited."""

    temperatures_c: tuple[float, ...]
    soak: SoakCriterion = SoakCriterion()
    ramp_c_per_min: float | None = None      # None: the controller's own ramp

    def __post_init__(self) -> None:
        if len(self.temperatures_c) < 1:
            raise PlanError("temperatures_c needs one temperature at least")
        if not all(math.isfinite(t) for t in self.temperatures_c):
            raise PlanError(f"temperatures_c must be finite, got {list(self.temperatures_c)}")


def _end_deg(steps: list[Step], start: tuple[float, float, float]) -> tuple[float, float, float]:
    """Where the table is after `steps` (absolute controller angles)."""
    for step in reversed(steps):
        if isinstance(step, TurnStep):
            return step.end_deg
        if isinstance(step, (MoveStep, DwellStep)):
            a, b, c = step.target_deg
            return a, b, c
    return start


def compile_thermal_plan(positions: Schedule | None, rotations: Schedule | None, timing: PlanTiming,
                         thermal: ThermalPlan, *, start_deg=(0.0, 0.0, 0.0), limits: TurntableLimits | None = None,
                         order: str = "optimal", start_c: float = START_C) -> CompiledPlan:
    """Per temperature: set the chamber, soak, then the calibration steps (units "T<k>-<unit>").

    `start_c` is the temperature the chamber is assumed to start at (only the soak estimates use it).
    """
    steps: list[Step] = []
    x, y, z = (float(a) for a in start_deg)
    here = (x, y, z)
    previous_c = start_c
    total = lower = listed = 0.0
    for k, setpoint_c in enumerate(thermal.temperatures_c, start=1):
        block = thermal_prefix(k)
        soak = thermal.soak
        rate = thermal.ramp_c_per_min or NOMINAL_AIR_RATE_C_PER_MIN
        soak_s = min(abs(setpoint_c - previous_c) / rate * 60.0 + soak.stable_min * 60.0, soak.max_soak_min * 60.0)
        steps.append(SetTemperatureStep(index=len(steps), unit=block, temperature_index=k, setpoint_c=float(setpoint_c),
                                        ramp_c_per_min=thermal.ramp_c_per_min, estimated_s=0.0))
        steps.append(SoakStep(index=len(steps), unit=block, temperature_index=k, setpoint_c=float(setpoint_c),
                              rate_c_per_min=soak.rate_c_per_min, stable_s=soak.stable_min * 60.0,
                              max_soak_s=soak.max_soak_min * 60.0, chamber_tolerance_c=soak.chamber_tolerance_c,
                              rate_window_s=soak.rate_window_s, estimated_s=soak_s))
        part = compile_plan(positions, rotations, timing, start_deg=here, limits=limits, order=order)
        for step in part.steps:
            steps.append(dataclasses.replace(step, index=len(steps), unit=f"{block}-{step.unit}"))
        here = _end_deg(list(part.steps), here)
        total += soak_s + part.estimated_total_s
        lower += soak_s + part.lower_bound_s
        listed += soak_s + part.listed_total_s
        previous_c = setpoint_c
    return CompiledPlan(tuple(steps), timing, order, total, lower, listed)


def block_observation_units(steps: tuple[Step, ...], temperature_index: int) -> set[str]:
    """The observation units (dwells, turns) of block `temperature_index` of a thermal plan."""
    prefix = thermal_prefix(temperature_index) + "-"
    return {s.unit for s in steps if isinstance(s, (DwellStep, TurnStep)) and s.unit.startswith(prefix)}


__all__ = ["NOMINAL_AIR_RATE_C_PER_MIN", "START_C", "SoakCriterion", "ThermalPlan", "block_observation_units",
           "compile_thermal_plan"]
