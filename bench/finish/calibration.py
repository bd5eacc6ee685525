"""Solving a recorded calibration: all of it or the subset schedules choose (the logic of `bench solve`).

`solve_recorded` solves all of a `Recorded` or a subset chosen by schedules (`select`: a recorded position counts
for a schedule position with the same nominal angles modulo 360, a turn for a schedule turn with the same start
state, frame and direction); with no subset it is the very computation the live run makes (`bench.finish`), so a
re-solve's coefficients equal the run's bit for bit. Comparing methods (`--compare`) is in `bench.jobs.compare`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

from bench import __version__
from bench.acceptance.limits import AcceptanceLimits
from bench.acceptance.quality import judged_failures, quality_failures
from bench.acceptance.verdict import Verdict, judge
from bench.finish.recorded import Recorded, SolveInputError, angle_key
from bench.log.events import TurnRecord, finished_observation_steps
from bench.log.temperature import imu_temperature
from bench.model.observations import PositionObservation, RotationObservation
from bench.model.quality import FailureKind, QualityFailure, texts
from bench.model.result import CalibrationResult
from bench.model.run_section import ImuIdentity, ImuLink, LostSamples, RunInfo, utc_stamp
from bench.solve.extract import Extraction, without_windows
from bench.solve.from_logs import LogSolution, solve_extraction
from bench.solve.inputs import budget_inputs
from bench.solve.methods import SolverError
from schedules import ScheduleError, resolve_schedule

#: Subset value that keeps none of a kind (e.g. `--rotations none`: a positions-only solve).
NONE = "none"

# -- subsets ------------------------------------------------------------------------------------

def load_subset_schedule(spec: str | None, kind: str):
    """The schedule of `--positions`/`--rotations` (`kind`): None = keep all, NONE = keep none."""
    if spec is None:
        return None
    if spec == NONE:
        return NONE

    try:
        schedule = resolve_schedule(spec)
    except ScheduleError as exc:
        raise SolveInputError(str(exc)) from exc
    wanted = ("positions", "table-check") if kind == "positions" else ("rotations",)
    if schedule.kind not in wanted:
        raise SolveInputError(f"schedule {schedule.name!r} is a {schedule.kind!r} schedule, --{kind} needs a "
                              f"{kind!r} schedule")
    return schedule


def _pick(keys: list, wanted: list, describe) -> tuple[list[int], list[str]]:
    free: dict[tuple, list[int]] = {}
    for i, key in enumerate(keys):
        free.setdefault(key, []).append(i)
    picked, missing = [], []
    for want in wanted:
        if free.get(want):
            picked.append(free[want].pop(0))
        else:
            missing.append(describe(want))
    return sorted(picked), missing


def select(extraction: Extraction, positions=None, rotations=None) -> Extraction:
    """The observations a subset keeps, in recorded order (None: all of that kind; NONE: none).

    Raises SolveInputError listing what a schedule needs that the extraction lacks.
    """
    chosen = Extraction(list(extraction.positions), list(extraction.rotations), list(extraction.problems))
    missing = []
    if positions == NONE:
        chosen.positions = []
    elif positions is not None:
        keys = [angle_key(o.angles_deg) for o in extraction.positions]
        wanted = [angle_key(p.angles_deg) for p in positions.positions]
        idx, lacking = _pick(keys, wanted, lambda k: "(" + ", ".join(f"{a:g}" for a in k) + ")")
        chosen.positions = [extraction.positions[i] for i in idx]
        if lacking:
            missing.append(f"{len(lacking)} of the {len(wanted)} positions of {positions.name} "
                           f"({', '.join(lacking)})")
    if rotations == NONE:
        chosen.rotations = []
    elif rotations is not None:
        turn_keys = [(angle_key(o.start_deg), o.frame, o.direction) for o in extraction.rotations]
        wanted_turns = [(angle_key(r.start_deg), r.frame, r.direction) for r in rotations.rotations]
        idx, lacking = _pick(turn_keys, wanted_turns,
                             lambda k: "(" + ", ".join(f"{a:g}" for a in k[0]) + f") {k[1]} {k[2]}")
        chosen.rotations = [extraction.rotations[i] for i in idx]
        if lacking:
            missing.append(f"{len(lacking)} of the {len(wanted_turns)} rotations of {rotations.name} "
                           f"({', '.join(lacking)})")
    if missing:
        raise SolveInputError("the logs lack " + " and ".join(missing))
    return chosen


def subset_name(schedule, recorded_name: str) -> str:
    """The name a subset's schedule gives (`recorded_name`: none chosen; "": none kept)."""
    if schedule is None:
        return recorded_name
    return "" if schedule == NONE else schedule.name


# -- solving ------------------------------------------------------------------------------------

@dataclass
class Resolved:
    """One solve of (a subset of) the recorded observations."""

    solution: LogSolution
    result: CalibrationResult
    failures: list[QualityFailure]
    positions: str                     # schedule names ("" = none)
    rotations: str
    subset: bool                       # a subset was selected (the output name says which)
    verdict: Verdict | None = None     # the acceptance verdict (the recorded configuration's [acceptance])


def solve_recorded(recorded: Recorded, positions=None, rotations=None, *,
                   run_section: RunSection | None = None, terms: tuple[str, ...] | None = None) -> Resolved:
    """Solve every recorded step, or the subset the schedules choose (SolverError: nothing to solve).

    When the whole solve fails (too few turns or positions left by damage) the positions or the rotations alone
    are solved, the others left out with the reason. `run_section` writes the result's run section (default:
    a re-solve's, `resolved_run_section`; the live run passes its own). `terms`: the extended model's families
    (`bench.solve.extended`), None: the recorded configuration's `[model] terms`."""
    run_section = run_section or resolved_run_section
    config, setup = recorded.setup.config, recorded.setup
    inputs = budget_inputs(config, recorded.sim) if config is not None else None
    chosen = select(recorded.extraction, positions, rotations)
    # a subset does not use the windows it leaves out: their lost samples are outside the windows it uses
    unused = _unused_windows(recorded, chosen, positions, rotations)
    chosen.problems = [p for p in recorded.problems() if not (p.window_loss and p.unit in unused)]
    if terms is None:
        terms = config.model_terms if config is not None else ()
    calibration, chosen, dropped = _solve_what_can_be(chosen, setup.site, inputs, setup.mounting, terms,
                                                      setup.lever_arm_m)
    solution = LogSolution(calibration, chosen, list(recorded.imu_stats), list(recorded.damage))
    failures = quality_failures(solution)
    lost = without_windows(recorded.extraction.lost_samples(), unused)
    plan = recorded.logs[-1].metadata.get("plan", {})
    pos_name = subset_name(positions, plan.get("positions", ""))
    rot_name = subset_name(rotations, plan.get("rotations", ""))
    subset = positions is not None or rotations is not None
    run_info = run_section(recorded, Solved(pos_name, rot_name, failures, lost, sorted({*recorded.left_out, *dropped}),
                                            subset))
    result = calibration.to_result(run=run_info, sim_truth=recorded.truth)
    result.temperature = imu_temperature(recorded.logs, setup.layout, setup.rate_hz)
    limits = config.acceptance if config is not None else AcceptanceLimits()
    verdict = judge(result, limits, lost_samples=lost["total"],
                    quality_failures=texts(judged_failures(failures, limits)))
    result.verdict = verdict.to_section()
    return Resolved(solution, result, failures, pos_name, rot_name, subset, verdict)


@dataclass
class Solved:
    """What a solve found that the result's run section records."""

    positions: str                     # schedule names ("" = none)
    rotations: str
    failures: list[QualityFailure]
    lost: dict                         # the lost samples (`Extraction.lost_samples`)
    left_out: list[str] = field(default_factory=list)    # units not solved (not recorded, or dropped)
    subset: bool = False               # a what-if subset (never the run's record)


#: Writes the result's run section of a solve of a recorded run.
RunSection = Callable[[Recorded, Solved], RunInfo]


def resolved_run_section(recorded: Recorded, solved: Solved) -> RunInfo:
    """The run section of a calibration re-solved from its logs: `solved_run_info` and what a plain solve adds
    (whether it is a subset, when the run started, the units left out, the damage)."""
    run_info = solved_run_info(recorded, solved.positions, solved.rotations, solved.failures, solved.lost)
    run_info.subset = solved.subset
    run_info.started_utc = recorded.logs[0].metadata.get("run", {}).get("started_utc", "")
    run_info.left_out = list(solved.left_out)
    run_info.damage = list(recorded.damage)
    return run_info


def solved_run_info(recorded: Recorded, positions: str, rotations: str, failures: list[QualityFailure],
                    lost: dict) -> RunInfo:
    """The result's run section of a re-solve of `recorded` (what a plain solve adds, the caller sets)."""
    meta, imu = recorded.run_meta, recorded.logs[-1].metadata.get("imu", {})
    return RunInfo(run_id=recorded.run_id, mode=meta.get("mode", ""), operator=meta.get("operator", ""),
                   software_version=__version__, recorded_with=meta.get("software_version", ""),
                   state=recorded.final_state, log=Path(recorded.logs[-1].path).name,
                   logs=[Path(log.path).name for log in recorded.logs], positions=positions, rotations=rotations,
                   solved_utc=utc_stamp(), solved_by="bench solve",
                   imu=ImuIdentity(imu.get("model", ""), imu.get("serial", "")),
                   site=recorded.site.to_dict(), quality_failures=failures,
                   imu_link=ImuLink.from_dict(recorded.imu_link().as_dict()), lost_samples=LostSamples.from_dict(lost),
                   notes=list(recorded.notes))


def _unused_windows(recorded: Recorded, chosen: Extraction, positions, rotations) -> set[str]:
    """The recorded dwells (with `positions` given) and turns (with `rotations`) a subset leaves out."""
    kept = set(chosen.units)
    kinds = {unit: "turn" if isinstance(finished.record, TurnRecord) else "dwell" for log in recorded.logs
             for unit, (_, finished) in finished_observation_steps(log.events).items()}
    return {unit for unit, kind in kinds.items() if unit not in kept
            and ((kind == "dwell" and positions is not None) or (kind == "turn" and rotations is not None))}


def _solve_what_can_be(chosen: Extraction, site, inputs, mounting=None, terms: tuple[str, ...] = (),
                       lever_arm_m=None):
    """Solve all of `chosen`; when that fails (too few turns or positions left by damage),
    the positions or the rotations alone, the others left out with the reason.
    Returns (calibration, the extraction solved, units left out); SolverError if neither solves."""

    def attempt(extraction):
        return solve_extraction(extraction, site, budget=inputs, mounting=mounting, terms=terms,
                                lever_arm_m=lever_arm_m)

    try:
        return attempt(chosen), chosen, []
    except SolverError as exc:
        first = exc
    kept: Sequence[PositionObservation | RotationObservation]
    dropped: Sequence[PositionObservation | RotationObservation]
    for keep_positions in (True, False):
        kept, dropped = (chosen.positions, chosen.rotations) if keep_positions else (chosen.rotations, chosen.positions)
        if not kept or not dropped:
            continue
        part = (Extraction(list(chosen.positions), [], list(chosen.problems)) if keep_positions
                else Extraction([], list(chosen.rotations), list(chosen.problems)))
        try:
            calibration = attempt(part)
        except SolverError:
            continue
        part.problems += [QualityFailure(FailureKind.LEFT_OUT, f"{o.label}: left out: {first}", o.label)
                          for o in dropped]
        return calibration, part, [o.label for o in dropped]
    raise first


__all__ = ["NONE", "Resolved", "RunSection", "Solved", "load_subset_schedule", "resolved_run_section", "select",
           "solve_recorded", "solved_run_info", "subset_name"]
