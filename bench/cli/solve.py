"""`bench solve`: re-solve recorded runs from their MCAP logs (`bench.finish`; outputs: `bench.jobs.resolve`).

Exit codes: 0 solved, the verdict PASS or NOT CHECKED; 2 usage error, a file that cannot be
read as a run log, a subset the logs lack, or a static noise recording (`bench noise`
analyses those); 4 solved but the verdict is FAIL (a quality check: damage, steps left out,
outliers; or an acceptance limit; the report says which) or nothing left to solve.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from bench.cli.common import ExitCode, fail
from bench.cli.db import add_db_options, not_recorded_exit, record_outputs
from bench.cli.solve_archive import add_archive_options, cmd_archive
from bench.errors import InputError
from bench.files import write_output_text
from bench.model.result import CalibrationResult
from bench.model.run_section import RunInfo
from bench.report.facts import lost_samples_note

PROG = "bench solve"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "solve",
        description="Extract the observations (position means, rest-to-rest turn integrals) from one or more run "
                    "logs of one IMU (a resumed run's earlier logs are read too) and solve; write result JSON and "
                    "report as `bench run` does. Damaged logs are read around the damage and the report lists "
                    "what was lost. Exit codes: 0 solved, 2 usage error or unreadable log or a subset the log "
                    "lacks or a static noise recording (`bench noise LOG` analyses it), 4 solved but a quality "
                    "check failed. A thermal run's log ([plan] temperatures_c) is solved one calibration per "
                    "temperature and its thermal model refitted, as the run did.")
    parser.add_argument("logs", nargs="*", metavar="LOG", help="run log(s) (.mcap)")
    parser.add_argument("--positions", metavar="NAME|FILE",
                        help="solve only these recorded positions (a schedule: optimal-24, traditional-12, all-64, "
                             "a file; 'none' for none)")
    parser.add_argument("--rotations", metavar="NAME|FILE",
                        help="solve only these recorded rotations (optimal-5s6r, traditional-3s6r, all-96, a file; "
                             "'none' for none)")
    parser.add_argument("--compare", metavar="METHODS",
                        help="solve each method's subset and print its differences from the last one, e.g. "
                             "optimal,traditional,all (a method is optimal, traditional, all or POSITIONS+ROTATIONS)")
    parser.add_argument("--json", metavar="FILE", help="with --compare: also write the table as JSON")
    parser.add_argument("--model", metavar="TERMS",
                        help="the extended model: 'auto' (the higher-order families the data find significant), "
                             "comma-separated families (gyro_g_sensitivity,acc_second_order,...) or '30' for the 30 "
                             "coefficients alone (default: the recorded configuration's [model] terms)")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: next to the first log)")
    parser.add_argument("--against", metavar="OLD.result.json",
                        help="compare the new result with an earlier result file in the reports")
    parser.add_argument("--no-html", action="store_true",
                        help="write the Markdown report only (the HTML report's plots take seconds on a long log)")
    parser.add_argument("--no-earlier", action="store_true",
                        help="do not add the earlier logs a resumed log names")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    parser.add_argument("--unit", metavar="SERIAL", action="append",
                        help="a log of several IMUs ([[imu]]): re-solve this unit only (repeatable; default: every "
                             "unit)")
    add_db_options(parser)
    add_archive_options(parser)
    parser.set_defaults(func=cmd_solve)


def _notes(recorded, run: RunInfo) -> list[str]:
    """The notes of reading the logs, and the samples lost outside every window the solve uses (`run`: its
    result's, `lost_samples_note`)."""
    lost = lost_samples_note(run)
    return list(recorded.notes) + ([lost] if lost else [])


def _thermal_lines(recorded, finished) -> list[str]:
    """What `bench solve` says of a thermal log's re-solve."""
    solution = finished.thermal
    blocks = solution.blocks
    lines = [f"solved {recorded.run_id} from {len(recorded.logs)} log(s): {len(blocks)} "
             f"temperature{'s' if len(blocks) != 1 else ''}, one calibration each"]
    lines += [f"note: {note}" for note in _notes(recorded, solution.head.point.result.run)]
    lines += [f"result: {path}" for path in finished.thermal_results]
    if finished.thermal_model_path is not None:
        lines.append(f"thermal: {finished.thermal_model_path}")
    lines.append(f"report: {finished.report_path} (T{solution.head.temperature_index}, nearest "
                 f"{solution.reference_c:g} degC)" + (f"\n        {finished.html_report_path}"
                                                      if finished.html_report_path else ""))
    return lines


def _calibration_lines(recorded, finished) -> list[str]:
    """What `bench solve` says of a calibration's re-solve."""
    resolved = finished.resolved
    extraction = resolved.solution.extraction
    return ([f"solved {recorded.run_id} from {len(recorded.logs)} log(s): {len(extraction.positions)} positions "
             f"({resolved.positions or 'none'}), {len(extraction.rotations)} rotations "
             f"({resolved.rotations or 'none'})"]
            + [f"note: {note}" for note in _notes(recorded, resolved.result.run)]
            + [f"result: {finished.result_path}\nreport: {finished.report_path}"
               + (f"\n        {finished.html_report_path}" if finished.html_report_path else "")])


def _solve_units(args: argparse.Namespace, recorded, subset: bool,
                 model_terms: tuple[str, ...] | None) -> ExitCode:
    """A log of several IMUs: every unit (or those of --unit) re-solved on its own, `<run-id>.<serial>.solved.*`."""
    # heavy (scipy, python-can, mcap): imported when the command runs, not for its --help
    from bench.finish.recorded import SolveInputError
    from bench.finish.units import finish_units, is_several

    log = recorded.logs[-1]
    if not is_several(log):
        raise SolveInputError(f"{log.path} records one IMU, not several ([[imu]]): drop --unit")
    if subset or len(recorded.logs) > 1:
        raise SolveInputError(f"{log.path} records several IMUs: it is re-solved whole, from its one log (no "
                              "--compare, --positions, --rotations or earlier logs yet)")
    config = recorded.setup.config
    if config is None:
        raise SolveInputError(f"{log.path}: its configuration cannot be rebuilt ({'; '.join(recorded.setup.notes)}): "
                              "a log of several IMUs is solved with it")
    out_dir = Path(args.out) if args.out else Path(log.path).parent
    if args.against:
        raise SolveInputError(f"{log.path} records several IMUs: --against compares one result with one solve, "
                              "which is not supported for a log of several units yet")
    finished = finish_units(recorded.logs, config, out_dir, recorded.run_id, recorded.sim, serials=args.unit,
                            html=not args.no_html, model_terms=model_terms)
    failures: list[str] = []
    for serial, one in finished.items():
        if one.result is None:           # a unit that cannot be solved (silent): the others are still solved
            failures += one.failures
            continue
        if not args.quiet:
            print(f"unit {serial}: result: {one.result_path}\n        report: {one.report_path}")
            if one.verdict is not None:
                print(f"        verdict: {one.verdict.headline()}")
        failures += [f"unit {serial}: {c.labelled()}" for c in (one.verdict.failed if one.verdict else [])]
    del recorded
    # every unit's result solved, each under its own record (`<run-id>.<serial>` of the run)
    recorded_ok = record_outputs(args, PROG, [*(one.result_path for one in finished.values()), log.path])
    code = fail(PROG, "verdict FAIL: " + "; ".join(failures), ExitCode.QUALITY) if failures else ExitCode.OK
    return code if recorded_ok else not_recorded_exit(PROG, code)


def cmd_solve(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy, python-can, mcap, matplotlib): imported when the command runs, not for its --help
    from bench.finish.calibration import load_subset_schedule
    from bench.finish.finish import finish
    from bench.finish.recorded import SolveInputError, load_recorded
    from bench.finish.units import is_several
    from bench.jobs.compare import compare, format_comparison, parse_methods
    from bench.jobs.resolve import ResolveTarget, output_stem
    from bench.log.reader import LogError
    from bench.log.run_kind import RunKind
    from bench.solve.methods import SolverError

    if args.archive:
        return cmd_archive(args)
    if not args.logs:
        return fail(PROG, "give run log(s), or --archive DIR...", ExitCode.USAGE)
    if args.compare and (args.positions or args.rotations):
        return fail(PROG, "--compare chooses the subsets itself: drop --positions/--rotations", ExitCode.USAGE)
    if args.json and not args.compare:
        return fail(PROG, "--json writes the --compare table: give --compare too", ExitCode.USAGE)
    against = None
    if args.against:
        if args.compare:
            return fail(PROG, "--against is for the reports of a solve, not for --compare", ExitCode.USAGE)
        try:
            against = CalibrationResult.load(args.against)
        except OSError as exc:
            return fail(PROG, f"{args.against}: cannot read: {exc.strerror or exc}", ExitCode.USAGE)
        except InputError as exc:   # not a result, not a regular file, too large
            return fail(PROG, str(exc), ExitCode.USAGE)
    try:
        model_terms = _model_terms(args.model)
    except SolverError as exc:
        return fail(PROG, f"--model: {exc}", ExitCode.USAGE)
    try:
        methods = parse_methods(args.compare) if args.compare else None
        positions = load_subset_schedule(args.positions, "positions")
        rotations = load_subset_schedule(args.rotations, "rotations")
        recorded = load_recorded(args.logs, earlier=not args.no_earlier)
        if is_several(recorded.logs[-1]) or args.unit:
            return _solve_units(args, recorded, methods is not None or positions is not None or rotations is not None,
                                model_terms)
        if recorded.kind is RunKind.THERMAL and (methods is not None or positions is not None or rotations is not None):
            # its blocks are solved one temperature each, never together
            thermal_log = recorded.first_log_of_kind(RunKind.THERMAL) or recorded.logs[-1]
            return fail(PROG, f"{thermal_log.path} is a calibration over temperature "
                              "([plan] temperatures_c): it is re-solved whole, one calibration per temperature (no "
                              "--compare, --positions or --rotations)", ExitCode.USAGE)
        if methods is not None and recorded.kind is not RunKind.STATIC_NOISE:
            comparison = compare(recorded, methods)
        else:
            out_dir = Path(args.out) if args.out else Path(recorded.logs[0].path).parent
            target = ResolveTarget(out_dir, output_stem(recorded, positions, rotations), html=not args.no_html,
                                   against=against, against_label=args.against and Path(args.against).name,
                                   model_terms=model_terms)
            finished = finish(recorded, target, positions=positions, rotations=rotations)
    except (LogError, SolveInputError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    except SolverError as exc:
        return fail(PROG, f"cannot be solved: {exc}", ExitCode.QUALITY)
    except InputError as exc:       # a name from the log that would leave the output folder
        return fail(PROG, str(exc), ExitCode.USAGE)
    except OSError as exc:
        return fail(PROG, f"cannot write the result: {exc}", ExitCode.USAGE)

    if methods is not None:
        if not args.quiet:
            print(format_comparison(comparison), end="")
        if args.json:
            try:
                write_output_text(args.json, json.dumps(comparison.to_json(), indent=2) + "\n", args.logs,
                                  option="--json")
            except InputError as exc:   # a log read, or a run log
                return fail(PROG, str(exc), ExitCode.USAGE)
            except OSError as exc:
                return fail(PROG, f"cannot write {args.json}: {exc.strerror or exc}", ExitCode.USAGE)
            if not args.quiet:
                print(f"wrote {args.json}")
        failures = comparison.failures
        recorded_ok = True             # a comparison writes no result to record
    else:
        if not args.quiet:
            lines = (_thermal_lines if finished.thermal is not None else _calibration_lines)(recorded, finished)
            print("\n".join(lines))
        thermal = finished.thermal is not None
        if not args.quiet and thermal and finished.verdict is not None:
            print(f"verdict: {finished.verdict.headline()}")
        logs_solved = [log.path for log in recorded.logs]
        # the logs' decoded samples and states go before the records database reads the logs' metadata again
        # (a 1 GB log solved and then read for its records peaked at 2.1 GB)
        del recorded
        recorded_ok = record_outputs(args, PROG, [finished.result_path, *logs_solved])   # after the files are written
        failures = finished.failures
        if finished.verdict is not None:
            if not args.quiet and not thermal:
                print(f"verdict: {finished.verdict.headline()}")
            # the recorded [acceptance] limits judge (they include the quality checks)
            failures = [c.labelled() for c in finished.verdict.failed]
    code = fail(PROG, "verdict FAIL: " + "; ".join(failures), ExitCode.QUALITY) if failures else ExitCode.OK
    return code if recorded_ok else not_recorded_exit(PROG, code)


def _model_terms(option: str | None) -> tuple[str, ...] | None:
    """`--model`: None (the recorded configuration's), () for "30", else the families (SolverError if unknown)."""
    if option is None:
        return None
    if option.strip() == "30":
        return ()
    from bench.solve.extended import parse_terms  # scipy: not loaded for --help

    terms = tuple(t.strip() for t in option.split(",") if t.strip())
    parse_terms(terms)
    return terms
