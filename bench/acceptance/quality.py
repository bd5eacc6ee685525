"""The quality failures of a run: why a finished run's result should not be trusted as is, each a
`QualityFailure` (`bench.model.quality`: a step left out, damage in the log, samples lost on the IMU link, residual
outliers, an inconsistent budget), and which of them fail the verdict as they are (`judged_failures`) when the
configuration sets a limit instead. They are told apart by their kind, never by their words.
"""

from __future__ import annotations

from typing import Iterable

from bench.acceptance.limits import AcceptanceLimits
from bench.model.quality import FailureKind, QualityFailure, damage, outliers
from bench.model.result import CalibrationResult

#: the kinds `max_lost_samples` judges instead when set: the link's lost samples and a dwell's (never a turn left
#: out for them: its integral is missing from the solve)
_LOST_SAMPLES = frozenset({FailureKind.LINK_LOST_SAMPLES, FailureKind.DWELL_LOST_SAMPLES})


def quality_failures(solution) -> list[QualityFailure]:
    """Why a finished run's result should not be trusted as is (empty = passed). Samples lost on the IMU link
    fail it where they touch an observation: the line of each dwell or turn whose window lost samples (the
    extraction's); samples lost outside every window are a note of the result (`run.lost_samples`), not a failure.
    Both are told from the logs' sample counters, so `bench run` and `bench solve LOG` agree."""
    failures = list(solution.extraction.problems) + damage(solution.damage)
    found = solution.calibration.quality().outliers or []
    if found:
        failures.append(outliers(len(found)))
    budget = solution.calibration.budget
    if budget is not None and budget.table_included:    # without the table's part any real table fails the test
        failures += [QualityFailure(FailureKind.BUDGET, c.describe()) for c in budget.inconsistent()]
    return failures


def window_loss_failures(problems: Iterable[QualityFailure]) -> list[QualityFailure]:
    """A thermal run's failures of the dwells and turns (of every temperature block) whose windows lost samples,
    from its extraction's problems."""
    return [p for p in problems if p.window_loss]


def thermal_failures(result: CalibrationResult, problems: list[QualityFailure], damage_lines: list[str],
                     link_failures: list[QualityFailure]) -> list[QualityFailure]:
    """A thermal run's quality failures, as its headline result records them (`run.quality_failures`): the
    block's problems, the logs' damage, the IMU link's, its residual outliers."""
    failures = problems + damage(damage_lines) + link_failures
    found = result.quality.outliers or []
    if found:
        failures.append(outliers(len(found)))
    result.run.quality_failures = list(failures)
    return failures


def judged_failures(failures: Iterable[QualityFailure], limits: AcceptanceLimits) -> list[QualityFailure]:
    """The quality failures that fail the verdict as they are: lost samples and residual outliers are
    judged by `max_lost_samples` and `max_residual_sigma` instead when the configuration sets them. The limit
    counts every lost sample, in windows and outside; it takes over a dwell's lost samples (its mean is over the
    samples received), never a turn left out for them (its integral is missing from the solve)."""
    return [f for f in failures
            if not (limits.max_lost_samples is not None and f.kind in _LOST_SAMPLES)
            and not (limits.max_residual_sigma is not None and f.kind is FailureKind.OUTLIERS)]


__all__ = ["judged_failures", "quality_failures", "thermal_failures", "window_loss_failures"]
