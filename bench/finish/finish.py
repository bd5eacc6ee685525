"""One way to finish a recorded run: `finish(recorded, target) -> Finished`, dispatched on the run's kind.

The live run (`bench.run.runner.BenchRun.finish`, for `bench run` and the TUI), `bench solve` and the archive
(`bench.jobs`) all finish a run here, from its logs: a calibration (and a verification's or a table check's log,
solved as a calibration) is solved and judged (`bench.finish.calibration`), a thermal run gets one calibration
per temperature and its thermal model, a static noise recording its noise terms. What differs between a live
run and a re-solve is the `Target`'s: where the outputs go and under which names, what the result's run section
says, and how a file is kept (the live run attaches every output to its log, still open, and renames the result
into place only once all of it is written).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

from bench.acceptance.quality import window_loss_failures
from bench.acceptance.verdict import Verdict
from bench.finish.calibration import Resolved, RunSection, Solved, solve_recorded
from bench.finish.recorded import Recorded, SolveInputError, static_noise_plan
from bench.log.run_kind import RunKind
from bench.model.quality import texts
from bench.model.result import CalibrationResult
from bench.model.run_section import RunInfo
from bench.noise.from_log import NoiseInputError, analyse_log
from bench.thermal.from_log import ThermalSolution, solve_thermal
from bench.thermal.model import ThermalModel
from bench.thermal.verdict import judge_thermal_head
from drivers.imu import ImuStats


@dataclass
class Reports:
    """What a result's reports show besides the result (`bench.report.markdown.write_reports`)."""

    title: str
    problems: list[str]
    failures: list[str]


@dataclass
class Finished:
    """What finishing a recorded run wrote and found (paths None: not written)."""

    kind: RunKind
    result_path: Path | None = None
    report_path: Path | None = None
    html_report_path: Path | None = None
    result: CalibrationResult | None = None
    failures: list[str] = field(default_factory=list)
    verdict: Verdict | None = None        # the acceptance verdict of the result (None: no result)
    problems: list[str] = field(default_factory=list)   # steps left out or degraded (the extraction's lines)
    #: a calibration's solve (its observations, subset names)
    resolved: Resolved | None = None
    #: a thermal run's solve, its per-temperature results and its thermal model file and model (None: fewer than
    #: two temperatures)
    thermal: ThermalSolution | None = None
    thermal_results: list[Path] = field(default_factory=list)
    thermal_model_path: Path | None = None
    thermal_model: ThermalModel | None = None

    @property
    def thermal_paths(self) -> list[Path]:
        """A thermal run's files besides its own result: the per-temperature results, then the model's."""
        return self.thermal_results + ([self.thermal_model_path] if self.thermal_model_path is not None else [])


class Target(ABC):
    """Where a finished run's outputs go, under which names, and what its result's run section says."""

    out_dir: Path
    stem: str                  # the outputs' file name stem
    html: bool = True          # HTML reports too (else the Markdown report only)
    live: bool = False         # the run that recorded the logs finishes them (its log still open)
    #: the extended model's families for the solve (`bench solve --model`); None: the recorded `[model] terms`
    model_terms: tuple[str, ...] | None = None

    @abstractmethod
    def run_section(self, recorded: Recorded, solved: Solved) -> RunInfo:
        """The result's run section."""

    @abstractmethod
    def title(self, what: str, detail: str = "") -> str:
        """A report's title: `what` ("Calibration report", "Thermal model") of this target, with `detail`."""

    @abstractmethod
    def thermal_run(self, run_info: RunInfo) -> dict:
        """The `run` entry of a thermal model file written for this target."""

    @abstractmethod
    def write_result(self, recorded: Recorded, result: CalibrationResult, reports: Reports,
                     also: Sequence[Path] = ()) -> tuple[Path, Path, Path | None]:
        """Write `<stem>.result.json` and its reports (`also`: files written before it that go with it).
        Returns (result, Markdown report, HTML report or None)."""

    @abstractmethod
    def link_stats(self, recorded: Recorded) -> ImuStats:
        """The IMU link statistics of the run (live: the receiver's; re-solved: decoded from the logs)."""

    def noise_failures(self, recorded: Recorded) -> list[str]:
        """The quality lines a noise analysis reports besides its own damage lines."""
        stats = self.link_stats(recorded)
        return [f"IMU link lost samples: {stats.summary()}"] if stats.lost_samples else []

    def keep(self, path: Path) -> None:  # noqa: B027 - a re-solve keeps nothing more; the live run attaches it
        """A file written for this target that is not a result (the live run attaches it to its log)."""


def finish(recorded: Recorded, target: Target, *, positions=None, rotations=None) -> Finished:
    """Finish `recorded` as its kind finishes (SolverError: nothing to solve; SolveInputError: what the logs
    cannot give; OSError: an output cannot be written). `positions`, `rotations`: the subset of a calibration
    to solve (`bench.finish.calibration.select`)."""
    kind = recorded.kind
    if not target.live and kind is RunKind.STATIC_NOISE:
        # `bench noise LOG` analyses it: it has the options (`--calibration`) a hardware log's noise needs
        static = static_noise_plan(recorded)
        raise SolveInputError(f"{recorded.logs[-1].path} is a static noise recording (plan positions {static!r}: one "
                              f"dwell, nothing to calibrate): analyse it with `bench noise {recorded.logs[-1].path}`")
    if FINISHERS[kind] is finish_calibration:
        return finish_calibration(recorded, target, positions, rotations)
    if positions is not None or rotations is not None:
        raise SolveInputError(f"{recorded.logs[-1].path} records a {kind.value} run: it is finished whole (no "
                              "--positions or --rotations)")
    return FINISHERS[kind](recorded, target)


def finish_calibration(recorded: Recorded, target: Target, positions=None, rotations=None) -> Finished:
    """Solve all of `recorded` (or the subset the schedules choose), judge it, write its result and reports."""
    resolved = solve_recorded(recorded, positions, rotations, run_section=target.run_section,
                              terms=target.model_terms)
    problems = texts(resolved.solution.extraction.problems)
    result_path, report_path, html_path = target.write_result(
        recorded, resolved.result, Reports(target.title("Calibration report"), problems, texts(resolved.failures)))
    return Finished(recorded.kind, result_path, report_path, html_path, resolved.result, texts(resolved.failures),
                    resolved.verdict, problems, resolved=resolved)


def finish_thermal(recorded: Recorded, target: Target) -> Finished:
    """A thermal run: one calibration per temperature (`<stem>.T<k>.result.json`), the thermal model
    (`<stem>.thermal.json/.md/.html`), and as the run's own result (verdict, reports) the calibration nearest
    the model's reference temperature (`bench.thermal.from_log.solve_thermal`)."""
    setup, config = recorded.setup, recorded.setup.config
    if config is None:
        raise SolveInputError(f"{recorded.logs[-1].path}: its configuration cannot be rebuilt "
                              f"({'; '.join(setup.notes)}): a thermal log is solved with it")
    link_failures = window_loss_failures(recorded.extraction.problems)
    lost = recorded.extraction.lost_samples()
    positions, rotations = config.plan.positions, config.plan.rotations
    run_info = target.run_section(recorded, Solved(positions.name if positions is not None else "",
                                                   rotations.name if rotations is not None else "",
                                                   link_failures, lost))
    # the observations `recorded` holds (merged by unit, the damage of every log): not read twice
    solution = solve_thermal(recorded.logs, recorded.site, setup.layout, setup.rate_hz, config, recorded.sim,
                             run=run_info, extracted=(recorded.extraction, list(recorded.damage)))
    target.out_dir.mkdir(parents=True, exist_ok=True)
    from bench.report.thermal import write_thermal_files  # matplotlib: only for a thermal run's files

    results, model_path = write_thermal_files(solution, target.out_dir, target.stem, target.thermal_run(run_info),
                                              title=target.title("Thermal model"), html=target.html)
    written = results + ([model_path] if model_path is not None else [])
    head = solution.head
    result, problems, failures, verdict = judge_thermal_head(solution, results, model_path, link_failures,
                                                             config.acceptance, lost["total"])
    result_path, report_path, html_path = target.write_result(
        recorded, result,
        Reports(target.title("Calibration report", f"temperature block T{head.temperature_index}"), problems,
                texts(failures)), also=written)
    return Finished(recorded.kind, result_path, report_path, html_path, result, texts(failures), verdict, problems,
                    thermal=solution, thermal_results=results, thermal_model_path=model_path,
                    thermal_model=solution.model)


def finish_noise(recorded: Recorded, target: Target) -> Finished:
    """The Allan deviation and noise terms of the dwell recorded: `<stem>.noise.json/.md/.html`.

    On the simulator the outputs become deg/h and ug with the simulated IMU's true scales; a
    hardware log needs a calibration's (`bench noise LOG --calibration RESULT.json`)."""
    log_path = recorded.logs[-1].path
    failures = target.noise_failures(recorded)
    try:
        result, _ = analyse_log(log_path, still_open=target.live)
    except NoiseInputError as exc:
        failures.append(f"noise not analysed: {exc}; analyse the log with `bench noise {log_path} "
                        "--calibration RESULT.json`")
        return Finished(recorded.kind, failures=failures)
    result.source["operator"] = recorded.run_meta.get("operator", "")
    from bench.report.noise import write_noise_outputs  # matplotlib: only for a noise recording's files

    json_path, md_path, html_path = write_noise_outputs(result, target.out_dir, target.stem)
    target.keep(json_path)
    return Finished(recorded.kind, json_path, md_path, html_path, None, failures + list(result.source["damage"]))


#: How a run of each kind finishes. A verification's and a table check's commands read their logs themselves
#: (`bench.run.runner.BenchRun.finish_observations`, `bench.table_check`); finished here such a run is solved as
#: a calibration, as `bench solve` solves its log. A log of manual moves is no run (`load_recorded` refuses it).
FINISHERS: dict[RunKind, Callable[[Recorded, Target], Finished]] = {
    RunKind.CALIBRATION: finish_calibration,
    RunKind.THERMAL: finish_thermal,
    RunKind.STATIC_NOISE: finish_noise,
    RunKind.VERIFICATION: finish_calibration,
    RunKind.TABLE_CHECK: finish_calibration,
}


__all__ = ["FINISHERS", "Finished", "Reports", "RunSection", "Target", "finish", "finish_calibration",
           "finish_noise", "finish_thermal"]
