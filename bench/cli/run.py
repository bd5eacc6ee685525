"""`bench run`: an unattended calibration run, on hardware or on the simulator.

Exit codes: 0 done, the verdict PASS or NOT CHECKED (no check ran: no acceptance limits, no
verification; not a pass, but no error either); 2 usage or configuration error, or the
table/IMU cannot be reached (nothing moved); 3 hardware fault or aborted (Ctrl-C, e-stop,
timeout; the table is stopped and the log kept: `--resume LOG` continues it); 4 the run
finished but its verdict is FAIL: a quality check, an acceptance limit or a verification
check failed (the report says which).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bench.acceptance.verdict import Verdict
from bench.cli.common import ExitCode, ended_early, fail, raise_interrupted, run_plan, stop_signals
from bench.cli.db import add_db_options, not_recorded_exit, record_outputs
from bench.cli.equipment import run_lab_record
from bench.cli.verify import run_verification
from bench.model.units import format_hms
from bench.plan.compiler import PlanError
from bench.report.facts import lost_samples_note


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "run",
        description="Run a calibration plan unattended: move through the schedules, record everything to "
                    "MCAP, solve from the log, write result JSON and a report. Exit codes: 0 done, 2 usage or "
                    "configuration error (nothing moved), 3 hardware fault or aborted (table stopped; "
                    "--resume the log), 4 finished but the verdict is FAIL (a quality check, an acceptance limit or "
                    "a verification check failed). A verdict NOT CHECKED (no limits, no verification) exits 0.")
    parser.add_argument("--config", metavar="FILE", help="bench configuration (see bench.example.toml)")
    parser.add_argument("--sim", action="store_true",
                        help="run on the simulator: the built-in simulated bench, or --config's plan and [sim]")
    parser.add_argument("--dry-run", action="store_true",
                        help="print the compiled steps and the estimated duration; move nothing")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the config's [output] folder; with "
                                                     "--resume, the resumed log's folder)")
    parser.add_argument("--resume", metavar="LOG", help="continue an interrupted run from its log (into a new log "
                                                        "beside it unless --out says otherwise: then a warning)")
    parser.add_argument("--operator", default="", help="who runs it (recorded in the log)")
    parser.add_argument("--customer", metavar="NAME", help="the run's customer (recorded in the log's lab record; "
                                                           "default: [lab] customer)")
    parser.add_argument("--item", metavar="TEXT", help="the item calibrated, as the customer names it (recorded in "
                                                       "the log's lab record; default: [lab] item)")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress output (the summary, verdict, worst check, the result and report paths "
                             "and the records database, is always printed)")
    add_db_options(parser)
    parser.set_defaults(func=cmd_run)


PROG = "bench run"


def cmd_run(args: argparse.Namespace) -> ExitCode:
    # Every stop signal from the plan on is handled where it comes (run_plan, the solve, the result's tail); one
    # that ends the command here came before the run began (while loading, compiling) or after it said its line.
    started: list[bool] = []
    try:
        return _cmd_run(args, started)
    except KeyboardInterrupt as exc:
        where = "after the run ended; the table is at rest" if started else "before the run started; nothing moved"
        return fail(PROG, f"interrupted ({exc or 'Ctrl-C'}) {where}", ExitCode.INTERRUPTED if not started
                    else ExitCode.FAULT)


def output_folder(out: str | None, resume: str | None, configured: str | Path) -> Path:
    """Where a run writes: --out; else, resuming, beside the resumed log (one run, one folder: `bench solve` finds
    a run's earlier logs beside its last); else the configuration's [output] folder."""
    if out:
        return Path(out)
    return Path(resume).parent if resume else Path(configured)


def _cmd_run(args: argparse.Namespace, started: list[bool]) -> ExitCode:
    # heavy (scipy, python-can, mcap, matplotlib): imported when the command runs, not for its --help
    from bench.config.load import ConfigError, default_sim_config, load_config
    from bench.log.reader import LogError
    from bench.log.recorder import RecorderError
    from bench.log.run_setup import SetupMismatch
    from bench.plan.retime import retime
    from bench.run.devices import device_opener
    from bench.run.resume import resume_point
    from bench.run.runner import BenchRun, compile_from_config
    from bench.run.timing import estimates, timing_profile
    from bench.solve.inputs import SolveInputError, check_solvable
    from bench.solve.methods import SolverError
    from bench.verify.plan import verification_config, verification_plan

    if not args.config and not args.sim:
        return fail(PROG, "say --config FILE or --sim", ExitCode.USAGE)
    try:
        config = load_config(args.config) if args.config else default_sim_config()
        if config.several and args.resume:
            return fail(PROG, "--resume: resuming a run of several IMUs ([[imu]]) is not supported yet; run it "
                              "again", ExitCode.USAGE)
        plan = compile_from_config(config)
        # a verification plan that does not fit the table is refused here, before the calibration moves anything
        verification = (verification_plan(verification_config(config)) if config.plan.verification is not None
                        else None)
        sim = args.sim or config.table.is_sim
        # a log of another plan, IMU, site or table is refused here, before anything moves
        resumed = resume_point(args.resume, config, plan, sim=sim)
        # what the solve will need (the budget's kernel and priors) is built now, not after the whole run
        check_solvable(config, plan.steps, sim)
    except (ConfigError, LogError, PlanError, SetupMismatch, SolveInputError, OSError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    completed, previous_logs = resumed.completed, resumed.previous_logs
    out_dir = output_folder(args.out, args.resume, config.output.folder)
    if not args.quiet:
        for note in resumed.notes:
            print(f"note: {note}")
        if args.resume and out_dir.resolve() != Path(args.resume).parent.resolve():
            earlier = " ".join(str(p) for p in previous_logs) or args.resume
            print(f"{PROG}: warning: --out {out_dir} is not the folder of the resumed log "
                  f"({Path(args.resume).parent}): the run is split over two folders, and `bench solve` of the new "
                  f"log finds the earlier ones only beside it (move them together, or give every log: bench solve "
                  f"{earlier} NEW.mcap)", file=sys.stderr)
    if args.dry_run:
        # the estimates of the controller that runs the plan (the simulator's own timing under --sim); the plan
        # and its recorded estimates stay the same whoever runs it
        profile = timing_profile(config, sim)
        print(plan.format_dry_run(retime(plan.steps, profile), profile.name))
        if config.plan.verification is not None and verification is not None:
            verification_s = sum(estimates(verification_config(config), verification.steps, sim))
            print(f"then the verification ({config.plan.verification.name}): {len(verification.steps)} steps, "
                  f"estimated {format_hms(verification_s)}")
        if completed:
            print(f"resume: {len(completed)} units complete in earlier logs would be skipped: "
                  f"{', '.join(sorted(completed))}")
        return ExitCode.OK
    # the configured equipment is checked against the register before anything moves (refused: exit 2)
    lab = run_lab_record(args, config, PROG)
    if isinstance(lab, ExitCode):
        return lab
    # A stop signal (Ctrl-C, SIGTERM, SIGHUP) aborts the plan while it runs (run_plan); after it, it ends
    # the solve (an Interrupted): either way the devices and the log are closed.
    with stop_signals(raise_interrupted), BenchRun(config, plan, devices=device_opener(sim), out_dir=out_dir,
                                                   operator=args.operator, completed=completed,
                                                   previous_logs=previous_logs, lab=lab) as run:
        stage = "after the plan"
        started.append(True)
        try:
            # a signal after the plan's last check is raised here (Interrupted): the run ends as interrupted
            failed = run_plan(run, PROG, quiet=args.quiet, simulated=sim)
            if failed is not None:
                return failed
            stage = "while solving"
            outcome = run.finish()      # the result file appears, renamed into place, only when all is written
        except KeyboardInterrupt as exc:        # a stop signal after the plan ended: the table is at rest
            return fail(PROG, f"interrupted ({exc or 'Ctrl-C'}) {stage}; the table is at rest; no result written. "
                              f"Log: {run.log_path} (bench solve {run.log_path} solves it)", ExitCode.FAULT)
        except SolverError as exc:
            return fail(PROG, f"the run finished but cannot be solved: {exc}. Log: {run.log_path}", ExitCode.QUALITY)
        except RecorderError as exc:            # the log's last records (result, summary) could not be written
            return fail(PROG, f"{exc}; table stopped. Log: {run.log_path}", ExitCode.FAULT)
        except OSError as exc:                  # the result or the report could not be written
            return fail(PROG, f"the run finished but its result cannot be written: "
                              f"{exc.strerror or exc} ({exc.filename}). Log: {run.log_path}", ExitCode.FAULT)
    if outcome.error is not None:
        not_recorded = _record(args, [outcome.log_path])     # the table is stopped and the log closed: now record
        return ended_early(PROG, f"{outcome.state.value}: {outcome.error}", run.sequencer,
                           f". Log: {outcome.log_path}" + ("" if config.several else    # several: no --resume yet
                                                            f" (continue with --resume {outcome.log_path})")
                           + (f"; {not_recorded}" if not_recorded else ""))
    # After the result is written a stop signal ends the command where it is: the result stays as written (it was
    # renamed into place complete), what is not done yet (verification, summary, recording) is said in the line.
    with stop_signals(raise_interrupted):
        try:
            return _after_the_result(args, config, outcome, run, sim, out_dir)
        except KeyboardInterrupt as exc:
            return fail(PROG, f"interrupted ({exc or 'Ctrl-C'}) after the result was written; the table is at rest; "
                              f"not verified or recorded: {outcome.result_path} (bench db import records it)",
                        ExitCode.FAULT)


def _record(args: argparse.Namespace, paths: list) -> tuple[str, bool]:
    """`record_outputs`; a stop signal ends it: (the words saying the recording was interrupted, '' if it was not;
    whether the records database took the files)."""
    try:
        with stop_signals(raise_interrupted):
            return "", record_outputs(args, PROG, paths)
    except KeyboardInterrupt as exc:
        return (f"interrupted ({exc or 'Ctrl-C'}) while recording: NOT recorded in the records database (the files "
                "are kept: bench db import records them)"), False


def _after_the_result(args: argparse.Namespace, config, outcome, run, sim: bool, out_dir: Path) -> ExitCode:
    """The verification (if configured), the summary and the recording of a run that has its result."""
    # heavy (scipy, python-can): imported when the command runs, not for its --help
    from bench.verify.plan import format_errors

    if not args.quiet:
        print(f"log:    {outcome.log_path}")
    verified = None
    if config.plan.verification is not None and outcome.result is not None and outcome.result_path is not None:
        # after the calibration, on data it did not use; its checks join the result's verdict
        code, verified = run_verification(config, outcome.result, calibration_label=outcome.result_path.name,
                                          sim=sim, out_dir=out_dir, run_id=f"{run.run_id}-verify", quiet=args.quiet,
                                          prog=PROG, operator=args.operator)
        if code is not None or verified is None:
            return code if code is not None else ExitCode.FAULT
        if not args.quiet:
            print(format_errors(verified.verification))
        add_verification(outcome, verified, config)
    # the summary, also with --quiet: the verdict, its worst check, where the result and reports are
    print(run_summary(outcome, verified))
    if outcome.thermal_paths:       # a calibration over temperature: each temperature's result and the model
        print("thermal: " + ", ".join(str(p) for p in outcome.thermal_paths))
    others = {serial: one for serial, one in outcome.units.items() if one.result_path != outcome.result_path}
    for serial, one in others.items():       # a run of several IMUs: the summary above is its reference unit's
        print(f"unit {serial}: verdict: {one.verdict.headline()}; result: {one.result_path}  report: "
              f"{one.report_path}" if one.verdict is not None else f"unit {serial}: {'; '.join(one.failures)}")
    # a run of several IMUs: every unit's result, each recorded as `<run-id>.<serial>` of the run
    interrupted, recorded = _record(args, [outcome.result_path, *(one.result_path for one in others.values()),
                                           outcome.log_path])   # after the files
    if interrupted:
        return fail(PROG, f"{interrupted}; result: {outcome.result_path}", ExitCode.FAULT)
    print(records_line(args, recorded))
    code = ExitCode.OK
    failed = [c.labelled() for c in (outcome.verdict.failed if outcome.verdict is not None else [])]
    failed += [f"unit {serial}: {c.labelled()}" for serial, one in others.items()
               for c in (one.verdict.failed if one.verdict is not None else [])]
    failed += ["; ".join(one.failures) for one in others.values() if one.result is None]
    if failed:
        code = fail(PROG, "verdict FAIL: " + "; ".join(failed), ExitCode.QUALITY)
    return code if recorded else not_recorded_exit(PROG, code)


def records_line(args: argparse.Namespace, recorded: bool = True) -> str:
    """`records: FILE-OR-URL`, the records database the run's files went to (`--db`, else the default), `records:
    NOT recorded in FILE-OR-URL (...)` when it did not take them (the warning line above says why), or `records: not
    recorded (--no-db)`."""
    if getattr(args, "no_db", False):
        return "records: not recorded (--no-db)"
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from sqlalchemy import make_url
    from sqlalchemy.exc import ArgumentError

    from bench.records.store import database_url

    url = database_url(getattr(args, "db", None))
    try:
        parsed = make_url(url)
        shown = (parsed.database if parsed.get_backend_name() == "sqlite" and parsed.database
                 else parsed.render_as_string(hide_password=True))
    except ArgumentError:
        shown = url
    return f"records: {shown}" if recorded else (f"records: NOT recorded in {shown} (the warning above says why; "
                                                 "`bench db import` records the files)")


def run_summary(outcome, verified=None) -> str:
    """Three lines: `verdict: PASS|FAIL|NOT CHECKED (...)`, `worst:   ...`, `result:  FILE  report: FILE, FILE[
    verification: FILE]` (the fourth, `records: ...`, is printed after recording); between the second and the third,
    `note:    ...` when IMU samples were lost outside every dwell and turn window."""
    verdict = outcome.verdict
    worst = verdict.worst if verdict is not None else None
    reports = ", ".join(str(p) for p in (outcome.report_path, outcome.html_report_path) if p is not None)
    verification = f"  verification: {verified.md_path}" if verified is not None else ""
    lost = lost_samples_note(outcome.result.run) if outcome.result is not None else None
    return (f"verdict: {verdict.headline() if verdict is not None else 'none'}\n"
            f"worst:   {worst.labelled() if worst is not None else 'no check ran'}\n"
            + (f"note:    {lost}\n" if lost else "")
            + f"result:  {outcome.result_path}  report: {reports}{verification}")


def add_verification(outcome, verified, config) -> None:
    """The verification's checks into the result's verdict; the result file and its reports written again."""
    # heavy (scipy, python-can, mcap, matplotlib): imported when the command runs, not for its --help
    from bench.log.reader import read_log
    from bench.report.markdown import write_reports
    from bench.run.runner import save_replacing

    outcome.verdict = Verdict([*outcome.verdict.checks, *verified.checks])
    result = outcome.result
    result.verdict = outcome.verdict.to_section()
    result.run.extra["verification"] = {"file": verified.json_path.name, "log": verified.log_path.name,
                                        "errors": len(verified.verification.errors)}
    save_replacing(result, outcome.result_path)
    run_id = outcome.result_path.name.removesuffix(".result.json")
    write_reports(result, outcome.result_path.parent, run_id, log=read_log(str(outcome.log_path)),
                  layout=config.imu.layout, problems=outcome.problems, failures=outcome.failures,
                  imu_link=result.run.link_dict(), title=f"Calibration report {run_id}")
