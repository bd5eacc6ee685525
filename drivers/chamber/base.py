"""The one thermal-chamber interface every dialect implements, and its shared types.

Temperatures are degrees Celsius, ramp rates degC/min (0 = no ramp: the controller steps
its setpoint). `Chamber` does the shared work (limit checks before anything is sent,
serialised access, alarm checks, the best-effort safe paths); a dialect implements the
small `_` methods.
"""

from __future__ import annotations

import enum
import math
from abc import abstractmethod
from dataclasses import dataclass

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import ChamberAlarm, ChamberConfigError, ChamberLimitError
from drivers.session import DeviceSession

#: hard bounds of any configured limit: what a chamber controller could mean at all
ABSOLUTE_MIN_C = -273.15
ABSOLUTE_MAX_C = 1000.0


class ChamberAlarms(enum.IntFlag):
    """Alarm bits common to every dialect (each dialect's page maps its own codes or bits)."""

    OVER_TEMPERATURE = 0x01     # air above the controller's high limit (heater cut)
    UNDER_TEMPERATURE = 0x02    # air below the low limit (refrigeration cut)
    DOOR_OPEN = 0x04
    SENSOR_FAULT = 0x08         # open or shorted temperature sensor
    EQUIPMENT_FAULT = 0x10      # compressor, heater, blower, water: anything else the controller reports

    def describe(self) -> str:
        """'over-temperature, door open'; '' for none."""
        return ", ".join(word for flag, word in _ALARM_WORDS.items() if self & flag)


_ALARM_WORDS = {ChamberAlarms.OVER_TEMPERATURE: "over-temperature", ChamberAlarms.UNDER_TEMPERATURE:
                "under-temperature", ChamberAlarms.DOOR_OPEN: "door open", ChamberAlarms.SENSOR_FAULT: "sensor fault",
                ChamberAlarms.EQUIPMENT_FAULT: "equipment fault"}
#: alarm name (configuration, consoles) -> flag
ALARM_NAMES = {"over_temperature": ChamberAlarms.OVER_TEMPERATURE, "under_temperature": ChamberAlarms.UNDER_TEMPERATURE,
               "door_open": ChamberAlarms.DOOR_OPEN, "sensor_fault": ChamberAlarms.SENSOR_FAULT,
               "equipment_fault": ChamberAlarms.EQUIPMENT_FAULT}


@dataclass(frozen=True)
class ChamberState:
    """One read of the chamber; `time_s` is the reading's time on the driver's clock.

    `ramp_c_per_min` is the controller's ramp rate (0 = steps; None = the dialect has no ramp).
    """

    time_s: float
    temperature_c: float
    setpoint_c: float
    ramp_c_per_min: float | None
    running: bool
    alarms: ChamberAlarms = ChamberAlarms(0)
    alarm_text: str = ""

    @property
    def alarm(self) -> bool:
        return bool(self.alarms) or bool(self.alarm_text)

    def describe_alarms(self) -> str:
        """A one-line account of the alarms ('' when there are none)."""
        return "; ".join(part for part in (self.alarms.describe(), self.alarm_text) if part)

    def describe(self) -> str:
        """'23.4 degC, setpoint 25.0 degC, ramp 2.0 degC/min, running, alarms: none'."""
        ramp = "no ramp" if self.ramp_c_per_min is None else (
            "step" if self.ramp_c_per_min == 0 else f"ramp {self.ramp_c_per_min:g} degC/min")
        return (f"{self.temperature_c:.1f} degC, setpoint {self.setpoint_c:.1f} degC, {ramp}, "
                f"{'running' if self.running else 'stopped'}, alarms: {self.describe_alarms() or 'none'}")


@dataclass(frozen=True)
class ChamberLimits:
    """What the bench may demand of the chamber: setpoint range (degC) and largest ramp rate (degC/min)."""

    min_setpoint_c: float = -40.0
    max_setpoint_c: float = 85.0
    max_ramp_c_per_min: float = 5.0

    def __post_init__(self) -> None:
        for name in ("min_setpoint_c", "max_setpoint_c"):
            value = getattr(self, name)
            if not (math.isfinite(value) and ABSOLUTE_MIN_C <= value <= ABSOLUTE_MAX_C):
                raise ChamberConfigError(f"{name} must be within [{ABSOLUTE_MIN_C}, {ABSOLUTE_MAX_C}] degC, "
                                         f"got {value}")
        if not self.min_setpoint_c < self.max_setpoint_c:
            raise ChamberConfigError(f"min_setpoint_c must be below max_setpoint_c, got {self.min_setpoint_c} >= "
                                     f"{self.max_setpoint_c}")
        if not (math.isfinite(self.max_ramp_c_per_min) and self.max_ramp_c_per_min > 0):
            raise ChamberConfigError(f"max_ramp_c_per_min must be positive and finite, got {self.max_ramp_c_per_min}")

    def check_setpoint(self, setpoint_c: float) -> None:
        if not (math.isfinite(setpoint_c) and self.min_setpoint_c <= setpoint_c <= self.max_setpoint_c):
            raise ChamberLimitError(f"setpoint {setpoint_c} degC is outside the limits "
                                    f"[{self.min_setpoint_c:g}, {self.max_setpoint_c:g}] degC")

    def check_ramp(self, ramp_c_per_min: float) -> None:
        if not (math.isfinite(ramp_c_per_min) and 0 < ramp_c_per_min <= self.max_ramp_c_per_min):
            raise ChamberLimitError(f"ramp rate {ramp_c_per_min} degC/min is outside (0, "
                                    f"{self.max_ramp_c_per_min:g}] degC/min")


class Chamber(DeviceSession[ChamberState]):
    """A thermal chamber's temperature controller, whatever its dialect and transport.

    Public methods check limits before sending and serialise access (a poller thread and
    the sequencer can share a driver). Use as a context manager: leaving the block on an
    exception stops the chamber (best effort).
    """

    #: whether the dialect (or its register map) can set a ramp rate
    supports_ramp: bool = True

    def __init__(self, limits: ChamberLimits | None = None, clock: Clock = SYSTEM_CLOCK):
        super().__init__(clock)
        self.limits = limits if limits is not None else ChamberLimits()

    # -- what a dialect implements (and DeviceSession's _open, _close, _read_state) --
    @abstractmethod
    def _set_setpoint(self, setpoint_c: float) -> None: ...

    @abstractmethod
    def _set_ramp(self, ramp_c_per_min: float) -> None:
        """0 = no ramp (step); only called when `supports_ramp`."""

    @abstractmethod
    def _run(self) -> None: ...

    @abstractmethod
    def _stop(self) -> None:
        """Stop temperature control (heating and cooling off; the air drifts toward ambient)."""

    @abstractmethod
    def _clear_alarms(self) -> None: ...

    # -- the interface -----------------------------------------------------------
    def set_setpoint(self, setpoint_c: float, ramp_c_per_min: float | None = None) -> None:
        """Demand a setpoint (degC), with a ramp rate (degC/min; None leaves the controller's, 0 steps).

        Both are checked against the limits before anything is sent; the ramp goes first, so the
        new setpoint is approached at the new rate.
        """
        setpoint_c = float(setpoint_c)
        self.limits.check_setpoint(setpoint_c)
        if ramp_c_per_min is not None:
            ramp_c_per_min = float(ramp_c_per_min)
            if ramp_c_per_min != 0:
                self.limits.check_ramp(ramp_c_per_min)
            if not self.supports_ramp:
                raise ChamberConfigError(f"the {self.dialect} chamber has no ramp rate (its register map has none)")
        with self._lock:
            if ramp_c_per_min is not None:
                self._set_ramp(ramp_c_per_min)
            self._set_setpoint(setpoint_c)

    def run(self) -> None:
        """Start temperature control (toward the setpoint)."""
        with self._lock:
            self._run()

    def clear_alarms(self) -> None:
        """Acknowledge latched alarms (an alarm whose cause remains comes back)."""
        with self._lock:
            self._clear_alarms()

    def _state_error(self, state: ChamberState) -> ChamberAlarm | None:
        """`check_state` raises `ChamberAlarm` for a state that shows an alarm."""
        return ChamberAlarm(f"{self.dialect} chamber alarm: {state.describe_alarms()}", state) if state.alarm else None

    def stop_caveat(self) -> str:
        """What `stop` may leave on, as the controller reports it ('' for nothing known)."""
        return ""

    def safe_stop(self) -> bool:
        """Best effort to stop temperature control; True if the stop was acknowledged. Never raises:
        it runs on error paths where the first error must survive."""
        try:
            self.stop()
            return True
        except Exception:  # noqa: BLE001 - nothing more a driver can do; the caller reports the first error
            return False

    def make_safe(self, safe_setpoint_c: float | None = None) -> str:
        """Best effort to leave the chamber safe; never raises; returns what was done, for the log.

        With a safe setpoint (within the limits) the chamber is sent there and keeps running (a chamber at
        -40 degC brought back to room temperature, not left to frost); without one, or when that fails,
        temperature control is stopped.
        """
        if safe_setpoint_c is not None:
            try:
                self.set_setpoint(safe_setpoint_c)
                self.run()
                return f"setpoint {safe_setpoint_c:g} degC (safe setpoint), running"
            except Exception as exc:  # noqa: BLE001 - the stop below is the fallback for any failure
                reason = f"safe setpoint {safe_setpoint_c:g} degC failed ({type(exc).__name__}: {exc}); "
        else:
            reason = ""
        if self.safe_stop():
            caveat = self.stop_caveat()
            return reason + "stopped" + (f" ({caveat})" if caveat else "")
        return reason + "stop failed: the chamber may still be controlling"
