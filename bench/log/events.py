"""Sequencer events, one class per kind, and the listener interface shared by the recorder, CLI progress and the TUI.

The sequencer calls every listener on its own thread; a listener must be quick (the
TUI buffers and redraws at 10-20 Hz; the recorder writes). Times are on the
sequencer's injected clock (simulated seconds with the simulator).

An event is logged as `Event.to_dict()` (the `/events` topic): `time_s`, `kind`, `message`,
`state`, `step_index`, `step_unit` and a `data` object whose keys depend on the kind. A log
is read back with `Event.from_dict`, the one place the logged fields are parsed (a log from
outside may hold anything: a field of the wrong type raises, which the reader counts as
damage; a kind the bench does not write is kept as `OtherEvent`). A dwell's or turn's
`StepFinished` whose step record or counter window cannot be used is kept, with the reason in
`malformed` (`malformed_observation_steps` names it; the solvers leave it out).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any, ClassVar, Sequence

from bench.model.kinematics import FRAMES
from bench.model.observations import DIRECTION_SIGN
from bench.plan.steps import OBSERVATION_KINDS
from schedules.loader import Direction, Frame

if TYPE_CHECKING:   # types only: the log layer does not import the drivers or python-can at run time
    import can

    from drivers.chamber import ChamberState
    from drivers.imu import ImuSampleBlock
    from drivers.turntable import TableState


class RunState(enum.Enum):
    IDLE = "idle"
    RUNNING = "running"
    PAUSED = "paused"
    ABORTING = "aborting"
    DONE = "done"
    FAILED = "failed"


class EventKind(enum.StrEnum):
    """The kinds of event the bench writes: a state transition, step boundaries, and things worth a line."""

    TRANSITION = "transition"
    STEP_STARTED = "step_started"
    STEP_FINISHED = "step_finished"
    STEP_SKIPPED = "step_skipped"
    FAULT = "fault"
    WARNING = "warning"
    INFO = "info"


#: Event kinds: a state transition, step boundaries, and things worth a line in the log.
EVENT_KINDS = tuple(k.value for k in EventKind)


@dataclass(frozen=True)
class SoakStatus:
    """What the soak tracker (`bench.run.soak.SoakTracker`) knows at `time_s`; `decision` names a change worth an
    event ('' if none)."""

    time_s: float
    imu_temperature_c: float | None
    rate_c_per_min: float | None
    chamber_c: float | None
    chamber_at_setpoint: bool
    steady_for_s: float
    done: bool
    decision: str = ""

    def as_dict(self) -> dict:
        return {"imu_temperature_c": self.imu_temperature_c, "rate_c_per_min": self.rate_c_per_min,
                "chamber_c": self.chamber_c, "chamber_at_setpoint": self.chamber_at_setpoint,
                "steady_for_s": self.steady_for_s}

    @classmethod
    def from_logged(cls, time_s: float, data: dict[str, Any], done: bool, decision: str = "") -> SoakStatus | None:
        """The status an event's `data` holds (`as_dict`'s keys), None when a field is missing or of the wrong type
        (nothing reads a soak's numbers from a log but the TUI's display)."""
        def number(key: str) -> float | None:
            value = data.get(key)
            if value is not None and type(value) not in (int, float):
                raise TypeError(key)
            return None if value is None else float(value)
        try:
            steady_for_s = number("steady_for_s")
            if type(data.get("chamber_at_setpoint")) is not bool or steady_for_s is None:
                return None
            return cls(time_s, number("imu_temperature_c"), number("rate_c_per_min"), number("chamber_c"),
                       data["chamber_at_setpoint"], steady_for_s, done, decision)
        except TypeError:
            return None


@dataclass(frozen=True)
class Event:
    """One thing that happened in a run: what every kind has. `kind` is the logged kind (a class per kind)."""

    time_s: float
    message: str
    step_index: int | None = None
    step_unit: str | None = None
    KIND: ClassVar[str] = ""

    @property
    def kind(self) -> str:
        return self.KIND

    def _state(self) -> str | None:
        return None

    def _data(self) -> dict[str, Any]:
        """The kind's `data` object as logged."""
        return {}

    def to_dict(self) -> dict[str, Any]:
        return {"time_s": self.time_s, "kind": self.kind, "message": self.message, "state": self._state(),
                "step_index": self.step_index, "step_unit": self.step_unit, "data": self._data()}

    @staticmethod
    def from_dict(d: dict[str, Any]) -> Event:
        """The event a logged object describes, of its kind's class. Raises KeyError, TypeError, ValueError (or
        AttributeError, OverflowError) when it cannot be an event: no time or kind, a field of the wrong type."""
        time_s, kind, message = float(d["time_s"]), str(d["kind"]), str(d.get("message", ""))
        state, step_index, step_unit = d.get("state"), d.get("step_index"), d.get("step_unit")
        data = dict(d.get("data") or {})
        if not (state is None or type(state) is str):
            raise TypeError("state")
        if not (step_unit is None or type(step_unit) is str):
            raise TypeError("step_unit")
        if not (step_index is None or (type(step_index) in (int, bool) and -(1 << 63) <= step_index < 1 << 63)):
            raise TypeError("step_index")
        parse = _PARSERS.get(kind)
        if parse is None:
            return OtherEvent(time_s, message, step_index, step_unit, logged_kind=kind, state=state, data=data)
        return parse(time_s, message, state, step_index, step_unit, data)


@dataclass(frozen=True, kw_only=True)
class Transition(Event):
    """The run's state changed to `state` (a `RunState` value) from `previous` (`data["from"]`)."""

    state: str | None
    previous: str | None = None
    KIND: ClassVar[str] = EventKind.TRANSITION

    def _state(self) -> str | None:
        return self.state

    def _data(self) -> dict[str, Any]:
        return {} if self.previous is None else {"from": self.previous}

    def to(self, *states: RunState) -> bool:
        """Whether the run went to one of `states`."""
        return self.state in {s.value for s in states}


@dataclass(frozen=True, kw_only=True)
class StepEvent(Event):
    """A step boundary of the step `step_index` / `step_unit`; `step` its record (`bench.plan.steps.step_to_dict`;
    None when the event carries none, or, from a log, when it is not an object)."""

    step: dict[str, Any] | None = None

    @property
    def step_kind(self) -> str | None:
        """The step record's kind (`move`, `dwell`, ...), None without one."""
        kind = self.step.get("kind") if self.step is not None else None
        return kind if isinstance(kind, str) else None

    @property
    def observation(self) -> bool:
        """Whether the step is a dwell or a turn (its record says so)."""
        return self.step_kind in OBSERVATION_KINDS

    def _data(self) -> dict[str, Any]:
        return {} if self.step is None else {"step": self.step}


@dataclass(frozen=True, kw_only=True)
class StepStarted(StepEvent):
    KIND: ClassVar[str] = EventKind.STEP_STARTED


@dataclass(frozen=True, kw_only=True)
class StepSkipped(StepEvent):
    """A step complete in an earlier run (a resumed run skips it)."""

    KIND: ClassVar[str] = EventKind.STEP_SKIPPED


@dataclass(frozen=True)
class CounterWindow:
    """The IMU sample counters a dwell or turn recorded, `first`..`last` inclusive, and the `samples` received
    in it (as the sequencer counted them; None when a log does not say)."""

    first: int
    last: int
    samples: Any = None

    def as_dict(self) -> dict[str, Any]:
        return {"counter_first": self.first, "counter_last": self.last, "samples": self.samples}


@dataclass(frozen=True)
class DwellRecord:
    """A finished dwell's step record, as the solvers read it."""

    angles_deg: tuple[float, float, float]


@dataclass(frozen=True)
class TurnRecord:
    """A finished turn's step record, as the solvers read it."""

    start_deg: tuple[float, float, float]
    target_deg: tuple[float, float, float]
    frame: Frame
    direction: Direction
    revolutions: int


@dataclass(frozen=True, kw_only=True)
class StepFinished(StepEvent):
    """A step done. A dwell or turn carries the IMU counter `window` it recorded; a soak the time it took
    (`soak_s`) and the `soak` status it ended with. From a log, `malformed` says why a dwell's or turn's event
    cannot be used (then `window` is None)."""

    window: CounterWindow | None = None
    soak_s: float | None = None
    soak: SoakStatus | None = None
    malformed: str | None = None
    KIND: ClassVar[str] = EventKind.STEP_FINISHED

    def _data(self) -> dict[str, Any]:
        out = super()._data()
        if self.window is not None:
            out.update(self.window.as_dict())
        if self.soak is not None:
            out.update({"soak_s": self.soak_s, **self.soak.as_dict()})
        return out

    @cached_property
    def record(self) -> DwellRecord | TurnRecord | None:
        """A dwell's or turn's step record with its window (`usable`), else None."""
        if self.window is None or self.malformed is not None or not self.observation:
            return None
        record = _observation_record(self.step)
        return None if isinstance(record, str) else record

    @property
    def usable(self) -> bool:
        """Whether this is a well-formed finished dwell or turn: its record and counter window can be used."""
        return self.record is not None


@dataclass(frozen=True, kw_only=True)
class Note(Event):
    """A line worth the log: `details` are the annotations it carries (an operator's command and its arguments,
    the IMU link's counts, ...), logged as they are and read by no code but one: a unit dropped (`UNIT_DROPPED`)."""

    details: dict[str, Any] = field(default_factory=dict)

    def _data(self) -> dict[str, Any]:
        return dict(self.details)


@dataclass(frozen=True, kw_only=True)
class Fault(Note):
    """What went wrong, before the safe stop: `error` the exception's type; `table_state` "unknown" when the
    stop could not be confirmed."""

    error: str | None = None
    table_state: str | None = None
    KIND: ClassVar[str] = EventKind.FAULT

    def _data(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.error is not None:
            out["error"] = self.error
        if self.table_state is not None:
            out["table_state"] = self.table_state
        return {**out, **self.details}


#: the `RunWarning` details key naming a unit of several dropped from the run (`bench.run.units` writes it,
#: `bench.finish.units` reads it: that unit gets no result, saying why)
UNIT_DROPPED = "unit_dropped"


@dataclass(frozen=True, kw_only=True)
class RunWarning(Note):
    KIND: ClassVar[str] = EventKind.WARNING


@dataclass(frozen=True, kw_only=True)
class Info(Note):
    """A line of information; a soak's decision carries the `soak` status it was taken on."""

    soak: SoakStatus | None = None
    KIND: ClassVar[str] = EventKind.INFO

    def _data(self) -> dict[str, Any]:
        soak = {} if self.soak is None else {"soak": self.soak.decision, **self.soak.as_dict()}
        return {**soak, **self.details}


@dataclass(frozen=True, kw_only=True)
class OtherEvent(Event):
    """An event of a kind the bench does not write (a log from outside), kept as logged."""

    logged_kind: str
    state: str | None = None
    data: dict[str, Any] = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return self.logged_kind

    def _state(self) -> str | None:
        return self.state

    def _data(self) -> dict[str, Any]:
        return dict(self.data)


# -- parsing the logged data of each kind -----------------------------------------------------------------------

def _vector(v, n: int = 3) -> bool:
    return (isinstance(v, list) and len(v) == n
            and all(type(x) in (int, float) and math.isfinite(x) for x in v))


def _int(x) -> bool:
    return type(x) is int and abs(x) < 1 << 62


def _observation_record(step: Any) -> DwellRecord | TurnRecord | str:
    """A dwell's or turn's step record, or why it cannot be used (a log from outside may hold anything)."""
    if not isinstance(step, dict):
        return "its step record is not an object"
    if step.get("kind") == "dwell":
        if not _vector(step.get("angles_deg")):
            return "its angles_deg are not three finite numbers"
        return DwellRecord(tuple(step["angles_deg"]))
    if not (_vector(step.get("start_deg")) and _vector(step.get("target_deg"))):
        return "its start_deg or target_deg are not three finite numbers"
    if step.get("frame") not in FRAMES or step.get("direction") not in DIRECTION_SIGN:
        return "its frame or direction is not one the bench knows"
    if not (_int(step.get("revolutions")) and step["revolutions"] > 0):
        return "its revolutions are not a positive integer"
    return TurnRecord(tuple(step["start_deg"]), tuple(step["target_deg"]), step["frame"], step["direction"],
                      step["revolutions"])


def _transition(time_s, message, state, step_index, step_unit, data) -> Event:
    previous = data.get("from")
    return Transition(time_s, message, step_index, step_unit, state=state,
                      previous=previous if isinstance(previous, str) else None)


def _step(cls: type[StepStarted] | type[StepSkipped]):
    def parse(time_s, message, state, step_index, step_unit, data) -> Event:
        step = data.get("step")
        return cls(time_s, message, step_index, step_unit, step=step if isinstance(step, dict) else None)
    return parse


def _step_finished(time_s, message, state, step_index, step_unit, data) -> Event:
    """A dwell's or turn's window and record are checked here (a malformed one is kept, `malformed` saying why);
    a soak's status is kept when well-formed."""
    step = data.get("step")
    record = step if isinstance(step, dict) else None
    window, malformed = None, None
    if "counter_first" in data and (record is None or record.get("kind") in OBSERVATION_KINDS):
        first, last = data.get("counter_first"), data.get("counter_last")
        if record is None:
            malformed = "its step record is not an object"
        elif not (_int(first) and _int(last) and first <= last):
            malformed = "its IMU counter window is not two integers, first <= last"
        else:
            checked = _observation_record(step)
            if isinstance(checked, str):
                malformed = checked
            else:
                window = CounterWindow(first, last, data.get("samples"))
    soak, soak_s = None, data.get("soak_s")
    if type(soak_s) in (int, float):
        soak = SoakStatus.from_logged(time_s, data, done=True)
    return StepFinished(time_s, message, step_index, step_unit, step=record, window=window,
                        soak_s=float(soak_s) if soak is not None else None, soak=soak, malformed=malformed)


def _fault(time_s, message, state, step_index, step_unit, data) -> Event:
    error, table_state = data.pop("error", None), data.pop("table_state", None)
    if not isinstance(error, str):
        error = None
    if not isinstance(table_state, str):
        table_state = None
    return Fault(time_s, message, step_index, step_unit, error=error, table_state=table_state, details=data)


def _warning(time_s, message, state, step_index, step_unit, data) -> Event:
    return RunWarning(time_s, message, step_index, step_unit, details=data)


_SOAK_KEYS = ("soak", "imu_temperature_c", "rate_c_per_min", "chamber_c", "chamber_at_setpoint", "steady_for_s")


def _info(time_s, message, state, step_index, step_unit, data) -> Event:
    decision = data.get("soak")
    soak = (SoakStatus.from_logged(time_s, data, done=decision == "done", decision=decision)
            if isinstance(decision, str) else None)
    if soak is not None:
        data = {k: v for k, v in data.items() if k not in _SOAK_KEYS}
    return Info(time_s, message, step_index, step_unit, soak=soak, details=data)


_PARSERS = {EventKind.TRANSITION.value: _transition, EventKind.STEP_STARTED.value: _step(StepStarted),
            EventKind.STEP_SKIPPED.value: _step(StepSkipped), EventKind.STEP_FINISHED.value: _step_finished,
            EventKind.FAULT.value: _fault, EventKind.WARNING.value: _warning, EventKind.INFO.value: _info}


def make_event(time_s: float, kind: str, message: str, state: str | None = None, step_index: int | None = None,
               step_unit: str | None = None, data: dict[str, Any] | None = None) -> Event:
    """The event of `kind` with these logged fields (`Event.from_dict`): a line the UI adds, a test's event."""
    return Event.from_dict({"time_s": time_s, "kind": kind, "message": message, "state": state,
                            "step_index": step_index, "step_unit": step_unit, "data": data or {}})


# -- the finished dwells and turns of a log ---------------------------------------------------------------------

def finished_observation_steps(events: Sequence[Event]) -> dict[str, tuple[StepStarted | None, StepFinished]]:
    """unit -> (its step_started event, its step_finished event) for dwells and turns; a re-run wins.
    Only well-formed finished steps count (`StepFinished.usable`; `malformed_observation_steps` lists the others)."""
    started: dict[str, StepStarted] = {}
    done: dict[str, tuple[StepStarted | None, StepFinished]] = {}
    for event in events:
        unit = event.step_unit
        if unit is None:
            continue
        if isinstance(event, StepStarted) and event.observation:
            started[unit] = event
        elif isinstance(event, StepFinished) and event.usable:
            done[unit] = (started.get(unit), event)
    return done


def malformed_observation_steps(events: Sequence[Event]) -> dict[str, str]:
    """unit -> its line, in the order of the units, for each dwell or turn whose step_finished event cannot be
    used (`StepFinished.malformed`), unless a well-formed one of the same unit replaces it."""
    good = finished_observation_steps(events)
    lines = {}
    for event in events:
        if (isinstance(event, StepFinished) and event.malformed is not None and event.step_unit is not None
                and event.step_unit not in good):
            lines[event.step_unit] = (f"{event.step_unit}: its step_finished event is malformed ({event.malformed}); "
                                      "left out")
    return {k: lines[k] for k in sorted(lines)}


def final_state(events: Sequence[Event]) -> str | None:
    """The state of the last transition that names one (None: no such transition)."""
    return next((e.state for e in reversed(events) if isinstance(e, Transition) and e.state), None)


class RunListener:
    """Receives everything a run produces. Override what you need; the defaults ignore it.

    `on_can_frames` gets every raw CAN frame before decoding (a poll's frames: a sequence of python-can
    `Message`s; from a live receiver a `drivers.imu.frames.CanFrameBatch`, whose arrays spare the per-frame work);
    `on_imu` the decoded samples (`drivers.imu.ImuSampleBlock`); `on_table_state` each
    polled `drivers.turntable.TableState`; `on_chamber_state` each polled
    `drivers.chamber.ChamberState` (a thermal plan's runs); `on_soak_status` the soak's state
    (`SoakStatus`) at every check of a soak step. `close()` is called once at the end of a run.
    """

    def on_event(self, event: Event) -> None:
        pass

    def on_table_state(self, state: TableState) -> None:
        pass

    def on_imu(self, block: ImuSampleBlock) -> None:
        pass

    def on_chamber_state(self, state: ChamberState) -> None:
        """Each polled thermal-chamber state (runs with a chamber only)."""

    def on_soak_status(self, status: SoakStatus) -> None:
        """The soak's state at each check while a soak step runs (its decisions are `info` events too)."""

    def on_can_frames(self, frames: Sequence[can.Message]) -> None:
        pass

    def close(self) -> None:
        pass
