"""The operator's bench session behind the TUI: devices, an idle monitor, one run at a time (no Textual here).

`BenchSession` owns a `bench.run.runner.BenchRun` (the same devices, sequencer, recorder
and solve as `bench run`) and adds only what an interactive session needs:

- connect / disconnect (open the devices; close them); the run's log is opened when a plan
  starts (`start`), after the output folder is checked again: connecting writes no file, and
  a plan whose log cannot be written does not start;
- the log of manual moves (`bench.tui.manual_log`): opened by the first manual move (go to,
  rate, jog), closed when a plan starts (which writes its own log) or the session ends; a log
  that cannot be opened or written is a warning, never a refusal or a delay of a table command;
- an idle monitor thread that reads the table and drains the IMU into the `UiBuffer` (and the
  log of manual moves, when one is open) while no run is active (with the simulator it also
  advances the simulated clock in real time, so a manual move takes as long as on the real table);
- manual commands (enable, disable, go to position, rate mode, jog, stop) and the run controls (start,
  pause, resume, abort) and the emergency stop (abort the run and the controller's
  abort, servos off), each off the caller's thread: the UI never waits on the wire.

A BenchRun records one run: after a run ended, `start()` opens a fresh one (a new log;
with the simulator a new simulated world, table back at zero).
"""

from __future__ import annotations

import enum
import shlex
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence, cast

from bench.config.load import SIM_CONFIG_TOML
from bench.errors import BenchError
from bench.log.events import RunState
from bench.run.devices import Devices, ImuSource, device_opener
from bench.run.runner import BenchRun, RunOutcome
from bench.run.sequencer import RunAborted
from bench.solve.methods import SolverError
from bench.tui.buffer import UiBuffer
from bench.tui.manual_log import ManualLogs
from bench.tui.tracks import UnitTee, unit_outcomes
from drivers.errors import DeviceError, TurntableLimitError
from drivers.imu.receiver import ImuReceiver
from drivers.turntable import FRAMES, AxisMode, Turntable, frame_index

LINK_DISCONNECTED, LINK_CONNECTING, LINK_CONNECTED, LINK_ERROR = "disconnected", "connecting", "connected", "error"


def run_end_of(outcome: RunOutcome, stop_words: str = "table stopped") -> tuple[EndKind, str, str]:
    """How a finished run ends, from what `BenchRun.finish()` returned: (its `EndKind`, the reason a non-zero exit
    gives, the line the event log shows). A judged run ends by its verdict, as `bench run` does. `stop_words`: what
    the run's stop did ("table stopped", or TABLE STATE UNKNOWN when it could not be sent or confirmed)."""
    if isinstance(outcome.error, RunAborted):
        return (EndKind.ABORTED, str(outcome.error),
                f"aborted: {outcome.error}; {stop_words}. Log: {outcome.log_path.name}")
    if outcome.error is not None:
        return (EndKind.FAILED, f"{outcome.error}",
                f"{outcome.state.value}: {outcome.error}; {stop_words}. Log: {outcome.log_path.name}")
    if outcome.verdict is not None and outcome.verdict.failed:
        text = "verdict FAIL: " + "; ".join(c.labelled() for c in outcome.verdict.failed)
        return EndKind.QUALITY, text, text
    if outcome.verdict is None and outcome.failures:         # not judged (a noise recording)
        text = "quality check failed: " + "; ".join(outcome.failures)
        return EndKind.QUALITY, text, text
    if outcome.result_path is not None:
        verdict = f"verdict {outcome.verdict.outcome}; " if outcome.verdict is not None else ""
        return EndKind.DONE, "", f"done; {verdict}result {outcome.result_path.name}"
    text = f"{outcome.state.value}: no result written"       # finish() writes a result whenever the run ended well
    return EndKind.UNSOLVED, text, text


class SessionError(BenchError):
    """An operator command that cannot be done now (says why)."""


class EndKind(enum.StrEnum):
    """How a session's run ended (`RunEnd.kind`)."""

    DONE = "done"
    QUALITY = "quality"
    UNSOLVED = "unsolved"
    ABORTED = "aborted"
    FAILED = "failed"


@dataclass(frozen=True)
class RunEnd:
    """How the session's last run ended, for what `bench tui` says and returns when it quits.

    `kind`: done, quality (a quality check failed), unsolved (finished, cannot be solved), aborted
    (on request: a, F12, quit), failed (a fault; the table was stopped). `reason`: one line, '' when done.
    `log_path`: the run's log. `resume`: the command that continues an aborted or failed run from its log
    (`resume_command`), '' otherwise."""

    kind: EndKind
    reason: str
    log_path: Path | None
    resume: str = ""


def resume_command(config, sim: bool, log_path: Path) -> str:
    """The `bench run --resume LOG` command line that continues the run recorded in `log_path`: this session's
    configuration (its file, or --sim for the built-in simulated bench; `--config FILE` for one given as text,
    which only the Python API does), and `--out` the log's folder when that is not the configuration's output
    folder, so that the continued run writes beside the log it continues."""
    args = ["bench", "run"]
    builtin = config.path is None and config.source_text == SIM_CONFIG_TOML
    if not builtin:
        args += ["--config", str(config.path) if config.path is not None else "FILE"]
    if sim and (builtin or not config.table.is_sim):
        args.append("--sim")
    args += ["--resume", str(log_path)]
    if log_path.parent.resolve() != Path(config.output.folder).resolve():
        args += ["--out", str(log_path.parent)]
    return shlex.join(args)


#: what an operator command can fail with, shown to the operator; anything else is a bug and ends the app,
#: whose unmount stops the table
OPERATOR_ERRORS = (BenchError, DeviceError, OSError)


class BenchSession:
    """An interactive bench: `config` and compiled `plan`, on the simulator when `sim`.

    `poll_s` is the idle monitor's period (real seconds). Thread-safe: every public
    method may be called from the UI thread; slow work runs on the session's threads,
    which `close()` joins.
    """

    replaying = False                         # the replay session's counterpart (bench.tui.replay_session)

    def __init__(self, config, plan, *, sim: bool, out_dir: str | Path, buffer: UiBuffer,
                 operator: str = "", poll_s: float = 0.1, join_timeout_s: float = 20.0):
        self.config, self.plan, self.sim = config, plan, sim
        self.out_dir = Path(out_dir)
        self.buffer = buffer
        self.operator = operator
        self.poll_s = float(poll_s)
        self.join_timeout_s = float(join_timeout_s)
        self.run: BenchRun | None = None
        self.outcome: RunOutcome | None = None    # of the last run
        self.last_end: RunEnd | None = None       # how the last run ended (None: no run ended yet)
        self.link = LINK_DISCONNECTED
        self.link_detail = ""
        self._spent = False                   # the current BenchRun has run: a new run needs a new one
        self._estop = False
        self._lock = threading.RLock()
        self._worker: threading.Thread | None = None
        self._threads: list[threading.Thread] = []
        self._monitor: threading.Thread | None = None
        self._monitor_stop = threading.Event()
        self._imu: ImuSource | None = None
        self.manual = ManualLogs(self.buffer.note, self.join_timeout_s)   # the logs of manual moves

    # -- state -----------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        """A run is under way (started and not yet finished and solved)."""
        worker = self._worker
        return worker is not None and worker.is_alive()

    @property
    def connected(self) -> bool:
        return self.link == LINK_CONNECTED

    @property
    def busy(self) -> bool:
        """Anything that must be stopped before quitting: a run, or the session's commands."""
        return self.running or any(t.is_alive() for t in self._threads)

    def describe_plan(self) -> str:
        """What starting the plan will do, for the confirmation dialog."""
        steps = self.plan.steps
        kinds: dict[str, int] = {}
        for s in steps:
            kinds[s.kind] = kinds.get(s.kind, 0) + 1
        what = ", ".join(f"{n} {k}" for k, n in kinds.items())
        p = self.config.plan
        schedules = " + ".join(s.name for s in (p.positions, p.rotations) if s is not None)
        limits = self.config.table.limits.axes
        turns = sorted({s.frame for s in steps if s.kind == "turn"})
        lines = [
            f"Plan {schedules}: {len(steps)} steps ({what}), about {self.buffer.total_estimated_s / 60:.1f} min.",
            "ALL THREE AXES will be enabled (servos on) and moved"
            + (f"; continuous turns on {', '.join(turns)}" if turns else "") + ".",
            f"Moves at up to {p.move_rate_dps:g} deg/s, turns at {p.turn_rate_dps:g} deg/s; limits: "
            + ", ".join(f"{name} {_range(a)}" for name, a in zip(FRAMES, limits)) + ".",
            ("Simulator: nothing real moves." if self.sim else f"Table at {self.config.table.url}.")
            + " Keep clear of the table.",
        ]
        return "\n".join(lines)

    # -- threads ------------------------------------------------------------------------------
    def _spawn(self, name: str, body: Callable[[], None]) -> threading.Thread:
        def guarded() -> None:
            try:
                body()
            except Exception as exc:  # noqa: BLE001 - an operator command failed: say so in the log
                self._note("warning", f"{name} failed: {type(exc).__name__}: {exc}")

        thread = threading.Thread(target=guarded, name=f"bench-tui-{name}", daemon=True)
        with self._lock:
            self._threads = [t for t in self._threads if t.is_alive()] + [thread]
        thread.start()
        return thread

    def _start_monitor(self) -> None:
        self._stop_monitor()
        self._monitor_stop = threading.Event()
        self._monitor = threading.Thread(target=self._monitor_loop, args=(self._monitor_stop,),
                                         name="bench-tui-monitor", daemon=True)
        self._monitor.start()

    def _stop_monitor(self) -> None:
        monitor, self._monitor = self._monitor, None
        if monitor is not None:
            self._monitor_stop.set()
            monitor.join(self.join_timeout_s)

    def _monitor_loop(self, stop: threading.Event) -> None:
        failing = False
        while not stop.wait(self.poll_s):
            run, imu = self.run, self._imu
            if run is None or imu is None:
                return
            manual = self.manual.current                        # (its frames come through the receiver)
            try:
                _devices(run).let_idle_time_pass(self.poll_s)   # (the simulator's run clock moves when told)
                state = _table(run).read_state()
                self.buffer.on_table_state(state)
                if manual is not None:
                    manual.on_table_state(state)
                block = imu.poll()
                self.buffer.on_imu(block)
                if manual is not None:
                    manual.on_imu(block)
                for unit in _devices(run).units:    # a run of several IMUs: the others (the tee feeds the buffer)
                    unit.receiver.poll()
                if failing:
                    failing = False
                    self.link, self.link_detail = LINK_CONNECTED, ""
                    self._note("info", "link to the table is back")
            except (DeviceError, OSError) as exc:
                if not failing:
                    failing = True
                    self.link, self.link_detail = LINK_ERROR, f"{type(exc).__name__}: {exc}"
                    self._note("warning", f"idle monitor: {type(exc).__name__}: {exc}")

    # -- connect -------------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the devices, not the log (blocking; call it off the UI thread). Nothing moves."""
        with self._lock:
            if self.run is not None:
                raise SessionError("already connected")
            self.link, self.link_detail = LINK_CONNECTING, ""
        run = BenchRun(self.config, self.plan, devices=device_opener(self.sim), out_dir=self.out_dir,
                       operator=self.operator, listeners=[self.buffer])
        try:
            run.open(record=False)          # the log starts with the plan (start): connecting writes no file
        except BaseException as exc:
            self.link, self.link_detail = LINK_ERROR, f"{type(exc).__name__}: {exc}"
            raise
        with self._lock:
            devices = _devices(run)
            self.run, self._spent, self._estop = run, False, False
            self._imu = devices.imu_source()
            self.buffer.stats_source = devices.receiver.stats
            for unit in devices.units:          # a run of several IMUs: each other unit's samples to the buffer too
                # (the tee stands in for the receiver: it has what the run uses of one, the rest passed through)
                unit.receiver = cast(ImuReceiver, UnitTee(unit.serial, unit.receiver, self.buffer.on_unit_imu))
                self.buffer.unit_stats_sources[unit.serial] = unit.receiver.stats
            self.link = LINK_CONNECTED
            self.link_detail = (f"{self.config.table.dialect}, simulator" if self.sim
                                else f"{self.config.table.dialect} at {self.config.table.url}")
        self.buffer.note("info", f"connected ({self.link_detail})")
        self._start_monitor()

    def disconnect(self, reason: str = "disconnected") -> None:
        """Stop the table (servos off), then close the log of manual moves (`reason` is its last event) and
        the devices. Refused while a run is active."""
        if self.running:
            raise SessionError("a run is active: abort it first")
        self._stop_monitor()
        with self._lock:
            run, self.run = self.run, None
        if run is None:
            return
        try:
            table = _table(run)
            table.safe_stop()
            table.disable()
        except Exception as exc:  # noqa: BLE001 - closing matters more; the log says what failed
            self._note("warning", f"stop on disconnect failed: {type(exc).__name__}: {exc}")
        else:
            self._end_manual_log(table)
        self._close_manual_log(run, reason)
        run.close()
        self.link, self.link_detail = LINK_DISCONNECTED, ""
        self.buffer.note("info", "disconnected")

    def _require_idle_table(self):
        if self.run is None:
            raise SessionError("not connected")
        if self.running:
            raise SessionError("a run is active")
        return self.run.table

    def _require_idle_run(self) -> BenchRun:
        """The connected run, no plan running (SessionError otherwise)."""
        run = self.run
        if run is None or self._require_idle_table() is None:
            raise SessionError("not connected")
        return run

    # -- the log of manual moves ---------------------------------------------------------------
    @property
    def manual_logs(self) -> list[Path]:
        """The logs of manual moves this session wrote."""
        return self.manual.paths

    def _note(self, kind: str, message: str, **data) -> None:
        """A line in the event log, and an event in the log of manual moves when one is open."""
        self.buffer.note(kind, message, **data)
        self.manual.event(kind, message, **data)

    def _log_manual_moves(self, run: BenchRun, what: str) -> None:
        """Before a manual move (on the command's thread, before anything is sent): open the log of manual moves
        unless one is open, and record where the table is. Never refuses: the move goes ahead."""
        manual = self.manual.open_for_move(run, what, lambda: self.run is run and not self.running)
        if manual is None:
            return
        try:
            manual.on_table_state(_table(run).read_state())     # where the table was before the move
        except (DeviceError, OSError):
            pass                                                # the monitor's next poll records it

    def _end_manual_log(self, table: Turntable) -> None:
        """The last records of an open log of manual moves, after the table was stopped: the stop, the table's state."""
        manual = self.manual.current
        if manual is None:
            return
        manual.event("info", "table stopped, servos off")
        try:
            manual.on_table_state(table.read_state())
        except (DeviceError, OSError):
            pass                                    # the stop is in the log; the link is going anyway

    def _close_manual_log(self, run: BenchRun | None, reason: str) -> None:
        self.manual.close(run, reason)

    # -- manual commands (return at once; the work runs on a session thread) -------------------
    def enable(self) -> threading.Thread:
        table = self._require_idle_table()

        def body() -> None:
            table.reset_faults()
            table.enable()
            self._note("info", "servos on", command="enable")
        return self._spawn("enable", body)

    def disable(self) -> threading.Thread:
        table = self._require_idle_table()

        def body() -> None:
            table.safe_stop()
            table.disable()
            self._note("info", "table stopped, servos off", command="disable")
        return self._spawn("disable", body)

    def go_to(self, angles_deg: Sequence[float]) -> threading.Thread:
        """Enable and move to `angles_deg` (outer, middle, inner) at the plan's move rate; limits checked first."""
        run = self._require_idle_run()
        table = _table(run)
        angles = tuple(float(a) for a in angles_deg)
        for k, a in enumerate(angles):
            table.limits.check_position(k, a)     # TurntableLimitError before anything is sent
        rate = self.config.plan.move_rate_dps
        text = f"moving to {', '.join(f'{a:g}' for a in angles)} deg at {rate:g} deg/s"

        def body() -> None:
            self._log_manual_moves(run, f"go to {', '.join(f'{a:g}' for a in angles)} deg")
            table.reset_faults()
            table.enable()
            table.move_to(angles, rate_dps=rate)
            self._note("info", text, command="go_to", angles_deg=list(angles), rate_dps=rate)
        return self._spawn("go-to", body)

    def set_rate(self, frame: int | str, rate_dps: float) -> threading.Thread:
        """Servo on and rate mode on one frame at the signed `rate_dps`; checked first (`check_rate_command`)."""
        run = self._require_idle_run()
        table = _table(run)
        k = frame_index(frame)
        rate = float(rate_dps)
        check_rate_command(table.limits, k, rate)     # TurntableLimitError before anything is sent

        def body() -> None:
            self._log_manual_moves(run, f"{FRAMES[k]} at {rate:g} deg/s")
            table.reset_faults()
            table.enable([k])
            table.set_rate(k, rate)
            self._note("info", f"{FRAMES[k]} turning at {rate:g} deg/s (rate mode; h stops)", command="rate",
                       frame=FRAMES[k], rate_dps=rate)
        return self._spawn("rate", body)

    def stop_motion(self) -> threading.Thread:
        """Controlled stop of every axis: decelerate and hold in position (servos stay on)."""
        table = self._require_idle_table()

        def body() -> None:
            table.stop()
            self._note("info", "stop: every axis decelerates and holds its position (servos on)", command="stop")
        return self._spawn("stop", body)

    def jog(self, frame: int | str, step_deg: float) -> threading.Thread:
        """Move one frame by `step_deg` from where it is, at the plan's move rate. Refused unless the
        frame's servo is on (a jog key never switches servos on); the target is checked against the
        limits before the move is sent."""
        run = self._require_idle_run()
        table = _table(run)
        k = frame_index(frame)
        step = float(step_deg)
        state = self.buffer.snapshot().table_state
        if state is None:
            raise SessionError("no table state yet")
        _require_at_rest(state, k)
        table.limits.check_position(k, state.axes[k].angle_deg + step)    # early refusal, on the shown angle
        rate = self.config.plan.move_rate_dps

        def body() -> None:
            fresh = table.read_state()
            _require_at_rest(fresh, k)         # a jog goes from where the frame rests, never from mid-move
            target = fresh.axes[k].angle_deg + step
            table.limits.check_position(k, target)
            self._log_manual_moves(run, f"jog {FRAMES[k]} {step:+g} deg")
            angles: list[float | None] = [None, None, None]
            angles[k] = target
            table.move_to(angles, rate_dps=rate)
            self._note("info", f"jog {FRAMES[k]} {step:+g} deg to {target:.4f} deg", command="jog", frame=FRAMES[k],
                       step_deg=step, target_deg=target, rate_dps=rate)
        return self._spawn("jog", body)

    def require_hardware(self, what: str) -> None:
        """Nothing to check: this session has a table (a replay session refuses here)."""

    # -- the run -------------------------------------------------------------------------------
    def start(self) -> threading.Thread:
        """Start the plan on a worker thread (then solve from the log). Raises SessionError if it cannot."""
        with self._lock:
            if self.running:
                raise SessionError("a run is already active")
            if self.run is None:
                raise SessionError("not connected")
            if self._spent:
                # One BenchRun, one log: a new run opens the devices afresh.
                old = self.run
                self._stop_monitor()
                self._close_manual_log(old, "a plan starts; it writes its own log")
                old.close()
                self.run = None
                self.link = LINK_DISCONNECTED
            self._estop = False
        if self.run is None:
            self.connect()
        run = self.run
        if run is None:                     # connect() sets it or raises
            raise SessionError("not connected")
        try:
            run.start_log()                 # before anything moves: a run that cannot be logged does not start
        except (BenchError, OSError) as exc:      # OutputFolderError: the folder or the file cannot be written
            raise SessionError(f"cannot start the run's log: {exc}; nothing moved") from exc
        self._stop_monitor()
        self._close_manual_log(run, f"a plan starts; it writes its own log, {run.log_path.name}")
        self.buffer.note("info", f"log {run.log_path}")
        self._spent = True
        self.outcome = None
        self.buffer.begin_run(self.plan.steps)
        self._worker = threading.Thread(target=self._run_body, args=(run,), name="bench-tui-run", daemon=True)
        self._worker.start()
        return self._worker

    def _run_body(self, run: BenchRun) -> None:
        text, result = "", None
        kind, reason = EndKind.FAILED, "the run's thread ended without an account"    # replaced on every known path
        try:
            if self._estop:
                text = "not started: emergency stop"
                kind, reason = EndKind.ABORTED, "emergency stop before the start"
                return
            try:
                run.run()
            except DeviceError as exc:
                text = f"cannot enable the table: {exc}; nothing moved"
                reason = text
                self.buffer.note("fault", text)
                return
            try:
                self.outcome = run.finish()
            except SolverError as exc:
                text = f"the run finished but cannot be solved: {exc}"
                kind, reason = EndKind.UNSOLVED, text
                self.buffer.note("warning", text)
                return
            outcome = self.outcome
            result = outcome.result
            if outcome.units:
                self.buffer.set_unit_outcomes(unit_outcomes(outcome.units))
            kind, reason, text = run_end_of(outcome, _stop_words(run))
            self.buffer.note("info", text)
        except Exception as exc:  # noqa: BLE001 - the operator must see it; the sequencer already stopped the table
            text = f"run error: {type(exc).__name__}: {exc}"
            kind, reason = EndKind.FAILED, text
            self.buffer.note("fault", text)
        finally:
            if run.receiver is not None:
                run.receiver.on_frames = None      # the finished sequencer's listeners are closed
            for unit in run.devices.units if run.devices is not None else ():
                unit.receiver.on_frames = None     # (a unit of several: its frames went to the closed log too)
            log = run.log_path if run.recorder is not None else None
            resume = resume_command(self.config, self.sim, log) if log is not None and kind in (EndKind.ABORTED,
                                                                                               EndKind.FAILED) else ""
            if resume:
                text = f"{text}; continue with: {resume}" if text else f"continue with: {resume}"
                self.buffer.note("info", f"continue this run with: {resume}")
            self.last_end = RunEnd(kind, reason, log, resume)
            self.buffer.set_outcome(result, text)
            if self.run is run and run.table is not None:
                self._start_monitor()

    def pause(self) -> None:
        seq = self._sequencer()
        seq.pause()
        self.buffer.note("info", "pause requested (takes effect at the next step boundary)")

    def resume(self) -> None:
        self._sequencer().resume()
        self.buffer.note("info", "resume requested")

    def abort(self, reason: str = "aborted by the operator") -> None:
        self._active_run().abort(reason)
        self.buffer.note("warning", f"abort requested: {reason}")

    def _active_run(self) -> BenchRun:
        """The run under way, its sequencer running, paused or about to start (SessionError otherwise)."""
        run = self.run
        if not self.running or run is None or run.sequencer is None:
            raise SessionError("no run is active")
        if run.sequencer.state not in (RunState.RUNNING, RunState.PAUSED, RunState.IDLE):
            raise SessionError(f"the run is {run.sequencer.state.value}")
        return run

    def _sequencer(self):
        return self._active_run().sequencer

    def estop(self) -> threading.Thread | None:
        """Emergency stop: abort the run and send the controller's abort (servos off) at once."""
        self._estop = True
        run = self.run
        self._note("fault", "EMERGENCY STOP by the operator", command="estop")
        if run is None:
            return None
        run.abort("emergency stop by the operator")
        table = run.table
        if table is None:                   # a run in the session is open: cannot happen
            return None

        def body() -> None:
            stopped = table.safe_abort()
            self._note("fault" if stopped.unknown else "info", f"e-stop: {stopped.describe()}")
        return self._spawn("e-stop", body)

    # -- the end -----------------------------------------------------------------------------------
    def close(self) -> None:
        """Abort any run, wait for it (bounded), stop the table (servos off), close the devices."""
        if self.running and self.run is not None:
            self.run.abort("the operator quit")
        worker = self._worker
        if worker is not None:
            worker.join(self.join_timeout_s)
        for thread in list(self._threads):
            thread.join(self.join_timeout_s)
        try:
            self.disconnect("the session ended")
        except SessionError:
            self._stop_monitor()
            self._close_manual_log(self.run, "the session ended")
            if self.run is not None:
                self.run.close()


def _table(run: BenchRun) -> Turntable:
    """The table of an opened run (the session holds only opened runs)."""
    if run.table is None:
        raise SessionError("not connected")
    return run.table


def _devices(run: BenchRun) -> Devices:
    """The devices of an opened run."""
    if run.devices is None:
        raise SessionError("not connected")
    return run.devices


def _require_at_rest(state, k: int) -> None:
    axis = state.axes[k]
    if not axis.enabled:
        raise SessionError(f"{FRAMES[k]} servo is off (press e or use go to)")
    if axis.mode is AxisMode.RATE or not axis.in_position:
        raise SessionError(f"{FRAMES[k]} is moving: wait, or stop it (h)")


def check_rate_command(limits, frame: int, rate_dps: float) -> None:
    """Raise `TurntableLimitError` unless `rate_dps` may be commanded on `frame`: within its rate limit,
    and the axis has no travel limits (a constant rate would run into them; use go to or jog there)."""
    limits.check_rate(frame, rate_dps)
    axis = limits.axes[frame]
    if axis.min_deg is not None or axis.max_deg is not None:
        raise TurntableLimitError(f"{FRAMES[frame]} has travel limits [{axis.min_deg}, {axis.max_deg}] deg: "
                                  "no rate mode there (use go to or jog)")


def _range(axis) -> str:
    if axis.min_deg is None or axis.max_deg is None:
        return f"continuous <= {axis.max_rate_dps:g} deg/s"
    return f"[{axis.min_deg:g}, {axis.max_deg:g}] deg"


def _stop_words(run) -> str:
    """"table stopped", or TABLE STATE UNKNOWN when the run's stop could not be sent or confirmed."""
    return run.sequencer.stop_words if run.sequencer is not None else "table stopped"
