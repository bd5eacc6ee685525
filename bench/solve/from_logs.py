"""Solve a calibration from run logs: the one path shared by `bench run` (its own log) and re-solving.

Each log is decoded on its own (IMU counters restart with every connection, so a
recorded window only means something inside its log); the observations of all logs
are merged by unit, a later log's observation of a unit replacing an earlier one
(a resumed run repeats the unit that was cut off).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TypeVar

from bench.log.reader import RunLog
from bench.model.earth import Site
from bench.model.observations import PositionObservation, RotationObservation
from bench.model.units import DEG_PER_HOUR, MICRO_G
from bench.solve.budget import BudgetInputs
from bench.solve.calibrate import Calibration, solve
from bench.solve.extended import solve_extended
from bench.solve.extract import Extraction, extract_observations
from drivers.imu.layout import ImuLayout
from drivers.imu.samples import ImuStats


@dataclass
class LogSolution:
    calibration: Calibration
    extraction: Extraction
    imu_stats: list[ImuStats] = field(default_factory=list)    # per log, from decoding its raw frames
    damage: list[str] = field(default_factory=list)             # per log damage lines, prefixed with the file


_Observation = TypeVar("_Observation", PositionObservation, RotationObservation)


def _merge(merged: dict[str, _Observation], observed: list[_Observation], log_path: str, source: dict[str, str],
           replaced: list[tuple[str, str, str]]) -> None:
    """Add one log's observations by unit, a later log's replacing an earlier's (noted in `replaced`)."""
    for o in observed:
        if o.label in merged:
            replaced.append((o.label, source[o.label], log_path))
        merged[o.label] = o
        source[o.label] = log_path


def extract_from_logs(logs: list[RunLog], site: Site, layout: ImuLayout, rate_hz: float, mounting=None,
                      still_open: frozenset[str] = frozenset()) -> tuple[Extraction, list[ImuStats], list[str]]:
    """Observations of all logs merged by unit, the IMU link statistics and the damage of each log.

    The samples each log's decode lost (`ImuStats.lost_samples`) are told apart by where they fell:
    inside the counter window of a dwell or turn (`Extraction.lost_in_windows`) or outside every one
    (`Extraction.lost_outside`). `bench run` and `bench solve` both count them here, from the logs.

    A log in `still_open` (the live run reading its own log before closing it, or an interrupted run's log it
    resumes) has no summary yet by design, and a resumed one may end inside a record, as a full disk or a crash
    leaves it: neither is reported as damage (the cut-off tail holds only what came after the last message that
    reached the disk; a unit not finished there is run again).
    """
    merged_positions: dict[str, PositionObservation] = {}
    merged_rotations: dict[str, RotationObservation] = {}
    problems = []
    source: dict[str, str] = {}     # unit -> the log its kept observation came from
    replaced: list[tuple[str, str, str]] = []
    stats, damage = [], []
    lost_in_windows: dict[str, int] = {}
    lost_outside = 0
    for log in logs:
        samples, link = log.imu_samples(layout, rate_hz)
        stats.append(link)
        damage += [f"{log.path}: {d.describe()}" for d in log.scan().lost
                   if not (d.kind in ("no_summary", "truncated") and log.path in still_open)]
        states = log.read_table_states()
        part = extract_observations(log.events, samples.counter, samples.gyro_counts, samples.acc_counts, rate_hz,
                                    site, states.time_s, states.angles_deg, mounting, samples.status,
                                    layout.status_invalid, layout.status_required, layout.output_step)
        _merge(merged_positions, part.positions, str(log.path), source, replaced)
        _merge(merged_rotations, part.rotations, str(log.path), source, replaced)
        problems += [p.prefixed(str(log.path)) for p in part.problems]
        for unit, n in part.lost_in_windows.items():
            lost_in_windows[unit] = lost_in_windows.get(unit, 0) + n
        # the link's count (every sample the decode lost) less those inside a window: the ones outside every window
        lost_outside += max(0, link.lost_samples - sum(part.lost_in_windows.values()))
    extraction = Extraction([merged_positions[k] for k in sorted(merged_positions)],
                            [merged_rotations[k] for k in sorted(merged_rotations)], problems,
                            lost_in_windows, lost_outside, replaced)
    return extraction, stats, damage


def solve_logs(logs: list[RunLog], site: Site, layout: ImuLayout, rate_hz: float, *, mounting=None,
               gyro_bias_stability_dph: float | None = None, acc_bias_stability_ug: float | None = None,
               budget: BudgetInputs | None = None, still_open: frozenset[str] = frozenset()) -> LogSolution:
    """Extract every log's observations, merge them and solve (SolverError if there is nothing to solve)."""
    extraction, stats, damage = extract_from_logs(logs, site, layout, rate_hz, mounting, still_open)
    calibration = solve_extraction(extraction, site, mounting=mounting, gyro_bias_stability_dph=gyro_bias_stability_dph,
                                   acc_bias_stability_ug=acc_bias_stability_ug, budget=budget)
    return LogSolution(calibration, extraction, stats, damage)


def solve_extraction(extraction: Extraction, site: Site, *, mounting=None, gyro_bias_stability_dph: float | None = None,
                     acc_bias_stability_ug: float | None = None, budget: BudgetInputs | None = None,
                     terms: tuple[str, ...] = (), lever_arm_m=None) -> Calibration:
    """Solve merged observations (all of a log's or a subset); SolverError if there is nothing to solve.

    `budget` (what is known beyond the data) replaces the two bias stabilities when given. `terms`: the extended
    model's families (`bench.solve.extended`; ("auto",): the data choose), none: the 30 coefficients. `lever_arm_m`:
    the unit's known place from the rotation centre (body axes, m), taken out of the turns by the extended model's
    lever-arm fit (the 30 coefficients use no accelerometer output from a turn)."""
    if terms:
        return solve_extended(extraction.positions, extraction.rotations, site, terms, mounting,
                              lever_arm_m=lever_arm_m, budget_inputs=budget or BudgetInputs(
                                  gyro_bias_instability=(gyro_bias_stability_dph or 0.0) * DEG_PER_HOUR,
                                  acc_bias_instability=(acc_bias_stability_ug or 0.0) * MICRO_G))
    return solve(extraction.positions, extraction.rotations, site, mounting,
                 gyro_bias_stability=(gyro_bias_stability_dph or 0.0) * DEG_PER_HOUR,
                 acc_bias_stability=(acc_bias_stability_ug or 0.0) * MICRO_G, budget_inputs=budget)
