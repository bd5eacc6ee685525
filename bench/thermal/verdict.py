"""The verdict of a thermal run: its headline result (the temperature block nearest the model's reference
temperature) judged with the run's quality failures (`bench.acceptance.quality`)."""

from __future__ import annotations

from pathlib import Path

from bench.acceptance.limits import AcceptanceLimits
from bench.acceptance.quality import judged_failures, thermal_failures
from bench.acceptance.verdict import Verdict, judge
from bench.model.quality import QualityFailure, texts
from bench.model.result import CalibrationResult
from bench.thermal.from_log import ThermalSolution


def judge_thermal_head(solution: ThermalSolution, results: list[Path], model_path: Path | None,
                       link_failures: list[QualityFailure], limits: AcceptanceLimits,
                       lost_samples: int) -> tuple[CalibrationResult, list[str], list[QualityFailure], Verdict]:
    """A thermal run's headline result (the block nearest the model's reference temperature) with its quality
    failures, the names of the files written and its verdict: (result, problems, failures, verdict)."""
    head = solution.head
    result = head.point.result
    problems = list(head.extraction.problems)
    failures = thermal_failures(result, problems, solution.damage, [f for f in link_failures if f not in problems])
    result.run.extra["thermal"] = {"model": model_path.name if model_path is not None else None,
                             "results": [p.name for p in results], "this_block": head.temperature_index}
    verdict = judge(result, limits, lost_samples=lost_samples,
                    quality_failures=texts(judged_failures(failures, limits)))
    result.verdict = verdict.to_section()
    return result, texts(problems), failures, verdict


__all__ = ["judge_thermal_head"]
