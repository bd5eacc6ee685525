"""The one turntable interface every dialect implements, and its shared types.

Angles are the controller's frame angles in degrees, absolute (not wrapped), and rates
are d(angle)/dt in deg/s, exactly as the controller reports them. (In the paper's
convention a positive angle rate is "clockwise"; a CCW turn has a negative rate. See
docs/explanation/model.md#frame-rotations.) Frames are indexed 0, 1, 2 = outer, middle, inner; on the wire most
controllers number them 1, 2, 3.

`Turntable` does the shared work (limit checks before anything is sent, waiting for a
move to complete, safe shutdown); a dialect implements the small `_` methods.
"""

from __future__ import annotations

import contextlib
import enum
import math
from abc import abstractmethod
from dataclasses import dataclass, field
from typing import Callable, Iterable, Sequence

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import (
    DeviceCommandError,
    DeviceError,
    DeviceFault,
    TurntableCommandError,
    TurntableConfigError,
    TurntableEStop,
    TurntableFault,
    TurntableLimitError,
    TurntableTimeout,
)
from drivers.session import DeviceSession

FRAMES = ("outer", "middle", "inner")
ALL_FRAMES = (0, 1, 2)


def frame_index(frame: int | str) -> int:
    """0, 1, 2 or 'outer', 'middle', 'inner' (any case) -> 0, 1, 2."""
    if isinstance(frame, str):
        name = frame.strip().lower()
        if name in FRAMES:
            return FRAMES.index(name)
    elif isinstance(frame, int) and not isinstance(frame, bool) and 0 <= frame < 3:
        return frame
    raise ValueError(f"frame must be one of {FRAMES} or 0-2, got {frame!r}")


class AxisMode(enum.Enum):
    """Servo mode of one axis."""

    OFF = "off"
    POSITION = "position"
    RATE = "rate"


class AxisStatus(enum.IntFlag):
    """Status bits of one axis, common to every dialect (each dialect page maps its own bits)."""

    ENABLED = 0x01       # servo on (interlock closed)
    MOVING = 0x02        # rate or position changing
    IN_POSITION = 0x04   # position mode, within the controller's in-position window
    FAULT = 0x08         # servo/amplifier fault latched; needs a reset
    ESTOP = 0x10         # emergency stop active
    LIMIT = 0x20         # a travel/rate limit tripped

    def describe(self) -> str:
        """In words, the same for every dialect: 'enabled, moving', 'disabled, fault, e-stop'."""
        words = ["enabled" if self & AxisStatus.ENABLED else "disabled"]
        words += [_STATUS_WORDS[flag] for flag in _STATUS_WORDS if self & flag]
        return ", ".join(words)


_STATUS_WORDS = {AxisStatus.MOVING: "moving", AxisStatus.IN_POSITION: "in position", AxisStatus.FAULT: "fault",
                 AxisStatus.ESTOP: "e-stop", AxisStatus.LIMIT: "limit tripped"}


@dataclass(frozen=True)
class AxisState:
    angle_deg: float
    rate_dps: float
    mode: AxisMode
    status: AxisStatus

    @property
    def enabled(self) -> bool:
        return bool(self.status & AxisStatus.ENABLED)

    @property
    def in_position(self) -> bool:
        return bool(self.status & AxisStatus.IN_POSITION)


@dataclass(frozen=True)
class TableState:
    """One read of the whole table; `time_s` is the reading's time on the driver's clock."""

    time_s: float
    axes: tuple[AxisState, AxisState, AxisState]
    fault_text: str = ""

    @property
    def angles_deg(self) -> tuple[float, float, float]:
        outer, middle, inner = self.axes
        return outer.angle_deg, middle.angle_deg, inner.angle_deg

    @property
    def rates_dps(self) -> tuple[float, float, float]:
        outer, middle, inner = self.axes
        return outer.rate_dps, middle.rate_dps, inner.rate_dps

    @property
    def modes(self) -> tuple[AxisMode, AxisMode, AxisMode]:
        outer, middle, inner = self.axes
        return outer.mode, middle.mode, inner.mode

    @property
    def estop(self) -> bool:
        return any(a.status & AxisStatus.ESTOP for a in self.axes)

    @property
    def fault(self) -> bool:
        return any(a.status & (AxisStatus.FAULT | AxisStatus.LIMIT) for a in self.axes)

    def why_refused(self, frames: Iterable[int]) -> str:
        """Why a controller refuses to move `frames`, in the same words for every dialect ('' if the
        state shows no reason): an e-stop, a latched fault or limit, an axis not enabled."""
        if self.estop:
            return "emergency stop active"
        reasons, disabled = [], []
        for k in sorted(set(frames)):
            axis, name = self.axes[k], FRAMES[k]
            if axis.status & (AxisStatus.FAULT | AxisStatus.LIMIT):
                reasons.append(f"{name} axis: " + ", ".join(
                    word for flag, word in ((AxisStatus.FAULT, "fault"), (AxisStatus.LIMIT, "limit tripped"))
                    if axis.status & flag))
            elif not axis.enabled:
                disabled.append(name)
        if disabled:
            reasons.append(f"{', '.join(disabled)} ax{'e' if len(disabled) > 1 else 'i'}s not enabled")
        return "; ".join(reasons)

    def describe_fault(self) -> str:
        """A one-line account of what is wrong ('' when nothing is)."""
        parts = []
        if self.estop:
            parts.append("emergency stop active")
        for name, axis in zip(FRAMES, self.axes):
            bad = []
            for flag in (AxisStatus.FAULT, AxisStatus.LIMIT):
                if axis.status & flag:
                    assert flag.name is not None  # single members of a Flag always have a name
                    bad.append(flag.name.lower().replace("_", " "))
            if bad:
                parts.append(f"{name}: {', '.join(bad)}")
        if self.fault_text:
            parts.append(self.fault_text)
        return "; ".join(parts)


#: what every message says when no stop could be sent or confirmed: the operator must act at the controller
TABLE_STATE_UNKNOWN = "TABLE STATE UNKNOWN: the controller cannot be reached; stop it at the controller"


class StopOutcome(enum.Enum):
    """What a safe stop achieved, as far as the bench can know."""

    STOPPED = "stopped"          # the controller accepted the controlled stop
    ABORT_SENT = "abort sent"    # the controlled stop failed; the controller accepted the abort (servos off)
    UNKNOWN = "unknown"          # neither could be sent (or confirmed): the table may still be moving


@dataclass(frozen=True)
class StopResult:
    """`Turntable.safe_stop`/`safe_abort`'s answer: the outcome, the error that made the abort fail (`UNKNOWN`)
    and the one that made the controlled stop fail (if one was tried and failed)."""

    outcome: StopOutcome
    error: BaseException | None = None
    stop_error: BaseException | None = None

    @property
    def unknown(self) -> bool:
        return self.outcome is StopOutcome.UNKNOWN

    def describe(self) -> str:
        """In words an operator cannot misread: 'table commanded to stop', '... abort sent (servos off)', or
        `TABLE_STATE_UNKNOWN` with the reason."""
        stop_failed = (f"controlled stop failed ({type(self.stop_error).__name__}: {self.stop_error}); "
                       if self.stop_error is not None else "")
        if self.outcome is StopOutcome.STOPPED:
            return "table commanded to stop"
        if self.outcome is StopOutcome.ABORT_SENT:
            return f"{stop_failed}abort sent (servos off)"
        return f"{TABLE_STATE_UNKNOWN} ({stop_failed}abort failed: {type(self.error).__name__}: {self.error})"


@dataclass(frozen=True)
class AxisLimits:
    """What the bench may demand of one axis. `min_deg`/`max_deg` None = continuous axis."""

    min_deg: float | None = None
    max_deg: float | None = None
    max_rate_dps: float = 100.0
    max_accel_dps2: float = 50.0

    def __post_init__(self) -> None:
        for name in ("max_rate_dps", "max_accel_dps2"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise TurntableConfigError(f"{name} must be positive and finite, got {value}")
        if self.min_deg is not None and self.max_deg is not None and not self.min_deg < self.max_deg:
            raise TurntableConfigError(f"min_deg must be below max_deg, got {self.min_deg} >= {self.max_deg}")


@dataclass(frozen=True)
class TurntableLimits:
    axes: tuple[AxisLimits, AxisLimits, AxisLimits] = field(
        default_factory=lambda: (AxisLimits(), AxisLimits(), AxisLimits()))

    def check_position(self, frame: int, angle_deg: float) -> None:
        lim = self.axes[frame]
        if not math.isfinite(angle_deg):
            raise TurntableLimitError(f"{FRAMES[frame]} position must be finite, got {angle_deg}")
        if (lim.min_deg is not None and angle_deg < lim.min_deg) or (
                lim.max_deg is not None and angle_deg > lim.max_deg):
            raise TurntableLimitError(f"{FRAMES[frame]} position {angle_deg} deg is outside its limits "
                                      f"[{lim.min_deg}, {lim.max_deg}] deg")

    def check_rate(self, frame: int, rate_dps: float) -> None:
        lim = self.axes[frame]
        if not (math.isfinite(rate_dps) and abs(rate_dps) <= lim.max_rate_dps):
            raise TurntableLimitError(f"{FRAMES[frame]} rate {rate_dps} deg/s exceeds its limit "
                                      f"{lim.max_rate_dps} deg/s")


class Turntable(DeviceSession[TableState]):
    """A three-axis turntable controller, whatever its dialect and transport.

    Public methods check limits before sending, serialise access (one request at a
    time, so a poller thread and the sequencer can share a driver), and translate a
    reported fault into `TurntableFault`/`TurntableEStop`. Use as a context manager:
    leaving the block on an exception commands a stop (and an abort if that fails).
    """

    def __init__(self, limits: TurntableLimits | None = None, clock: Clock = SYSTEM_CLOCK):
        super().__init__(clock)
        self.limits = limits if limits is not None else TurntableLimits()

    # -- what a dialect implements (and DeviceSession's _open, _close, _read_state) --
    @abstractmethod
    def _enable(self, frames: Sequence[int]) -> None: ...

    @abstractmethod
    def _disable(self, frames: Sequence[int]) -> None: ...

    @abstractmethod
    def _reset_faults(self, frames: Sequence[int]) -> None: ...

    @abstractmethod
    def _set_mode(self, frame: int, mode: AxisMode) -> None: ...

    @abstractmethod
    def _demand_positions(self, targets: dict[int, float], rate_dps: dict[int, float]) -> None:
        """Position mode is set; command each frame in `targets` (deg) at its move rate (deg/s)."""

    @abstractmethod
    def _demand_rate(self, frame: int, rate_dps: float) -> None:
        """Rate mode is set; command the signed rate."""

    @abstractmethod
    def _stop(self) -> None:
        """Controlled stop of every axis: decelerate and hold (servo stays on)."""

    @abstractmethod
    def _abort(self) -> None:
        """Servo off on every axis now (the controller's emergency-stop command)."""

    # -- the interface -----------------------------------------------------------
    def enable(self, frames: Iterable[int | str] = ALL_FRAMES) -> None:
        with self._lock:
            self._enable([frame_index(f) for f in frames])

    def disable(self, frames: Iterable[int | str] = ALL_FRAMES) -> None:
        with self._lock:
            self._disable([frame_index(f) for f in frames])

    def reset_faults(self, frames: Iterable[int | str] = ALL_FRAMES) -> None:
        with self._lock:
            self._reset_faults([frame_index(f) for f in frames])

    def set_mode(self, frame: int | str, mode: AxisMode | str) -> None:
        with self._lock:
            self._set_mode(frame_index(frame), AxisMode(mode))

    def move_to(self, angles_deg: Sequence[float | None], rate_dps: float | Sequence[float] | None = None) -> None:
        """Demand absolute positions (None leaves that frame alone) at a move rate (default: the limit).

        Every demand is checked against the limits before anything is sent.
        """
        if len(angles_deg) != 3:
            raise ValueError(f"need three angles (outer, middle, inner; None to skip), got {angles_deg!r}")
        targets = {k: float(a) for k, a in enumerate(angles_deg) if a is not None}
        rates_in = [rate_dps] * 3 if rate_dps is None or isinstance(rate_dps, (int, float)) else list(rate_dps)
        rates = {}
        for k, target in targets.items():
            self.limits.check_position(k, target)
            rate_in = rates_in[k]
            rate = self.limits.axes[k].max_rate_dps if rate_in is None else float(rate_in)
            self.limits.check_rate(k, rate)
            if rate <= 0:
                raise TurntableLimitError(f"{FRAMES[k]} move rate must be positive, got {rate} deg/s")
            rates[k] = rate
        if not targets:
            return
        with self._lock, self._explained_refusal(targets):
            for k in targets:
                self._set_mode(k, AxisMode.POSITION)
            self._demand_positions(targets, rates)

    def set_rate(self, frame: int | str, rate_dps: float) -> None:
        """Rate mode on one frame at the signed rate d(angle)/dt, deg/s (limits checked first)."""
        k = frame_index(frame)
        self.limits.check_rate(k, float(rate_dps))
        with self._lock, self._explained_refusal([k]):
            self._set_mode(k, AxisMode.RATE)
            self._demand_rate(k, float(rate_dps))

    @contextlib.contextmanager
    def _explained_refusal(self, frames: Iterable[int]):
        """A refused move says why in the same words for every dialect (a Modbus controller only says
        "exception 4"): the state is read and its reason put first, the controller's own words after."""
        try:
            yield
        except DeviceCommandError as exc:
            try:
                reason = self._read_state().why_refused(frames)
            except DeviceError:
                reason = ""
            if not reason:
                raise
            raise TurntableCommandError(f"refused: {reason} (controller: {exc})", exc.code) from exc

    def abort(self) -> None:
        with self._lock:
            self._abort()

    def _state_error(self, state: TableState) -> DeviceFault | None:
        """`check_state` raises `TurntableEStop`/`TurntableFault` for a state that shows one."""
        if state.estop:
            return TurntableEStop(f"{self.dialect} controller: {state.describe_fault()}", state)
        if state.fault:
            return TurntableFault(f"{self.dialect} controller: {state.describe_fault()}", state)
        return None

    def wait_in_position(self, targets_deg: Sequence[float | None], tolerance_deg: float = 0.001,
                         settle_s: float = 0.0, timeout_s: float = 60.0, poll_s: float = 0.05,
                         on_state: Callable[[TableState], None] | None = None) -> TableState:
        """Poll until every targeted frame reports in-position within tolerance for `settle_s`;
        `on_state` sees every state read (progress on a terminal).

        A fault or e-stop during the wait stops the table (abort on e-stop) and raises;
        no completion within `timeout_s` stops the table and raises `TurntableTimeout`.
        """
        start = self.clock.now()
        settled_since: float | None = None
        while True:
            state = self.read_state()
            if on_state is not None:
                on_state(state)
            try:
                self.check_state(state)
            except TurntableEStop:
                self.safe_abort()
                raise
            except DeviceError:
                self.safe_stop()
                raise
            done = all(target is None or (state.axes[k].in_position
                                          and abs(state.axes[k].angle_deg - target) <= tolerance_deg)
                       for k, target in enumerate(targets_deg))
            now = self.clock.now()
            if done:
                settled_since = now if settled_since is None else settled_since
                if now - settled_since >= settle_s:
                    return state
            else:
                settled_since = None
            if now - start > timeout_s:
                self.safe_stop()
                raise TurntableTimeout(f"move to {list(targets_deg)} deg not complete after {timeout_s} s "
                                       f"(at {[round(a, 4) for a in state.angles_deg]} deg)")
            self.clock.sleep(poll_s)

    def safe_stop(self) -> StopResult:
        """Best effort to leave the table stopped: a controlled stop, an abort if that fails.

        Never raises (it runs on error paths where the first error must survive); returns what was sent:
        `STOPPED` (the controlled stop was accepted), `ABORT_SENT`, or `UNKNOWN` (nothing could be sent).
        """
        try:
            self.stop()
            return StopResult(StopOutcome.STOPPED)
        except Exception as exc:  # noqa: BLE001 - the abort below is the fallback for any failure
            stop_error = exc
        aborted = self.safe_abort()
        return StopResult(aborted.outcome, aborted.error, stop_error)

    def safe_abort(self) -> StopResult:
        """Best effort to switch every servo off (after an e-stop or a failed stop); never raises.

        Returns `ABORT_SENT` when the controller accepted the abort, `UNKNOWN` (with the error) when it did not."""
        try:
            self.abort()
            return StopResult(StopOutcome.ABORT_SENT)
        except Exception as exc:  # noqa: BLE001 - nothing more a driver can do: the caller says the state is unknown
            return StopResult(StopOutcome.UNKNOWN, exc)
