"""`bench solve THERMAL_LOG`: a thermal run's log re-solved as the run solved it (CLI in `bench.cli.solve`).

Every temperature block is solved again (`bench.thermal.from_log.solve_thermal`, with the
recorded configuration's bias stabilities and budget inputs) and the thermal model refitted;
the outputs are the run's, under the stem `<run-id>.solved` (nothing the run wrote is
overwritten): `<run-id>.solved.T<k>.result.json`, `<run-id>.solved.thermal.json` (`.md`,
`.html`), and the block nearest the model's reference as `<run-id>.solved.result.json` with
its verdict and reports (`--no-html`: the Markdown reports only).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.acceptance.quality import window_loss_failures
from bench.acceptance.verdict import Verdict
from bench.files import write_output_text
from bench.jobs.resolve import Recorded, SolveInputError, solved_run_info
from bench.log.names import output_path
from bench.model.quality import QualityFailure, texts
from bench.report.markdown import markdown_report, write_reports
from bench.report.thermal import write_thermal_files
from bench.thermal.from_log import ThermalSolution, solve_thermal
from bench.thermal.verdict import judge_thermal_head


@dataclass
class ThermalResolved:
    """What `bench solve` wrote for a thermal log."""

    solution: ThermalSolution
    result_path: Path                  # the headline block's result
    report_path: Path
    html_report_path: Path | None
    results: list[Path]                # one per temperature
    model_path: Path | None            # None below two temperatures
    failures: list[QualityFailure]
    verdict: Verdict


def resolve_thermal(recorded: Recorded, out_dir: str | Path, *, html: bool = True) -> ThermalResolved:
    """Solve every temperature of `recorded` again, refit the model and write the outputs (SolverError: nothing
    to solve; SolveInputError: the log's configuration cannot be rebuilt)."""
    setup, config = recorded.setup, recorded.setup.config
    if config is None:
        raise SolveInputError(f"{recorded.logs[-1].path}: its configuration cannot be rebuilt "
                              f"({'; '.join(setup.notes)}): a thermal log is solved with it")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    link = recorded.imu_link()
    link_failures = window_loss_failures(recorded.extraction.problems)
    lost = recorded.extraction.lost_samples()
    positions, rotations = config.plan.positions, config.plan.rotations
    run_info = solved_run_info(recorded, positions.name if positions is not None else "",
                               rotations.name if rotations is not None else "", link_failures, lost)
    # the observations `load_recorded` extracted (merged by unit, the damage of every log): not read twice
    solution = solve_thermal(recorded.logs, recorded.site, setup.layout, setup.rate_hz, config, recorded.sim,
                             run=run_info, extracted=(recorded.extraction, list(recorded.damage)))
    stem = f"{recorded.run_id}.solved"
    output_path(out, f"{stem}.thermal.json")        # a name from the log never leaves `out` (InputError)
    results, model_path = write_thermal_files(
        solution, out, stem, {"mode": run_info.mode, "run_id": recorded.run_id, "log": run_info.log,
                              "solved_by": "bench solve"}, title=f"Thermal model {stem} (re-solved from the log)",
        html=html)
    head = solution.head
    result, problems, failures, verdict = judge_thermal_head(solution, results, model_path, link_failures,
                                                             config.acceptance, lost["total"])
    result_path = out / f"{stem}.result.json"
    result.save(result_path)
    report: dict[str, Any] = dict(
        problems=problems, failures=texts(failures), imu_link=link.as_dict(),
        title=f"Calibration report {stem} (temperature block T{head.temperature_index}, re-solved)")
    if html:
        report_path, html_path = write_reports(result, out, stem, log=recorded.logs[-1], layout=setup.layout,
                                               **report)
    else:
        report_path, html_path = out / f"{stem}.report.md", None
        write_output_text(report_path, markdown_report(result, **report))   # renamed into place
    return ThermalResolved(solution, result_path, report_path, html_path, results, model_path, failures, verdict)


__all__ = ["ThermalResolved", "resolve_thermal"]
