"""`bench solve --archive DIR...`: re-solve every run log below the folders on Dask (logic in `bench.solve.archive`).

Each log is solved as `bench solve LOG` solves it, its result written next to it (or under
`--out` at the same relative place) and recorded in the records database; a log that
cannot be solved is reported and the others go on. A resumed run's earlier logs are solved
with its last log, which names them, not on their own. Resumable: a log whose run already has
a result of this software version in the database is skipped (`--redo` solves it again).
Exit codes: 0 every log solved; 2 usage error, no log found, Dask missing or the
scheduler unreachable; 4 some logs failed or failed a quality check (listed).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from bench.cli.common import ExitCode, add_scheduler_arguments, fail
from bench.cli.progress import CountProgress

PROG = "bench solve"


def add_archive_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("re-solving an archive (Dask distributed; pip install -e '.[archive]')")
    group.add_argument("--archive", metavar="DIR", nargs="+", action="extend",
                       help="re-solve every *.mcap below these folders, each log on its own, in parallel")
    add_scheduler_arguments(group, default="local", what="the logs are solved", note="with --archive: ")
    group.add_argument("--html", action="store_true",
                       help="with --archive: also write each HTML report (default: Markdown only, as --no-html)")
    group.add_argument("--redo", action="store_true",
                       help="with --archive: solve also the logs already solved by this software version")


def cmd_archive(args: argparse.Namespace) -> ExitCode:
    # imported when the command runs: `bench` starts without the bench core or SQLAlchemy
    from bench import __version__
    from bench.parallel import SchedulerError, check_scheduler, describe
    from bench.records.ingest import import_file
    from bench.records.store import RecordsError, open_records
    from bench.solve.archive import ArchiveItem, find_logs, output_folder, resumed_parts, solve_archive

    if args.logs:
        return fail(PROG, "give logs or --archive DIR..., not both", ExitCode.USAGE)
    others = [o for o, on in (("--compare", args.compare), ("--positions", args.positions),
                              ("--rotations", args.rotations), ("--against", args.against), ("--json", args.json))
              if on]
    if others:
        return fail(PROG, f"--archive re-solves whole logs: drop {', '.join(others)}", ExitCode.USAGE)
    try:
        check_scheduler(args.scheduler, args.workers)
    except SchedulerError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    missing = [d for d in args.archive if not Path(d).exists()]
    if missing:
        return fail(PROG, f"{missing[0]}: no such folder", ExitCode.USAGE)
    logs = find_logs(args.archive)
    if not logs:
        return fail(PROG, f"no run log (*.mcap) below {', '.join(args.archive)}", ExitCode.USAGE)
    records = None
    skip: set[str] = set()
    if not args.no_db:
        try:
            records = open_records(args.db)
            skip = set() if args.redo else records.logs_solved_by(__version__)
        except RecordsError as exc:
            print(f"{PROG}: warning: records database not used ({exc}): nothing is recorded and no log is skipped",
                  file=sys.stderr)
            records = None
    # a resumed run's earlier logs are solved with its last log, which names them, not on their own
    parts = resumed_parts(logs)
    todo = [log for log in logs if str(log) not in skip and log not in parts]
    out = Path(args.out) if args.out else None
    roots = [Path(d) for d in args.archive]
    tasks = [(log, output_folder(log, roots, out)) for log in todo]
    if not args.quiet:
        for earlier, later in sorted(parts.items()):
            print(f"{earlier}: an earlier log of a resumed run, solved with {later.name}")
        already = sum(1 for log in logs if str(log) in skip and log not in parts)
        print(f"{len(logs)} log(s), {already} already solved by {__version__} (skipped), "
              f"{len(parts)} earlier log(s) of resumed runs, {len(todo)} to solve on "
              f"{describe(args.scheduler, args.workers)}")
    recording = records
    failed: list[ArchiveItem] = []
    start = time.monotonic()
    progress = CountProgress(len(tasks), quiet=args.quiet)

    def on_done(item: ArchiveItem) -> None:
        nonlocal recording
        if not item.ok:
            failed.append(item)
            progress.item(f"FAILED {item.log}: {item.error}", problem=True)
            return
        if item.failures:
            failed.append(item)
        progress.item(f"{item.result}" + (f"  (failed checks: {'; '.join(item.failures)})" if item.failures else ""))
        if recording is not None and item.result is not None:
            try:
                import_file(recording, item.result)
                import_file(recording, item.log)
            except RecordsError as exc:
                progress.note(f"{PROG}: warning: not recorded ({exc}); the results are kept: `bench db import` them "
                              "later")
                recording = None
            except (OSError, ValueError) as exc:
                progress.note(f"{PROG}: warning: {item.log}: not recorded ({exc})")

    try:
        solve_archive(tasks, scheduler=args.scheduler, workers=args.workers, html=args.html, on_done=on_done)
    except SchedulerError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    finally:
        progress.close()
        if records is not None:
            records.close()
    solved = len(tasks) - sum(1 for i in failed if not i.ok)
    print(f"solved {solved} of {len(tasks)} log(s) in {time.monotonic() - start:.1f} s; "
          f"{sum(1 for i in failed if not i.ok)} failed, {sum(1 for i in failed if i.ok)} with a failed quality "
          f"check; {len(logs) - len(todo) - len(parts)} skipped, {len(parts)} solved with their resumed run")
    if failed:
        return fail(PROG, f"{len(failed)} log(s) failed or failed a quality check (listed above)", ExitCode.QUALITY)
    return ExitCode.OK
