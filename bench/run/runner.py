"""One calibration run end to end: devices, recorder, sequencer, solve from the log, result and report.

`BenchRun` is what `bench run` executes and what the TUI will drive: open the devices
(the simulator or the drivers, `bench.run.devices`), record everything to `<out>/<run-id>.mcap`, run the
compiled plan, then solve from the log just written (plus the logs of the run it
resumes) and write `<run-id>.result.json`, `<run-id>.report.md` and `<run-id>.report.html`.
"""

from __future__ import annotations

import json
import os
import secrets
import tempfile
import time
from contextlib import ExitStack, contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator, Mapping, Sequence

from bench import __version__
from bench.acceptance.verdict import Verdict
from bench.config.load import BenchConfig
from bench.errors import BenchError
from bench.files import folder_reason
from bench.finish.calibration import Solved
from bench.finish.finish import Finished, Reports, Target, finish
from bench.finish.recorded import Recorded, recorded_run
from bench.finish.units import finish_units
from bench.log.events import RunListener, RunState
from bench.log.reader import read_log
from bench.log.recorder import CHUNK_RUN_INTERVAL_S, McapRecorder, RecorderError
from bench.log.run_info import MANUAL_LOG_SUFFIX, LogSetup
from bench.log.run_kind import RunKind, kind_of_config
from bench.model.quality import damage, link_lost_samples
from bench.model.result import CalibrationResult
from bench.model.run_section import ImuIdentity, ImuLink, LostSamples, RunInfo, utc_stamp
from bench.plan.compiler import CompiledPlan, compile_plan
from bench.plan.steps import step_to_dict
from bench.plan.thermal import compile_thermal_plan
from bench.report.markdown import write_reports
from bench.run.devices import DeviceOpener, Devices
from bench.run.sequencer import ListenerError, Sequencer, SequencerOptions, describe_listener_error
from bench.run.units import UnitsSource, other_serials, units_metadata
from bench.sim.world import SimWorld
from bench.solve.extract import Extraction
from bench.solve.from_logs import extract_from_logs
from bench.solve.methods import SolverError
from bench.thermal.model import ThermalModel
from bench.verify.plan import sim_table_record
from drivers.chamber import Chamber
from drivers.clock import Clock
from drivers.imu import ImuStats
from drivers.imu.receiver import ImuReceiver
from drivers.turntable import Turntable
from schedules import builtin_path

#: The sequencer's loop periods on the simulator: coarse, because the simulated clock jumps.
SIM_OPTIONS = dict(move_poll_s=0.1, imu_poll_s=0.5, state_period_s=1.0)
#: ... and without a soak (whose decisions are taken drain by drain), the IMU drained every 2 s (the IMU timeout):
#: the clock still stops at every state poll (the sequencer never steps past one), each drain's block is four
#: times as large, a quarter of the per-block work (the default run's result is bit for bit the same).
SIM_IMU_POLL_S = 2.0


@dataclass
class RunOutcome:
    state: RunState
    log_path: Path
    result_path: Path | None = None
    report_path: Path | None = None
    result: CalibrationResult | None = None
    failures: list[str] = field(default_factory=list)
    error: BaseException | None = None
    html_report_path: Path | None = None
    verdict: Verdict | None = None        # the acceptance verdict of the result (None: no result)
    problems: list[str] = field(default_factory=list)   # steps left out or degraded (the extraction's lines)
    #: a thermal run's per-temperature results and thermal model file; and the model (None: not thermal, or
    #: fewer than two temperatures)
    thermal_paths: list[Path] = field(default_factory=list)
    thermal_model: ThermalModel | None = None
    #: a run of several IMUs: what finishing each unit wrote and found, by serial (the reference unit's is the
    #: outcome's own)
    units: dict[str, Finished] = field(default_factory=dict)

    @classmethod
    def of(cls, state: RunState, log_path: Path, finished: Finished) -> "RunOutcome":
        """The outcome of a run that ended well and was finished (`bench.finish.finish`)."""
        return cls(state, log_path, finished.result_path, finished.report_path, finished.result, finished.failures,
                   html_report_path=finished.html_report_path, verdict=finished.verdict, problems=finished.problems,
                   thermal_paths=finished.thermal_paths, thermal_model=finished.thermal_model)


def _new_run_id() -> str:
    """A run's id: its UTC start time and a random suffix (the log and result files are named by it)."""
    return time.strftime("%Y%m%dT%H%M%SZ", time.gmtime()) + "-" + secrets.token_hex(3)


def compile_from_config(config: BenchConfig) -> CompiledPlan:
    """The compiled plan of a configuration (PlanError on a plan that cannot run); with `temperatures_c`,
    a calibration at each chamber temperature (`bench.plan.thermal`)."""
    plan = config.plan
    if plan.thermal is not None:
        return compile_thermal_plan(plan.positions, plan.rotations, plan, plan.thermal, limits=config.table.limits,
                                    order=plan.order)
    return compile_plan(plan.positions, plan.rotations, plan, limits=config.table.limits, order=plan.order)


def schedule_file(schedule) -> Path | None:
    """The file a loaded schedule came from (a built-in one's shipped file), None if none."""
    if schedule is None:
        return None
    if schedule.source.startswith("builtin:"):

        return builtin_path(schedule.source.split(":", 1)[1])
    path = Path(schedule.source)
    return path if path.is_file() else None


def _name(schedule) -> str:
    return schedule.name if schedule is not None else ""


def lab_record(config: BenchConfig, equipment: Sequence[Mapping[str, str]] | None = None, customer: str = "",
               item: str = "") -> dict[str, str]:
    """The run log's `lab` metadata: the configuration's [lab], `customer` and `item` in place of its own when
    given, and the equipment (as the register describes it; None: the configured tags alone). Empty when the
    configuration has no [lab] and nothing is given."""
    lab = config.lab
    record = {k: v for k, v in lab.metadata().items() if v}
    record.update({k: v for k, v in (("customer", customer), ("item", item)) if v})
    listed = list(equipment) if equipment is not None else [{"tag": tag} for tag in lab.equipment]
    if listed:
        record["equipment_json"] = json.dumps([dict(e) for e in listed])
    if record or lab.refuse_overdue_equipment:
        record["refuse_overdue_equipment"] = str(lab.refuse_overdue_equipment).lower()
    return record


class OutputFolderError(BenchError):
    """The output folder cannot be made or written: the run does not start (no device is opened)."""


class BenchRun:
    """A run of `plan` on the devices `devices` opens (`bench.run.devices`: the simulator or the drivers)."""

    def __init__(self, config: BenchConfig, plan: CompiledPlan, *, devices: DeviceOpener, out_dir: str | Path,
                 operator: str = "", completed: Iterable[str] = (), previous_logs: Iterable[str] = (),
                 listeners: Iterable[RunListener] = (), run_id: str | None = None,
                 lab: Mapping[str, str] | None = None):
        self.config, self.plan, self.opener = config, plan, devices
        # the log's `lab` record: the caller's (`bench run`: the equipment as the register has it, --customer,
        # --item), else the configuration's [lab] with its equipment tags
        self.lab = dict(lab) if lab is not None else lab_record(config)
        self.out_dir = Path(out_dir)
        self.operator = operator
        self.completed = set(completed)
        self.previous_logs = list(previous_logs)
        self.extra_listeners = list(listeners)
        # (`run_id`: a name of the caller's, e.g. a verification run named after its calibration run)
        self.run_id = run_id or _new_run_id()
        self.kind = kind_of_config(config)       # recorded in the log (`run.kind`); `finish` dispatches on it
        self.log_path = self.out_dir / f"{self.run_id}.mcap"
        # set by open() and run(); None before
        self.devices: Devices | None = None
        self.recorder: McapRecorder | None = None
        self.sequencer: Sequencer | None = None
        self._abort_reason: str | None = None      # an abort asked for before the sequencer existed
        self._stack = ExitStack()

    # -- devices -----------------------------------------------------------------------
    def open(self, *, record: bool = True) -> None:
        """Open the devices (the opener's) and the recorder. Raises DeviceError/OSError/ValueError; nothing moves.

        The output folder is checked first (`OutputFolderError`): no device is opened for a run that could
        not be logged. `record=False` leaves the log for `start_log()` (the TUI opens it when a plan starts,
        so a session that runs nothing writes no log); `run()` refuses to start without it."""
        self._check_output_folder()
        try:
            self.devices = devices = self.opener.open(self.config, self.is_thermal)
            self._stack.callback(devices.close)
            if record:
                self._open_recorder()
        except BaseException:
            self.close()
            raise

    @property
    def is_thermal(self) -> bool:
        """A calibration at each chamber temperature (`[plan] temperatures_c`)."""
        return self.config.plan.thermal is not None

    @property
    def sim(self) -> bool:
        """The devices are the simulator's (the opener's choice, known before they open)."""
        return self.opener.simulated

    # the opened devices' parts (None before open())
    @property
    def table(self) -> Turntable | None:
        return self.devices.table if self.devices is not None else None

    @property
    def receiver(self) -> ImuReceiver | None:
        return self.devices.receiver if self.devices is not None else None

    @property
    def clock(self) -> Clock | None:
        return self.devices.clock if self.devices is not None else None

    @property
    def chamber(self) -> Chamber | None:
        """A thermal plan's chamber."""
        return self.devices.chamber if self.devices is not None else None

    @property
    def world(self) -> SimWorld | None:
        """The simulated world behind the devices (None: hardware, or not open)."""
        return self.devices.world if self.devices is not None else None

    @property
    def imu_check(self) -> str:
        """What the check of a hardware IMU found before the run."""
        return self.devices.imu_check if self.devices is not None else ""

    def start_log(self) -> None:
        """Open the log of a run opened with `record=False` (nothing if it is open): the output folder is
        checked again first and the run id and log name are taken now. Raises `OutputFolderError` when the
        log cannot be written: the run must not start (nothing has moved)."""
        if self.recorder is not None:
            return
        if self.table is None:
            raise BenchError("BenchRun: open() it first")
        self._check_output_folder()
        self.run_id = _new_run_id()
        self.log_path = self.out_dir / f"{self.run_id}.mcap"
        try:
            self._open_recorder()
        except OSError as exc:
            recorder, self.recorder = self.recorder, None
            if recorder is not None:
                recorder.close()            # (the run's exit stack closes it again: closing twice is a no-op)
            raise OutputFolderError(f"log {self.log_path}: {exc.strerror or exc}") from exc

    def _check_output_folder(self) -> None:
        """Make the output folder if missing and check it takes a new file (a file created and removed)."""
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=self.out_dir):
                pass
        except OSError as exc:
            raise OutputFolderError(f"output folder {self.out_dir}: {folder_reason(exc, self.out_dir)}") from exc

    def _open_recorder(self) -> None:
        self.recorder = recorder = self._new_recorder(self.log_path, self._metadata())
        self._stack.callback(recorder.close)

    def open_manual_log(self) -> McapRecorder:
        """A new log of manual moves (the TUI's, `<id>-manual.mcap`): this run's devices, configuration, site
        and IMU records, no plan (`run.kind` = "manual"). Not the run's log (`recorder`): the caller
        writes it from one thread and closes it. Raises `OutputFolderError` when it cannot be written."""
        if self.table is None:
            raise BenchError("BenchRun: open() it first")
        self._check_output_folder()
        run_id = _new_run_id() + MANUAL_LOG_SUFFIX
        path = self.out_dir / f"{run_id}.mcap"
        metadata = self._metadata(run_id)
        del metadata["plan"]
        metadata["run"]["kind"] = RunKind.MANUAL.value
        try:
            return self._new_recorder(path, metadata)
        except OSError as exc:
            raise OutputFolderError(f"log {path}: {exc.strerror or exc}") from exc

    def _new_recorder(self, path: Path, metadata: dict) -> McapRecorder:
        """A recorder on `path` with `metadata` and the run's files attached (the DBC, the configuration, the
        schedules, the acceptance reference); closed again when attaching fails."""
        config = self.config
        interval = config.output.chunk_run_interval_s
        recorder = McapRecorder(str(path), metadata=metadata,
                                chunk_run_interval_s=CHUNK_RUN_INTERVAL_S if interval is None else interval,
                                chamber=self.chamber is not None, units=other_serials(config))
        try:
            self._attach_files(recorder)
        except BaseException:
            with suppress(RecorderError):   # the attaching error is the one to raise
                recorder.close()
            raise
        return recorder

    def _attach_files(self, recorder: McapRecorder) -> None:
        config = self.config
        assert self.clock is not None   # open() chose the clock before the recorder
        now_s = self.clock.now()        # attachments carry the run clock's time, like every record
        recorder.add_attachment(config.imu.dbc.name, "text/plain", config.imu.layout.dbc_text.encode(), now_s)
        if config.path:
            recorder.add_attachment(Path(config.path).name, "application/toml", config.source_text.encode(), now_s)
        for schedule in (config.plan.positions, config.plan.rotations):
            path = schedule_file(schedule)
            if path is not None:
                recorder.add_attachment(path.name, "application/toml", path.read_bytes(), now_s)
        if config.acceptance.reference_path:
            reference = Path(config.acceptance.reference_path)
            recorder.add_attachment(reference.name, "application/json", reference.read_bytes(), now_s)

    def _metadata(self, run_id: str | None = None) -> dict:
        config, identity = self.config, self.config.imu.identity
        return {
            "run": {"run_id": run_id or self.run_id, "operator": self.operator, "software_version": __version__,
                    "started_utc": utc_stamp(),
                    "mode": "simulator" if self.sim else "hardware", "kind": self.kind.value,
                    "logs_before": json.dumps(self.previous_logs), "resumed_units": json.dumps(sorted(self.completed))},
            "config": {"toml": config.source_text, "path": str(config.path or "<built-in --sim>")},
            # a value the site does not have (local g: from latitude and height) is left out, not "None"
            "site": {k: str(v) for k, v in config.site.site.to_dict().items() if v is not None},
            "imu": {"model": identity.model, "serial": identity.serial, "rate_hz": str(config.imu.rate_hz),
                    "interface": str(config.imu.interface), "channel": str(config.imu.channel),
                    "dbc": config.imu.dbc.name, **self._time_base()},
            "plan": {"steps_json": json.dumps([step_to_dict(s) for s in self.plan.steps]),
                     "estimated_total_s": f"{self.plan.estimated_total_s:.1f}", "order": self.plan.order,
                     "positions": _name(config.plan.positions), "rotations": _name(config.plan.rotations)},
            **({"lab": self.lab} if self.lab else {}),
            **units_metadata(config),
        }

    def _time_base(self) -> dict[str, str]:
        """How the CAN interface's timestamps map onto the run clock (hardware; the IMU check has seen
        frames by the time the metadata is written): interface time = run time + can_time_offset_s."""
        base = self.receiver.time_base if self.receiver is not None else None
        if base is None or base.offset_s is None:
            return {}
        return {"can_time_offset_s": repr(base.offset_s)}

    # -- the run -------------------------------------------------------------------------
    def options(self) -> SequencerOptions:
        chamber = self.config.chamber
        thermal = {"chamber_poll_s": chamber.poll_s, "chamber_safe_setpoint_c": chamber.safe_setpoint_c} \
            if chamber is not None and self.is_thermal else {}
        return SequencerOptions(**{"settle_tolerance_deg": self.config.table.settle_tolerance_deg,
                                   "move_poll_s": self.config.table.poll_s, **thermal,
                                   **(SIM_OPTIONS if self.sim else {}),
                                   **({"imu_poll_s": SIM_IMU_POLL_S} if self.sim and not self.is_thermal else {})})

    def _opened(self) -> tuple[Turntable, ImuReceiver, McapRecorder, Clock]:
        if self.table is None or self.receiver is None or self.recorder is None or self.clock is None:
            raise BenchError("BenchRun: open() it first")
        return self.table, self.receiver, self.recorder, self.clock

    def run(self) -> RunState:
        """Enable the table and execute the plan (blocking). Errors end in a safe stop, see `sequencer.error`."""
        table, receiver, recorder, clock = self._opened()
        assert self.devices is not None          # (_opened checked it)
        source = self.devices.imu_source()
        options = self.options()
        units = UnitsSource(source, self.devices.units, recorder, now=clock.now, timeout_s=options.imu_timeout_s,
                            on_failure=self.config.on_unit_failure) if self.config.several else None
        imu = units if units is not None else source
        self.sequencer = sequencer = Sequencer(self.plan.steps, table, imu, clock,
                                               [recorder, *self.extra_listeners], options, self.completed,
                                               chamber=self.chamber)
        if units is not None:       # a unit that fails: a warning in the log, the unit dropped ([run] on_unit_failure)
            units.warn = sequencer.warn
        if self._abort_reason is not None:      # asked for while the devices opened: the run ends at once
            sequencer.abort(self._abort_reason)
        table.reset_faults()
        table.enable()
        try:
            state = sequencer.run()
        finally:
            # The samples still pending in the assembler reach every listener, like all the others.
            block = receiver.flush()
            if len(block):
                sequencer.publish_imu(block)
            if units is not None:
                units.drain_units(flush=True)
        return state

    def abort(self, reason: str = "abort requested") -> None:
        """End the run as soon as possible, the table stopped; asked before `run()`, the run aborts at its start."""
        if self._abort_reason is None:
            self._abort_reason = reason
        if self.sequencer is not None:
            self.sequencer.abort(reason)

    # -- after the run ---------------------------------------------------------------------
    def finish(self) -> RunOutcome:
        """Finish the run from its log(s) as its kind finishes (`bench.finish.finish`: solve, judge, write the result
        and reports as `<run-id>.*`, attach them to the log), close the log."""
        _, receiver, recorder, _ = self._opened()
        seq = self.sequencer
        if seq is None or seq.error is not None:
            recorder.close()
            return RunOutcome(seq.state if seq else RunState.FAILED, self.log_path, error=seq.error if seq else None)
        broken = next((exc for listener, exc in seq.listener_errors if listener is recorder), None)
        if broken is not None:          # the log failed on the run's very last event: no result from it
            recorder.close()
            error = ListenerError(describe_listener_error(recorder, broken))
            return RunOutcome(seq.state, self.log_path, error=error)
        recorder.flush()
        config = self.config
        if config.several:
            return self._finish_units(seq.state, recorder)
        logs = [read_log(p) for p in self.previous_logs] + [read_log(str(self.log_path))]
        setup = LogSetup(config.imu.layout, float(config.imu.rate_hz), config, config.site.site)
        # A log being resumed was cut off: its missing summary is expected, not damage; this one is still open.
        still_open = frozenset({str(self.log_path), *map(str, self.previous_logs)})
        recorded = recorded_run(logs, setup, self.sim, still_open)
        finished = finish(recorded, _LiveTarget(self, seq.state, receiver, recorder))
        recorder.close()            # (a result's writing closed it already: closing twice is a no-op)
        return RunOutcome.of(seq.state, self.log_path, finished)

    def _finish_units(self, state: RunState, recorder: McapRecorder) -> RunOutcome:
        """A run of several IMUs: every unit finished from the log as `bench solve` finishes it (`bench.finish.units`:
        `<run-id>.<serial>.*` beside the log, each result attached to the log), then the log closed; the outcome
        is the reference unit's, with every unit's in `units`."""
        def attach(path: Path) -> None:
            recorder.add_attachment(path.name, "application/json", path.read_bytes(),
                                    self.clock.now() if self.clock is not None else 0.0)

        try:
            # the log is read still open (flushed): each unit's result is attached to it as it is written
            finished = finish_units([read_log(str(self.log_path))], self.config, self.out_dir, self.run_id, self.sim,
                                    solved=False, still_open=frozenset({str(self.log_path)}), attach=attach)
        finally:
            recorder.close()
        reference = finished[self.config.imu.identity.serial]
        if reference.result is None:    # the run is timed with it: without its result there is no run's result
            raise SolverError("; ".join(reference.failures) + f" (the other units' files are in {self.out_dir})")
        outcome = RunOutcome.of(state, self.log_path, reference)
        outcome.units = finished
        return outcome

    def finish_observations(self) -> tuple[Extraction | None, BaseException | None]:
        """For a run that is not solved (a verification): close the log and extract its observations.

        Returns (observations, None), or (None, the error) when the run failed."""
        _, receiver, recorder, _ = self._opened()
        seq = self.sequencer
        if seq is None or seq.error is not None:
            recorder.close()
            return None, seq.error if seq is not None else BenchError("the run did not start")
        broken = next((exc for listener, exc in seq.listener_errors if listener is recorder), None)
        recorder.close()
        if broken is not None:          # the log failed on the run's very last event
            return None, ListenerError(describe_listener_error(recorder, broken))
        config = self.config
        extraction, _, damage_lines = extract_from_logs([read_log(str(self.log_path))], config.site.site,
                                                  config.imu.layout, config.imu.rate_hz)
        extraction.problems += damage(damage_lines)
        if receiver.stats.lost_samples:
            extraction.problems.append(link_lost_samples(receiver.stats.summary()))
        return extraction, None

    def close(self) -> None:
        self._stack.close()

    def __enter__(self) -> "BenchRun":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _LiveTarget(Target):
    """The outputs of the run that recorded the logs: `<run-id>.*` beside its log, each attached to the log (still
    open); the result is renamed into place once its reports are written and the log is closed."""

    live = True

    def __init__(self, run: BenchRun, state: RunState, receiver: ImuReceiver, recorder: McapRecorder):
        self.run, self.state, self.receiver, self.recorder = run, state, receiver, recorder
        self.out_dir, self.stem = run.out_dir, run.run_id

    def _now_s(self) -> float:
        return self.run.clock.now() if self.run.clock is not None else 0.0

    def run_section(self, recorded: Recorded, solved: Solved) -> RunInfo:
        run, config, receiver = self.run, self.run.config, self.receiver
        identity = config.imu.identity
        return RunInfo(run_id=run.run_id, mode="simulator" if run.sim else "hardware", operator=run.operator,
                       software_version=__version__, state=self.state.value, log=run.log_path.name,
                       logs=[Path(p).name for p in run.previous_logs] + [run.log_path.name],
                       positions=_name(config.plan.positions), rotations=_name(config.plan.rotations),
                       started_utc=recorded.logs[0].metadata.get("run", {}).get("started_utc") or None,
                       finished_utc=utc_stamp(), imu=ImuIdentity(identity.model, identity.serial),
                       site=config.site.site.to_dict(), quality_failures=solved.failures,
                       sim=sim_table_record(config) if run.sim else None,      # (its verification's table)
                       imu_link=ImuLink.from_dict({**receiver.stats.as_dict(), **(
                           receiver.time_base.as_dict() if receiver.time_base is not None else {})}),
                       lost_samples=LostSamples.from_dict(solved.lost))

    def title(self, what: str, detail: str = "") -> str:
        return f"{what} {self.stem}" + (f" ({detail})" if detail else "")

    def thermal_run(self, run_info: RunInfo) -> dict:
        return {"mode": run_info.mode, "run_id": self.stem, "log": self.run.log_path.name}

    def write_result(self, recorded: Recorded, result: CalibrationResult, reports: Reports,
                     also: Sequence[Path] = ()) -> tuple[Path, Path, Path | None]:
        result_path = self.out_dir / f"{self.stem}.result.json"
        with unfinished(result_path) as partial:
            result.save(partial)
            report_path, html_report_path = write_reports(
                result, self.out_dir, self.stem, log=recorded.logs[-1], layout=recorded.setup.layout,
                log_still_open=True, problems=reports.problems, failures=reports.failures,
                imu_link=self.receiver.stats.as_dict(), title=reports.title)
            now_s = self._now_s()
            self.recorder.add_attachment(result_path.name, "application/json", partial.read_bytes(), now_s)
            for path in also:
                self.recorder.add_attachment(path.name, "application/json", path.read_bytes(), now_s)
            self.recorder.close()
        return result_path, report_path, html_report_path

    def link_stats(self, recorded: Recorded) -> ImuStats:
        return self.receiver.stats

    def keep(self, path: Path) -> None:
        self.recorder.add_attachment(path.name, "application/json", path.read_bytes(), self._now_s())


@contextmanager
def unfinished(path: Path) -> Iterator[Path]:
    """A temporary name next to `path` for a file the block writes: renamed to `path` when the block ends, removed
    when it raises (a stop signal while solving leaves no complete-looking result)."""
    partial = path.with_name(f".{path.name}.partial")
    try:
        yield partial
    except BaseException:
        with suppress(OSError):
            partial.unlink()
        raise
    os.replace(partial, path)


def save_replacing(result: CalibrationResult, path: Path) -> None:
    """Write `result` over `path` in one step (a temporary file renamed): a reader never sees half of it."""
    with unfinished(path) as partial:
        result.save(partial)
