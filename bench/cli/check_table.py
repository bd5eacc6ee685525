"""`bench check-table`: measure the turntable's pointing error (paper section 5.1).

Runs a table-check schedule (default `table-check-324`: middle 0, 18 outer x 18 inner
positions; positions only) on the hardware of `--config` or on the simulator, records
it to MCAP like `bench run`, then estimates the observable combinations of the nine
black-box angles from the horizontal accelerometers (`bench.table_check.estimate`) and writes
`<run-id>.table-check.json`, `.md`, `.html` and two SVG figures. `--log` analyses a
recorded check without hardware.

Exit codes: 0 done; 5 simulator only: the estimate misses the simulated truth by more
than 3 sigma; 2 usage or configuration error, a log that cannot be read or is not a
table check, or the table/IMU cannot be reached (nothing moved); 3 hardware fault or
aborted (the table is stopped, the log kept); 4 the run finished but the check cannot
be computed from it or a quality check failed (samples lost, log damaged).
"""

from __future__ import annotations

import argparse
import dataclasses
import re
from pathlib import Path

from bench.cli.common import ExitCode, ended_early, fail, raise_interrupted, run_plan, stop_signals
from bench.cli.db import add_db_options, not_recorded_exit, record_outputs
from bench.errors import BenchError, InputError
from bench.model.imu import ImuCoefficients
from bench.model.result import CalibrationResult
from bench.model.units import format_hms
from bench.plan.compiler import PlanError
from schedules import ScheduleError, resolve_schedule

PROG = "bench check-table"
DEFAULT_SCHEDULE = "table-check-324"
DEFAULT_DWELL_S = 10.0


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "check-table",
        description="Run the table-check schedule (middle 0, outer x inner positions) and estimate, from the "
                    "horizontal accelerometers, the observable combinations of the table's nine black-box "
                    "angles (outer-axis tilt = levelness; inner-axis tilt at middle 0) with 1-sigma "
                    "uncertainties. Exit codes: 0 done, 5 simulated truth missed by > 3 sigma, 2 usage/"
                    "configuration error or unusable log (nothing moved), 3 hardware fault or aborted (table "
                    "stopped), 4 finished but the check cannot be computed or a quality check failed.")
    source = parser.add_argument_group("what to check (one of)")
    source.add_argument("--sim", action="store_true",
                        help="on the simulator: the built-in simulated bench, or --config's table/IMU and [sim]")
    source.add_argument("--config", metavar="FILE", help="bench configuration of the hardware (or of the simulator)")
    source.add_argument("--log", metavar="LOG.mcap", help="analyse a recorded table check; nothing moves")
    parser.add_argument("--schedule", metavar="NAME|FILE", default=DEFAULT_SCHEDULE,
                        help=f"a 'table-check' schedule (default {DEFAULT_SCHEDULE})")
    parser.add_argument("--dwell-s", type=float, default=DEFAULT_DWELL_S,
                        help=f"dwell per position, s (default {DEFAULT_DWELL_S:g})")
    parser.add_argument("--black-box-arcsec", type=float, metavar="RMS",
                        help="built-in simulator: draw the nine black-box angles with this RMS (default 20)")
    parser.add_argument("--seed", type=int, help="built-in simulator: seed of the black box and the noise (default 0)")
    parser.add_argument("--calibration", metavar="RESULT.json",
                        help="convert the accelerometers with this calibration's Ka, K0, Ea (default: x and y "
                             "take the z accelerometer's measured scale)")
    parser.add_argument("--out", metavar="DIR",
                        help="output folder (default: the config's [output] folder; with --log next to the log)")
    parser.add_argument("--operator", default="", help="who runs it (recorded in the log)")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    add_db_options(parser)
    parser.set_defaults(func=cmd_check_table)


class UsageError(BenchError):
    """A command-line or configuration problem (exit 2)."""


def _load_calibration(path: str | None):
    """The accelerometer model of a result file (gyro part ideal: unused here), or None."""
    if path is None:
        return None
    try:
        values = CalibrationResult.load(path).values()
    except OSError as exc:
        raise UsageError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    except InputError as exc:   # not a result, not a regular file, too large
        raise UsageError(str(exc)) from exc
    ideal = ImuCoefficients.ideal().to_canonical()
    needed = [n for n in ideal if n.split("_")[0] in ("Ka", "K0", "Ea")]
    missing = [n for n in needed if n not in values]
    if missing:
        raise UsageError(f"{path}: the result lacks the accelerometer coefficients {', '.join(missing)}")
    return ImuCoefficients.from_canonical({**ideal, **{n: values[n] for n in needed}})


def _sim_config_text(black_box_arcsec: float | None, seed: int | None) -> str:
    """The built-in simulator configuration with the black box and seed asked for (recorded in the log)."""
    # heavy (scipy, python-can): imported when the command runs, not for its --help
    from bench.config.load import SIM_CONFIG_TOML

    text = SIM_CONFIG_TOML
    for key, value in (("black_box_arcsec", black_box_arcsec), ("seed", seed)):
        if value is None:
            continue
        text, n = re.subn(rf"^{key} = .*$", f"{key} = {value!r}", text, count=1, flags=re.M)
        if n != 1:
            raise UsageError(f"internal: the built-in simulator configuration has no {key} line")
    return text


def build_config(args: argparse.Namespace):
    """(config, sim) for a live or simulated check; UsageError on bad arguments or configuration."""
    # heavy (scipy, python-can): imported when the command runs, not for its --help
    from bench.config.load import ConfigError, load_config, parse_config

    if args.black_box_arcsec is not None or args.seed is not None:
        if args.config:
            raise UsageError("--black-box-arcsec/--seed set the built-in simulator; with --config set "
                             "[sim] black_box_arcsec and seed in the file")
        if not args.sim:
            raise UsageError("--black-box-arcsec/--seed need --sim")
        if args.black_box_arcsec is not None and not args.black_box_arcsec >= 0:
            raise UsageError(f"--black-box-arcsec must be >= 0, got {args.black_box_arcsec:g}")
        if args.seed is not None and args.seed < 0:
            raise UsageError(f"--seed must be >= 0, got {args.seed}")
    try:
        if args.config:
            config = load_config(args.config)
        else:
            config = parse_config(_sim_config_text(args.black_box_arcsec, args.seed), source="<builtin sim config>")
    except (ConfigError, OSError) as exc:
        raise UsageError(str(exc)) from exc
    return config, bool(args.sim or config.table.is_sim)


def table_check_plan(config, schedule_spec: str, dwell_s: float):
    """(config with the table-check schedule as its plan, compiled plan); UsageError when it cannot run."""
    # heavy (scipy, python-can, mcap, matplotlib): imported when the command runs, not for its --help
    from bench.run.runner import compile_from_config
    from bench.table_check.estimate import TableCheckError, check_positions

    if not dwell_s > 0:
        raise UsageError(f"--dwell-s must be positive, got {dwell_s:g}")
    try:
        schedule = resolve_schedule(schedule_spec)
    except ScheduleError as exc:
        raise UsageError(str(exc)) from exc
    if schedule.kind != "table-check":
        raise UsageError(f"schedule {schedule.name!r} is a {schedule.kind!r} schedule; --schedule needs a "
                         "'table-check' schedule (e.g. table-check-324)")

    try:
        check_positions([p.angles_deg for p in schedule.positions])
    except TableCheckError as exc:
        raise UsageError(f"schedule {schedule.name!r}: {exc}") from exc
    plan_config = dataclasses.replace(config.plan, positions=schedule, rotations=None, dwell_s=float(dwell_s))
    config = dataclasses.replace(config, plan=plan_config)
    try:
        return config, compile_from_config(config)
    except PlanError as exc:
        raise UsageError(str(exc)) from exc


def cmd_check_table(args: argparse.Namespace) -> ExitCode:
    chosen = [name for name, on in (("--log", args.log), ("--sim", args.sim), ("--config", args.config)) if on]
    if not chosen:
        return fail(PROG, "say --config FILE, --sim or --log LOG.mcap", ExitCode.USAGE)
    if args.log and len(chosen) > 1:
        return fail(PROG, f"--log analyses a recorded check: drop {' and '.join(c for c in chosen if c != '--log')}",
                     ExitCode.USAGE)
    try:
        calibration = _load_calibration(args.calibration)
        if args.log:
            return _from_log(args, calibration)
        config, sim = build_config(args)
        config, plan = table_check_plan(config, args.schedule, args.dwell_s)
    except UsageError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    return _live(args, config, plan, sim, calibration)


def _from_log(args, calibration) -> ExitCode:
    # heavy (scipy, python-can, mcap): imported when the command runs, not for its --help
    from bench.log.reader import LogError
    from bench.table_check.estimate import TableCheckError
    from bench.table_check.from_log import analyse_log

    if args.black_box_arcsec is not None or args.seed is not None:
        return fail(PROG, "--black-box-arcsec/--seed are for a simulated run, not for --log", ExitCode.USAGE)
    try:
        analysis = analyse_log(args.log, calibration=calibration)
    except (LogError, TableCheckError, OSError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    out_dir = Path(args.out) if args.out else Path(args.log).resolve().parent
    return _report(args, analysis, out_dir)


def _live(args, config, plan, sim: bool, calibration) -> ExitCode:
    # heavy (scipy, python-can, mcap, matplotlib): imported when the command runs, not for its --help
    from bench.log.reader import LogError
    from bench.log.recorder import RecorderError
    from bench.run.devices import device_opener
    from bench.run.runner import BenchRun
    from bench.run.timing import estimates
    from bench.table_check.estimate import TableCheckError
    from bench.table_check.from_log import analyse_log
    from bench.table_check.report import write_outputs

    out_dir = Path(args.out) if args.out else Path(config.output.folder)
    if not args.quiet:
        print(f"table check: {config.plan.positions.name}, {len(config.plan.positions.positions)} positions, dwell "
              f"{config.plan.dwell_s:g} s, about {format_hms(sum(estimates(config, plan.steps, sim)))} of table time"
              + (" (simulated)" if sim else ""))
    # A stop signal (Ctrl-C, SIGTERM, SIGHUP) aborts the plan while it runs (run_plan); after it, it ends
    # the analysis (an Interrupted): either way the devices and the log are closed.
    with stop_signals(raise_interrupted), BenchRun(config, plan, devices=device_opener(sim), out_dir=out_dir,
                                                   operator=args.operator) as run:
        try:     # a signal after the plan's last check is raised here: the run ends as interrupted
            failed = run_plan(run, PROG, quiet=args.quiet, simulated=sim)
        except KeyboardInterrupt as exc:
            return fail(PROG, f"interrupted ({exc or 'Ctrl-C'}) after the plan; the table is at rest. "
                              f"Log: {run.log_path} (bench check-table --log {run.log_path} analyses it)",
                        ExitCode.FAULT)
        if failed is not None:
            return failed
        seq, recorder = run.sequencer, run.recorder
        assert seq is not None and recorder is not None   # run_plan returned None: the run opened and ran
        try:
            if seq.error is not None:
                recorder.close()
                return ended_early(PROG, f"{seq.state.value}: {seq.error}", seq, f". Log: {run.log_path}")
            # Not BenchRun.finish(): that solves a calibration. The check reads the log it just wrote.
            recorder.flush()
            try:
                analysis = analyse_log(run.log_path, calibration=calibration, still_open=True)
            except (LogError, TableCheckError) as exc:
                recorder.close()
                return fail(PROG, f"the run finished but the check cannot be computed: {exc}. Log: {run.log_path}",
                             ExitCode.QUALITY)
            paths = write_outputs(analysis, out_dir)
            recorder.add_attachment(paths["json"].name, "application/json", paths["json"].read_bytes(),
                                    run.clock.now() if run.clock is not None else 0.0)
            recorder.close()
        except KeyboardInterrupt as exc:        # a stop signal after the plan ended: the table is at rest
            return fail(PROG, f"interrupted ({exc or 'Ctrl-C'}) while analysing; the table is at rest. "
                              f"Log: {run.log_path} (bench check-table --log {run.log_path} analyses it)",
                        ExitCode.FAULT)
        except RecorderError as exc:            # the log's last records could not be written
            return fail(PROG, f"{exc}; table stopped. Log: {run.log_path}", ExitCode.FAULT)
        except OSError as exc:                  # the check's outputs could not be written
            return fail(PROG, f"the run finished but the check cannot be written: {exc.strerror or exc} "
                              f"({exc.filename}). Log: {run.log_path}", ExitCode.FAULT)
    return _report(args, analysis, out_dir, paths)


def format_summary(analysis) -> str:
    """The result as printed: one line per combination (with the truth on the simulator), then the fit."""
    # heavy (scipy, python-can, mcap, matplotlib): imported when the command runs, not for its --help
    from bench.table_check.report import summary_rows

    est = analysis.estimate
    sim = analysis.black_box_rad is not None
    head = f"{'combination':<12} {'angles':<20} {'estimate':>10} {'1-sigma':>8}"
    if sim:
        head += f" {'truth':>10} {'z':>6}  3-sigma"
    lines = [f"table check {analysis.run_id}: {len(analysis.labels)} positions; arcsec", head]
    for row in summary_rows(analysis):
        line = f"{row[0]:<12} {row[1]:<20} {row[2]:>10} {row[3]:>8}"
        if sim:
            line += f" {row[4]:>10} {row[5]:>6}  {'ok' if row[6] == 'yes' else 'MISS'}"
        lines.append(line)
    lines.append(f"residual RMS {est.residual_rms_g * 1e6:.3f} ug, reduced chi-square {est.reduced_chi2:.2f}; "
                 f"offsets x {est.offsets_g[0] * 1e6:.2f} ug, y {est.offsets_g[1] * 1e6:.2f} ug")
    lines.append("level_*: outer axis tilt from vertical (levelness); inner_*: inner axis tilt against the outer "
                 "axis at middle 0")
    return "\n".join(lines)


def _report(args, analysis, out_dir: Path, paths: dict | None = None) -> ExitCode:
    # heavy (scipy, python-can, mcap, matplotlib): imported when the command runs, not for its --help
    from bench.table_check.report import write_outputs

    if paths is None:
        try:
            paths = write_outputs(analysis, out_dir)
        except OSError as exc:
            return fail(PROG, f"cannot write the report: {exc}", ExitCode.USAGE)
    if not args.quiet:
        print(format_summary(analysis))
        for note in analysis.problems + analysis.notes:
            print(f"note: {note}")
        print(f"log:    {analysis.log_path}\nresult: {paths['json']}\nreport: {paths['markdown']}, {paths['html']}")
    recorded = record_outputs(args, PROG, [paths["json"], analysis.log_path])     # after the files are written
    code = ExitCode.OK
    if analysis.problems:
        code = fail(PROG, "quality check failed: " + "; ".join(analysis.problems), ExitCode.QUALITY)
    elif analysis.sim_within_3_sigma is False:
        code = fail(PROG, "the estimate misses the simulated table's truth by more than 3 sigma",
                    ExitCode.SIM_TRUTH_MISSED)
    return code if recorded else not_recorded_exit(PROG, code)
