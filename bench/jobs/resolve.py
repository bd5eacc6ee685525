"""Re-solve recorded runs from their MCAP logs: the outputs of `bench solve` and the archive (CLI in
`bench.cli.solve`).

A re-solve finishes the recorded run as the live run did (`bench.finish.finish`, from `load_recorded`) with a
`ResolveTarget`: the outputs are named `<run-id>.solved.*` for the whole record (never the names `bench run`
wrote: nothing is overwritten) and `<run-id>.<positions>+<rotations>.*` for a subset; the result's run section says
who solved it when (`bench.finish.calibration.resolved_run_section`), and the Markdown report ends with the logs
it was solved from. Comparing methods (`--compare`) is in `bench.jobs.compare`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from bench.files import make_output_folder, write_output_text
from bench.finish.calibration import NONE, Solved, resolved_run_section, solved_run_info, subset_name
from bench.finish.finish import Reports, Target
from bench.finish.recorded import Recorded
from bench.log.names import output_path
from bench.log.run_kind import RunKind
from bench.model.result import CalibrationResult
from bench.model.run_section import RunInfo
from bench.report.markdown import markdown_report, md_text, write_reports
from drivers.imu import ImuStats


def output_stem(recorded: Recorded, positions=None, rotations=None) -> str:
    """`<run-id>.solved` for the whole record; `<run-id>.<positions>+<rotations>` for a subset (the schedules of
    `bench.finish.calibration.load_subset_schedule`; a name from a file is made a safe file name)."""
    if positions is None and rotations is None:
        return f"{recorded.run_id}.solved"
    plan = recorded.logs[-1].metadata.get("plan", {})
    names = (subset_name(positions, plan.get("positions", "")), subset_name(rotations, plan.get("rotations", "")))
    return f"{recorded.run_id}." + "+".join(re.sub(r"[^A-Za-z0-9._-]+", "-", name) or NONE for name in names)


@dataclass
class ResolveTarget(Target):
    """The outputs of a re-solve in `out_dir` (`against`: an earlier result the reports compare with)."""

    out_dir: Path
    stem: str
    html: bool = True
    against: CalibrationResult | None = None
    against_label: str | None = None
    #: the extended model's families (`bench solve --model`); None: the recorded configuration's `[model] terms`
    model_terms: tuple[str, ...] | None = None

    def run_section(self, recorded: Recorded, solved: Solved) -> RunInfo:
        if recorded.kind is RunKind.THERMAL:        # its blocks' sections say only who solved them
            return solved_run_info(recorded, solved.positions, solved.rotations, solved.failures, solved.lost)
        return resolved_run_section(recorded, solved)

    def title(self, what: str, detail: str = "") -> str:
        return f"{what} {self.stem} ({detail + ', re-solved' if detail else 're-solved from the log'})"

    def thermal_run(self, run_info: RunInfo) -> dict:
        return {"mode": run_info.mode, "run_id": run_info.run_id, "log": run_info.log, "solved_by": "bench solve"}

    def write_result(self, recorded: Recorded, result: CalibrationResult, reports: Reports,
                     also: Sequence[Path] = ()) -> tuple[Path, Path, Path | None]:
        make_output_folder(self.out_dir)
        result_path = output_path(self.out_dir, f"{self.stem}.result.json")    # a name from a log never leaves out
        result.save(result_path)
        report: dict[str, Any] = dict(problems=reports.problems, failures=reports.failures,
                                      imu_link=recorded.imu_link().as_dict(), title=reports.title)
        if recorded.kind is not RunKind.THERMAL:
            report |= dict(against=self.against, against_label=self.against_label)
        if self.html:
            md_path, html_path = write_reports(result, self.out_dir, self.stem, log=recorded.logs[-1],
                                               layout=recorded.setup.layout, **report)
        else:
            md_path, html_path = output_path(self.out_dir, f"{self.stem}.report.md"), None
            write_output_text(md_path, markdown_report(result, **report))     # renamed into place
        if recorded.kind is not RunKind.THERMAL:
            with open(md_path, "a", encoding="utf-8") as f:
                f.write("\n" + _provenance(recorded))
        return result_path, md_path, html_path

    def link_stats(self, recorded: Recorded) -> ImuStats:
        return recorded.imu_link()


def _provenance(recorded: Recorded) -> str:
    lines = ["## Logs", ""]
    for log in recorded.logs:
        lines.append(f"- {md_text(log.summary())}")
        lines += [f"  - {md_text(d)}" for d in log.scan().damage]
    if recorded.left_out:
        lines += ["", f"Units planned but not solved ({len(recorded.left_out)}): "
                  + md_text(", ".join(sorted(recorded.left_out)))]
    if recorded.notes:
        lines += ["", "Notes:"] + [f"- {md_text(n)}" for n in recorded.notes]
    return "\n".join(lines) + "\n"


__all__ = ["ResolveTarget", "output_stem"]
