"""Finishing a run of several IMUs (`[[imu]]`): every unit solved on its own, in its own body axes.

Each unit is solved from the log as a single IMU is (`bench.finish.finish`): its frames from its own topics (the
reference unit's are `/can/raw`), its configuration the run's with `[imu]` = that unit (identity, layout and ids,
rate; on the simulator its own truth, `bench.sim.units.unit_truth`), its mounting taken out in the kinematics
(`LogSetup.mounting`), so its coefficients are those of its body axes whatever face it sat on. The sequencer timed
the dwells and turns with the reference unit's counters; another unit's window is the span of its samples received
within the reference window's first and last sample (half a sample either side): on the simulator the very same
sample times. The live run and `bench solve` both come here: a re-solve reproduces every unit's result bit for bit.
Outputs: `<run-id>.<serial>.result.json` and its reports (a re-solve: `<run-id>.<serial>.solved.*`).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from bench.config.load import BenchConfig
from bench.config.units import FACES, lever_arm_in_body_m
from bench.files import write_output_text
from bench.finish.calibration import Solved, resolved_run_section
from bench.finish.finish import Finished, Reports, Target, finish
from bench.finish.recorded import Recorded, SolveInputError, recorded_run
from bench.log.events import UNIT_DROPPED, CounterWindow, Event, RunWarning, StepFinished
from bench.log.names import output_path
from bench.log.reader import LogError, RunLog, read_log
from bench.log.run_info import LogSetup
from bench.log.run_kind import RunKind
from bench.model.result import CalibrationResult
from bench.model.run_section import ImuIdentity, RunInfo
from bench.report.markdown import markdown_report, write_reports
from bench.sim.units import unit_truth
from bench.solve.methods import SolverError
from drivers.imu import ImuSampleBlock, ImuStats


def is_several(log: RunLog) -> bool:
    """The log records a run of several IMUs (its `units` record)."""
    return "units_json" in log.metadata.get("units", {})


def recorded_serials(log: RunLog) -> list[str]:
    """The serials of the units a log of several IMUs records, the reference unit first."""
    try:
        units = json.loads(log.metadata["units"]["units_json"])
        return [str(unit["serial"]) for unit in units]
    except (KeyError, TypeError, ValueError) as exc:
        raise SolveInputError(f"{log.path}: its units record is malformed ({exc})") from None


def unit_config(config: BenchConfig, index: int) -> BenchConfig:
    """The run's configuration as unit `index` sees it: `[imu]` is that unit, the simulated truth its own."""
    sim = dataclasses.replace(config.sim, imu=unit_truth(config.sim.imu, index, config.sim.seed))
    return dataclasses.replace(config, imu=config.units[index], sim=sim)


def _mounting(config: BenchConfig, index: int) -> np.ndarray | None:
    rows = config.units[index].mounting
    return None if rows is None or rows == FACES["z-up"] else np.array(rows, dtype=float)


def remapped_events(events: list[Event], reference: ImuSampleBlock, unit: ImuSampleBlock,
                    unit_rate_hz: float) -> list[Event]:
    """`events` with every dwell's and turn's counter window (the reference unit's counters) turned into the
    unit's: its samples received from the window's first reference sample to its last, half a sample either side."""
    tolerance_s = 0.5 / unit_rate_hz
    out: list[Event] = []
    for event in events:
        if isinstance(event, StepFinished) and event.window is not None:
            ref = np.flatnonzero((reference.counter >= event.window.first) & (reference.counter <= event.window.last))
            if len(ref):
                t0, t1 = reference.receive_time_s[ref[0]], reference.receive_time_s[ref[-1]]
                inside = np.flatnonzero((unit.receive_time_s >= t0 - tolerance_s)
                                        & (unit.receive_time_s <= t1 + tolerance_s))
                # no sample of the unit there: an empty window past its last counter (the extraction says so)
                window = (CounterWindow(int(unit.counter[inside[0]]), int(unit.counter[inside[-1]]), len(inside))
                          if len(inside) else CounterWindow(_past(unit), _past(unit), 0))
                event = dataclasses.replace(event, window=window)
        out.append(event)
    return out


def _past(unit: ImuSampleBlock) -> int:
    return int(unit.counter[-1]) + 1 if len(unit.counter) else 0


def recorded_unit(logs: list[RunLog], config: BenchConfig, index: int, sim: bool,
                  still_open: frozenset[str] = frozenset()) -> Recorded:
    """Unit `index` of a run of several IMUs, recorded in `logs` (each read as `read_log` reads it), ready to
    finish: its own frames, windows, configuration and mounting."""
    reference = config.units[0]
    own = unit_config(config, index)
    unit = own.imu
    unit_logs = []
    for log in logs:
        if index == 0:
            unit_logs.append(log)
            continue
        ref_block, _ = log.imu_samples(reference.layout, reference.rate_hz)
        unit_log = read_log(log.path, unit=unit.identity.serial)
        unit_block, _ = unit_log.imu_samples(unit.layout, unit.rate_hz)
        unit_log.events = remapped_events(unit_log.events, ref_block, unit_block, unit.rate_hz)
        unit_logs.append(unit_log)
    setup = LogSetup(unit.layout, float(unit.rate_hz), own, own.site.site, mounting=_mounting(config, index),
                     lever_arm_m=lever_arm_in_body_m(unit))
    return recorded_run(unit_logs, setup, sim, still_open)


@dataclass
class UnitTarget(Target):
    """One unit's outputs, `<stem>.result.json` and its reports in `out_dir` (`stem`: `<run-id>.<serial>`, a
    re-solve's `<run-id>.<serial>.solved`); the result's run section is a re-solve's with the unit's identity
    (`solved_by`: who solved it; None for the run's own result, as a single IMU's run writes it: the records keep
    it as the unit's record of truth, not a re-solve)."""

    out_dir: Path
    stem: str
    model: str
    serial: str
    solved_by: str | None = "bench solve"     # None: the live run's own result (`bench run` solved none again)
    html: bool = True
    #: the live run's: attaches a file written to its log (still open); None: a re-solve attaches nothing
    attach: Callable[[Path], None] | None = None
    #: the serials of the run's units, the reference first (the result's `run.units`: the records keep each unit
    #: as `<run-id>.<serial>` of its run)
    units: tuple[str, ...] = ()
    #: the extended model's families (`bench solve --model`); None: the recorded `[model] terms`
    model_terms: tuple[str, ...] | None = None

    def run_section(self, recorded: Recorded, solved: Solved) -> RunInfo:
        run_info = resolved_run_section(recorded, solved)
        run_info.imu = ImuIdentity(self.model, self.serial)
        run_info.solved_by = self.solved_by
        if self.units:
            run_info.extra["units"] = list(self.units)
        config = recorded.setup.config
        if config is not None and config.imu.lever_arm_mm is not None:    # the unit's known place, as configured
            run_info.extra["lever_arm_mm"] = list(config.imu.lever_arm_mm)
        return run_info

    def title(self, what: str, detail: str = "") -> str:
        return f"{what} {self.stem} (unit {self.serial}{', ' + detail if detail else ''})"

    def thermal_run(self, run_info: RunInfo) -> dict:
        raise SolveInputError("a calibration over temperature of several units is not supported yet")

    def write_result(self, recorded: Recorded, result: CalibrationResult, reports: Reports,
                     also: Sequence[Path] = ()) -> tuple[Path, Path, Path | None]:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        result_path = output_path(self.out_dir, f"{self.stem}.result.json")
        result.save(result_path)
        if self.attach is not None:
            self.attach(result_path)
        report: dict[str, Any] = dict(problems=reports.problems, failures=reports.failures,
                                      imu_link=recorded.imu_link().as_dict(), title=reports.title)
        if not self.html:
            md_path = output_path(self.out_dir, f"{self.stem}.report.md")
            write_output_text(md_path, markdown_report(result, **report))
            return result_path, md_path, None
        md_path, html_path = write_reports(result, self.out_dir, self.stem, log=recorded.logs[-1],
                                           layout=recorded.setup.layout, **report)
        return result_path, md_path, html_path

    def link_stats(self, recorded: Recorded) -> ImuStats:
        return recorded.imu_link()


def dropped_units(logs: list[RunLog]) -> dict[str, str]:
    """serial -> why, of every unit dropped from the run while it ran (the `RunWarning` that dropped it)."""
    dropped = {}
    for log in logs:
        for event in log.events:
            if not isinstance(event, RunWarning):
                continue
            serial = event.details.get(UNIT_DROPPED)
            if isinstance(serial, str):
                dropped[serial] = (f"dropped from the run at {event.time_s:.1f} s "
                                   f"({event.details.get('reason', 'no reason recorded')})")
    return dropped


def finish_units(logs: list[RunLog], config: BenchConfig, out_dir: Path, run_id: str, sim: bool, *,
                 serials: Sequence[str] | None = None, solved: bool = True,
                 still_open: frozenset[str] = frozenset(),
                 attach: Callable[[Path], None] | None = None, html: bool = True,
                 model_terms: tuple[str, ...] | None = None) -> dict[str, Finished]:
    """Finish every unit (or those of `serials`) of a run of several IMUs recorded in `logs`: serial -> what was
    written. `solved`: a re-solve's names (`<run-id>.<serial>.solved.*`), else the live run's (`attach`: each
    result attached to the log, still open, as it is written). `html`: HTML reports too; `model_terms`: the extended
    model's families (`bench solve --model`; None: the recorded `[model] terms`). A unit that cannot be solved (no
    samples: a silent unit) gets no result, its `failures` saying why; the others are finished."""
    known = [unit.identity.serial for unit in config.units]
    for serial in serials or ():
        if serial not in known:
            raise SolveInputError(f"no unit {serial!r} in {logs[-1].path} (its units: {', '.join(known)})")
    out: dict[str, Finished] = {}
    dropped = dropped_units(logs)
    for index, unit in enumerate(config.units):
        serial = unit.identity.serial
        if serials and serial not in serials:
            continue
        if serial in dropped:       # failed while the run ran: what it sent before is not a calibration
            out[serial] = Finished(RunKind.CALIBRATION, failures=[f"unit {serial} has no result: {dropped[serial]}"])
            continue
        target = UnitTarget(out_dir, f"{run_id}.{serial}" + (".solved" if solved else ""), unit.identity.model,
                            serial, "bench solve" if solved else None, html=html, attach=attach, units=tuple(known),
                            model_terms=model_terms)
        try:
            recorded = recorded_unit(logs, config, index, sim, still_open)
            out[serial] = finish(recorded, target)
        except (SolverError, SolveInputError, LogError) as exc:   # this unit only: the others are finished still
            out[serial] = Finished(RunKind.CALIBRATION, failures=[f"unit {serial} has no result: {exc}"])
    return out


__all__ = ["UnitTarget", "finish_units", "is_several", "recorded_serials", "recorded_unit", "remapped_events",
           "unit_config"]
