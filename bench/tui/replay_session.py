"""Replay mode behind the TUI: a recorded run played into the `UiBuffer`, no hardware (no Textual here).

`ReplaySession` has the `BenchSession` surface the app uses; every hardware command
(connect, enable, go to, rate, jog, stop, start, abort) is refused with a
`SessionError` saying so. `bench.log.replay.replay` plays the log on a session thread at
`speed` times real time (None: as fast as the UI takes it), through a `PlaybackClock`
so that pause/resume hold the playback. When the playback has ended, the result is
the one `bench run` attached to the log; a log without one is solved as `bench solve`
does.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.config.load import BenchConfig
from bench.errors import InputError
from bench.finish.calibration import solve_recorded
from bench.finish.recorded import SolveInputError, load_recorded
from bench.finish.units import dropped_units, is_several
from bench.log.events import RunListener
from bench.log.reader import LogError, RunLog, read_log
from bench.log.replay import ReplayStats, replay
from bench.log.run_info import NO_PLAN_IN_MANUAL_LOG, is_manual_log, layout_and_config_from_log, steps_from_log
from bench.model.quality import texts
from bench.model.result import CalibrationResult
from bench.solve.methods import SolverError
from bench.tui.buffer import UiBuffer
from bench.tui.session import LINK_DISCONNECTED, SessionError
from bench.tui.tracks import UnitOutcome
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.imu import ImuSampleBlock, ImuStats
from drivers.turntable import TurntableLimits

LINK_REPLAY = "replay"


class PlaybackClock:
    """`base` with the time standing still while paused (what `replay` paces itself by)."""

    def __init__(self, base: Clock = SYSTEM_CLOCK):
        self._base = base
        self._lock = threading.Lock()
        self._offset_s = 0.0
        self._paused_at: float | None = None

    @property
    def paused(self) -> bool:
        return self._paused_at is not None

    def now(self) -> float:
        with self._lock:
            t = self._paused_at if self._paused_at is not None else self._base.now()
            return t - self._offset_s

    def sleep(self, seconds: float) -> None:
        self._base.sleep(seconds)

    def pause(self) -> None:
        with self._lock:
            if self._paused_at is None:
                self._paused_at = self._base.now()

    def resume(self) -> None:
        with self._lock:
            if self._paused_at is not None:
                self._offset_s += self._base.now() - self._paused_at
                self._paused_at = None


@dataclass(frozen=True)
class OpenedLog:
    """A run log read for replay, with what the app needs to draw it."""

    path: Path
    log: RunLog
    steps: tuple
    config: BenchConfig | None  # the recorded configuration (None if it cannot be rebuilt)
    limits: TurntableLimits
    simulated: bool
    notes: tuple[str, ...]


def open_log(path: str | Path) -> OpenedLog:
    """Read `path` for replay; `bench.log.reader.LogError` if it is not a readable run log."""
    log = read_log(str(path))
    notes = [f"damaged log: {line}" for line in log.scan().damage]
    try:
        steps = tuple(steps_from_log(log))
    except LogError as exc:
        if not is_manual_log(log):          # (a log of manual moves has no plan: `log_result` says so)
            notes.append(f"{exc}; no plan shown")
        steps = ()
    try:
        config = layout_and_config_from_log(log).config
    except LogError as exc:
        notes.append(str(exc))
        config = None
    limits = config.table.limits if config is not None else TurntableLimits()
    simulated = log.metadata.get("run", {}).get("mode") == "simulator"
    return OpenedLog(Path(path), log, steps, config, limits, simulated, tuple(notes))


def log_result(opened: OpenedLog) -> tuple[CalibrationResult | None, str]:
    """(CalibrationResult or None, one line): the result attached to the log, else a fresh solve."""
    if is_manual_log(opened.log):
        return None, f"no result: {NO_PLAN_IN_MANUAL_LOG}, so there is nothing to solve"
    why = ""
    # the run's own result first: an [acceptance] reference result may be attached too
    own = f"{opened.log.metadata.get('run', {}).get('run_id', '')}.result.json"
    for name, (_media, data) in sorted(opened.log.attachments.items(), key=lambda item: (item[0] != own, item[0])):
        if name.endswith(".result.json"):
            try:
                return (CalibrationResult.loads(data.decode("utf-8"), origin=f"{opened.path.name}:{name}"),
                        f"result attached to the log ({name})")
            except (InputError, UnicodeDecodeError) as exc:   # not a result, or a number out of range
                why = f"the attached {name} is unreadable ({exc}); "
    try:
        resolved = solve_recorded(load_recorded([str(opened.path)], earlier=False))
    except (LogError, SolveInputError, SolverError) as exc:
        return None, f"no result in this log: {why}cannot solve it: {exc}"
    failures = f"; quality: {'; '.join(texts(resolved.failures))}" if resolved.failures else ""
    return resolved.result, f"{why}no result attached: solved from the log as `bench solve` does{failures}"


def log_units(opened: OpenedLog) -> list[tuple[str, str]]:
    """(serial, mounting face) of every unit of a log of several IMUs, the reference unit first ([] for one IMU or
    when the log's configuration cannot be rebuilt: the units' layouts come from it)."""
    if opened.config is None or not is_several(opened.log) or not opened.config.several:
        return []
    return [(unit.identity.serial, unit.mounting_name) for unit in opened.config.units]


def unit_results(opened: OpenedLog) -> list[UnitOutcome]:
    """Each unit's result attached to a log of several IMUs (`<run-id>.<serial>.result.json`), or why it has none:
    dropped from the run (the reason the run logged), or not attached."""
    run_id = opened.log.metadata.get("run", {}).get("run_id", "")
    dropped = dropped_units([opened.log])
    out = []
    for serial, _ in log_units(opened):
        name = f"{run_id}.{serial}.result.json"
        attached = opened.log.attachments.get(name)
        if attached is None:
            why = dropped.get(serial) or (f"no result attached to the log (bench solve {opened.path.name} --unit "
                                          f"{serial} solves it)")
            out.append(UnitOutcome(serial, None, why))
            continue
        try:
            result = CalibrationResult.loads(attached[1].decode("utf-8"), origin=f"{opened.path.name}:{name}")
        except (InputError, UnicodeDecodeError) as exc:
            out.append(UnitOutcome(serial, None, f"the attached {name} is unreadable ({exc})"))
            continue
        out.append(UnitOutcome(serial, result, f"result attached to the log ({name})"))
    return out


class UnitFeeder(RunListener):
    """Plays the other units of a log of several IMUs along with the reference unit: after each of the reference
    unit's sample blocks, every unit's samples received up to the block's last one go to `buffer`
    (`UiBuffer.on_unit_imu`), so the units advance with the replay's pace and pause with it."""

    def __init__(self, opened: OpenedLog, buffer: UiBuffer):
        self.buffer = buffer
        self.units: list[tuple[str, ImuSampleBlock]] = []
        self.stats: dict[str, ImuStats] = {}
        self._sent: dict[str, int] = {}
        self._times: dict[str, np.ndarray] = {}
        config = opened.config
        for k, (serial, _) in enumerate(log_units(opened)[1:], 1):
            assert config is not None           # (log_units has the units only from a configuration)
            unit = config.units[k]
            block, stats = read_log(str(opened.path), unit=serial).imu_samples(unit.layout, unit.rate_hz)
            self.units.append((serial, block))
            # (received in order; a reordered frame's sample goes with its neighbours)
            self._times[serial] = np.maximum.accumulate(block.receive_time_s) if len(block) else block.receive_time_s
            self.stats[serial], self._sent[serial] = stats, 0

    def on_imu(self, block: ImuSampleBlock) -> None:
        if len(block):
            self._feed(float(block.receive_time_s[-1]))

    def _feed(self, until_s: float) -> None:
        for serial, samples in self.units:
            start = self._sent[serial]
            end = int(np.searchsorted(self._times[serial], until_s, side="right"))
            if end > start:
                part = slice(start, end)
                self.buffer.on_unit_imu(serial, ImuSampleBlock(
                    samples.counter[part], samples.receive_time_s[part], samples.gyro_counts[part],
                    samples.acc_counts[part], samples.temperature_c[part], samples.status[part], samples.rate_hz))
                self._sent[serial] = end

    def finish(self) -> None:
        """The units' samples after the reference unit's last, and their link counts."""
        self._feed(math.inf)
        self.buffer.unit_stats_sources.update(self.stats)


class ReplaySession:
    """Plays `opened` into `buffer` at `speed` times real time (None: as fast as possible); no hardware."""

    replaying = True
    sim = False

    def __init__(self, opened: OpenedLog, *, buffer: UiBuffer, speed: float | None = 1.0,
                 clock: Clock = SYSTEM_CLOCK, join_timeout_s: float = 20.0):
        if speed is not None and not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be a positive factor of real time, got {speed!r}")
        self.opened, self.buffer, self.speed = opened, buffer, speed
        self.config = opened.config
        self.join_timeout_s = float(join_timeout_s)
        self.clock = PlaybackClock(clock)
        self.run = None
        self.stats: ReplayStats | None = None     # once played
        self.link = LINK_DISCONNECTED
        self.link_detail = ""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- state --------------------------------------------------------------------------
    @property
    def playing(self) -> bool:
        thread = self._thread
        return thread is not None and thread.is_alive()

    running = False                           # no run of the bench's: nothing to stop on quit
    connected = False
    busy = False

    @property
    def paused(self) -> bool:
        return self.clock.paused

    def describe_plan(self) -> str:
        return f"replay of {self.opened.path.name}"

    # -- playback ----------------------------------------------------------------------------
    def play(self) -> threading.Thread:
        """Start the playback (once)."""
        if self._thread is not None:
            raise SessionError("the log is already being replayed")
        self.link = LINK_REPLAY
        # (the header names the log: here its name would wrap the table panel's line at 100 columns)
        self.link_detail = f"{self.speed:g}x" if self.speed else "as fast as possible"
        for note in self.opened.notes:
            self.buffer.note("warning", note)
        self._thread = threading.Thread(target=self._body, name="bench-tui-replay", daemon=True)
        self._thread.start()
        return self._thread

    def _body(self) -> None:
        self.buffer.note("info", f"replaying {self.opened.path.name} (no hardware)")
        try:
            feeder = UnitFeeder(self.opened, self.buffer)
            self.stats = stats = replay(self.opened.log, [self.buffer, feeder], speed=self.speed, clock=self.clock,
                                        stop=self._stop)
        except Exception as exc:  # noqa: BLE001 - a log the replay cannot play: the operator must see why
            text = f"replay failed: {type(exc).__name__}: {exc}"
            self.buffer.note("fault", text)
            self.buffer.set_outcome(None, text)
            return
        if stats.imu_stats is not None:
            self.buffer.stats_source = stats.imu_stats
        if not stats.stopped:
            feeder.finish()
        for note in stats.notes:
            self.buffer.note("warning", note)
        self.buffer.note("info", stats.summary())
        if stats.stopped:
            return
        try:
            result, text = log_result(self.opened)
        except Exception as exc:  # noqa: BLE001 - shown, not raised: the replay itself went fine
            result, text = None, f"no result: {type(exc).__name__}: {exc}"
        self.buffer.note("info" if result is not None or is_manual_log(self.opened.log) else "warning", text)
        units = unit_results(self.opened)
        if units:
            self.buffer.set_unit_outcomes(units)
        self.buffer.set_outcome(result, text)
        self.link_detail = "played to the end"

    def pause(self) -> None:
        if not self.playing:
            raise SessionError("the replay is not playing")
        if self.speed is None:
            raise SessionError("the replay runs as fast as possible (no --speed): nothing to pause")
        self.clock.pause()
        self.buffer.note("info", "replay paused")

    def resume(self) -> None:
        if not self.playing or not self.clock.paused:
            raise SessionError("the replay is not paused")
        self.clock.resume()
        self.buffer.note("info", "replay resumed")

    # -- no hardware -------------------------------------------------------------------------
    def require_hardware(self, what: str) -> None:
        raise SessionError(f"replay mode: no hardware, cannot {what}")

    def connect(self) -> None:
        self.require_hardware("connect")

    def disconnect(self) -> None:
        self.require_hardware("disconnect")

    def enable(self):
        self.require_hardware("enable")

    def disable(self):
        self.require_hardware("disable")

    def go_to(self, angles_deg):
        self.require_hardware("go to a position")

    def set_rate(self, frame, rate_dps):
        self.require_hardware("set a rate")

    def stop_motion(self):
        self.require_hardware("stop the table")

    def jog(self, frame, step_deg):
        self.require_hardware("jog")

    def start(self):
        self.require_hardware("start a plan")

    def abort(self, reason: str = "") -> None:
        self.require_hardware("abort a run (q quits the replay)")

    def estop(self) -> None:
        """Nothing to stop: say so (the key must never look dead)."""
        self.buffer.note("warning", "EMERGENCY STOP pressed: replay mode, no hardware is connected")

    def close(self) -> None:
        """Stop the playback and wait for it (bounded)."""
        self._stop.set()
        self.clock.resume()
        thread = self._thread
        if thread is not None:
            thread.join(self.join_timeout_s)
