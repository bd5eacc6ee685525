"""Run progress on a terminal: a live status line on a TTY, plain lines otherwise.

A `RunListener`. Live mode (a TTY): the current step, an overall bar by estimated time and
the ETA in the run clock's time; under the simulator, whose clock runs faster than the
wall, the wall-clock ETA as well. The line is redrawn in place (erased to its end, so no
stale text stays) and no longer once the run is ending (an abort prints its lines, not the
bar again after each). Plain mode (not a TTY: logs, CI): one line per unit (a position or
a rotation with its moves and settles), warnings, faults and transitions. Both end with a
summary line. Quiet mode prints faults only.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, Sequence, TextIO

from bench.cli.edge import bounded_line
from bench.log.events import (
    Event,
    Fault,
    Info,
    RunListener,
    RunState,
    RunWarning,
    StepFinished,
    StepSkipped,
    StepStarted,
    Transition,
)
from bench.model.units import format_hms
from bench.plan.steps import Step

#: erase from the cursor to the end of the line (ECMA-48 EL): what the last draw left goes
ERASE_TO_END = "\x1b[K"
#: below this fraction done the wall-clock ETA is not yet worth stating
_MIN_FRACTION_FOR_WALL_ETA = 0.01
_ENDING = {RunState.ABORTING.value, RunState.DONE.value, RunState.FAILED.value}


def text_bar(fraction: float, width: int) -> str:
    """`fraction` (0..1) of `width` as `#`, the rest as `-`."""
    filled = int(round(fraction * width))
    return "#" * filled + "-" * (width - filled)


class ProgressPrinter(RunListener):
    """Prints progress of a run of `steps` to `stream` (default stderr); `estimates` (s, one per step; default
    the steps' own) are what the run is expected to take (`bench.plan.retime`); `wall_clock` (seconds,
    default `time.monotonic`) measures the wall time for the simulator's wall ETA and the summary."""

    def __init__(self, steps: Sequence[Step], stream: TextIO | None = None, *, quiet: bool = False,
                 live: bool | None = None, simulated: bool = False, bar_width: int = 24,
                 wall_clock: Callable[[], float] = time.monotonic, estimates: Sequence[float] | None = None):
        self.stream = stream if stream is not None else sys.stderr
        self.steps = list(steps)
        self.estimates = [s.estimated_s for s in self.steps] if estimates is None else [float(e) for e in estimates]
        if len(self.estimates) != len(self.steps):
            raise ValueError(f"{len(self.estimates)} estimates for {len(self.steps)} steps")
        self.quiet = quiet
        self.live = self.stream.isatty() if live is None else live
        self.simulated = simulated
        self.bar_width = bar_width
        self.wall_clock = wall_clock
        self.total_s = sum(self.estimates) or 1.0
        self.units = list(dict.fromkeys(s.unit for s in self.steps))
        self._done_s = 0.0
        self._current: Step | None = None
        self._started_at = 0.0
        self._line_open = False
        self._ending = False
        self._last_unit: str | None = None
        self._first_time_s: float | None = None
        self._last_time_s = 0.0
        self._wall_start = wall_clock()
        self._finished = self._skipped = 0

    def _print(self, text: str) -> None:
        if self._line_open:
            self.stream.write("\n")
            self._line_open = False
        self.stream.write(text + "\n")
        self.stream.flush()

    def _fraction(self, now: float) -> float:
        step = self._current
        done = self._done_s + (min(now - self._started_at, self.estimates[step.index]) if step else 0.0)
        return min(1.0, done / self.total_s)

    def _status(self, now: float) -> None:
        step = self._current
        elapsed_in_step = now - self._started_at
        fraction = self._fraction(now)
        bar = text_bar(fraction, self.bar_width)
        what = f"step {step.index + 1}/{len(self.steps)} {step.unit} {step.kind}" if step else ""
        left = (f" {format_hms(self.estimates[step.index] - elapsed_in_step)} left"
                if step and step.kind in ("dwell", "settle") else "")
        remaining_s = self.total_s * (1.0 - fraction)
        eta = f"ETA sim {format_hms(remaining_s)}" if self.simulated else f"ETA {format_hms(remaining_s)}"
        if self.simulated and fraction >= _MIN_FRACTION_FOR_WALL_ETA:
            wall_s = self.wall_clock() - self._wall_start
            eta += f", wall ~{format_hms(wall_s * (1.0 - fraction) / fraction)}"
        self.stream.write(f"\r[{bar}] {fraction:5.1%} {what}{left}  {eta}{ERASE_TO_END}")
        self.stream.flush()
        self._line_open = True

    def _note_time(self, time_s: float) -> None:
        if self._first_time_s is None:
            self._first_time_s = time_s
            self._last_time_s = time_s
        self._last_time_s = max(self._last_time_s, time_s)

    def _stamp(self, time_s: float) -> str:
        """`[h:mm:ss]` since the run's first event: a hardware run's clock is the machine's monotonic
        clock (its uptime), which means nothing to a reader."""
        return f"[{format_hms(time_s - (self._first_time_s or 0.0))}]"

    def on_event(self, event: Event) -> None:
        self._note_time(event.time_s)
        if isinstance(event, Fault):
            self._print(f"FAULT: {event.message}")
            return
        if isinstance(event, Transition) and event.state in _ENDING:
            self._ending = True
        if self.quiet:
            return
        if isinstance(event, StepStarted):
            index = event.step_index
            self._current = self.steps[index] if index is not None else None
            self._started_at = event.time_s
            if not self.live and self._current is not None and self._current.unit != self._last_unit:
                self._last_unit = self._current.unit
                number = self.units.index(self._current.unit) + 1
                # "unit 30 of 30, 97% done": the unit starting and the run done so far ("30/30 units" read as
                # all of them done)
                self._print(f"{self._stamp(event.time_s)} {self._current.unit} (unit {number} of {len(self.units)}, "
                            f"{self._fraction(event.time_s):.0%} done)")
        elif isinstance(event, (StepFinished, StepSkipped)):
            if event.step_index is not None:
                self._done_s += self.estimates[event.step_index]
            self._current = None
            if isinstance(event, StepFinished):
                self._finished += 1
            else:
                self._skipped += 1
                if not self.live and event.step_unit != self._last_unit:
                    self._last_unit = event.step_unit
                    self._print(f"skipped {event.step_unit} (complete in an earlier log)")
        elif isinstance(event, (Transition, RunWarning, Info)):
            self._print(f"{self._stamp(event.time_s)} {event.kind}: {event.message}")
        if self.live and not self._ending:
            self._status(event.time_s)

    def on_table_state(self, state) -> None:
        if self.live and not self.quiet and not self._ending and self._current is not None:
            self._status(state.time_s)

    def close(self) -> None:
        """End the line and print the summary; never raises (it runs on the way out of every run, and
        a stream whose reader went away has already failed this listener, which the run reported)."""
        try:
            self._close()
        except (OSError, ValueError):       # BrokenPipeError; ValueError: the stream was closed
            pass

    def _close(self) -> None:
        if self._line_open:
            self.stream.write("\n")
            self._line_open = False
        if not self.quiet and self._first_time_s is not None:
            run_s = self._last_time_s - self._first_time_s
            wall_s = self.wall_clock() - self._wall_start
            clock = f"{format_hms(run_s)} simulated, {format_hms(wall_s)} wall" if self.simulated \
                else format_hms(run_s)
            skipped = f", {self._skipped} skipped" if self._skipped else ""
            self.stream.write(f"{self._finished} of {len(self.steps)} steps done{skipped} in {clock}\n")
        self.stream.flush()


class CountProgress:
    """Progress of `total` independent items (the logs of `bench solve --archive`): `item(text)` prints one line
    per item as it completes, tagged `[12/50 24%, ETA 0:00:41]` (the ETA from the mean time per item so far);
    `problem(text)` prints a line to `err` (shown even when quiet). On a terminal (`live`) a bar is redrawn in
    place below the lines, from the start (a cluster starting up) to `close()`, which erases it."""

    def __init__(self, total: int, stream: TextIO | None = None, err: TextIO | None = None, *, quiet: bool = False,
                 live: bool | None = None, bar_width: int = 24, clock: Callable[[], float] = time.monotonic):
        self.stream = stream if stream is not None else sys.stdout
        self.err = err if err is not None else sys.stderr
        self.total, self.quiet, self.bar_width, self.clock = total, quiet, bar_width, clock
        self.live = (not quiet and self.stream.isatty()) if live is None else live
        self.done = 0
        self.start = clock()
        self._bar_shown = False
        self._draw()

    def _tag(self) -> str:
        fraction = self.done / self.total if self.total else 1.0
        eta = ""
        if 0 < self.done < self.total:
            eta = f", ETA {format_hms((self.clock() - self.start) / self.done * (self.total - self.done))}"
        return f"{self.done}/{self.total} {fraction:.0%}{eta}"

    def _erase(self) -> None:
        if self._bar_shown:
            self.stream.write("\r" + ERASE_TO_END)
            self.stream.flush()
            self._bar_shown = False

    def _draw(self) -> None:
        if not self.live:
            return
        bar = text_bar(self.done / self.total if self.total else 1.0, self.bar_width)
        self.stream.write(f"\r[{bar}] {self._tag()}{ERASE_TO_END}")
        self.stream.flush()
        self._bar_shown = True

    def item(self, text: str, *, problem: bool = False) -> None:
        """One item completed: its line (to `err` when `problem`, and then even when quiet)."""
        self.done += 1
        self._erase()
        if problem or not self.quiet:
            out = self.err if problem else self.stream
            out.write(bounded_line(f"[{self._tag()}] {text}") + "\n")
            out.flush()
        self._draw()

    def advance_to(self, done: int) -> None:
        """`done` items completed so far, no line of their own (work counted in parts, e.g. percent of a search):
        the bar is redrawn when the count grows."""
        done = min(max(done, 0), self.total)
        if done > self.done:
            self.done = done
            self._draw()

    def note(self, text: str) -> None:
        """A line to `err` that is not an item (a warning), the bar kept below it."""
        self._erase()
        self.err.write(bounded_line(text) + "\n")
        self.err.flush()
        self._draw()

    def close(self) -> None:
        self._erase()
