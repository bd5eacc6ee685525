"""`bench run`: an unattended calibration run, on hardware or on the simulator.

Exit codes: 0 done (quality checks passed); 2 usage or configuration error, or the
table/IMU cannot be reached (nothing moved); 3 hardware fault or aborted (Ctrl-C, e-stop,
timeout; the table is stopped and the log kept: `--resume LOG` continues it); 4 the run
finished but a quality check failed (the report says which).
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

EXIT_OK, EXIT_USAGE, EXIT_FAULT, EXIT_QUALITY = 0, 2, 3, 4


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "run", help="run a calibration plan (hardware from --config, or the simulator with --sim)",
        description="Run a calibration plan unattended: move through the schedules, record everything to "
                    "MCAP, solve from the log, write result JSON and a report. Exit codes: 0 done, 2 usage or "
                    "configuration error (nothing moved), 3 hardware fault or aborted (table stopped; "
                    "--resume the log), 4 finished but a quality check failed.")
    parser.add_argument("--config", metavar="FILE", help="bench configuration (see bench.example.toml)")
    parser.add_argument("--sim", action="store_true",
                        help="run on the simulator: the built-in simulated bench, or --config's plan and [sim]")
    parser.add_argument("--dry-run", action="store_true",
                        help="print the compiled steps and the estimated duration; move nothing")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the config's [output] folder)")
    parser.add_argument("--resume", metavar="LOG", help="continue an interrupted run from its log")
    parser.add_argument("--operator", default="", help="who runs it (recorded in the log)")
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    parser.set_defaults(func=cmd_run)


def _fail(message: str, code: int) -> int:
    print(f"bench run: {message}", file=sys.stderr)
    return code


def compile_from_config(config):
    """The compiled plan of a configuration (PlanError/ValueError on a plan that cannot run)."""
    from bench.plan.compiler import PlanTiming, compile_plan

    p = config.plan
    timing = PlanTiming(dwell_s=p.dwell_s, settle_s=p.settle_s, move_rate_dps=p.move_rate_dps,
                        move_accel_dps2=p.move_accel_dps2, turn_rate_dps=p.turn_rate_dps,
                        turn_accel_dps2=p.turn_accel_dps2, rest_s=p.rest_s, revolutions=p.revolutions)
    return compile_plan(p.positions, p.rotations, timing, limits=config.table.limits, order=p.order)


def run_plan(run, *, quiet: bool, simulated: bool, fail) -> int | None:
    """Open `run`'s devices and execute its plan with terminal progress, Ctrl-C aborting it.

    Returns `fail(message, exit code)` when it could not start (EXIT_USAGE, nothing moved)
    or enable the table (EXIT_FAULT); None once the plan ran (see `run.sequencer` for how
    it ended)."""
    from bench.cli.progress import ProgressPrinter
    from drivers.errors import ImuError, TurntableError

    try:
        run.open()
    except (TurntableError, ImuError, ValueError, OSError) as exc:
        return fail(f"cannot start: {exc}; nothing moved", EXIT_USAGE)
    progress = ProgressPrinter(run.plan.steps, quiet=quiet, simulated=simulated)
    run.extra_listeners.append(progress)
    previous_handler = signal.signal(signal.SIGINT, lambda *_: run.abort("interrupted (Ctrl-C)"))
    try:
        try:
            run.run()
        except TurntableError as exc:
            return fail(f"cannot enable the table: {exc}; nothing moved", EXIT_FAULT)
    finally:
        signal.signal(signal.SIGINT, previous_handler)
        progress.close()
    return None


def cmd_run(args: argparse.Namespace) -> int:
    from bench.config.load import ConfigError, default_sim_config, load_config
    from bench.log.reader import LogError
    from bench.run.runner import BenchRun, completed_units
    from bench.solve.methods import SolverError

    if not args.config and not args.sim:
        return _fail("say --config FILE or --sim", EXIT_USAGE)
    try:
        config = load_config(args.config) if args.config else default_sim_config()
        completed, previous_logs = completed_units(args.resume)
        plan = compile_from_config(config)
    except (ConfigError, LogError, ValueError, OSError) as exc:
        return _fail(str(exc), EXIT_USAGE)
    sim = args.sim or config.table.is_sim
    if args.dry_run:
        print(plan.format_dry_run())
        if completed:
            print(f"resume: {len(completed)} units complete in earlier logs would be skipped: "
                  f"{', '.join(sorted(completed))}")
        return EXIT_OK
    out_dir = Path(args.out) if args.out else Path(config.output.folder)
    with BenchRun(config, plan, sim=sim, out_dir=out_dir, operator=args.operator, completed=completed,
                  previous_logs=previous_logs) as run:
        failed = run_plan(run, quiet=args.quiet, simulated=sim, fail=_fail)
        if failed is not None:
            return failed
        try:
            outcome = run.finish()
        except SolverError as exc:
            return _fail(f"the run finished but cannot be solved: {exc}. Log: {run.log_path}", EXIT_QUALITY)
    if outcome.error is not None:
        return _fail(f"{outcome.state.value}: {outcome.error}; table stopped. Log: {outcome.log_path} "
                     f"(continue with --resume {outcome.log_path})", EXIT_FAULT)
    if not args.quiet:
        print(f"log:    {outcome.log_path}\nresult: {outcome.result_path}\nreport: {outcome.report_path}, "
              f"{outcome.html_report_path}")
    if outcome.failures:
        return _fail("quality check failed: " + "; ".join(outcome.failures), EXIT_QUALITY)
    return EXIT_OK
