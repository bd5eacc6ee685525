"""Duration estimates of a compiled plan for the equipment that runs it, without changing the plan.

A compiled plan (`bench.plan.compiler`) carries one estimate per step, made with `[plan]`'s
profile: a real controller's move and turn accelerations and its command latency. Those
estimates are part of the plan and of its log (a resumed run compares them) and stay as they
are. What a run *will take* depends on who runs it: the simulated controller moves every axis at
its table's acceleration limit and answers at once, and a soak lasts until the IMU itself has
settled, not only until the chamber air has arrived. `retime(steps, profile)` re-estimates
every step for a `TimingProfile` (built from the configuration by `bench.run.timing`); the
dry-run, the progress display and `bench check-table` print these.

The soak model (`SoakModel`): the chamber's working setpoint ramps at the step's ramp (or the
profile's when the plan names none; none at all: it steps), the air follows it as a first-order
lag with its heating and cooling rate limits (a time constant of 0: the air is the working
setpoint), the IMU's case follows the air as a first-order lag. The soak ends as
`bench.run.soak.SoakTracker` decides it: the air within the tolerance of the setpoint, then the
IMU's rate over the rate window below the threshold for the stable time (at most the maximum).
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass
from typing import Sequence

from bench.model.motion import trapezoid_timing
from bench.plan.steps import DwellStep, MoveStep, SetTemperatureStep, SettleStep, SoakStep, Step, TurnStep

_EPS_DEG = 1e-9


@dataclass(frozen=True)
class SoakModel:
    """How the chamber air and the IMU's case reach a setpoint (for the soak estimates).

    `ramp_c_per_min`: the working setpoint's rate when the step names no ramp (None: it steps);
    `air_time_constant_s`: the air's lag behind the working setpoint (0: none), its rate at most
    `max_heat_c_per_min` up and `max_cool_c_per_min` down; `imu_time_constant_s`: the case's lag
    behind the air (None: the IMU's temperature does not follow it, its rate is 0); `start_air_c`,
    `start_imu_c`: where they are when the plan starts."""

    ramp_c_per_min: float | None = None
    air_time_constant_s: float = 0.0
    max_heat_c_per_min: float = math.inf
    max_cool_c_per_min: float = math.inf
    imu_time_constant_s: float | None = 600.0
    start_air_c: float = 23.0
    start_imu_c: float = 23.0
    step_s: float = 1.0


@dataclass(frozen=True)
class TimingProfile:
    """How the controller that runs a plan moves: per axis (outer, middle, inner) the acceleration of moves
    and of turns, deg/s^2; `move_overhead_s` added to every move that moves and `turn_overhead_s` to every turn
    (command latency, the in-position poll); the soak model. `name` says whose profile it is (printed)."""

    name: str
    move_accel_dps2: tuple[float, float, float]
    turn_accel_dps2: tuple[float, float, float]
    move_overhead_s: float
    turn_overhead_s: float
    soak: SoakModel = SoakModel()


def _move_s(here: Sequence[float], target: Sequence[float], rate_dps: float, accel_dps2: Sequence[float],
            overhead_s: float) -> float:
    longest, moved = 0.0, False
    for k in range(3):
        distance = target[k] - here[k]
        if abs(distance) <= _EPS_DEG:
            continue
        moved = True
        ramp, cruise, _ = trapezoid_timing(distance, rate_dps, accel_dps2[k])
        longest = max(longest, 2.0 * ramp + cruise)
    return longest + overhead_s if moved else 0.0


class _Thermal:
    """The air and the IMU's case through the soaks of a plan (state carried from one soak to the next)."""

    def __init__(self, model: SoakModel):
        self.model = model
        self.air_c, self.imu_c = model.start_air_c, model.start_imu_c
        self.ramp_c_per_min = model.ramp_c_per_min
        self.working_c = self.air_c
        self.setpoint_c: float | None = None

    def set_temperature(self, step: SetTemperatureStep) -> None:
        self.ramp_c_per_min = step.ramp_c_per_min if step.ramp_c_per_min is not None else self.model.ramp_c_per_min
        self.working_c = self.air_c          # a ramp starts from where the air is
        self.setpoint_c = step.setpoint_c

    def _air_after(self, dt: float) -> float:
        m = self.model
        if m.air_time_constant_s <= 0.0:
            return self.working_c
        gap = self.working_c - self.air_c
        limit = (m.max_heat_c_per_min if gap > 0 else m.max_cool_c_per_min) / 60.0
        rate = gap / m.air_time_constant_s
        if abs(rate) > limit:               # rate-limited: linear for this step
            return self.air_c + math.copysign(min(limit * dt, abs(gap)), gap)
        return self.working_c - gap * math.exp(-dt / m.air_time_constant_s)

    def _step(self, setpoint_c: float | None, dt: float) -> None:
        """The working setpoint, the air and the case `dt` later (`setpoint_c` None: the chamber not yet set)."""
        m = self.model
        if setpoint_c is not None:
            if self.ramp_c_per_min:
                gap = setpoint_c - self.working_c
                self.working_c += math.copysign(min(abs(gap), self.ramp_c_per_min / 60.0 * dt), gap)
            else:
                self.working_c = setpoint_c
        air0, self.air_c = self.air_c, self._air_after(dt)
        if m.imu_time_constant_s is not None:
            # the case's exact step for an air temperature linear over the step
            tau = m.imu_time_constant_s
            e, slope_tau = math.exp(-dt / tau), (self.air_c - air0) / dt * tau
            self.imu_c = e * self.imu_c + (self.air_c - slope_tau) - e * (air0 - slope_tau)

    def advance(self, duration_s: float) -> None:
        """The air and the case after a step of `duration_s` that leaves the chamber as it is."""
        if self.setpoint_c is None:
            return                           # before the first setpoint: the chamber stopped, nothing to follow
        whole, rest = divmod(duration_s, self.model.step_s)
        for _ in range(int(whole)):
            self._step(self.setpoint_c, self.model.step_s)
        if rest > 0.0:
            self._step(self.setpoint_c, rest)

    def soak(self, step: SoakStep) -> float:
        """Seconds until the soak of `step` is done (at most its maximum); the state moves on that long."""
        dt, self.setpoint_c = self.model.step_s, step.setpoint_c
        window = max(1, int(round(step.rate_window_s / dt)))
        history: collections.deque[float] = collections.deque([self.imu_c], maxlen=window + 1)
        at_setpoint, steady_since, t = False, None, 0.0
        while t < step.max_soak_s:
            self._step(step.setpoint_c, dt)
            history.append(self.imu_c)
            t += dt
            at_setpoint = at_setpoint or abs(self.air_c - step.setpoint_c) <= step.chamber_tolerance_c
            # the rate over the window (the tracker's fit needs 90 % of it covered)
            covered = len(history) - 1
            rate = ((history[-1] - history[0]) / (covered * dt) * 60.0 if covered >= 0.9 * window else None)
            if at_setpoint and rate is not None and abs(rate) < step.rate_c_per_min:
                steady_since = t if steady_since is None else steady_since
                if t - steady_since >= step.stable_s - 1e-9:
                    return t
            else:
                steady_since = None
        return step.max_soak_s


def retime(steps: Sequence[Step], profile: TimingProfile, start_deg=(0.0, 0.0, 0.0)) -> tuple[float, ...]:
    """The estimated duration (s) of each of `steps` when `profile`'s controller runs them from `start_deg`
    (absolute controller angles). The steps are read, never changed."""
    here = tuple(float(a) for a in start_deg)
    thermal = _Thermal(profile.soak)
    out: list[float] = []
    for step in steps:
        if isinstance(step, MoveStep):
            out.append(_move_s(here, step.target_deg, step.rate_dps, profile.move_accel_dps2, profile.move_overhead_s))
            here = step.target_deg
        elif isinstance(step, TurnStep):
            ramp, cruise, _ = trapezoid_timing(360.0 * step.revolutions, step.rate_dps,
                                               profile.turn_accel_dps2[step.frame_index])
            out.append(2.0 * step.rest_s + 2.0 * ramp + cruise + profile.turn_overhead_s)
            here = step.end_deg
        elif isinstance(step, SettleStep):
            out.append(step.duration_s)
        elif isinstance(step, DwellStep):
            out.append(step.dwell_s)
            here = step.target_deg
        elif isinstance(step, SetTemperatureStep):
            thermal.set_temperature(step)
            out.append(0.0)
        else:
            out.append(thermal.soak(step))
        if not isinstance(step, SoakStep):
            thermal.advance(out[-1])
    return tuple(out)


__all__ = ["SoakModel", "TimingProfile", "retime"]
