"""Sequencer events and the listener interface shared by the recorder, CLI progress and the TUI.

The sequencer calls every listener on its own thread; a listener must be quick (the
TUI buffers and redraws at 10-20 Hz; the recorder writes). Times are on the
sequencer's injected clock (simulated seconds with the simulator).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Sequence

if TYPE_CHECKING:   # types only: the plan layer does not import the drivers or python-can at run time
    import can

    from bench.run.soak import SoakStatus
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


#: Event kinds: a state transition, step boundaries, and things worth a line in the log.
EVENT_KINDS = ("transition", "step_started", "step_finished", "step_skipped", "fault", "warning", "info")


@dataclass(frozen=True)
class Event:
    """One thing that happened in a run.

    `transition`: `state` is the new RunState value, `data["from"]` the old one.
    `step_started` / `step_finished` / `step_skipped`: `step_index`, `step_unit` and
    `data["step"]` (the step record as a dict); a finished observation step carries
    `data["counter_first"]`, `data["counter_last"]` (the IMU sample counters of its
    window, inclusive) and `data["samples"]`.
    `fault`: what went wrong (`data["error"]` the exception type), before the safe stop.
    """

    time_s: float
    kind: str
    message: str
    state: str | None = None
    step_index: int | None = None
    step_unit: str | None = None
    data: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"time_s": self.time_s, "kind": self.kind, "message": self.message, "state": self.state,
                "step_index": self.step_index, "step_unit": self.step_unit, "data": self.data}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Event":
        return cls(float(d["time_s"]), str(d["kind"]), str(d.get("message", "")), d.get("state"),
                   d.get("step_index"), d.get("step_unit"), dict(d.get("data") or {}))


class RunListener:
    """Receives everything a run produces. Override what you need; the defaults ignore it.

    `on_can_frames` gets every raw CAN frame (python-can `Message`s) before decoding;
    `on_imu` the decoded samples (`drivers.imu.ImuSampleBlock`); `on_table_state` each
    polled `drivers.turntable.TableState`; `on_chamber_state` each polled
    `drivers.chamber.ChamberState` (a thermal plan's runs); `on_soak_status` the soak's state
    (`bench.run.soak.SoakStatus`) at every check of a soak step. `close()` is called once at the end of a run.
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
