"""Run progress on a terminal: a live status line on a TTY, plain lines otherwise.

A `RunListener`: the current step, an overall bar by estimated time, and the ETA in
the run clock's time (simulated seconds under the simulator, which says so). Plain
mode (not a TTY: logs, CI) prints one line per step start, warning, fault and
transition; quiet mode prints faults only.
"""

from __future__ import annotations

import sys
from typing import Sequence, TextIO

from bench.model.units import format_hms
from bench.plan.events import Event, RunListener
from bench.plan.steps import Step


class ProgressPrinter(RunListener):
    """Prints progress of a run of `steps` to `stream` (default stderr)."""

    def __init__(self, steps: Sequence[Step], stream: TextIO | None = None, *, quiet: bool = False,
                 live: bool | None = None, simulated: bool = False, bar_width: int = 24):
        self.stream = stream if stream is not None else sys.stderr
        self.steps = list(steps)
        self.quiet = quiet
        self.live = self.stream.isatty() if live is None else live
        self.simulated = simulated
        self.bar_width = bar_width
        self.total_s = sum(s.estimated_s for s in self.steps) or 1.0
        self._done_s = 0.0
        self._current: Step | None = None
        self._started_at = 0.0
        self._line_open = False

    def _print(self, text: str) -> None:
        if self._line_open:
            self.stream.write("\n")
            self._line_open = False
        self.stream.write(text + "\n")
        self.stream.flush()

    def _status(self, now: float) -> None:
        step = self._current
        elapsed_in_step = now - self._started_at
        done = self._done_s + (min(elapsed_in_step, step.estimated_s) if step else 0.0)
        fraction = min(1.0, done / self.total_s)
        filled = int(round(fraction * self.bar_width))
        bar = "#" * filled + "-" * (self.bar_width - filled)
        what = f"step {step.index + 1}/{len(self.steps)} {step.unit} {step.kind}" if step else ""
        left = (f" {format_hms(step.estimated_s - elapsed_in_step)} left" if step and step.kind in ("dwell", "settle")
                else "")
        clock = " sim" if self.simulated else ""
        self.stream.write(f"\r[{bar}] {fraction:5.1%} {what}{left}  ETA{clock} {format_hms(self.total_s - done)}   ")
        self.stream.flush()
        self._line_open = True

    def on_event(self, event: Event) -> None:
        if event.kind in ("fault",):
            self._print(f"FAULT: {event.message}")
            return
        if self.quiet:
            return
        if event.kind == "step_started":
            index = event.step_index
            self._current = self.steps[index] if index is not None else None
            self._started_at = event.time_s
            if not self.live and index is not None:
                self._print(f"[{format_hms(event.time_s)}] step {index + 1}/{len(self.steps)} {event.message}")
        elif event.kind in ("step_finished", "step_skipped"):
            if event.step_index is not None:
                self._done_s += self.steps[event.step_index].estimated_s
            self._current = None
            if event.kind == "step_skipped" and not self.live:
                self._print(f"skipped {event.message}")
        elif event.kind in ("transition", "warning", "info"):
            self._print(f"[{format_hms(event.time_s)}] {event.kind}: {event.message}")
        if self.live:
            self._status(event.time_s)

    def on_table_state(self, state) -> None:
        if self.live and not self.quiet and self._current is not None:
            self._status(state.time_s)

    def close(self) -> None:
        if self._line_open:
            self.stream.write("\n")
            self.stream.flush()
            self._line_open = False
