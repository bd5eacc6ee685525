"""`bench run --resume LOG`: what an interrupted run's log lets the new run skip, checked first.

The units of the log (and of the earlier logs it names, next to it) are skipped by label,
so the log must be of this very run's setup: the same plan (schedules by name and
content, timing, order), IMU, site and table (`bench.log.run_setup`). A log of anything
else is refused with `SetupMismatch` naming the difference (exit code 2, nothing moved),
as is a log whose finished units are not this plan's steps, a log of a run that ended done
(nothing to resume) and a log whose recorded run id is not its name's (another run's, renamed).
A log that ends inside a record, as a full disk or a crash leaves it, is resumed: its cut-off
tail is not damage (`bench.solve.from_logs`). An earlier log the log names
is only ever looked for next to it by base name (`bench.log.names.sibling_log`); an entry
that is not such a file is skipped with a note.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from bench.config.load import BenchConfig
from bench.log.events import RunState, final_state, finished_observation_steps
from bench.log.names import LOG_SUFFIX, logs_before, shown, sibling_log
from bench.log.reader import RunLog, read_log
from bench.log.run_info import NO_PLAN_IN_MANUAL_LOG, is_manual_log
from bench.log.run_setup import SetupMismatch, check_same_setup, nominal, setup_of_log, setup_of_run
from bench.plan.compiler import CompiledPlan
from bench.plan.steps import step_to_dict


@dataclass
class ResumePoint:
    """What a resumed run skips and which logs its solve reads before its own."""

    completed: set[str] = field(default_factory=set)      # units finished in the earlier logs
    previous_logs: list[str] = field(default_factory=list)  # the earlier logs, oldest first (the resumed one last)
    notes: list[str] = field(default_factory=list)        # earlier-log entries skipped, and why


def resume_point(resume_log: str | Path | None, config: BenchConfig, plan: CompiledPlan, *, sim: bool) -> ResumePoint:
    """Read the log to resume and its earlier logs, refusing any that is not of this run's setup.

    Raises `LogError` (a log that cannot be read) or `SetupMismatch` (one of another
    plan, IMU, site or table, or with finished units that are not this plan's).
    """
    if not resume_log:
        return ResumePoint()
    here = setup_of_run(config, plan, sim=sim)
    planned = {s.unit: nominal(step_to_dict(s)) for s in plan.steps if s.kind in ("dwell", "turn")}
    log = read_log(str(resume_log))
    if is_manual_log(log):
        raise SetupMismatch(f"{log.path}: {NO_PLAN_IN_MANUAL_LOG}, so there is nothing to resume")
    name = Path(log.path).name
    notes: list[str] = []
    entries, malformed = logs_before(log.metadata)
    if malformed:
        notes.append(f"{name}: {malformed}")
    previous: list[str] = []
    earlier: list[RunLog] = []
    for entry in entries:
        path, why = sibling_log(log.path, entry)
        if path is None:
            notes.append(f"{name} {why}")
            continue
        if not path.is_file():
            notes.append(f"{name} names {path.name} as an earlier log of its run, which is not next to it: "
                         "its units are run again")
            continue
        if str(path) not in previous:
            earlier.append(read_log(str(path)))
            previous.append(str(path))
    completed: set[str] = set()
    for each in [*earlier, log]:
        check_same_setup(setup_of_log(each), here, "the log", "this run", f"{each.path} is not a log of this run")
        _check_resumable(each)
        completed |= _finished_units(each, planned)
    return ResumePoint(completed, [*previous, str(resume_log)], notes)


def _check_resumable(log: RunLog) -> None:
    """`SetupMismatch` for a log that is not an interrupted run's own: one whose run ended done (resuming it would
    turn one measurement into two calibrations: `bench solve LOG` solves it) or whose recorded run id is not the
    one its name says (`<run-id>.mcap`: a renamed or copied log of another run)."""
    name = Path(log.path).name
    run_id = (log.metadata.get("run") or {}).get("run_id")
    if run_id != name.removesuffix(LOG_SUFFIX):
        raise SetupMismatch(f"{log.path} records run id {shown(run_id)}, not the one its name says "
                            f"({shown(name.removesuffix(LOG_SUFFIX))}): a log of another run is not resumed")
    if final_state(log.events) == RunState.DONE.value:
        raise SetupMismatch(f"{log.path} is of a finished run (it ended done): there is nothing to resume "
                            f"(bench solve {log.path} solves it)")


def _finished_units(log: RunLog, planned: dict[str, tuple]) -> set[str]:
    """The log's finished observation units; `SetupMismatch` if one is not the plan's step of that label."""
    done = set()
    for unit, (_, finished) in finished_observation_steps(log.events).items():
        step = finished.step
        if unit not in planned or step is None or nominal(step) != planned[unit]:
            raise SetupMismatch(f"{log.path} is not a log of this run: its unit {shown(unit)} is not this plan's "
                                "step of that name")
        done.add(unit)
    return done


__all__ = ["ResumePoint", "resume_point"]
