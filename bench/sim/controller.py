"""A simulated turntable controller: servo state, modes, demands and faults over a `SimTable`.

This is the part every wire-level simulator shares: the SCPI, $MN and Modbus servers
parse their dialect and call these methods, so all three behave alike. Time is the
injected clock's, counted from the controller's creation (simulated table time 0).

Behaviour, as on a real controller:
- a demand on a disabled axis, in the wrong mode, or beyond the controller's own travel
  or rate limits is refused (`SimCommandError`, which the servers turn into an error
  reply) and nothing moves;
- `stop` decelerates every axis and holds it (servo stays on); `abort` and an e-stop
  decelerate at the maximum acceleration and switch every servo off;
- a tripped limit or fault latches on its axis (servo off) until `reset`; an e-stop
  latches on every axis until it is released and reset.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

from bench.model.units import DEG
from bench.sim.table import SimTable
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.turntable.base import FRAMES, AxisLimits, AxisMode, AxisState, AxisStatus, TableState


class SimCommandError(Exception):
    """The simulated controller refuses a command; `code` is a small error number for the wire."""

    def __init__(self, message: str, code: int = 1):
        super().__init__(message)
        self.code = code


# Error codes the servers put on the wire (each dialect page lists them).
ERR_SYNTAX = 1        # not a command of the dialect
ERR_ARGUMENT = 2      # bad axis number or value
ERR_NOT_ENABLED = 3   # axis servo off
ERR_WRONG_MODE = 4    # demand does not match the axis mode
ERR_LIMIT = 5         # beyond the controller's travel or rate limits
ERR_FAULT = 6         # a fault or e-stop is latched; reset first

_ENABLED, _MOVING, _IN_POSITION = int(AxisStatus.ENABLED), int(AxisStatus.MOVING), int(AxisStatus.IN_POSITION)
_FAULT, _LIMIT, _ESTOP = int(AxisStatus.FAULT), int(AxisStatus.LIMIT), int(AxisStatus.ESTOP)


@dataclass
class _Axis:
    enabled: bool = False
    mode: AxisMode = AxisMode.OFF
    demand_deg: float = 0.0
    rate_demand_dps: float = 0.0
    fault: bool = False
    limit: bool = False


#: the wire faults a `WireFaults` counts, in the order `take` applies them (also the fault consoles' commands)
WIRE_FAULTS = ("timeout", "garbage", "checksum", "exception", "late")


@dataclass
class WireFaults:
    """Faults the wire servers inject into their next replies (each counter counts replies).

    `timeout`: swallow the reply; `garbage`: reply with junk bytes; `checksum`: corrupt
    the reply's checksum/CRC (the dialect decides how); `exception`: reply with an error
    or Modbus exception code `exception_code` instead of executing; `late` (line dialects):
    hold the reply back and send it just before the reply to the next request, as a slow
    controller does when the client has given up waiting.
    """

    timeout: int = 0
    garbage: int = 0
    checksum: int = 0
    exception: int = 0
    late: int = 0
    exception_code: int = 4
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _held: bytes = field(default=b"", repr=False)

    def take(self) -> str | None:
        """The fault to apply to the reply being built (and count it), or None."""
        with self._lock:
            for name in WIRE_FAULTS:
                if getattr(self, name) > 0:
                    setattr(self, name, getattr(self, name) - 1)
                    return name
        return None

    def hold(self, reply: bytes) -> None:
        """Keep `reply` (a `late` fault) for `release`."""
        with self._lock:
            self._held += reply

    def release(self) -> bytes:
        """The replies held back so far (sent before the next reply), and forget them."""
        with self._lock:
            held, self._held = self._held, b""
        return held


class SimController:
    """The simulated controller of a three-axis table (thread-safe)."""

    def __init__(self, table: SimTable | None = None, clock: Clock = SYSTEM_CLOCK,
                 limits: tuple[AxisLimits, AxisLimits, AxisLimits] | None = None,
                 in_position_window_deg: float = 1e-4):
        self.table = table if table is not None else SimTable()
        self.clock = clock
        self._t0 = clock.now()
        rate, accel = self.table.limits.max_rate_dps, self.table.limits.max_accel_dps2
        self.limits = limits if limits is not None else tuple(
            AxisLimits(None, None, rate[k], accel[k]) for k in range(3))
        self.in_position_window_deg = in_position_window_deg
        self.faults = WireFaults()
        self._axes = [_Axis() for _ in range(3)]
        for k in range(3):
            self._axes[k].demand_deg = self.table.axis_at(0.0, k)[0] / DEG
        self._estop = False
        self._fault_text = ""
        self._lock = threading.RLock()

    # -- time ---------------------------------------------------------------------
    def now(self) -> float:
        """Simulated table time, s (0 at creation)."""
        return self.clock.now() - self._t0

    # -- checks -------------------------------------------------------------------
    @staticmethod
    def _axis_index(axis: int) -> int:
        if not (isinstance(axis, int) and 0 <= axis < 3):
            raise SimCommandError(f"no axis {axis!r}", ERR_ARGUMENT)
        return axis

    def _require_enabled(self, k: int) -> _Axis:
        ax = self._axes[k]
        if self._estop or ax.fault or ax.limit:
            raise SimCommandError(f"{FRAMES[k]} axis has a latched fault; reset first", ERR_FAULT)
        if not ax.enabled:
            raise SimCommandError(f"{FRAMES[k]} axis is not enabled", ERR_NOT_ENABLED)
        return ax

    def _rate_ok(self, k: int, rate_dps: float) -> float:
        rate_dps = float(rate_dps)
        if not (math.isfinite(rate_dps) and abs(rate_dps) <= self.limits[k].max_rate_dps):
            raise SimCommandError(f"{FRAMES[k]} rate {rate_dps} deg/s beyond {self.limits[k].max_rate_dps}",
                                  ERR_LIMIT)
        return rate_dps

    # -- commands -----------------------------------------------------------------
    def enable(self, axis: int) -> None:
        with self._lock:
            k = self._axis_index(axis)
            ax = self._axes[k]
            if self._estop or ax.fault or ax.limit:
                raise SimCommandError(f"{FRAMES[k]} axis has a latched fault; reset first", ERR_FAULT)
            if not ax.enabled:
                ax.enabled = True
                ax.mode = AxisMode.POSITION
                ax.demand_deg = self.table.axis_at(self.now(), k)[0] / DEG
                self.table.move_axis(self.now(), k, ax.demand_deg)  # hold where it is

    def disable(self, axis: int) -> None:
        with self._lock:
            k = self._axis_index(axis)
            self._servo_off(k)

    def _servo_off(self, k: int) -> None:
        ax = self._axes[k]
        ax.enabled, ax.mode = False, AxisMode.OFF
        self.table.set_rate(self.now(), k, 0.0)   # brakes: to rest at the max acceleration

    def reset(self, axis: int) -> None:
        """Clear latched faults and limit trips on one axis (not an active e-stop)."""
        with self._lock:
            k = self._axis_index(axis)
            if self._estop:
                raise SimCommandError("emergency stop still active", ERR_FAULT)
            self._axes[k].fault = self._axes[k].limit = False
            if not any(a.fault or a.limit for a in self._axes):
                self._fault_text = ""

    def set_mode(self, axis: int, mode: AxisMode) -> None:
        with self._lock:
            k = self._axis_index(axis)
            mode = AxisMode(mode)
            if mode is AxisMode.OFF:
                self._servo_off(k)
                return
            ax = self._require_enabled(k)
            if mode is ax.mode:
                return
            t = self.now()
            ax.mode = mode
            if mode is AxisMode.POSITION:
                # Entering position mode holds the axis where it comes to rest.
                self.table.set_rate(t, k, 0.0)
                ax.demand_deg = self.table.axis_at(t + 3600.0, k)[0] / DEG
            else:
                ax.rate_demand_dps = self.table.axis_at(t, k)[1] / DEG

    def _accel_ok(self, k: int, accel_dps2: float | None) -> float | None:
        """A commanded acceleration (None: the table's limit), at most the table's limit."""
        return None if accel_dps2 is None else min(float(accel_dps2), self.table.limits.max_accel_dps2[k])

    def demand_position(self, axis: int, angle_deg: float, rate_dps: float | None = None,
                        accel_dps2: float | None = None) -> float:
        """Move one axis to an absolute angle (at `accel_dps2`, None: the table's limit); returns the simulated time
        it arrives."""
        with self._lock:
            k = self._axis_index(axis)
            ax = self._require_enabled(k)
            if ax.mode is not AxisMode.POSITION:
                raise SimCommandError(f"{FRAMES[k]} axis is in {ax.mode.value} mode", ERR_WRONG_MODE)
            angle_deg = float(angle_deg)
            lim = self.limits[k]
            if not math.isfinite(angle_deg) or (lim.min_deg is not None and angle_deg < lim.min_deg) or (
                    lim.max_deg is not None and angle_deg > lim.max_deg):
                raise SimCommandError(f"{FRAMES[k]} position {angle_deg} outside travel", ERR_LIMIT)
            rate = lim.max_rate_dps if rate_dps is None else self._rate_ok(k, rate_dps)
            if rate <= 0:
                raise SimCommandError(f"{FRAMES[k]} move rate must be positive", ERR_ARGUMENT)
            ax.demand_deg = angle_deg
            return self.table.move_axis(self.now(), k, angle_deg, min(rate, self.table.limits.max_rate_dps[k]),
                                        self._accel_ok(k, accel_dps2))

    def demand_rate(self, axis: int, rate_dps: float, accel_dps2: float | None = None) -> float:
        """Ramp one axis (rate mode) to a signed rate d(angle)/dt (at `accel_dps2`, None: the table's limit);
        returns when it is reached."""
        with self._lock:
            k = self._axis_index(axis)
            ax = self._require_enabled(k)
            if ax.mode is not AxisMode.RATE:
                raise SimCommandError(f"{FRAMES[k]} axis is in {ax.mode.value} mode", ERR_WRONG_MODE)
            ax.rate_demand_dps = self._rate_ok(k, rate_dps)
            return self.table.set_rate(self.now(), k, ax.rate_demand_dps, self._accel_ok(k, accel_dps2))

    def stop(self) -> float:
        """Controlled stop: every axis decelerates and holds in position mode (servo stays on)."""
        with self._lock:
            t = self.now()
            end = self.table.stop(t)
            for k, ax in enumerate(self._axes):
                if ax.enabled:
                    ax.mode = AxisMode.POSITION
                    ax.demand_deg = self.table.axis_at(end, k)[0] / DEG
                ax.rate_demand_dps = 0.0
            return end

    def abort(self) -> None:
        """Servo off on every axis at once (decelerating at the maximum acceleration)."""
        with self._lock:
            for k in range(3):
                self._servo_off(k)

    # -- faults on demand ----------------------------------------------------------
    def trip_estop(self) -> None:
        """Press the emergency stop: every servo off, ESTOP latched until released and reset."""
        with self._lock:
            self._estop = True
            self._fault_text = "emergency stop pressed"
            self.abort()

    def release_estop(self) -> None:
        with self._lock:
            self._estop = False

    def trip_limit(self, axis: int, text: str = "") -> None:
        """A travel/rate limit switch trips on one axis: servo off, LIMIT latched until reset."""
        with self._lock:
            k = self._axis_index(axis)
            self._axes[k].limit = True
            self._fault_text = text or f"{FRAMES[k]} limit switch tripped"
            self._servo_off(k)

    def trip_fault(self, axis: int, text: str = "") -> None:
        """An amplifier/servo fault on one axis: servo off, FAULT latched until reset."""
        with self._lock:
            k = self._axis_index(axis)
            self._axes[k].fault = True
            self._fault_text = text or f"{FRAMES[k]} servo amplifier fault"
            self._servo_off(k)

    # -- state --------------------------------------------------------------------
    def axis_state(self, axis: int, t: float | None = None) -> AxisState:
        with self._lock:
            k = self._axis_index(axis)
            t = self.now() if t is None else t
            theta, rate, accel = self.table.axis_at(t, k)
            ax = self._axes[k]
            # the bits as an int, one AxisStatus made of them (a flag operation each costs more than the rest)
            bits = _ENABLED if ax.enabled else 0
            if rate != 0.0 or accel != 0.0:
                bits |= _MOVING
            elif (ax.enabled and ax.mode is AxisMode.POSITION
                  and abs(theta / DEG - ax.demand_deg) <= self.in_position_window_deg):
                bits |= _IN_POSITION
            if ax.fault:
                bits |= _FAULT
            if ax.limit:
                bits |= _LIMIT
            if self._estop:
                bits |= _ESTOP
            return AxisState(theta / DEG, rate / DEG, ax.mode, AxisStatus(bits))

    def state(self) -> TableState:
        with self._lock:
            t = self.now()
            return TableState(t, (self.axis_state(0, t), self.axis_state(1, t), self.axis_state(2, t)),
                              self._fault_text)

    @property
    def lock(self) -> threading.RLock:
        """Held while a command changes the table; hold it to read the table consistently from another thread."""
        return self._lock

    @property
    def estop(self) -> bool:
        return self._estop

    @property
    def fault_text(self) -> str:
        return self._fault_text
