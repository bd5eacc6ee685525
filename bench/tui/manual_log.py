"""The log of an operator's manual moves in `bench tui` (no Textual here).

A TUI session writes no file until something moves. The first manual move (go to, rate
mode, jog) opens a log of manual moves, `<out>/<run-id>-manual.mcap`, with the layout of a
run's log (`bench.log.recorder`: table states, events, raw CAN frames and IMU samples, the
configuration, site and IMU records, the DBC and configuration attached) but no plan record
(`run.kind` = "manual"). From then on the idle monitor hands it every table state, IMU block
and CAN frame it reads, and the session every operator command as an event. It is closed when
a plan starts (the plan writes its own log, as `bench run` does; a manual move after the plan
opens a new manual log) and when the session ends (disconnect or quit), after the table was
stopped.

`ManualLog` never raises and never blocks its callers: records go through a bounded queue to a
writer thread of its own, the only thread that touches the recorder (which is single-threaded).
A write that fails (a full disk, a folder gone) is contained as the sequencer contains a
failing listener: one warning to the operator (`warn`), nothing more is written, and the
table and the operator's controls carry on; a writer that cannot keep up drops records and
says how many.
"""

from __future__ import annotations

import queue
import threading
import time
from pathlib import Path
from typing import Callable

from bench.errors import BenchError
from bench.log.events import Event, Info, RunWarning, make_event
from bench.log.recorder import McapRecorder
from bench.run.runner import BenchRun
from drivers.clock import Clock

#: Records waiting for the writer thread (about a minute of a 10 Hz monitor's states and IMU blocks).
MAX_PENDING = 2000
_END = ("close", None)       # (by identity) the last item: the writer closes the file


class ManualLog:
    """Writes a session's manual moves to `recorder` on a thread of its own (see the module docstring).

    `clock`: the run clock events are stamped with; `warn(text)`: how a failure reaches the operator
    (the TUI's event log). Every method may be called from any thread.
    """

    def __init__(self, recorder: McapRecorder, clock: Clock, warn: Callable[[str], None], *,
                 max_pending: int = MAX_PENDING):
        self.recorder = recorder
        self.path = Path(recorder.path)
        self.clock = clock
        self._warn = warn
        self.failure: str | None = None        # why writing stopped (one line), None while it works
        self.dropped = 0                       # records the writer could not keep up with
        self._closing = False
        self._queue: queue.Queue[tuple[str, object]] = queue.Queue(maxsize=max_pending)
        self._thread = threading.Thread(target=self._write_loop, name="bench-tui-manual-log", daemon=True)
        self._thread.start()

    # -- records (any thread; never blocks, never raises) ---------------------------------------
    def event(self, kind: str, message: str, **data) -> None:
        """An operator command or a note, stamped now on the run clock."""
        self._put("on_event", make_event(self.clock.now(), kind, message, data=data))

    def on_table_state(self, state) -> None:
        self._put("on_table_state", state)

    def on_imu(self, block) -> None:
        if len(block):
            self._put("on_imu", block)

    def on_can_frames(self, frames) -> None:
        """The IMU receiver's frame callback (called on the thread that polls it)."""
        if len(frames):
            self._put("on_can_frames", frames)

    def _put(self, method: str, payload: object) -> None:
        if self._closing or self.failure is not None:
            return
        try:
            self._queue.put_nowait((method, payload))
        except queue.Full:
            self.dropped += 1
            if self.dropped == 1:
                self._warn(f"manual log {self.path.name}: the disk does not keep up; records are being dropped")

    # -- the writer thread -----------------------------------------------------------------------
    def _write_loop(self) -> None:
        while True:
            item = self._queue.get()
            if item is _END:
                break
            method, payload = item
            if self.failure is not None:
                continue
            try:
                getattr(self.recorder, method)(payload)
            except Exception as exc:  # noqa: BLE001 - contained like a sequencer listener: the table carries on
                self._fail(exc)
        try:
            self.recorder.close()
        except Exception as exc:  # noqa: BLE001 - the file is closed as it is; the operator is told
            self._fail(exc)

    def _fail(self, exc: Exception) -> None:
        if self.failure is not None:
            return
        what = str(exc) if isinstance(exc, BenchError) else f"{type(exc).__name__}: {exc}"
        self.failure = what
        self._warn(f"manual log {self.path.name} failed: {what}; manual moves are no longer recorded "
                   "(the table and the controls are not affected)")

    # -- the end ---------------------------------------------------------------------------------
    def close(self, reason: str, timeout_s: float = 20.0) -> bool:
        """Write a last event (`reason`), what is queued, the summary, and close the file (idempotent).

        Waits at most about `timeout_s`; False when the writer did not finish by then (a disk that hangs:
        the file may then lack its summary, readable like a crashed run's log)."""
        if not self._closing:
            self._closing = True                  # nothing more from the callers; the last records wait for room
            now = self.clock.now()
            last: list[Event] = [Info(now, f"manual log closed: {reason}")]
            if self.dropped:
                last.insert(0, RunWarning(now, f"{self.dropped} records were dropped: the disk did not keep up"))
            deadline = time.monotonic() + timeout_s
            try:
                for item in [*(("on_event", event) for event in last), _END]:
                    self._queue.put(item, timeout=max(0.0, deadline - time.monotonic()))
            except queue.Full:
                self._warn(f"manual log {self.path.name}: the writer did not finish; the file may be cut short")
                return False
            timeout_s = max(0.0, deadline - time.monotonic())
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    @property
    def closed(self) -> bool:
        return self._closing and not self._thread.is_alive()


class ManualLogs:
    """A session's logs of manual moves, at most one open at a time. `note(kind, text)`: the TUI's event log."""

    def __init__(self, note: Callable[[str, str], None], join_timeout_s: float = 20.0):
        self._note = note
        self.join_timeout_s = float(join_timeout_s)
        self.current: ManualLog | None = None
        self.paths: list[Path] = []                 # every log opened, in order
        self.failures: dict[Path, str] = {}         # those cut short: why (one line)
        self._lock = threading.Lock()
        self._warned = False                        # said that manual moves cannot be logged (until one is)

    def event(self, kind: str, message: str, **data) -> None:
        """An event in the open log (nothing when none is open)."""
        current = self.current
        if current is not None:
            current.event(kind, message, **data)

    def open_for_move(self, run: BenchRun, what: str, may_open: Callable[[], bool]) -> ManualLog | None:
        """Before a manual move (`what`): open a log of manual moves on `run`'s devices unless one is open or
        `may_open()` says no (a plan started meanwhile). Returns the log opened now, else None. A log that cannot
        be opened is one warning (until one opens again), never an error: the move goes ahead."""
        with self._lock:
            if self.current is not None or not may_open():
                return None
            try:
                recorder = run.open_manual_log()
            except Exception as exc:  # noqa: BLE001 - the operator's move matters more than its record
                if not self._warned:
                    self._warned = True
                    self._note("warning", f"manual moves are not logged: {exc}")
                return None
            assert run.clock is not None and run.receiver is not None     # an opened run has both
            manual = ManualLog(recorder, run.clock, lambda text: self._note("warning", text))
            self.current, self._warned = manual, False
            self.paths.append(manual.path)
            run.receiver.on_frames = manual.on_can_frames       # the frames the idle monitor's polls receive
        text = f"log of manual moves {manual.path} (from the first manual move: {what})"
        self._note("info", text)
        manual.event("info", text)
        return manual

    def close(self, run: BenchRun | None, reason: str) -> None:
        """Close the open log, if any (after the table was stopped, or before a plan starts): `reason` is its last
        event."""
        with self._lock:
            manual, self.current = self.current, None
        if manual is None:
            return
        receiver = run.receiver if run is not None else None
        if receiver is not None and receiver.on_frames == manual.on_can_frames:
            receiver.on_frames = None
        closed = manual.close(reason, self.join_timeout_s)
        if manual.failure is not None:
            self.failures[manual.path] = manual.failure
        elif not closed:
            self.failures[manual.path] = "its writer did not finish"
        else:
            self._note("info", f"log of manual moves closed ({reason}): {manual.path}")


__all__ = ["MAX_PENDING", "ManualLog", "ManualLogs"]
