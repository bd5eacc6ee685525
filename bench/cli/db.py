"""`bench db`: the calibration records (logic in `bench.records`).

`bench db import PATH...` records result files and logs already on disk (idempotent),
`bench db list` lists runs, `bench db results RUN_ID` a run's results (its record of truth
and what was derived from it), `bench db promote RESULT` makes a result its run's record of
truth, `bench db history SERIAL` shows a unit's coefficients over time, `bench db equipment` keeps the lab's
equipment register (`bench.cli.equipment`). `add_db_options` and
`record_outputs` are the hooks `bench run`, `bench solve` and
`bench check-table` use to record what they wrote: after the files are written, and a
database that fails only warns (the files are the record; `bench db import` adds them later).

Exit codes: 0 done; 2 usage error, or the database cannot be opened; 4 `import` found
files it could not read (the others are recorded).
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from bench.cli.common import ExitCode, fail
from bench.cli.equipment import register_equipment

if TYPE_CHECKING:
    from bench.records.store import RunRow

PROG = "bench db"
DB_HELP = ("records database: a SQLAlchemy URL (postgresql://user@host/db) or a SQLite file path (default: $BENCH_DB, "
           "else $XDG_DATA_HOME/turntable-bench/records.sqlite, i.e. ~/.local/share/turntable-bench/records.sqlite)")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "db",
        description="The records database (SQLite file by default; PostgreSQL with --db postgresql://...). "
                    "Exit codes: 0 done, 2 usage error or the database cannot be opened, 4 import found unreadable "
                    "files (the others are recorded).")
    parser.add_argument("--db", metavar="URL", help=DB_HELP)
    sub = parser.add_subparsers(dest="db_command", metavar="ACTION")
    sub.required = True
    p = sub.add_parser("import", help="record result files (*.result.json, *.table-check.json, *.noise.json) and "
                                      "logs (*.mcap)",
                       description="Record result files and run logs on disk; folders are searched recursively. "
                                   "Idempotent: a file already recorded is skipped. A file that cannot be recorded "
                                   "is one line (the others are recorded; exit 4 at the end); a thermal model "
                                   "(*.thermal.json) and in-memory simulations are named as holding nothing to "
                                   "record.")
    p.add_argument("paths", nargs="+", metavar="PATH", help="result files, logs, or folders to search")
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.add_argument("--quiet", action="store_true", help="print only the counts and failures")
    p.set_defaults(func=cmd_import)
    p = sub.add_parser("list", help="list recorded runs, newest first")
    p.add_argument("--serial", metavar="S", help="only this unit's runs")
    p.add_argument("--since", metavar="DATE", help="only runs started (else finished) on or after DATE (YYYY-MM-DD)")
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_list)
    p = sub.add_parser("results", help="a run's results: its record of truth and the results derived from it",
                       description="Every recorded result of the run: its id, origin (run: `bench run` wrote it; "
                                   "re-solve: `bench solve` of the whole log; subset: a what-if solve; damaged: a "
                                   "solve of a damaged or cut log), software version, verdict; '*' marks the run's "
                                   "record of truth, the one `db list`, `db history` and their exports use.")
    p.add_argument("run_id", metavar="RUN_ID", help="the run (as `bench db list` shows it)")
    p.add_argument("--unit", metavar="SERIAL", help="a run of several IMUs ([[imu]]): the unit (each unit is a "
                                                    "record of its own, `<run-id>.<serial>`)")
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_results)
    p = sub.add_parser("promote", help="make a result its run's record of truth",
                       description="Make a recorded result the record of truth of its run (instead of the result "
                                   "`bench run` wrote): `db list`, `db history` and their exports use it from now "
                                   "on. RESULT is a result id from `bench db results RUN_ID`, or a recorded result "
                                   "file (its path or SHA-256). The latest promotion wins.")
    p.add_argument("result", metavar="RESULT", help="a result id (`bench db results RUN_ID`) or a recorded result file")
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_promote)
    p = sub.add_parser("history", help="a unit's coefficients over time: changes in sigma, drift per year",
                       description="The record of truth of every calibration run of the unit (`bench db results`), "
                                   "oldest first: each coefficient with the digits that show its changes, its "
                                   "1-sigma, its change from the calibration before in combined sigma, marks (FAILED, "
                                   "simulated, promoted, a stand-in re-solve), and its drift per year (weighted "
                                   "straight-line fit, failed calibrations left out, stated over 30 days or more). "
                                   "--out writes JSON, CSV, a plot.")
    p.add_argument("serial", metavar="SERIAL", help="the unit's serial number (as its logs record it)")
    p.add_argument("--coefficient", metavar="NAME", nargs="+", action="extend",
                   help="only these coefficients (e.g. Kg_x bg_z)")
    p.add_argument("--model", metavar="MODEL", help="the model, when the serial is recorded for several")
    p.add_argument("--out", metavar="DIR", help="write <serial>.history.json, .csv and .png here")
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_history)
    register_equipment(sub, {"help": DB_HELP})


def _open(args: argparse.Namespace, create: bool = True):
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.store import open_records

    return open_records(getattr(args, "db", None), create=create)


def cmd_import(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.ingest import import_paths
    from bench.records.store import RecordsError

    missing = [p for p in args.paths if not Path(p).exists()]
    if missing:
        return fail(PROG, f"{missing[0]}: no such file or folder", ExitCode.USAGE)
    try:
        with _open(args) as records:
            report = import_paths(records, args.paths)
    except RecordsError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    if not args.quiet:
        for path in report.added:
            print(f"recorded {path}")
        for path, reason in report.not_recorded:
            print(f"not recorded {path}: {reason}")
    print(f"{len(report.added)} recorded, {len(report.known)} already known, {len(report.failed)} failed"
          + (f", {len(report.not_recorded)} with nothing to record" if report.not_recorded else ""))
    for path, reason in report.failed:
        print(f"{PROG}: {path}: {reason}", file=sys.stderr)
    return ExitCode.QUALITY if report.failed else ExitCode.OK


def cmd_list(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.store import RecordsError

    since = None
    if args.since:
        try:
            since = dt.datetime.fromisoformat(args.since)
        except ValueError:
            return fail(PROG, f"--since {args.since!r}: not a date (YYYY-MM-DD or YYYY-MM-DDTHH:MM)", ExitCode.USAGE)
        if since.tzinfo is not None:
            since = since.astimezone(dt.UTC).replace(tzinfo=None)
    try:
        with _open(args, create=False) as records:
            rows = records.list_runs(serial=args.serial, since=since)
    except RecordsError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    # columns as wide as their widest entry (a model name was cut at 20), up to a bound: names come from files
    run_w, model_w, serial_w = (min(max([len(h), *(len(getattr(r, key)) for r in rows)]), LIST_COLUMN_MAX)
                                for h, key in (("run", "run_id"), ("model", "model"), ("serial", "serial")))
    print(f"{'started (UTC)':20} {'run':{run_w}} {'kind':11} {'model':{model_w}} {'serial':{serial_w}} "
          f"{'outcome':9} {'results':>7} verdict (of the record of truth)")
    for r in rows:
        when = r.started_utc or r.finished_utc
        print(f"{(when.isoformat(timespec='seconds') if when else '-'):20} {_cell(r.run_id, run_w)} {r.kind:11} "
              f"{_cell(r.model, model_w)} {_cell(r.serial, serial_w)} {_outcome(r.outcome, r.log_complete):9} "
              f"{r.results:>7} {_truth_text(r)}")
    print(f"{len(rows)} run(s)")
    return ExitCode.OK


#: The widest a `db list` column of names grows (a longer name ends in "~").
LIST_COLUMN_MAX = 48


def _cell(text: str, width: int) -> str:
    return f"{text:{width}}" if len(text) <= width else text[:width - 1] + "~"


def _outcome(outcome: str, log_complete: bool | None) -> str:
    return (outcome or "-") + ("" if log_complete is not False else " (log unfinished)")


def _truth_text(row: RunRow) -> str:
    """The verdict of the run's record of truth, and where that record comes from when it is not the run's own."""
    if row.truth_id is None:
        return "- (only derived results: see `bench db results RUN_ID`)" if row.results else "-"
    note = "promoted" if row.promoted else ("" if row.truth_origin in ("run", None) else row.truth_origin)
    return (row.verdict or "-") + (f" ({note})" if note else "")


def cmd_results(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.store import RecordsError

    try:
        with _open(args, create=False) as records:
            run_id = records.unit_record(args.run_id, args.unit)
            rows = records.results_of(run_id)
    except RecordsError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    print(f"results of run {run_id} ('*': the record of truth)")
    print(f"  {'id':>6} {'origin':9} {'software':12} {'solved (UTC)':20} {'verdict':8} how")
    for r in rows:
        solved = r.solved_utc.isoformat(timespec="seconds") if r.solved_utc else "-"
        how = (r.derivation or ("bench run" if r.origin == "run" else "recorded before schema 3")) + (
            f"; promoted {r.promoted_utc.isoformat(timespec='seconds')}" if r.promoted_utc else "")
        print(f"{'*' if r.truth else ' '} {r.result_id:>6} {(r.origin or '-'):9} {r.software_version[:12]:12} "
              f"{solved:20} {(r.verdict or '-'):8} {how}")
    if not any(r.truth for r in rows):
        print("no record of truth: only derived results (`bench db promote RESULT_ID` makes one the record)")
    return ExitCode.OK


def cmd_promote(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.store import RecordsError

    try:
        with _open(args, create=False) as records:
            row = records.promote(args.result)
    except RecordsError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    print(f"result {row.result_id} ({row.origin or 'recorded before schema 3'}"
          f"{': ' + row.derivation if row.derivation else ''}) is now the record of truth of run {row.run_id}")
    return ExitCode.OK


def cmd_history(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.history import format_history, unit_history, write_history
    from bench.records.store import RecordsError

    try:
        with _open(args, create=False) as records:
            history = unit_history(records, args.serial, names=args.coefficient, model=args.model,
                                   budgets=bool(args.out))     # only the written JSON shows the budgets
    except RecordsError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    if args.coefficient and not history.coefficients:
        return fail(PROG, f"unit {args.serial!r} has no recorded coefficient named {', '.join(args.coefficient)}",
                    ExitCode.USAGE)
    print(format_history(history), end="")
    if args.out:
        try:
            paths = write_history(history, args.out)
        except OSError as exc:
            return fail(PROG, f"cannot write the history: {exc.strerror or exc} ({exc.filename})", ExitCode.USAGE)
        print("wrote " + ", ".join(str(p) for p in paths))
    return ExitCode.OK


# -- the hooks of bench run / solve / check-table ------------------------------------------------

def add_db_options(parser: argparse.ArgumentParser) -> None:
    """`--db URL` and `--no-db` on a command that records what it writes."""
    parser.add_argument("--db", metavar="URL", help=DB_HELP)
    parser.add_argument("--no-db", action="store_true", help="do not record the result in the records database")


def record_outputs(args: argparse.Namespace, prog: str, paths: list[Path | str | None]) -> bool:
    """Record the written result files (and logs) unless --no-db; whether that is done (True also with --no-db:
    nothing was asked). A failure is one warning line; the caller ends with `ExitCode.NOT_RECORDED`
    (`not_recorded_exit`) after its own lines, the files kept."""
    if getattr(args, "no_db", False):
        return True
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.ingest import import_file, sha256_of
    from bench.records.store import RecordsError, open_records

    files = [Path(p) for p in paths if p is not None]
    logs = [p for p in files if p.suffix == ".mcap"]
    path = None
    try:
        # a result is keyed to the log it was solved from (the last log named: the one its run.log names)
        log_sha = sha256_of(logs[-1]) if logs else None
        with open_records(getattr(args, "db", None)) as records:
            for path in files:
                import_file(records, path, log_sha256=None if path.suffix == ".mcap" else log_sha)
    except (RecordsError, OSError, ValueError) as exc:
        what = f"{path}: " if path is not None and not isinstance(exc, RecordsError) else ""
        print(f"{prog}: warning: {what}not recorded in the records database ({exc}); the files are kept: "
              f"`bench db import` records them later", file=sys.stderr)
        return False
    return True


def not_recorded_exit(prog: str, code: ExitCode) -> ExitCode:
    """The exit code of a command whose files the records database did not take: `NOT_RECORDED` unless `code`
    already says something worse than a success (the warning line above said why)."""
    if code == ExitCode.OK:
        return fail(prog, "finished, but NOT recorded in the records database (see the warning above)",
                    ExitCode.NOT_RECORDED)
    return code
