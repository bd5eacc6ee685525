"""`bench solve THERMAL_LOG`: a thermal run's log re-solved as the run solved it (CLI in `bench.cli.solve`).

Every temperature block is solved again (`bench.thermal.from_log.solve_thermal`, with the
recorded configuration's bias stabilities and budget inputs) and the thermal model refitted;
the outputs are the run's, under the stem `<run-id>.solved` (nothing the run wrote is
overwritten): `<run-id>.solved.T<k>.result.json`, `<run-id>.solved.thermal.json` (`.md`,
`.html`), and the block nearest the model's reference as `<run-id>.solved.result.json` with
its verdict and reports (`--no-html`: the Markdown reports only).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench import __version__
from bench.acceptance.quality import window_loss_failures
from bench.acceptance.verdict import Verdict
from bench.files import write_output_text
from bench.jobs.resolve import Recorded, SolveInputError
from bench.log.names import output_path
from bench.log.reader import RunLog
from bench.plan.steps import thermal_block
from bench.report.markdown import markdown_report, write_reports
from bench.report.thermal import write_thermal_files
from bench.thermal.from_log import ThermalSolution, solve_thermal
from bench.thermal.verdict import judge_thermal_head


def is_thermal_log(log: RunLog) -> bool:
    """A log of a thermal plan: its steps belong to temperature blocks ("T2-P03")."""
    return any(e.step_unit is not None and thermal_block(e.step_unit) is not None for e in log.events)


@dataclass
class ThermalResolved:
    """What `bench solve` wrote for a thermal log."""

    solution: ThermalSolution
    result_path: Path                  # the headline block's result
    report_path: Path
    html_report_path: Path | None
    results: list[Path]                # one per temperature
    model_path: Path | None            # None below two temperatures
    failures: list[str]
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
    meta, imu = recorded.run_meta, recorded.logs[-1].metadata.get("imu", {})
    names = [Path(log.path).name for log in recorded.logs]
    run_info = {"run_id": recorded.run_id, "mode": meta.get("mode", ""), "operator": meta.get("operator", ""),
                "software_version": __version__, "recorded_with": meta.get("software_version", ""),
                "state": recorded.final_state, "log": names[-1], "logs": names,
                "positions": config.plan.positions.name if config.plan.positions is not None else "",
                "rotations": config.plan.rotations.name if config.plan.rotations is not None else "",
                "solved_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "solved_by": "bench solve",
                "imu": {"model": imu.get("model", ""), "serial": imu.get("serial", "")},
                "site": recorded.site.to_dict(), "quality_failures": link_failures, "imu_link": link.as_dict(),
                "lost_samples": lost,
                "notes": list(recorded.notes)}
    # the observations `load_recorded` extracted (merged by unit, the damage of every log): not read twice
    solution = solve_thermal(recorded.logs, recorded.site, setup.layout, setup.rate_hz, config, recorded.sim,
                             run=run_info, extracted=(recorded.extraction, list(recorded.damage)))
    stem = f"{recorded.run_id}.solved"
    output_path(out, f"{stem}.thermal.json")        # a name from the log never leaves `out` (InputError)
    results, model_path = write_thermal_files(
        solution, out, stem, {"mode": run_info["mode"], "run_id": recorded.run_id, "log": names[-1],
                              "solved_by": "bench solve"}, title=f"Thermal model {stem} (re-solved from the log)",
        html=html)
    head = solution.head
    result, problems, failures, verdict = judge_thermal_head(solution, results, model_path, link_failures,
                                                             config.acceptance, lost["total"])
    result_path = out / f"{stem}.result.json"
    result.save(result_path)
    report: dict[str, Any] = dict(
        problems=problems, failures=failures, imu_link=link.as_dict(),
        title=f"Calibration report {stem} (temperature block T{head.temperature_index}, re-solved)")
    if html:
        report_path, html_path = write_reports(result, out, stem, log=recorded.logs[-1], layout=setup.layout,
                                               **report)
    else:
        report_path, html_path = out / f"{stem}.report.md", None
        write_output_text(report_path, markdown_report(result, **report))   # renamed into place
    return ThermalResolved(solution, result_path, report_path, html_path, results, model_path, failures, verdict)


__all__ = ["ThermalResolved", "resolve_thermal"]
