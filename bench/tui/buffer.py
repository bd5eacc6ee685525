"""What the TUI shows, collected from a run's listener calls (no Textual here).

`UiBuffer` is a `RunListener`: the sequencer (or the session's idle monitor, or a
replay) calls it on its own thread; each call takes a lock and updates a few fields or
ring buffers. The UI thread takes a consistent copy with `snapshot()` 10-20 times a
second: high-rate IMU data never becomes one UI message per sample.
"""

from __future__ import annotations

import enum
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable, Sequence

from bench.log.events import (
    UNIT_DROPPED,
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
    make_event,
)
from bench.model.kinematics import triple
from bench.model.result import CalibrationResult
from bench.model.units import DEG, G0
from bench.tui.tracks import (
    CHANNELS,
    MEAN_WINDOW_S,
    STALE_AFTER_S,
    ImuTrack,
    ImuView,
    UnitOutcome,
    UnitView,
    link_counts,
)
from drivers.chamber import ChamberState
from drivers.imu import ImuStats
from drivers.turntable import TableState


class StepState(enum.StrEnum):
    """Where a step of the plan stands, as the plan panel shows it."""

    PENDING = "pending"
    RUNNING = "running"
    DONE = "done"
    SKIPPED = "skipped"
    FAILED = "failed"
    #: the step under way when the operator aborted the run (an abort request, not a fault)
    ABORTED = "aborted"


#: what the TUI calls a run that failed because it was aborted on request (operator, e-stop, quit): the
#: sequencer's state is `failed` either way; the log tells them apart (a fault event comes before a failure)
RUN_ABORTED = "aborted"


@dataclass(frozen=True)
class LogLine:
    """An event as the event log shows it: `run_elapsed_s` is the time since the start of the run it belongs
    to, on the run's clock, never less than the line before it in that run (None: not part of a run: the
    session's own lines before, between and after runs); `wall_s` is the session's wall clock
    (`time.time()`) when the event reached the buffer."""

    event: Event
    run_elapsed_s: float | None
    wall_s: float


@dataclass(frozen=True)
class UiSnapshot:
    """A consistent copy of everything the UI draws."""

    run_state: RunState
    run_time_s: float | None               # latest time seen on the run's clock
    table_state: TableState | None
    table_states: int
    imu: ImuView
    step_states: tuple[StepState, ...]
    current_step: int | None
    current_started_s: float | None
    done_estimated_s: float
    event_count: int                       # events ever added (the UI appends the new ones)
    result: CalibrationResult | None = None
    outcome_text: str = ""
    aborted: bool = False                  # the run went to `aborting` on request, with no fault before it
    chamber_state: ChamberState | None = None   # the last polled chamber state (a thermal plan's runs)
    #: the current (or last) soak's state: `bench.log.events.SoakStatus.as_dict()` with `time_s`, `done` and the
    #: soak step's `step_index`; from the sequencer's checks, else (a replay) its decision events
    soak: dict | None = None
    #: a run of several IMUs: every unit as last seen, the reference unit first (its `imu` is `imu`); () for one IMU
    units: tuple[UnitView, ...] = ()
    #: a run of several IMUs that ended: every unit's result and verdict or why it has none (() until then)
    unit_outcomes: tuple[UnitOutcome, ...] = ()

    @property
    def run_state_text(self) -> str:
        """The run's state as the operator reads it: the sequencer's, with `aborted` for a requested abort."""
        if self.run_state is RunState.FAILED and self.aborted:
            return RUN_ABORTED
        return self.run_state.value


class UiBuffer(RunListener):
    """Thread-safe store of a run's latest state for the TUI (see the module docstring).

    `steps` are the compiled plan's steps (for step states and progress); `history`
    is the number of samples kept per IMU channel for the sparklines; `max_events`
    bounds the event log kept here. `stats_source` (an object with `lost_samples` and
    `frame_faults`, e.g. an `ImuReceiver`'s `stats`) supplies the link counters.
    """

    def __init__(self, steps: Sequence = (), *, history: int = 120, max_events: int = 2000,
                 clock: Callable[[], float] = time.monotonic, wall_clock: Callable[[], float] = time.time,
                 estimates: Sequence[float] | None = None):
        if history < 2:
            raise ValueError(f"history must be at least 2 samples, got {history}")
        self._lock = threading.Lock()
        self.history = int(history)
        self.stats_source: ImuStats | None = None
        self.clock, self.wall_clock = clock, wall_clock     # injected by tests: no test waits on real time
        self._events: deque[tuple[int, LogLine]] = deque(maxlen=max_events)
        self._event_count = 0
        self._run_origin_s: float | None = None      # the current run's start on its clock (None: no run)
        self._run_elapsed_s = 0.0                     # the last run line's elapsed time
        self._imu = ImuTrack(self.history)             # the IMU (a run of several: the reference unit)
        #: a run of several IMUs: (serial, face) of every unit, the reference first; the others' tracks and links
        self._units: tuple[tuple[str, str], ...] = ()
        self._unit_tracks: dict[str, ImuTrack] = {}
        self.unit_stats_sources: dict[str, ImuStats] = {}
        self._dropped: dict[str, str] = {}
        self._unit_outcomes: tuple[UnitOutcome, ...] = ()
        self._table_state: TableState | None = None
        self._table_states = 0
        self._run_time_s: float | None = None
        self._result: CalibrationResult | None = None
        self._outcome_text = ""
        self._chamber_state: ChamberState | None = None
        self.begin_run(steps, estimates)

    # -- set-up (any thread) ---------------------------------------------------------------
    def begin_run(self, steps: Sequence, estimates: Sequence[float] | None = None) -> None:
        """Forget the previous run's step states, progress and result; keep table/IMU/log. `estimates` (s, one
        per step; default the steps' own): what the steps will take (`bench.run.timing.estimates`)."""
        with self._lock:
            self.steps = tuple(steps)
            self.estimates = step_estimates(self.steps, estimates)
            self._step_states = [StepState.PENDING] * len(self.steps)
            self._current: int | None = None
            self._current_started: float | None = None
            self._done_estimated = 0.0
            self._run_state = RunState.IDLE
            self._fault_seen = False
            self._aborted = False
            self._result = None
            self._outcome_text = ""
            self._soak: dict | None = None
            self._dropped = {}
            self._unit_outcomes = ()

    @property
    def total_estimated_s(self) -> float:
        return sum(self.estimates)

    def note(self, kind: str, message: str, **data) -> None:
        """Add a line of the UI's own (operator actions, link errors) to the event log, at the latest time seen
        on the run's clock."""
        with self._lock:
            t = self._run_time_s if self._run_time_s is not None else 0.0
            self._add_event(make_event(t, kind, message, data=data))

    def set_outcome(self, result: CalibrationResult | None = None, text: str = "") -> None:
        """The finished run's result (a CalibrationResult, or None) and a one-line account."""
        with self._lock:
            self._result, self._outcome_text = result, text

    # -- RunListener (the sequencer's thread) ------------------------------------------------
    def _add_event(self, event: Event) -> None:
        """Keep `event` as a `LogLine` (lock held): a run's lines from its start transition (a transition to
        running from idle; a resume is not a start) to its end (done or failed) count from that start, the
        others are the session's."""
        if isinstance(event, Transition) and event.to(RunState.RUNNING) and event.previous == RunState.IDLE.value:
            self._run_origin_s, self._run_elapsed_s = event.time_s, 0.0
        elapsed = None
        if self._run_origin_s is not None:
            # a line of the run: monotonic (a note takes the latest time seen, which an event may trail)
            elapsed = self._run_elapsed_s = max(self._run_elapsed_s, event.time_s - self._run_origin_s)
            if isinstance(event, Transition) and event.to(RunState.DONE, RunState.FAILED):
                self._run_origin_s = None            # the run's last line
        self._event_count += 1
        self._events.append((self._event_count, LogLine(event, elapsed, self.wall_clock())))

    def on_event(self, event: Event) -> None:
        with self._lock:
            self._add_event(event)
            latest_s = event.time_s if self._run_time_s is None else max(self._run_time_s, event.time_s)
            self._run_time_s = event.time_s
            index = event.step_index
            k = index if index is not None and 0 <= index < len(self._step_states) else None  # None: no valid step
            if isinstance(event, Fault):
                self._fault_seen = True
            if isinstance(event, RunWarning) and isinstance(event.details.get(UNIT_DROPPED), str):
                # a unit of several dropped from the run (`bench.run.units`): its state says why
                self._dropped[event.details[UNIT_DROPPED]] = str(event.details.get("reason") or "no reason recorded")
            if isinstance(event, Transition) and event.state is not None:
                self._run_state = RunState(event.state)
                if self._run_state is RunState.ABORTING and not self._fault_seen:
                    self._aborted = True        # the sequencer emits a fault before an abort it was not asked for
                if self._run_state is RunState.FAILED and self._current is not None:
                    self._step_states[self._current] = StepState.ABORTED if self._aborted else StepState.FAILED
                    # the part of the step done before the end stays done: the progress never goes back
                    # (it counted min(elapsed, estimate) while the step ran, and the time only goes on)
                    if self._current_started is not None:
                        step_s = self.estimates[self._current]
                        self._done_estimated += min(max(0.0, latest_s - self._current_started), step_s)
                    self._current = None
            elif isinstance(event, StepStarted) and k is not None:
                self._step_states[k] = StepState.RUNNING
                self._current, self._current_started = k, event.time_s
            elif isinstance(event, (StepFinished, StepSkipped)) and k is not None:
                self._step_states[k] = StepState.DONE if isinstance(event, StepFinished) else StepState.SKIPPED
                self._done_estimated += self.estimates[k]
                if self._current == k:
                    self._current = None
            elif isinstance(event, Fault) and k is not None:
                self._step_states[k] = StepState.FAILED
            if isinstance(event, StepStarted) and k is not None and self.steps[k].kind == "soak":
                self._soak = None                # a new soak: nothing known of it yet
            elif isinstance(event, Info) and event.soak is not None and k is not None:
                self._set_soak(event.soak, k)

    def _set_soak(self, status: SoakStatus, step_index: int | None) -> None:
        """Keep a soak state (lock held); a decision event older than the last check changes nothing."""
        if self._soak is not None and self._soak["time_s"] > status.time_s:
            return
        self._soak = {**status.as_dict(), "time_s": status.time_s, "done": status.done,
                      "step_index": step_index if step_index is not None else self._current}

    def on_chamber_state(self, state: ChamberState) -> None:
        with self._lock:
            self._chamber_state = state
            self._run_time_s = state.time_s

    def on_soak_status(self, status: SoakStatus) -> None:
        with self._lock:
            self._set_soak(status, self._current)

    def on_table_state(self, state: TableState) -> None:
        with self._lock:
            self._table_state = state
            self._table_states += 1
            self._run_time_s = state.time_s

    def on_imu(self, block) -> None:
        if len(block) == 0:
            return
        with self._lock:
            self._imu.add(block, self.clock())

    # -- a run of several IMUs ---------------------------------------------------------------------
    def set_units(self, units: Sequence[tuple[str, str]]) -> None:
        """The units of a run of several IMUs: (serial, the face it is mounted on), the reference unit first (its
        samples come through `on_imu`, the others' through `on_unit_imu`). Fewer than two: a single IMU."""
        with self._lock:
            self._units = tuple(units) if len(units) > 1 else ()
            self._unit_tracks = {serial: ImuTrack(self.history) for serial, _ in self._units[1:]}

    @property
    def units(self) -> tuple[tuple[str, str], ...]:
        """(serial, face) of every unit of a run of several IMUs, the reference first; () for one IMU."""
        return self._units

    def on_unit_imu(self, serial: str, block) -> None:
        """A unit's samples (a unit other than the reference one; an unknown serial is ignored)."""
        if len(block) == 0:
            return
        with self._lock:
            track = self._unit_tracks.get(serial)
            if track is not None:
                track.add(block, self.clock())

    def set_unit_outcomes(self, outcomes: Sequence[UnitOutcome]) -> None:
        """Every unit's end of the run (its result and verdict, or why it has none), in the units' order."""
        with self._lock:
            self._unit_outcomes = tuple(outcomes)

    # -- the UI thread -------------------------------------------------------------------------
    def events_after(self, seen: int) -> list[Event]:
        """Events added after the `seen`-th one (those still kept), oldest first."""
        return [line.event for line in self.lines_since(seen)[0]]

    def lines_since(self, seen: int) -> tuple[list[LogLine], int]:
        """(the event log's lines added after the `seen`-th one, oldest first; the count of events ever
        added), taken together: the count is the `seen` of the next call, so no event is handed out twice
        or skipped (an event added between a `snapshot()` and this call is counted with those it returns)."""
        with self._lock:
            return [line for k, line in self._events if k > seen], self._event_count

    def snapshot(self) -> UiSnapshot:
        lost, bad = link_counts(self.stats_source)
        units_stats = {serial: link_counts(stats) for serial, stats in list(self.unit_stats_sources.items())}
        with self._lock:
            now = self.clock()
            imu = self._imu.view(lost, bad, now)
            units = tuple(UnitView(serial, face, imu if k == 0 else self._unit_tracks[serial].view(
                *units_stats.get(serial, (0, 0)), now), self._dropped.get(serial, ""), k == 0)
                for k, (serial, face) in enumerate(self._units))
            return UiSnapshot(self._run_state, self._run_time_s, self._table_state, self._table_states, imu,
                              tuple(self._step_states), self._current, self._current_started,
                              self._done_estimated, self._event_count, self._result, self._outcome_text,
                              self._aborted, self._chamber_state,
                              dict(self._soak) if self._soak is not None else None, units, self._unit_outcomes)


@dataclass(frozen=True)
class Progress:
    """Where a run stands by estimated time (run-clock seconds)."""

    fraction: float
    remaining_s: float
    step_left_s: float | None   # dwell/settle countdown of the current step, None otherwise


def step_estimates(steps: Sequence, estimates: Sequence[float] | None = None) -> tuple[float, ...]:
    """`estimates` (one per step), or the steps' own."""
    out = tuple(s.estimated_s for s in steps) if estimates is None else tuple(float(e) for e in estimates)
    if len(out) != len(steps):
        raise ValueError(f"{len(out)} estimates for {len(steps)} steps")
    return out


def progress(snapshot: UiSnapshot, steps: Sequence, estimates: Sequence[float] | None = None) -> Progress:
    """Overall progress by the steps' estimated durations (`estimates`, default the steps' own), and the current
    step's countdown."""
    each = step_estimates(steps, estimates)
    total = sum(each) or 1.0
    done = snapshot.done_estimated_s
    left = None
    k = snapshot.current_step
    if k is not None and k < len(steps) and snapshot.current_started_s is not None and snapshot.run_time_s is not None:
        elapsed = max(0.0, snapshot.run_time_s - snapshot.current_started_s)
        done += min(elapsed, each[k])
        if steps[k].kind in ("dwell", "settle"):
            left = max(0.0, each[k] - elapsed)
    fraction = min(1.0, done / total)
    return Progress(fraction, max(0.0, total - done), left)


#: the IMU panel's legend, under its values (its title says they are means over `MEAN_WINDOW_S`): the units,
#: and where the scale factors come from. Only the simulator knows its IMU's scale factors (its true ones).
SIM_SOURCE = "deg/s deg/h g (the simulator's scale)"
RAW_SOURCE = "counts/s (no scale factors known)"


@dataclass(frozen=True)
class ImuScales:
    """Nominal scale factors to show the IMU in physical units, where they came from, and the
    data's resolution.

    `gyro_cps_per_dps` (counts/s per deg/s) and `acc_cps_per_g` (counts/s per g) per
    axis; None = unknown: the panel shows raw counts/s. `step_counts`: the smallest step of a
    sample's increment, in counts (gyro, accelerometer): the layout's signal resolution, or one whole
    count when the IMU counts whole pulses (the simulated IMU with quantisation on). A mean over T
    seconds resolves `step_counts / T` counts/s: the panel shows that many decimals, no more.
    """

    gyro_cps_per_dps: tuple[float, float, float] | None = None
    acc_cps_per_g: tuple[float, float, float] | None = None
    source: str = RAW_SOURCE
    step_counts: tuple[float, float] = (1.0, 1.0)

    @classmethod
    def from_config(cls, config, sim: bool) -> "ImuScales":
        """The simulated IMU's true scale factors with the simulator; raw counts otherwise
        (the configuration has no nominal scale factors of a real IMU)."""
        if config is None:
            return cls()
        scale = config.imu.layout.scale      # the signals' resolution: counts per raw unit
        step = (float(max(scale[0:3])), float(max(scale[3:6])))
        if sim and config.sim.noise.quantise:
            step = (max(step[0], 1.0), max(step[1], 1.0))    # the simulated IMU counts whole pulses
        if not sim:
            return cls(source=RAW_SOURCE, step_counts=step)
        imu = config.sim.imu
        return cls(triple(float(k) * DEG for k in imu.gyro_scale), triple(float(k) * G0 for k in imu.acc_scale),
                   SIM_SOURCE, step)

    def decimals(self, gyro: bool, per_count: float, most: int) -> int:
        """Decimals that show what a `MEAN_WINDOW_S` mean resolves in a unit of `per_count` units per
        count/s (1 for counts/s; 3600 / scale for deg/h): the fewest decimals whose last digit steps by at
        most 1.5 resolution steps (0.1 deg/h for a resolution of 0.09997 deg/h, 0.01 for 0.05); at most
        `most` (the panel's column width)."""
        step = self.step_counts[0 if gyro else 1] / MEAN_WINDOW_S * abs(per_count)
        if not (math.isfinite(step) and step > 0):
            return 0
        return min(most, max(0, math.ceil(-math.log10(1.5 * step))))


#: (`CHANNELS`, `STALE_AFTER_S` and `ImuView` are `bench.tui.tracks`'s, kept importable from here)
__all__ = ["CHANNELS", "MEAN_WINDOW_S", "RUN_ABORTED", "STALE_AFTER_S", "ImuScales", "ImuView", "LogLine", "Progress",
           "StepState", "UiBuffer", "UiSnapshot", "UnitView", "progress", "step_estimates"]
