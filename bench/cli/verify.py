"""`bench verify`: check a calibration on data it did not use (logic in `bench.verify`).

Runs the verification plan (`[plan] verification`, default the shipped `verify-default`)
on the configured bench or the simulator, compensates its dwells and turns with the
calibration and reports the errors in physical units with their expanded uncertainties;
`[acceptance.verification]` limits and, unless `beyond_uncertainty = "warn"`, each error
against its U make the verdict (PASS, FAIL, or NOT CHECKED when no check ran). `bench run` calls the same
`run_verification` after a calibration when `[plan] verification` is set.

Exit codes: 0 done (no verification check failed); 2 usage or configuration error, a
calibration that cannot be used (nothing moved); 3 hardware fault or aborted (table
stopped); 4 a verification check failed.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from bench.acceptance.limits import BEYOND_FAIL
from bench.acceptance.verdict import Verdict
from bench.calibration.compensation import compensation_of, load_result
from bench.cli.common import ExitCode, ended_early, fail, raise_interrupted, run_plan, stop_signals
from bench.errors import InputError

if TYPE_CHECKING:
    from bench.acceptance.verdict import Check
    from bench.config.load import BenchConfig
    from bench.model.result import CalibrationResult
    from bench.verify.errors import Verification

PROG = "bench verify"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "verify",
        description="Run the verification plan ([plan] verification, default verify-default: positions at 45 deg "
                    "tilts, turns at three rates both ways), compensate it with the calibration and report the "
                    "errors (gyro bias deg/h, scale factor ppm per rate, misalignment arcsec, accelerometer bias ug, "
                    "scale factor ppm) with expanded uncertainties; [acceptance.verification] limits and each error "
                    "against its U (unless beyond_uncertainty = \"warn\") make the verdict. Exit codes: 0 no check "
                    "failed, 2 usage or configuration error (nothing moved), 3 hardware "
                    "fault or aborted (table stopped), 4 a verification check failed.")
    parser.add_argument("--config", metavar="FILE", help="bench configuration (see bench.example.toml)")
    parser.add_argument("--sim", action="store_true", help="on the simulator (the built-in bench, or --config's)")
    parser.add_argument("--calibration", metavar="RESULT", required=True, help="the result file to verify")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the config's [output] folder)")
    parser.add_argument("--operator", default="", help="who runs it (recorded in the log)")
    parser.add_argument("--quiet", action="store_true", help="no progress output and no error table")
    parser.set_defaults(func=cmd_verify)


@dataclass
class VerifyOutcome:
    verification: Verification
    checks: list[Check]
    json_path: Path
    md_path: Path
    log_path: Path


def run_verification(config: BenchConfig, calibration: CalibrationResult, *, calibration_label: str, sim: bool,
                     out_dir: Path, run_id: str | None, quiet: bool, prog: str,
                     operator: str = "") -> tuple[ExitCode | None, VerifyOutcome | None]:
    """Run the verification plan and check `calibration` on it: (an exit code after one line when it could not
    be done, None) or (None, the outcome)."""
    # heavy (scipy, python-can, mcap, matplotlib): imported when the command runs, not for its --help
    from bench.run.devices import device_opener
    from bench.run.runner import BenchRun
    from bench.solve.inputs import budget_inputs
    from bench.verify.errors import verify_extraction
    from bench.verify.plan import (
        turn_rates,
        verification_checks,
        verification_config,
        verification_plan,
        verification_schedule,
        write_verification,
    )

    try:
        compensation = compensation_of(calibration)
        vconfig = verification_config(config, calibration)
        plan = verification_plan(vconfig)
    except InputError as exc:
        return fail(prog, f"cannot verify: {exc}; the verification did not start", ExitCode.USAGE), None
    with stop_signals(raise_interrupted), BenchRun(vconfig, plan, devices=device_opener(sim), out_dir=out_dir,
                                                   operator=operator, run_id=run_id) as run:
        try:     # a signal after the plan's last check is raised here: the run ends as interrupted
            failed = run_plan(run, prog, quiet=quiet, simulated=sim)
        except KeyboardInterrupt as exc:
            return fail(prog, f"interrupted ({exc or 'Ctrl-C'}) after the plan; the table is at rest. "
                              f"Log: {run.log_path}", ExitCode.FAULT), None
        if failed is not None:
            return failed, None
        try:
            extraction, error = run.finish_observations()
        except KeyboardInterrupt as exc:        # a stop signal after the plan ended: the table is at rest
            return fail(prog, f"interrupted ({exc or 'Ctrl-C'}) while reading the verification; the table is at "
                              f"rest. Log: {run.log_path}", ExitCode.FAULT), None
    if extraction is None:
        state = run.sequencer.state.value if run.sequencer is not None else "failed"
        return ended_early(prog, f"verification {state}: {error}", run.sequencer, f". Log: {run.log_path}"), None
    # U includes the table's part: the pointing prior the calibration's uncertainty budget uses
    verification = verify_extraction(extraction, turn_rates(plan), compensation, calibration, config.site.site,
                                     table=budget_inputs(config, sim).table)
    limits = config.acceptance
    checks = verification_checks(verification, limits.verification, limits.verification_beyond_uncertainty)
    if limits.verification_beyond_uncertainty != BEYOND_FAIL and not all(e.within_uncertainty
                                                                         for e in verification.errors):
        verification.notes.append('errors beyond U are marked, not failed ([acceptance.verification] '
                                  'beyond_uncertainty = "warn")')
    json_path, md_path = write_verification(out_dir, run.run_id, verification, checks, calibration=calibration_label,
                                            schedule=verification_schedule(config).name, log=run.log_path.name)
    return None, VerifyOutcome(verification, checks, json_path, md_path, run.log_path)


def cmd_verify(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy, python-can): imported when the command runs, not for its --help
    from bench.config.load import ConfigError, default_sim_config, load_config
    from bench.verify.plan import format_errors

    if not args.config and not args.sim:
        return fail(PROG, "say --config FILE or --sim", ExitCode.USAGE)
    try:
        config = load_config(args.config) if args.config else default_sim_config()
        calibration = load_result(args.calibration)
    except (ConfigError, InputError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    except OSError as exc:
        return fail(PROG, f"{args.calibration}: cannot read: {exc.strerror or exc}", ExitCode.USAGE)
    out_dir = Path(args.out) if args.out else Path(config.output.folder)
    code, outcome = run_verification(config, calibration, calibration_label=Path(args.calibration).name,
                                     sim=args.sim or config.table.is_sim, out_dir=out_dir, run_id=None,
                                     quiet=args.quiet, prog=PROG, operator=args.operator)
    if code is not None or outcome is None:
        return code if code is not None else ExitCode.FAULT
    if not args.quiet:
        print(format_errors(outcome.verification))
    verdict = Verdict(outcome.checks)
    worst = verdict.worst
    print(f"verdict: {verdict.headline()}\nworst:   {worst.describe() if worst is not None else 'no check ran'}\n"
          f"verification: {outcome.json_path}  report: {outcome.md_path}")
    if verdict.failed:
        return fail(PROG, "verification failed: " + "; ".join(c.describe() for c in verdict.failed), ExitCode.QUALITY)
    return ExitCode.OK
