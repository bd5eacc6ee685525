"""A simulated thermal chamber: first-order air dynamics with heating and cooling rate limits, ramps, alarms.

The physics every wire simulator of the chamber shares (the ASCII and Modbus servers call
these methods). Time is the injected clock's (a `ManualClock` runs hours in no time),
counted from the chamber's creation; the state is brought up to the clock's time by
every call.

Model, as a chamber's controller and its air behave:
- running: the controller's working setpoint moves toward the setpoint at the ramp rate
  (0 = at once), starting from the air temperature when the setpoint changes or the run
  starts; the air follows the working setpoint as a first-order lag with time constant
  `time_constant_s`, its rate limited to `max_heat_c_per_min` up and `max_cool_c_per_min`
  down (the heater's and the refrigeration's capacity);
- stopped: heating and cooling off; the air drifts toward `ambient_c` with
  `passive_time_constant_s`;
- a setpoint outside the controller's own range, or a ramp beyond its maximum, is refused
  (`SimChamberError`); run is refused while an alarm is latched;
- alarms latch and stop the run: over-temperature / under-temperature trip when the air
  passes the controller's alarm limits (or on demand), door open, sensor fault and
  equipment fault on demand (`trip_alarm`); `clear_alarms` releases them, except a
  temperature alarm whose cause remains.

Integration is exact for a fixed working setpoint (a rate-limited stretch, then the
exponential) and in steps of at most `RAMP_STEP_S` while the working setpoint ramps.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

from bench.sim.controller import WireFaults
from drivers.chamber.base import ChamberAlarms, ChamberState
from drivers.clock import SYSTEM_CLOCK, Clock

#: the longest integration step while the working setpoint ramps, s
RAMP_STEP_S = 1.0

# Why the simulated controller refuses (each server maps these onto its dialect's error).
ERR_SYNTAX = 1      # not a command of the dialect
ERR_RANGE = 2       # setpoint or ramp beyond the controller's own range
ERR_ALARM = 3       # run refused while an alarm is latched


class SimChamberError(Exception):
    """The simulated controller refuses a command; `code` is one of the ERR_ codes."""

    def __init__(self, message: str, code: int = ERR_SYNTAX):
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class ChamberPhysics:
    """The simulated chamber's air and controller (defaults: a small benchtop chamber)."""

    ambient_c: float = 23.0
    time_constant_s: float = 240.0
    max_heat_c_per_min: float = 5.0
    max_cool_c_per_min: float = 3.0
    passive_time_constant_s: float = 3600.0
    min_setpoint_c: float = -70.0
    max_setpoint_c: float = 180.0
    max_ramp_c_per_min: float = 20.0
    over_temperature_c: float = 190.0
    under_temperature_c: float = -80.0

    def __post_init__(self) -> None:
        for name in ("time_constant_s", "max_heat_c_per_min", "max_cool_c_per_min", "passive_time_constant_s",
                     "max_ramp_c_per_min"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value}")
        if not (self.under_temperature_c < self.min_setpoint_c < self.max_setpoint_c < self.over_temperature_c):
            raise ValueError("need under_temperature_c < min_setpoint_c < max_setpoint_c < over_temperature_c")
        if not self.under_temperature_c < self.ambient_c < self.over_temperature_c:
            raise ValueError(f"ambient_c {self.ambient_c} must lie between the alarm limits")


def approach(temperature_c: float, target_c: float, tau_s: float, up_c_per_s: float, down_c_per_s: float,
             dt_s: float) -> float:
    """The air after `dt_s` of d(T)/dt = clip((target - T) / tau, -down, +up), exactly: a stretch at the
    rate limit while the lag asks for more, then the exponential."""
    if dt_s <= 0:
        return temperature_c
    gap = target_c - temperature_c
    limit = up_c_per_s if gap > 0 else down_c_per_s
    if abs(gap) > limit * tau_s:                 # the lag asks for more than the limit: linear until it does not
        edge = target_c - math.copysign(limit * tau_s, gap)
        t_linear = abs(edge - temperature_c) / limit
        if dt_s <= t_linear:
            return temperature_c + math.copysign(limit * dt_s, gap)
        temperature_c, dt_s = edge, dt_s - t_linear
    return target_c + (temperature_c - target_c) * math.exp(-dt_s / tau_s)


class SimChamber:
    """The simulated chamber (thread-safe); `faults` are the wire faults its servers inject."""

    def __init__(self, physics: ChamberPhysics | None = None, clock: Clock = SYSTEM_CLOCK,
                 temperature_c: float | None = None):
        self.physics = physics if physics is not None else ChamberPhysics()
        self.clock = clock
        self.faults = WireFaults()
        self._t0 = clock.now()
        self._t = 0.0
        start = self.physics.ambient_c if temperature_c is None else float(temperature_c)
        self._temperature_c = start
        self._setpoint_c = start
        self._working_c = start
        self._ramp_c_per_min = 0.0
        self._running = False
        self._alarms = ChamberAlarms(0)
        self._lock = threading.RLock()

    # -- time ---------------------------------------------------------------------------
    def now(self) -> float:
        """Simulated chamber time, s (0 at creation)."""
        return self.clock.now() - self._t0

    def _advance(self) -> None:
        t = self.now()
        while self._t < t:
            dt = t - self._t
            p = self.physics
            if not self._running:
                self._temperature_c = approach(self._temperature_c, p.ambient_c, p.passive_time_constant_s,
                                               math.inf, math.inf, dt)
            else:
                ramp = self._ramp_c_per_min / 60.0
                gap = self._setpoint_c - self._working_c
                if ramp > 0 and gap != 0:
                    dt = min(dt, RAMP_STEP_S, abs(gap) / ramp)
                    self._working_c += math.copysign(ramp * dt, gap)
                    if abs(self._setpoint_c - self._working_c) < 1e-9:
                        self._working_c = self._setpoint_c
                else:
                    self._working_c = self._setpoint_c
                self._temperature_c = approach(self._temperature_c, self._working_c, p.time_constant_s,
                                               p.max_heat_c_per_min / 60.0, p.max_cool_c_per_min / 60.0, dt)
            self._t += dt
            self._check_limits()

    def _check_limits(self) -> None:
        p = self.physics
        if self._temperature_c > p.over_temperature_c:
            self._latch(ChamberAlarms.OVER_TEMPERATURE)
        if self._temperature_c < p.under_temperature_c:
            self._latch(ChamberAlarms.UNDER_TEMPERATURE)

    def _latch(self, alarm: ChamberAlarms) -> None:
        self._alarms |= alarm
        self._running = False            # a controller cuts heating and cooling on an alarm

    # -- commands -------------------------------------------------------------------------
    def set_setpoint(self, setpoint_c: float) -> None:
        p = self.physics
        if not (math.isfinite(setpoint_c) and p.min_setpoint_c <= setpoint_c <= p.max_setpoint_c):
            raise SimChamberError(f"setpoint {setpoint_c} degC outside [{p.min_setpoint_c:g}, {p.max_setpoint_c:g}]",
                                  ERR_RANGE)
        with self._lock:
            self._advance()
            self._setpoint_c = float(setpoint_c)
            self._working_c = self._temperature_c      # a ramp starts from where the air is

    def set_ramp(self, ramp_c_per_min: float) -> None:
        """degC/min; 0 = no ramp (the working setpoint steps)."""
        p = self.physics
        if not (math.isfinite(ramp_c_per_min) and 0 <= ramp_c_per_min <= p.max_ramp_c_per_min):
            raise SimChamberError(f"ramp {ramp_c_per_min} degC/min outside [0, {p.max_ramp_c_per_min:g}]", ERR_RANGE)
        with self._lock:
            self._advance()
            self._ramp_c_per_min = float(ramp_c_per_min)

    def run(self) -> None:
        with self._lock:
            self._advance()
            if self._alarms:
                raise SimChamberError(f"alarm active: {self._alarms.describe()}", ERR_ALARM)
            if not self._running:
                self._working_c = self._temperature_c
            self._running = True

    def stop(self) -> None:
        with self._lock:
            self._advance()
            self._running = False

    def clear_alarms(self) -> None:
        with self._lock:
            self._advance()
            self._alarms = ChamberAlarms(0)
            self._check_limits()

    def trip_alarm(self, alarm: ChamberAlarms) -> None:
        """An alarm on demand (door opened, sensor broken, compressor failed, ...): latched, the run stops."""
        with self._lock:
            self._advance()
            self._latch(ChamberAlarms(alarm))

    # -- reading --------------------------------------------------------------------------
    def state(self) -> ChamberState:
        with self._lock:
            self._advance()
            return ChamberState(self._t, self._temperature_c, self._setpoint_c, self._ramp_c_per_min, self._running,
                                self._alarms)

    @property
    def temperature_c(self) -> float:
        """The air temperature now, degC."""
        return self.state().temperature_c


__all__ = ["ChamberPhysics", "ERR_ALARM", "ERR_RANGE", "ERR_SYNTAX", "RAMP_STEP_S", "SimChamber", "SimChamberError",
           "approach"]
