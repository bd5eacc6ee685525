"""What kind of run a log records: calibration, thermal, static noise, verification, table check or manual moves.

A run records its kind at its start (`run.kind` in the log's "run" metadata, `kind_of_config`
for the plan a `BenchRun` runs; a log of manual moves, `bench tui`, has always recorded
"manual"). `run_kind(log)` reads it back; a log written before the field existed gets
the kind the commands gave it then: a static noise recording when its recorded
configuration plans one (`config`: the configuration rebuilt from the log), a thermal
run when its steps belong to temperature blocks ("T2-P03"), else a calibration (a
verification or table-check log of those versions is read as a calibration, as it was).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any, Mapping, Sequence

from bench.config.load import BenchConfig
from bench.log.reader import RunLog
from bench.plan.steps import thermal_block


class RunKind(StrEnum):
    """The kind of a run, as its log records it (`run.kind`)."""

    CALIBRATION = "calibration"
    THERMAL = "thermal"                  # a calibration at each chamber temperature (`[plan] temperatures_c`)
    STATIC_NOISE = "static-noise"        # one long dwell analysed by `bench noise` (a "static" schedule)
    VERIFICATION = "verification"        # `bench verify`: a calibration checked on the verification schedule
    TABLE_CHECK = "table-check"          # `bench check-table`: the table's axis errors
    MANUAL = "manual"                    # manual moves in `bench tui`, no plan


def kind_of_config(config: BenchConfig) -> RunKind:
    """The kind of the run of `config`'s plan (what a `BenchRun` records at its start)."""
    plan = config.plan
    schedule_kinds = {schedule.kind for schedule in (plan.positions, plan.rotations) if schedule is not None}
    # static first, as the live run's finish decided; a verification or table check keeps the calibration
    # configuration's temperatures (its chamber) but is not a thermal calibration
    if "static" in schedule_kinds:
        return RunKind.STATIC_NOISE
    if "verification" in schedule_kinds:
        return RunKind.VERIFICATION
    if "table-check" in schedule_kinds:
        return RunKind.TABLE_CHECK
    if plan.thermal is not None:
        return RunKind.THERMAL
    return RunKind.CALIBRATION


def recorded_run_kind(metadata: Mapping[str, Any]) -> RunKind | None:
    """The kind a log's metadata records (None: not recorded, or a value this version does not know)."""
    run = metadata.get("run")
    raw = run.get("kind") if isinstance(run, Mapping) else None
    if not isinstance(raw, str):
        return None
    try:
        return RunKind(raw)
    except ValueError:
        return None


def run_kind(log: RunLog, config: BenchConfig | None = None) -> RunKind:
    """The kind of the run `log` records: its `run.kind`, else as the commands told it before the field
    (`config`: the configuration rebuilt from the log, None when it cannot be)."""
    recorded = recorded_run_kind(log.metadata)
    if recorded is not None:
        return recorded
    positions = config.plan.positions if config is not None else None
    if positions is not None and positions.kind == "static":
        return RunKind.STATIC_NOISE
    if any(e.step_unit is not None and thermal_block(e.step_unit) is not None for e in log.events):
        return RunKind.THERMAL
    return RunKind.CALIBRATION


def run_kind_of_logs(logs: Sequence[RunLog], config: BenchConfig | None = None) -> RunKind:
    """The kind of the run a set of logs of one run records (`run_kind` of each; `config` rebuilt from the
    first): manual moves if any log is one, a static noise recording, a thermal run if any log is one, else the
    last log's kind."""
    kinds = [run_kind(log, config) for log in logs]
    for kind in (RunKind.MANUAL, RunKind.STATIC_NOISE, RunKind.THERMAL):
        if kind in kinds:
            return kind
    return kinds[-1] if kinds else RunKind.CALIBRATION


__all__ = ["RunKind", "kind_of_config", "recorded_run_kind", "run_kind", "run_kind_of_logs"]
