"""The quality failures of a run: why a finished run's result should not be trusted as is, each a line of text
(a step left out, damage in the log, samples lost on the IMU link, residual outliers, an inconsistent budget),
and which of them fail the verdict as they are (`judged_failures`) when the configuration sets a limit instead.

The lines are told apart by their words (`LOST_SAMPLES_FAILURE`, `OUTLIERS_FAILURE`, `SAMPLES_LOST_IN_WINDOW`):
the extraction (`bench.solve.extract`) and the run write them with these constants, the functions here read them.
"""

from __future__ import annotations

import re
from typing import Iterable

from bench.acceptance.limits import AcceptanceLimits
from bench.model.result import CalibrationResult

#: the words of a dwell's or turn's line when its window lost samples (`dwell_lost_samples` finds the dwells')
SAMPLES_LOST_IN_WINDOW = "samples lost in its window"
_WINDOW_LOSS_LINE = re.compile(r"(?:^|: )(\S+) (?:dwell|turn): \d+ of \d+ " + SAMPLES_LOST_IN_WINDOW)


def dwell_lost_samples(line: str) -> bool:
    """Whether a problem line is a dwell's that lost samples but was used (a mean over the samples received)."""
    return f"{SAMPLES_LOST_IN_WINDOW}; mean over the" in line


def window_lost_samples(line: str) -> bool:
    """Whether a problem line is a dwell's or turn's whose window lost samples."""
    return SAMPLES_LOST_IN_WINDOW in line


def window_loss_unit(line: str) -> str | None:
    """The unit of a dwell's or turn's line saying its window lost samples (after any `FILE: ` prefix), else None."""
    found = _WINDOW_LOSS_LINE.search(line)
    return found.group(1) if found else None


#: how a verification's notes word samples the IMU link lost; how `quality_failures` words residual outliers
LOST_SAMPLES_FAILURE, OUTLIERS_FAILURE = "IMU link lost samples", "residual outliers beyond the outlier threshold"


def quality_failures(solution) -> list[str]:
    """Why a finished run's result should not be trusted as is (empty = passed). Samples lost on the IMU link
    fail it where they touch an observation: the line of each dwell or turn whose window lost samples (the
    extraction's); samples lost outside every window are a note of the result (`run.lost_samples`), not a failure.
    Both are told from the logs' sample counters, so `bench run` and `bench solve LOG` agree."""
    failures = list(solution.extraction.problems) + list(solution.damage)
    outliers = solution.calibration.quality().get("outliers", [])
    if outliers:
        failures.append(f"{len(outliers)} {OUTLIERS_FAILURE}")
    budget = solution.calibration.budget
    if budget is not None and budget.table_included:    # without the table's part any real table fails the test
        failures += [c.describe() for c in budget.inconsistent()]
    return failures


def window_loss_failures(problems: Iterable[str]) -> list[str]:
    """A thermal run's lines of the dwells and turns (of every temperature block) whose windows lost samples, from
    its extraction's problems."""
    return [p for p in problems if window_lost_samples(p)]


def thermal_failures(result: CalibrationResult, problems: list[str], damage: list[str],
                     link_failures: list[str]) -> list[str]:
    """A thermal run's quality failures, as its headline result records them (`run.quality_failures`): the
    block's problems, the logs' damage, the IMU link's, its residual outliers."""
    failures = problems + damage + link_failures
    outliers = result.quality.get("outliers", []) if isinstance(result.quality, dict) else []
    if outliers:
        failures.append(f"{len(outliers)} {OUTLIERS_FAILURE}")
    result.run["quality_failures"] = failures
    return failures


def judged_failures(failures: list[str], limits: AcceptanceLimits) -> list[str]:
    """The quality failures that fail the verdict as they are: lost samples and residual outliers are
    judged by `max_lost_samples` and `max_residual_sigma` instead when the configuration sets them. The limit
    counts every lost sample, in windows and outside; it takes over a dwell's lost samples (its mean is over the
    samples received), never a turn left out for them (its integral is missing from the solve)."""
    return [f for f in failures
            if not (limits.max_lost_samples is not None
                    and (f.startswith(LOST_SAMPLES_FAILURE) or dwell_lost_samples(f)))
            and not (limits.max_residual_sigma is not None and f.endswith(OUTLIERS_FAILURE))]


__all__ = ["LOST_SAMPLES_FAILURE", "OUTLIERS_FAILURE", "SAMPLES_LOST_IN_WINDOW", "dwell_lost_samples",
           "judged_failures", "quality_failures", "thermal_failures", "window_loss_failures", "window_loss_unit",
           "window_lost_samples"]
