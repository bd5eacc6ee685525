"""The sequencer: executes a compiled plan through an explicit state machine.

States (bench.log.events.RunState) and the only transitions allowed:

    idle -> running            start
    running -> paused          pause request, taken at the next step boundary (a safe point)
    paused -> running          resume
    running|paused -> aborting abort request (API, Ctrl-C) or any error
    aborting -> failed         after the safe stop
    running -> done            every step executed

Whatever ends a run early, the table is left stopped: a controlled stop, then (after
an abort request or an error) the servos are switched off; an e-stop or a failed stop
goes straight to the controller's abort. Every transition and step boundary is an
event to the listeners (recorder, progress, TUI). Time comes from the injected clock:
with the simulator a simulated clock runs the plan far faster than real time.

Listeners cannot prevent the safe stop (docs/explanation/decisions/0004-the-safe-stop-rule.md). Each call to a
listener is contained: a listener that raises (a recorder on a full disk, a progress
printer on a closed pipe) gets nothing more, the others still get everything, and
the run ends at its next check as a fault (`ListenerError`, naming the error once).
When a run ends early the table is stopped first, before any listener hears of it
(one that raises or blocks cannot keep the table moving); then the listeners get,
in order, the fault, the transition to aborting, what the stop produced, and the
transition to failed.

While the table moves, settles, dwells or turns, the sequencer keeps draining the IMU
receiver (every frame goes to the listeners: nothing is lost while the table moves)
and polls the table state. An observation step (dwell, turn) records the IMU sample
counters of its window in its `step_finished` event; the solver's observations are
extracted from the log with those windows (bench.solve.extract).

With a thermal chamber (a thermal plan, `bench.plan.thermal`) the sequencer also runs the
set-temperature and soak steps, polls the chamber every `chamber_poll_s` whatever the step
(each state to the listeners; an alarm or a lost link is a fault like the table's), decides
the soak on the IMU's own temperature (`bench.run.soak`; every decision an `info` event
with `data["soak"]`), and its safe stop makes the chamber safe after stopping the table
(`Chamber.make_safe`: the configured safe setpoint, else stopped). A run that ends well
also leaves the chamber that way.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from bench.errors import BenchError
from bench.log.events import (
    CounterWindow,
    Event,
    Fault,
    Info,
    RunListener,
    RunState,
    RunWarning,
    SoakStatus,
    StepFinished,
    StepSkipped,
    StepStarted,
    Transition,
)
from bench.plan.steps import (
    DwellStep,
    MoveStep,
    SetTemperatureStep,
    SettleStep,
    SoakStep,
    Step,
    TurnStep,
    step_to_dict,
)
from bench.plan.thermal import block_observation_units
from bench.run.soak import SOAK_DECISIONS, SoakTracker
from drivers.chamber import Chamber, ChamberState
from drivers.clock import Clock
from drivers.errors import ImuTimeout, TurntableEStop, TurntableTimeout
from drivers.turntable import TABLE_STATE_UNKNOWN, StopOutcome, StopResult, Turntable

_TRANSITIONS = {
    (RunState.IDLE, RunState.RUNNING),
    (RunState.RUNNING, RunState.PAUSED),
    (RunState.PAUSED, RunState.RUNNING),
    (RunState.RUNNING, RunState.ABORTING),
    (RunState.PAUSED, RunState.ABORTING),
    (RunState.IDLE, RunState.ABORTING),
    (RunState.ABORTING, RunState.FAILED),
    (RunState.RUNNING, RunState.DONE),
}


class SequencerError(BenchError):
    """A run could not go on (base of the sequencer's own errors)."""


class RunAborted(SequencerError):
    """The run was aborted on request (operator, Ctrl-C, a signal, API)."""


class SoakTimeout(SequencerError):
    """The IMU did not soak within the step's maximum soak time (a fault: the chamber is made safe)."""


class ListenerError(SequencerError):
    """A listener (recorder, progress output, TUI) raised: the run ended, the table stopped."""


def describe_listener_error(listener: RunListener, exc: Exception) -> str:
    """One line on a listener's failure: the bench's own errors say what failed (the recorder's:
    "log disk full: ..."), anything else is named with the listener."""
    if isinstance(exc, BenchError):
        return str(exc)
    return f"{type(listener).__name__} failed: {type(exc).__name__}: {exc}"


@dataclass(frozen=True)
class SequencerOptions:
    """Timing of the sequencer's own loops (clock seconds) and move completion criteria."""

    settle_tolerance_deg: float = 0.001
    move_poll_s: float = 0.05       # table state poll period while a move or turn is under way
    imu_poll_s: float = 0.05        # IMU drain period at rest (settle, dwell, rests of a turn)
    state_period_s: float = 0.5     # table state poll period at rest
    move_timeout_s: float = 900.0   # a move or turn not complete after this -> TurntableTimeout
    imu_timeout_s: float = 2.0      # no IMU sample for this long while recording -> ImuTimeout
    stop_timeout_s: float = 60.0    # waiting for the table to come to rest after a stop
    chamber_poll_s: float = 1.0     # chamber state poll period (runs with a chamber)
    #: where the chamber goes on abort, fault or the end of the run (None: temperature control stopped)
    chamber_safe_setpoint_c: float | None = None


class Sequencer:
    """Runs `steps` on a turntable driver and an IMU receiver, reporting to listeners.

    `imu` is a `drivers.imu.receiver.ImuReceiver` (or anything with `poll()`,
    `stats` and `on_frames`); the sequencer installs itself as its frame callback.
    `completed_units` (from an interrupted run's log) are skipped: resume.
    `pause()`, `resume()` and `abort()` may be called from any thread.
    `listener_errors` holds (listener, error) for every listener that raised (each one once).
    """

    def __init__(self, steps: Sequence[Step], table: Turntable, imu, clock: Clock,
                 listeners: Iterable[RunListener] = (), options: SequencerOptions = SequencerOptions(),
                 completed_units: Iterable[str] = (), chamber: Chamber | None = None):
        self.steps = tuple(steps)
        self.chamber = chamber
        if chamber is None and any(isinstance(s, (SetTemperatureStep, SoakStep)) for s in self.steps):
            raise SequencerError("the plan has thermal-chamber steps but the run has no chamber")
        self._last_chamber_poll = float("-inf")
        self._last_chamber_poll_wall = float("-inf")     # time.monotonic() of the last poll (see `_pause`)
        self._chamber_state: ChamberState | None = None     # the last chamber reading
        self._soak: SoakTracker | None = None
        self.table, self.imu, self.clock = table, imu, clock
        self.listeners = list(listeners)
        self.listener_errors: list[tuple[RunListener, Exception]] = []
        self._working = list(self.listeners)          # the listeners that have not raised
        self._reported = 0                             # listener_errors already raised or reported
        self._held: list[tuple[str, object]] | None = None    # deliveries held back while the table stops
        self.options = options
        self.completed_units = set(completed_units)
        self.state = RunState.IDLE
        self.error: BaseException | None = None
        self.stop_result: StopResult | None = None      # what the safe stop of a run ended early achieved
        self.current_step: Step | None = None
        self.windows: dict[str, CounterWindow] = {}          # unit -> counter window of its observation
        self._abort_reason: str | None = None
        self._pause_requested = threading.Event()
        self._resume = threading.Event()
        self._lock = threading.Lock()
        self._last_state_poll = float("-inf")
        self._last_drain = float("-inf")
        self._last_sample_at: float | None = None
        self._lost_reported = 0
        self._window: list[int] | None = None        # [first, last] counters while recording
        imu.on_frames = self._on_frames

    # -- control (any thread) ------------------------------------------------------
    def pause(self) -> None:
        """Pause at the next step boundary (the table holds its position)."""
        self._resume.clear()
        self._pause_requested.set()

    def resume(self) -> None:
        self._pause_requested.clear()
        self._resume.set()

    def abort(self, reason: str = "abort requested") -> None:
        """End the run as soon as the current loop iteration notices; the table is stopped."""
        with self._lock:
            if self._abort_reason is None:
                self._abort_reason = reason
        self._resume.set()

    @property
    def abort_requested(self) -> bool:
        return self._abort_reason is not None

    # -- listeners ---------------------------------------------------------------------
    def _dispatch(self, method: str, payload: object) -> None:
        """Hand `payload` to `method` of every listener still working; never raises.

        A listener that raises is set aside (it gets nothing more) and its error kept in
        `listener_errors`: the run ends at its next check (`_check_listeners`). While the
        table is being stopped the deliveries are held back (see `_fail`)."""
        if self._held is not None:
            self._held.append((method, payload))
            return
        for listener in tuple(self._working):
            try:
                getattr(listener, method)(payload)
            except Exception as exc:  # noqa: BLE001 - a listener must not stop the others or the safe stop
                self._working.remove(listener)
                self.listener_errors.append((listener, exc))

    def publish_imu(self, block) -> None:
        """Hand IMU samples to the listeners, the way the run does (the runner's last samples after a run)."""
        self._dispatch("on_imu", block)

    def _check_listeners(self) -> None:
        """Raise `ListenerError` for the first listener error not raised yet (the others: see `_fail`)."""
        if self._reported < len(self.listener_errors):
            listener, exc = self.listener_errors[self._reported]
            self._reported += 1
            raise ListenerError(describe_listener_error(listener, exc)) from exc

    def _report_listener_errors(self) -> None:
        """A warning to the listeners still working for each listener error not reported yet."""
        while self._reported < len(self.listener_errors):     # bounded: a listener fails at most once
            listener, exc = self.listener_errors[self._reported]
            self._reported += 1
            self._emit(RunWarning, f"{describe_listener_error(listener, exc)} (it gets nothing more)",
                       self.current_step)

    # -- events ----------------------------------------------------------------------
    def warn(self, message: str, details: dict[str, Any]) -> None:
        """A warning of the current step from outside the sequencer's own checks (a unit of several dropped:
        `bench.run.units`), with the `details` that annotate it."""
        self._emit(RunWarning, message, self.current_step, details=details)

    def _emit(self, kind: Callable[..., Event], message: str, at: Step | None = None, **fields: Any) -> None:
        """An event of class `kind` now, of step `at` (None: of no step), with its kind's `fields`."""
        event = kind(self.clock.now(), message, at.index if at is not None else None,
                     at.unit if at is not None else None, **fields)
        self._dispatch("on_event", event)

    def _transition(self, new: RunState, message: str) -> None:
        if (self.state, new) not in _TRANSITIONS:
            raise SequencerError(f"illegal transition {self.state.value} -> {new.value}")
        old, self.state = self.state, new
        self._emit(Transition, message, None, state=new.value, previous=old.value)

    def _on_frames(self, frames) -> None:
        self._dispatch("on_can_frames", frames)

    # -- the run ---------------------------------------------------------------------
    def run(self) -> RunState:
        """Execute every step; returns DONE or FAILED (then `error` says why)."""
        self._transition(RunState.RUNNING, f"run started: {len(self.steps)} steps")
        try:
            for step in self.steps:
                self._check_abort()
                if self._pause_requested.is_set():
                    self._pause()
                if step.unit in self.completed_units or self._block_complete(step):
                    self._emit(StepSkipped, f"{step.unit} {step.kind}: complete in an earlier run", step,
                               step=step_to_dict(step))
                    continue
                self._execute(step)
            self._drain_imu()
            self._check_abort()         # an abort asked for after the last step's checks ends the run as aborted
            if self.chamber is not None:
                self._emit(Info, f"chamber: {self.chamber.make_safe(self.options.chamber_safe_setpoint_c)}",
                           details={"chamber": "made_safe"})
            self._transition(RunState.DONE, "run complete")
        except BaseException as exc:  # noqa: BLE001 - every way out must stop the table; re-raised if not ours
            self.error = exc
            self._fail(exc)
            if not isinstance(exc, Exception):
                raise
        return self.state

    def _block_complete(self, step: Step) -> bool:
        """A chamber step of a temperature block whose every observation is complete (resume): skipped."""
        if not isinstance(step, (SetTemperatureStep, SoakStep)) or not self.completed_units:
            return False
        units = block_observation_units(self.steps, step.temperature_index)
        return bool(units) and units <= self.completed_units

    def _pause(self) -> None:
        self._transition(RunState.PAUSED, "paused at a step boundary; the table holds its position")
        while not self._resume.wait(0.05):
            self._drain_imu()
            # the run's clock may stand still while paused (the simulator's does): the chamber is polled when
            # either clock says it is due, so an alarm raised during a pause ends the run then
            if self.chamber is not None and time.monotonic() - self._last_chamber_poll_wall >= \
                    self.options.chamber_poll_s:
                self._poll_chamber()
            self._poll_chamber_when_due()
            self._check_listeners()
        self._check_abort()
        self._transition(RunState.RUNNING, "resumed")

    def _fail(self, exc: BaseException) -> None:
        """Stop the table, then tell the listeners: nothing a listener does can delay or skip the stop."""
        self._held = []
        try:
            if isinstance(exc, RunAborted):
                message = str(exc)
            else:
                message = f"{type(exc).__name__}: {exc}"
                self._emit(Fault, message, self.current_step, error=type(exc).__name__)
            if (self.state, RunState.ABORTING) in _TRANSITIONS:    # not from done (a KeyboardInterrupt after it)
                self._transition(RunState.ABORTING, message)
            try:
                self._safe_stop(estop=isinstance(exc, TurntableEStop))
            finally:
                if self.chamber is not None:      # after the table: never skipped, never raises
                    self._emit(Info, f"chamber: {self.chamber.make_safe(self.options.chamber_safe_setpoint_c)}",
                               details={"chamber": "made_safe"})
        finally:
            held, self._held = self._held, None
            for method, payload in held:
                self._dispatch(method, payload)
        self._report_listener_errors()
        if self.state is RunState.ABORTING:
            self._transition(RunState.FAILED, f"run ended early; {self.stop_words}")

    def _safe_stop(self, estop: bool) -> None:
        """Stop the table, wait (bounded) for rest, switch servos off; abort if anything fails.

        `stop_result` says what happened: `STOPPED` only when the table was seen at rest with its servos
        commanded off, `ABORT_SENT` when the controller took the abort, `UNKNOWN` when nothing could be sent or
        confirmed (the events say `TABLE_STATE_UNKNOWN`)."""
        if estop:
            self.stop_result = self.table.safe_abort()
            self._emit_stop_result("e-stop: controller ")
            return
        try:
            self.table.stop()
            deadline = self.clock.now() + self.options.stop_timeout_s
            while True:
                state = self.table.read_state()
                self._publish_state(state)
                if all(abs(r) < 1e-9 for r in state.rates_dps) or self.clock.now() > deadline:
                    break
                self.clock.sleep(self.options.move_poll_s)
            self.table.disable()
            self._publish_state(self.table.read_state())
            self.stop_result = StopResult(StopOutcome.STOPPED)
            self._emit(Info, "table stopped and servos off")
        except Exception as exc:  # noqa: BLE001 - fall back to the controller's abort, report the first error
            aborted = self.table.safe_abort()
            self.stop_result = StopResult(aborted.outcome, aborted.error, exc)
            self._emit_stop_result("")
        try:
            self._drain_imu()
        except Exception:  # noqa: BLE001 - the IMU link may be what failed; the stop matters more
            pass

    def _emit_stop_result(self, prefix: str) -> None:
        """The stop's outcome as an event: info when the abort was taken (a warning after a failed controlled stop),
        a fault when the table state is unknown."""
        result = self.stop_result
        assert result is not None
        if result.unknown:
            self._emit(Fault, prefix + result.describe(), None, table_state="unknown")
        else:
            self._emit(RunWarning if result.stop_error is not None else Info, prefix + result.describe())

    @property
    def stop_words(self) -> str:
        """How the end of an early-ended run describes the table: "table stopped", or `TABLE_STATE_UNKNOWN`."""
        if self.stop_result is not None and self.stop_result.unknown:
            return TABLE_STATE_UNKNOWN
        return "table stopped"

    def _check_abort(self) -> None:
        """Raise when the run must end: a listener failed (`ListenerError`) or an abort was asked (`RunAborted`)."""
        self._check_listeners()
        if self._abort_reason is not None:
            raise RunAborted(self._abort_reason)

    # -- steps -------------------------------------------------------------------------
    def _execute(self, step: Step) -> None:
        self.current_step = step
        self._emit(StepStarted, f"{step.unit} {step.kind}", step, step=step_to_dict(step))
        started = self.clock.now()
        data: dict[str, Any] = {}
        if isinstance(step, MoveStep):
            self._move(step.target_deg, step.rate_dps)
        elif isinstance(step, SettleStep):
            self._rest(step.duration_s)
        elif isinstance(step, DwellStep):
            data = {"window": self._record(lambda: self._rest(step.dwell_s))}
        elif isinstance(step, TurnStep):
            data = {"window": self._record(lambda: self._turn(step))}
        elif isinstance(step, SetTemperatureStep):
            self._set_temperature(step)
        elif isinstance(step, SoakStep):
            soak_s, status = self._soak_until_steady(step)
            data = {"soak_s": soak_s, "soak": status}
        else:
            raise SequencerError(f"unknown step {step!r}")
        if isinstance(step, (DwellStep, TurnStep)):
            self.windows[step.unit] = data["window"]
        self._emit(StepFinished, f"{step.unit} {step.kind} done in {self.clock.now() - started:.1f} s", step,
                   step=step_to_dict(step), **data)
        self.current_step = None

    def _turn(self, step: TurnStep) -> None:
        self._rest(step.rest_s)
        self._move(step.end_deg, step.rate_dps)
        self._rest(step.rest_s)

    def _record(self, body) -> CounterWindow:
        """Run `body` while collecting the counter window of the samples received during it."""
        self._drain_imu()                       # samples before the window belong to the previous step
        self._window = []
        self._last_sample_at = self.clock.now()
        try:
            body()
            self._drain_imu()
            window = self._window
        finally:
            self._window = None
        if not window:
            raise ImuTimeout("no IMU samples were received during the recording window")
        return CounterWindow(window[0], window[1], window[2])

    def _move(self, target_deg: Sequence[float], rate_dps: float) -> None:
        self.table.move_to(tuple(target_deg), rate_dps=rate_dps)
        start = self.clock.now()
        tolerance = self.options.settle_tolerance_deg
        while True:
            self._check_abort()
            state = self.table.read_state()
            self._publish_state(state)
            self.table.check_state(state)
            self._poll_chamber_when_due()
            if all(axis.in_position and abs(axis.angle_deg - target) <= tolerance
                   for axis, target in zip(state.axes, target_deg)):
                return
            if self.clock.now() - start > self.options.move_timeout_s:
                raise TurntableTimeout(f"move to {list(target_deg)} deg not complete after "
                                       f"{self.options.move_timeout_s} s")
            self.clock.sleep(self.options.move_poll_s)
            self._drain_imu_when_due()

    def _poll_state_when_due(self, now: float) -> None:
        """Read, publish and check the table's state once `state_period_s` has passed since the last one."""
        if now - self._last_state_poll >= self.options.state_period_s:
            state = self.table.read_state()
            self._publish_state(state)
            self.table.check_state(state)

    def _rest(self, duration_s: float) -> None:
        end = self.clock.now() + duration_s
        while True:
            self._check_abort()
            now = self.clock.now()
            self._poll_state_when_due(now)
            self._poll_chamber_when_due()
            if now >= end - 1e-9:
                return
            # the clock steps to the next IMU drain or state poll, whichever is first (no step skips a state poll)
            self.clock.sleep(min(self.options.imu_poll_s, self.options.state_period_s, end - now))
            self._drain_imu_when_due()

    # -- the chamber -----------------------------------------------------------------
    def _set_temperature(self, step: SetTemperatureStep) -> None:
        assert self.chamber is not None
        self.chamber.clear_alarms()
        self.chamber.set_setpoint(step.setpoint_c, step.ramp_c_per_min)
        self.chamber.run()
        self._poll_chamber(force=True)

    def _soak_until_steady(self, step: SoakStep) -> tuple[float, SoakStatus]:
        """Rest until the IMU is soaked (`bench.run.soak`); its decisions are events. The time it took and the
        last status; `SoakTimeout` past the step's maximum."""
        tracker = self._soak = SoakTracker(step, self.clock.now())
        try:
            while True:
                self._check_abort()
                self._poll_state_when_due(self.clock.now())
                self._poll_chamber_when_due()
                self._drain_imu()
                status = tracker.status(self.clock.now())
                self._dispatch("on_soak_status", status)
                if status.decision:
                    self._emit(Info, f"soak {step.setpoint_c:g} degC: {SOAK_DECISIONS[status.decision]}", step,
                               soak=status)
                if status.done:
                    return self.clock.now() - tracker.start_s, status
                if tracker.timed_out(self.clock.now()):
                    raise SoakTimeout(f"the IMU did not soak at {step.setpoint_c:g} degC within "
                                      f"{step.max_soak_s / 60.0:g} min (IMU {status.imu_temperature_c} degC, rate "
                                      f"{status.rate_c_per_min} degC/min, chamber {status.chamber_c} degC)")
                self.clock.sleep(self.options.imu_poll_s)
        finally:
            self._soak = None

    def _poll_chamber_when_due(self) -> None:
        if self.chamber is not None and self.clock.now() - self._last_chamber_poll >= self.options.chamber_poll_s:
            self._poll_chamber()

    def _poll_chamber(self, force: bool = False) -> None:
        """Read the chamber, hand the state to the listeners and the soak; `ChamberAlarm` on an alarm (a fault)."""
        assert self.chamber is not None
        state = self.chamber.read_state()
        self._last_chamber_poll, self._last_chamber_poll_wall = self.clock.now(), time.monotonic()
        self._chamber_state = state
        self._dispatch("on_chamber_state", state)
        if self._soak is not None:
            self._soak.add_chamber(state.temperature_c)
        self.chamber.check_state(state)

    # -- data ----------------------------------------------------------------------------
    def _publish_state(self, state) -> None:
        self._last_state_poll = self.clock.now()
        self._dispatch("on_table_state", state)

    def _drain_imu_when_due(self) -> None:
        if self.clock.now() - self._last_drain >= self.options.imu_poll_s - 1e-9:
            self._drain_imu()

    def _drain_imu(self) -> None:
        block = self.imu.poll()
        now = self._last_drain = self.clock.now()
        if len(block):
            self._last_sample_at = now
            if self._soak is not None:
                temps = block.temperature_c[np.isfinite(block.temperature_c)]
                if len(temps):
                    self._soak.add_imu(float(block.receive_time_s.mean()), float(temps.mean()))
                else:
                    raise SequencerError("the IMU reports no temperature (its layout has no temperature signal): "
                                         "a soak cannot be decided")
            if self._window is not None:
                first, last = int(block.counter[0]), int(block.counter[-1])
                if self._window:
                    self._window[1] = last
                    self._window[2] += len(block)
                else:
                    self._window.extend([first, last, len(block)])
            self._dispatch("on_imu", block)
        elif (self._window is not None and self._last_sample_at is not None
              and now - self._last_sample_at > self.options.imu_timeout_s):
            raise ImuTimeout(f"no IMU sample for {now - self._last_sample_at:.1f} s while recording")
        stats = self.imu.stats
        lost = stats.lost_samples + stats.frame_faults
        if lost > self._lost_reported:
            self._lost_reported = lost
            self._emit(RunWarning, f"IMU link: {stats.summary()}", self.current_step,
                       details={"imu_stats": stats.as_dict()})
