"""A recorded run read back from its MCAP logs: what `bench.finish.finish` finishes.

`load_recorded(paths)` reads one or more logs of one IMU (a resumed run's earlier logs
are added when the later log names them and they are found), rebuilds the run's setup
from the first log (`bench.log.run_info`), extracts every complete step and merges them by
unit exactly as the live run does (`bench.solve.from_logs`), and accounts for every planned
unit that is not in the logs (`Recorded.left_out`). The live run builds its own `Recorded` with
`recorded_run` from the logs it just wrote and its configuration.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

from bench.errors import InputError
from bench.log.events import (
    DwellRecord,
    StepSkipped,
    StepStarted,
    Transition,
    TurnRecord,
    final_state,
    finished_observation_steps,
)
from bench.log.names import logs_before, run_id_of, sibling_log
from bench.log.reader import LogError, RunLog, read_log
from bench.log.run_info import (
    NO_PLAN_IN_MANUAL_LOG,
    LogSetup,
    is_manual_log,
    layout_and_config_from_log,
    steps_from_log,
)
from bench.log.run_kind import RunKind, run_kind, run_kind_of_logs
from bench.log.run_setup import differences, setup_of_log
from bench.model.earth import Site
from bench.model.quality import FailureKind, QualityFailure
from bench.solve.extract import Extraction
from bench.solve.from_logs import extract_from_logs
from drivers.imu import ImuStats

NONE = "none"
_ANGLE_DECIMALS = 6
_RECORDED = "recorded but left out by the extraction"


class SolveInputError(InputError):
    """What was asked cannot be served from these logs (exit code 2): a subset the logs
    lack, an unknown schedule, logs of different IMUs or runs that do not merge."""


# -- reading the logs --------------------------------------------------------------------------

@dataclass
class Recorded:
    """Everything recorded in a set of logs of one run (or of one IMU), ready to solve."""

    logs: list[RunLog]                      # oldest first
    setup: LogSetup                         # of the first log: layout, rate, configuration, site
    sim: bool
    extraction: Extraction                  # every complete step of every log, merged by unit
    imu_stats: list[ImuStats]               # per log, from decoding its raw CAN frames
    damage: list[str]                       # per log damage lines, prefixed with the file
    planned: list[str]                      # every observation unit of the plan(s), in plan order
    left_out: dict[str, str]                # unit -> why it is not in `extraction` (one line)
    notes: list[str] = field(default_factory=list)

    @cached_property
    def kind(self) -> RunKind:
        """The kind of the recorded run (`bench.log.run_kind`: recorded, or told as before for an older log)."""
        return run_kind_of_logs(self.logs, self.setup.config)

    def first_log_of_kind(self, kind: RunKind) -> RunLog | None:
        """The first log that records a run of `kind` (the one a refusal names)."""
        return next((log for log in self.logs if run_kind(log, self.setup.config) is kind), None)

    @property
    def run_meta(self) -> dict[str, str]:
        return self.logs[-1].metadata.get("run", {})

    @property
    def run_id(self) -> str:
        """The run id outputs are named by: the log's own when it is a safe file name (`bench.log.names`)."""
        return run_id_of(self.logs[-1].path, self.logs[-1].metadata)[0]

    @property
    def final_state(self) -> str:
        return final_state(self.logs[-1].events) or "unknown"

    @property
    def site(self) -> Site:
        """The run's site (`load_recorded` refuses logs that record none)."""
        if self.setup.site is None:
            raise SolveInputError(f"{self.logs[0].path}: the log records no usable site")
        return self.setup.site

    @property
    def truth(self):
        """The simulated IMU's true coefficients (None for hardware or without a configuration)."""
        config = self.setup.config
        return config.sim.imu if self.sim and config is not None else None

    def problems(self) -> list[QualityFailure]:
        """Steps left out or degraded: the extraction's, then the units not in the logs."""
        return list(self.extraction.problems) + [QualityFailure(FailureKind.LEFT_OUT, f"{unit}: {why}", unit)
                                                 for unit, why in self.left_out.items()
                                                 if not why.startswith(_RECORDED)]

    def imu_link(self) -> ImuStats:
        """The IMU link statistics of all logs added up."""
        total = ImuStats()
        for stats in self.imu_stats:
            for f in dataclasses.fields(ImuStats):
                setattr(total, f.name, getattr(total, f.name) + getattr(stats, f.name))
        return total


def _name(path: str) -> str:
    return Path(path).name


def _earlier_names(log: RunLog) -> list[str]:
    """The file names of the earlier logs `log` names (`run.logs_before`), those that can be its siblings."""
    entries, _ = logs_before(log.metadata)
    return [path.name for path in (sibling_log(log.path, entry)[0] for entry in entries) if path is not None]


def _replacement_notes(logs: list[RunLog], replaced: list[tuple[str, str, str]]) -> list[str]:
    """A note per pair of logs where the later one's units replaced the earlier one's, unless the later log resumed
    the earlier (a resumed run repeats the unit that was cut off: expected). Several complete logs of one IMU solve
    together; without this note a user who gave two runs would not know one run's dwells were dropped."""
    resumes = {_name(log.path): set(_earlier_names(log)) for log in logs}
    pairs: dict[tuple[str, str], list[str]] = {}
    for unit, earlier, later in replaced:
        if _name(earlier) not in resumes.get(_name(later), set()):
            pairs.setdefault((earlier, later), []).append(unit)
    notes = []
    for (earlier, later), units in pairs.items():
        shown = ", ".join(units[:6]) + (f" and {len(units) - 6} more" if len(units) > 6 else "")
        notes.append(f"{_name(later)} replaces {len(units)} unit(s) of {_name(earlier)} ({shown}): logs of one IMU "
                     "solve as one run, a later log's unit replacing an earlier one's; solve each log on its own "
                     "to keep both")
    return notes


def _earlier_logs(log: RunLog, notes: list[str]) -> list[Path]:
    """The earlier logs `log` names that are `.mcap` files next to it; a note for every other entry."""
    entries, malformed = logs_before(log.metadata)
    if malformed:
        notes.append(f"{_name(log.path)}: {malformed}")
    found = []
    for entry in entries:
        path, why = sibling_log(log.path, entry)
        if path is None:
            notes.append(f"{_name(log.path)} {why}")
        elif not path.is_file():
            notes.append(f"{_name(log.path)} resumed {path.name}, which is not found next to it: "
                         "its units are not in this solve")
        else:
            found.append(path)
    return found


def read_logs(paths: list[str], *, earlier: bool = True) -> tuple[list[RunLog], list[str]]:
    """Read the logs (LogError on one that cannot be read at all), oldest first.

    With `earlier`, the logs a resumed log names as its run's earlier ones are read too
    when found next to the resumed log (by base name: an entry that is not a `.mcap` file
    name is skipped with a note, see `bench.log.names.sibling_log`). Returns the logs and
    notes on what was added, skipped or not found.
    """
    logs: dict[str, RunLog] = {}
    notes: list[str] = []
    for path in paths:
        if _name(str(path)) not in logs:
            logs[_name(str(path))] = read_log(path)
    if earlier:
        for log in list(logs.values()):
            for found in _earlier_logs(log, notes):
                if found.name in logs:
                    continue
                logs[found.name] = read_log(found)
                notes.append(f"also read {found}: the run of {_name(log.path)} resumed it")
    listed_before = {name: sum(name in map(_name, _earlier_names(other)) for other in logs.values()) for name in logs}
    order = sorted(logs, key=lambda n: (-listed_before[n], logs[n].metadata.get("run", {}).get("started_utc", ""),
                                        n))
    return [logs[n] for n in order], notes


def _check_one_imu(logs: list[RunLog]) -> None:
    first = logs[0]

    def ident(log):
        imu = log.metadata.get("imu", {})
        return imu.get("model", ""), imu.get("serial", ""), imu.get("rate_hz", "")

    for log in logs[1:]:
        if ident(log) != ident(first):
            model, serial, rate = ident(log)
            raise SolveInputError(f"{log.path} records IMU {model!r} serial {serial!r} at {rate} Hz but {first.path} "
                                  f"records {ident(first)[0]!r} serial {ident(first)[1]!r} at {ident(first)[2]} Hz: "
                                  "solve logs of one IMU together")


def _check_one_setup(logs: list[RunLog]) -> None:
    """Logs merged by unit label must be of one plan, IMU, site and table (`bench.log.run_setup`)."""
    first, setup = logs[0], setup_of_log(logs[0])
    for log in logs[1:]:
        found = differences(setup_of_log(log), setup, _name(log.path), _name(first.path))
        if found:
            raise SolveInputError(f"{log.path} and {first.path} are not logs of one run: {'; '.join(found)}: "
                                  "solve them separately")


def _nominal(record: DwellRecord | TurnRecord | None) -> tuple:
    if isinstance(record, TurnRecord):
        return ("turn", angle_key(record.start_deg), record.frame, record.direction)
    assert record is not None                   # a finished observation step has its record
    return ("dwell", angle_key(record.angles_deg))


def angle_key(angles_deg) -> tuple[float, ...]:
    """Nominal angles compared modulo 360 (to a micro-degree)."""
    return tuple(round(float(a) % 360.0, _ANGLE_DECIMALS) % 360.0 for a in angles_deg)


def _check_units_agree(logs: list[RunLog]) -> None:
    """Units merge by label: two logs may share a label only for the same nominal step."""
    seen: dict[str, tuple[str, tuple]] = {}
    for log in logs:
        for unit, (_, finished) in finished_observation_steps(log.events).items():
            nominal = _nominal(finished.record)
            if unit in seen and seen[unit][1] != nominal:
                raise SolveInputError(f"{seen[unit][0]} and {log.path} both record unit {unit} with different "
                                      "steps: they are not parts of one run; solve them separately")
            seen[unit] = (log.path, nominal)


def _planned_units(logs: list[RunLog], notes: list[str]) -> list[str]:
    units: dict[str, None] = {}
    for log in logs:
        try:
            steps = steps_from_log(log)
        except LogError as exc:
            notes.append(f"{exc}: units missing from the log cannot be listed")
            continue
        units.update((s.unit, None) for s in steps if s.kind in ("dwell", "turn"))
    return list(units)


def _left_out(logs: list[RunLog], planned: list[str], extraction: Extraction) -> dict[str, str]:
    """Why each planned unit without an observation has none (one line each)."""
    solved = set(extraction.units)
    finished, started, skipped = set(), {}, {}
    for log in logs:
        finished |= set(finished_observation_steps(log.events))
        started.update({e.step_unit: (log, e) for e in log.events if isinstance(e, StepStarted) and e.step_unit})
        skipped.update({e.step_unit: log for e in log.events if isinstance(e, StepSkipped) and e.step_unit})
    last = logs[-1]
    final = [e.state for e in last.events if isinstance(e, Transition) and e.state]
    ended = max((e.time_s for log in logs for e in log.events), default=0.0)
    out = {}
    for unit in planned:
        if unit in solved:
            continue
        if unit in finished:
            out[unit] = _RECORDED + " (see its line above)"
        elif unit in started:
            log, event = started[unit]
            out[unit] = (f"left out: started at {event.time_s:.1f} s in {_name(log.path)} but its end is not in the "
                         + ("log (cut off or damaged, see the damage lines)" if not log.scan().complete else "log"))
        elif unit in skipped:
            log = skipped[unit]
            earlier = ", ".join(map(_name, _earlier_names(log))) or "not named"
            out[unit] = (f"left out: {_name(log.path)} skipped it as done in an earlier log of its run ({earlier}), "
                         "which is not among the logs read")
        elif final and final[-1] == "done":
            out[unit] = "left out: the run finished but this unit's records are lost in the damage"
        elif not last.scan().complete:
            out[unit] = (f"left out: no record of it in the logs ({_name(last.path)} is cut off or damaged "
                         f"after {ended:.1f} s)")
        else:
            out[unit] = f"left out: not run (the run ended {final[-1] if final else 'early'} before it)"
    return out


def static_noise_plan(recorded: Recorded) -> str | None:
    """The name of the recorded plan's positions when the run is a static noise recording, else None."""
    if recorded.kind is not RunKind.STATIC_NOISE:
        return None
    config = recorded.setup.config
    positions = config.plan.positions if config is not None else None
    return positions.name if positions is not None else recorded.logs[-1].metadata.get("plan", {}).get("positions", "")


def load_recorded(paths: list[str], *, earlier: bool = True) -> Recorded:
    """Read and extract logs of one IMU (LogError: unreadable; SolveInputError: logs that do not go together)."""
    if not paths:
        raise SolveInputError("no log given")
    logs, notes = read_logs(list(map(str, paths)), earlier=earlier)
    manual = next((log for log in logs if is_manual_log(log)), None)
    if manual is not None:
        raise SolveInputError(f"{manual.path}: {NO_PLAN_IN_MANUAL_LOG}, so there is nothing to solve")
    _check_one_imu(logs)
    _check_one_setup(logs)
    _check_units_agree(logs)
    setup = layout_and_config_from_log(logs[0])
    notes += list(setup.notes)
    _, renamed = run_id_of(logs[-1].path, logs[-1].metadata)
    if renamed:
        notes.append(f"{_name(logs[-1].path)}: {renamed}")
    site = setup.site
    if site is None:
        raise SolveInputError(f"{logs[0].path}: the log records no usable site: cannot solve "
                              f"({'; '.join(setup.notes)})")
    # As in `bench run`: a log its run resumed was cut off, its missing summary is expected.
    resumed = {_name(p) for log in logs for p in _earlier_names(log)}
    still_open = frozenset(log.path for log in logs if _name(log.path) in resumed)
    sim = logs[0].metadata.get("run", {}).get("mode") == "simulator"
    return recorded_run(logs, setup, sim, still_open, notes)


def recorded_run(logs: list[RunLog], setup: LogSetup, sim: bool, still_open: frozenset[str] = frozenset(),
                 notes: list[str] | None = None) -> Recorded:
    """The recorded run of `logs` (oldest first) with a known setup: every complete step extracted and merged by
    unit, the planned units accounted for. The live run calls it on its own logs with its configuration's setup
    (`bench.run.runner`); `load_recorded` with the setup the log records. A log in `still_open` may lack its
    summary (a log being finished, or one its run resumed after it was cut off)."""
    if setup.site is None:
        raise SolveInputError(f"{logs[0].path}: no usable site: cannot solve")
    notes = list(notes or [])
    extraction, stats, damage = extract_from_logs(logs, setup.site, setup.layout, setup.rate_hz, setup.mounting,
                                                  still_open)
    notes += _replacement_notes(logs, extraction.replaced)
    planned = _planned_units(logs, notes)
    return Recorded(logs, setup, sim, extraction, stats, damage, planned, _left_out(logs, planned, extraction), notes)


__all__ = ["Recorded", "SolveInputError", "angle_key", "load_recorded", "read_logs", "recorded_run",
           "static_noise_plan"]
