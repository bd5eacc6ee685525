"""Replay a run log through the listener interface the live run uses (MCAP log -> replay:
docs/explanation/architecture.md#data-flow).

`replay(log, listeners)` merges the log's events, table states, thermal-chamber states
(a thermal run's), raw CAN frames and the IMU samples decoded from those frames (the
source of truth, with the layout recorded in the log) into one log-time order and calls
each listener's `on_event`, `on_table_state`, `on_chamber_state`, `on_can_frames` and
`on_imu` as the sequencer did, then `close()`.
No hardware, no bus: the frames come back as python-can `Message`s rebuilt from the
lossless `/can/raw` records, the table states as `drivers.turntable.TableState`s.

Order: each stream keeps its recorded order; across streams, items go by log time,
frames and samples stamped at or before an event's time before that event (the
sequencer drains the IMU before it reports a step finished), events before table
states and table states before chamber states of the same time. Frames are handed over
in batches of at most `block_s` of log time that never straddle an event or a state,
each batch followed by the samples its frames completed.

Pacing: `speed=None` delivers as fast as the listeners take it; `speed=X` sleeps on
the injected clock so that log time advances X times faster than clock time, in steps
of at most `step_s` so that `stop` (a `threading.Event`) is noticed quickly.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from bench.log.can_export import can_messages
from bench.log.events import RunListener, final_state
from bench.log.format import TOPIC_CAN
from bench.log.reader import LogError, RunLog
from bench.log.run_info import layout_and_config_from_log
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.imu import ImuSampleBlock, ImuStats
from drivers.imu.layout import ImuLayout
from drivers.turntable import AxisMode, AxisState, AxisStatus, TableState

_DATA, _EVENT, _STATE, _CHAMBER = 0, 1, 2, 3   # tie order at equal log time
_SAME_TIME_S = 1e-6


@dataclass
class ReplayStats:
    """What a replay delivered. Times: log seconds (run clock) and seconds on the replay clock."""

    events: int = 0
    table_states: int = 0
    chamber_states: int = 0
    samples: int = 0
    imu_blocks: int = 0
    frames: int = 0
    frame_batches: int = 0                     # the replay's deliveries of frames (cut at events, states, a grid)
    recorded_batches: int = 0                  # the log's /can/raw messages: the batches the recorder wrote
    log_start_s: float = 0.0
    log_duration_s: float = 0.0
    log_reached_s: float = 0.0                 # log time of the last item delivered, from the start
    run_state: str = ""                        # the recorded run's last transition ("done", "failed", ...)
    wall_s: float = 0.0                        # clock time of the whole replay, the log's reading included
    read_s: float = 0.0                        # of it, reading and decoding the log before the first item
    stopped: bool = False                      # `stop` was set before the end
    imu_stats: ImuStats | None = None          # from decoding the raw frames (None: not decoded)
    notes: list[str] = field(default_factory=list)   # e.g. why samples were not decoded, unusable states

    def summary(self) -> str:
        """One line: what was replayed, over how much log time, in how much clock time."""
        if self.stopped:
            span = f"stopped early at log time {self.log_reached_s:.1f} s of {self.log_duration_s:.1f} s"
        else:
            span = f"log time {self.log_duration_s:.1f} s"
        if self.run_state and self.run_state != "done":
            span += f" (the recorded run ended early: {self.run_state})" if self.run_state == "failed" \
                else f" (the recorded run's last state: {self.run_state})"
        chamber = f"{self.chamber_states} chamber states, " if self.chamber_states else ""
        return (f"replayed {self.events} events, {self.table_states} table states, {chamber}{self.samples} IMU "
                f"samples, {self.frames} CAN frames ({self.recorded_batches} recorded batches); {span} in "
                f"{self.wall_s:.2f} s ({self.read_s:.2f} s of it reading and decoding the log)")


def replay(log: RunLog, listeners: Iterable[RunListener], *, speed: float | None = None, clock: Clock = SYSTEM_CLOCK,
           layout: ImuLayout | None = None, rate_hz: float | None = None, block_s: float = 0.1,
           step_s: float = 0.05, stop: threading.Event | None = None) -> ReplayStats:
    """Play `log` to `listeners` (see the module docstring); returns what was delivered.

    `layout` / `rate_hz` default to the ones recorded in the log
    (`bench.log.run_info.layout_and_config_from_log`). Listener exceptions propagate, after
    every listener's `close()`.
    """
    if speed is not None and not (isinstance(speed, (int, float)) and math.isfinite(speed) and speed > 0):
        raise ValueError(f"speed must be a positive number of times real time (or None), got {speed!r}")
    if not block_s > 0 or not step_s > 0:
        raise ValueError(f"block_s and step_s must be positive, got {block_s!r}, {step_s!r}")
    listeners = list(listeners)
    stats = ReplayStats()
    try:
        _play(log, listeners, stats, speed, clock, layout, rate_hz, block_s, step_s, stop)
    except BaseException:
        _close(listeners)      # the replay's own error is the one worth raising
        raise
    error = _close(listeners)
    if error is not None:
        raise error
    return stats


def _close(listeners) -> Exception | None:
    """Close every listener; the first error, if any."""
    first = None
    for listener in listeners:
        try:
            listener.close()
        except Exception as exc:  # noqa: BLE001 - the others must be closed too
            first = first or exc
    return first


def _play(log, listeners, stats, speed, clock, layout, rate_hz, block_s, step_s, stop) -> None:
    started = clock.now()
    stats.recorded_batches = log.message_counts.get(TOPIC_CAN, 0)     # as the log's summary counts them
    states, bad_states = _table_states(log)
    if bad_states:
        stats.notes.append(f"{bad_states} table states with an unknown mode not replayed")
    events = log.events
    stats.run_state = final_state(events) or ""

    chamber = log.chamber_states
    ev_t = _monotone(np.array([e.time_s for e in events], float))
    st_t = _monotone(np.array([s.time_s for s in states], float))
    ch_t = _monotone(np.array([c.time_s for c in chamber], float))
    # Frame batches: cut where the time grid or the count of earlier events/states changes; found chunk by
    # chunk (the frames are never all held: only each batch's bounds and last time), in the same pass over
    # the frames as the samples' decode when that runs now
    marks = np.sort(np.concatenate([ev_t, st_t, ch_t]))
    batches = _FrameBatches(marks, ev_t, np.sort(np.concatenate([st_t, ch_t])), block_s)
    samples, visited = _decode(log, layout, rate_hz, stats, batches.visit)
    if not visited:
        for t, *_ in log.can_pieces():
            batches.visit(t)
    starts, ends, batch_end, t0 = batches.result()
    n_frames = int(ends[-1]) if len(ends) else 0
    firsts = [t[0] for t in (ev_t, st_t, ch_t) if len(t)] + ([t0] if n_frames else [])
    lasts = [t[-1] for t in (ev_t, st_t, ch_t, batch_end) if len(t)]
    t0 = min(firsts) if firsts else 0.0
    stats.log_start_s, stats.log_duration_s = float(t0), float(max(lasts) - t0) if lasts else 0.0
    batch_t = batch_end
    if n_frames and len(marks):
        # A batch goes before the first event or state it precedes, even if stamped a hair later.
        following = np.searchsorted(marks, batch_end - _SAME_TIME_S, side="left")
        inside = following < len(marks)
        batch_t = np.where(inside, np.minimum(batch_t, marks[np.minimum(following, len(marks) - 1)]), batch_t)
    # Each sample goes after the batch holding the frame that completed it.
    if samples is not None and len(samples) and n_frames:
        owner = np.searchsorted(batch_end, _monotone(samples.receive_time_s), side="left")
        owner = np.minimum(owner, len(batch_end) - 1)
        sample_bounds = np.searchsorted(owner, np.arange(len(batch_end) + 1), side="left")
    else:
        sample_bounds = np.zeros(len(batch_t) + 1, np.int64)

    times = np.concatenate([batch_t, ev_t, st_t, ch_t])
    kinds = np.concatenate([np.full(len(batch_t), _DATA), np.full(len(ev_t), _EVENT), np.full(len(st_t), _STATE),
                            np.full(len(ch_t), _CHAMBER)])
    index = np.concatenate([np.arange(len(batch_t)), np.arange(len(ev_t)), np.arange(len(st_t)),
                            np.arange(len(ch_t))])
    order = np.lexsort((index, kinds, times))

    want_frames = any(_overrides(listener, "on_can_frames") for listener in listeners)
    cursor = _FrameCursor(log) if want_frames else None
    wall0 = clock.now()
    stats.read_s = float(wall0 - started)
    for i in order.tolist():
        if stop is not None and stop.is_set():
            stats.stopped = True
            break
        if speed is not None and not _wait_until(clock, wall0 + (times[i] - t0) / speed, step_s, stop):
            stats.stopped = True
            break
        kind, k = kinds[i], index[i]
        stats.log_reached_s = float(times[i] - t0)
        if kind == _EVENT:
            for listener in listeners:
                listener.on_event(events[k])
            stats.events += 1
        elif kind == _STATE:
            for listener in listeners:
                listener.on_table_state(states[k])
            stats.table_states += 1
        elif kind == _CHAMBER:
            for listener in listeners:
                listener.on_chamber_state(chamber[k])
            stats.chamber_states += 1
        else:
            lo, hi = int(starts[k]), int(ends[k])
            frames = cursor.messages(lo, hi) if cursor is not None else ()
            if want_frames:
                for listener in listeners:
                    listener.on_can_frames(frames)
            stats.frames += hi - lo
            stats.frame_batches += 1
            s_lo, s_hi = int(sample_bounds[k]), int(sample_bounds[k + 1])
            if s_hi > s_lo:
                assert samples is not None   # sample bounds are all 0 unless samples were decoded
                block = _slice(samples, s_lo, s_hi)
                for listener in listeners:
                    listener.on_imu(block)
                stats.samples += s_hi - s_lo
                stats.imu_blocks += 1
    stats.wall_s = float(clock.now() - started)


class _FrameBatches:
    """The frame batches, found piece by piece (`visit` each piece's frame times in order, then `result`): a
    batch ends where the count of events/states before a frame or its cell of the `block_s` grid changes.
    The grid starts at the log's first time (the earliest of the first event, state and frame). Frame times
    are made monotone as `_monotone` does, across the pieces."""

    def __init__(self, marks: np.ndarray, ev_t: np.ndarray, st_t: np.ndarray, block_s: float):
        self.marks, self.ev_t, self.st_t, self.block_s = marks, ev_t, st_t, block_s
        self.begin: list[np.ndarray] = []    # global index of each batch's first frame
        self.before: list[np.ndarray] = []   # the time of the frame before it (the previous batch's last)
        self.t0: float | None = None
        self.first_frame: float | None = None
        self.prev_t, self.total = -np.inf, 0
        self.prev_key: tuple[int, float] | None = None

    def visit(self, t: np.ndarray) -> None:
        if not len(t):
            return
        ev_t, st_t = self.ev_t, self.st_t
        t = np.where(np.isfinite(t), np.asarray(t, float), -np.inf)
        t = np.maximum.accumulate(np.maximum(t, self.prev_t))
        if not np.isfinite(t[0]):   # no finite time yet: these take the first one found
            finite = np.isfinite(t)
            fill = t[finite][0] if finite.any() else min([x[0] for x in (ev_t, st_t) if len(x)], default=0.0)
            t = np.where(finite, t, fill)
        if self.t0 is None:
            self.first_frame = float(t[0])
            self.t0 = min([self.first_frame] + [float(x[0]) for x in (ev_t, st_t) if len(x)])
        key_marks = np.searchsorted(self.marks, t - _SAME_TIME_S, side="left")
        key_grid = np.floor((t - self.t0) / self.block_s)
        local = np.flatnonzero((np.diff(key_marks) != 0) | (np.diff(key_grid) != 0)) + 1
        if self.prev_key is None or self.prev_key != (int(key_marks[0]), float(key_grid[0])):
            self.begin.append(np.array([self.total]))
            self.before.append(np.array([self.prev_t]))
        self.begin.append(local + self.total)
        self.before.append(t[local - 1])
        self.prev_t, self.prev_key = t[-1], (int(key_marks[-1]), float(key_grid[-1]))
        self.total += len(t)

    def result(self):
        """(starts, ends, last frame time of each batch, the first frame's time)."""
        if not self.total or self.first_frame is None:
            z = np.zeros(0, np.int64)
            return z, z, np.zeros(0), 0.0
        starts = np.concatenate(self.begin).astype(np.int64)
        ends = np.append(starts[1:], self.total)
        batch_end = np.append(np.concatenate(self.before)[1:], self.prev_t).astype(float)
        return starts, ends, batch_end, float(self.first_frame)


class _FrameCursor:
    """The log's frames as python-can Messages, by index ranges asked for in order (one pass over the
    chunks, a piece held at a time)."""

    def __init__(self, log: RunLog):
        self.log = log
        self._restart()

    def _restart(self) -> None:
        self.pieces = self.log.can_pieces()
        self.piece, self.first = None, 0   # the current piece and the index of its first frame

    def messages(self, lo: int, hi: int) -> list:
        if self.piece is not None and lo < self.first:
            self._restart()
        out: list = []
        while lo < hi:
            if self.piece is None or lo >= self.first + len(self.piece[1]):
                if self.piece is not None:
                    self.first += len(self.piece[1])
                self.piece = next(self.pieces, None)
                if self.piece is None:
                    break
                continue
            a, b = lo - self.first, min(hi, self.first + len(self.piece[1])) - self.first
            out += can_messages(self.piece, a, b)
            lo = self.first + b
        return out


def _wait_until(clock: Clock, target: float, step_s: float, stop: threading.Event | None) -> bool:
    """Sleep on `clock` until `target` in steps; False if `stop` was set meanwhile."""
    while True:
        remaining = target - clock.now()
        if remaining <= 1e-9:
            return True
        if stop is not None and stop.is_set():
            return False
        clock.sleep(min(step_s, remaining))


def _monotone(t: np.ndarray) -> np.ndarray:
    """Times made usable for ordering: NaN takes the previous time, and time never goes back."""
    t = np.asarray(t, float)
    if not len(t):
        return t
    t = np.where(np.isfinite(t), t, -np.inf)
    t = np.maximum.accumulate(t)
    return np.where(np.isfinite(t), t, t[np.isfinite(t)][0] if np.isfinite(t).any() else 0.0)


def _overrides(listener, name: str) -> bool:
    return getattr(type(listener), name, None) is not getattr(RunListener, name)


def _decode(log: RunLog, layout, rate_hz, stats: ReplayStats, visit) -> tuple[ImuSampleBlock | None, bool]:
    """Samples from the raw data frames (error and remote frames are logged but never decoded, as live), and
    whether `visit` saw every piece's frame times on the way (the decode read the frames now)."""
    if layout is None or rate_hz is None:

        try:
            setup = layout_and_config_from_log(log)
        except LogError as exc:
            stats.notes.append(f"IMU samples not replayed: {exc}")
            return None, False
        stats.notes += list(setup.notes)
        layout = setup.layout if layout is None else layout
        rate_hz = setup.rate_hz if rate_hz is None else rate_hz
    block, imu_stats, visited = log.imu_samples_visiting(layout, rate_hz, visit)
    stats.imu_stats = imu_stats
    return block, visited


def _slice(block: ImuSampleBlock, lo: int, hi: int) -> ImuSampleBlock:
    return ImuSampleBlock(block.counter[lo:hi], block.receive_time_s[lo:hi], block.gyro_counts[lo:hi],
                          block.acc_counts[lo:hi], block.temperature_c[lo:hi], block.status[lo:hi], block.rate_hz)


def _table_states(log: RunLog) -> tuple[list[TableState], int]:
    """The recorded states as `TableState`s (and how many had a mode this version does not know)."""
    s = log.read_table_states()
    out, bad = [], 0
    angles, rates, status = s.angles_deg.tolist(), s.rates_dps.tolist(), s.status.tolist()
    for i, t in enumerate(s.time_s.tolist()):
        try:
            outer, middle, inner = (AxisState(angles[i][a], rates[i][a], AxisMode(s.modes[i][a]),
                                              AxisStatus(status[i][a])) for a in range(3))
        except (ValueError, IndexError, TypeError):
            bad += 1
            continue
        out.append(TableState(t, (outer, middle, inner), s.fault_text[i]))
    return out, bad


__all__ = ["ReplayStats", "replay"]
