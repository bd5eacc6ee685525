"""`bench solve --archive DIR...`: re-solve every run log below the folders on Dask (logic in `bench.jobs.archive`).

Each log is solved as `bench solve LOG` solves it, its result written next to it (or under
`--out` at the same relative place) and recorded in the records database; a log that
cannot be solved is reported and the others go on. A resumed run's earlier logs are solved
with its last log, which names them, not on their own. Resumable: a log this software
version already solved is skipped (`--redo` solves it again), known by its run id and the
SHA-256 of its content wherever it lies now. Two logs of one run that would write the same
outputs (a backup copy next to the log) are named and solved into folders of their own.
Exit codes: 0 every log solved and recorded; 2 usage error, no log found, Dask missing or the
scheduler unreachable; 4 some logs failed, failed a quality check, or their results were not
recorded (listed).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from bench import __version__
from bench.cli.common import ExitCode, add_scheduler_arguments, fail
from bench.cli.progress import CountProgress
from bench.errors import BenchError
from bench.parallel import SchedulerError, check_scheduler, describe

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
    # heavy (scipy, python-can, mcap, matplotlib, SQLAlchemy): imported when the command runs, not for its --help
    from bench.jobs.archive import (
        ArchiveItem,
        distinct_outputs,
        find_logs,
        log_run_ids,
        output_folder,
        resumed_parts,
        same_run_logs,
        solve_archive,
    )
    from bench.records.ingest import import_file, sha256_of
    from bench.records.store import RecordsError, open_records

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
    record_error: str | None = None      # the database cannot be used: every result is one not recorded
    solved_keys: set[tuple[str, str]] = set()
    if not args.no_db:
        try:
            records = open_records(args.db)
            solved_keys = set() if args.redo else records.solved_keys(__version__)
        except RecordsError as exc:
            record_error = str(exc)
            print(f"{PROG}: warning: records database not used ({exc}): nothing is recorded and no log is skipped",
                  file=sys.stderr)
            records = None
    # a resumed run's earlier logs are solved with its last log, which names them, not on their own
    parts = resumed_parts(logs)
    candidates = [log for log in logs if log not in parts]
    # the content's hash, not the path: a log moved into an archive is still the log solved (and the key a
    # result is recorded with); a file that cannot be read is left to its solve to report
    shas: dict[Path, str] = {}
    for log in candidates if records is not None else ():
        try:
            shas[log] = sha256_of(log)
        except OSError:
            pass
    solved_shas = {sha for _, sha in solved_keys}
    maybe_done = [log for log in candidates if shas.get(log) in solved_shas]
    run_ids = log_run_ids(maybe_done) if maybe_done else {}
    skipped = {log for log in maybe_done if (run_ids.get(log), shas[log]) in solved_keys}
    todo = [log for log in candidates if log not in skipped]
    # relative to this process's folder, not a (remote) worker's
    out = Path(args.out).absolute() if args.out else None
    roots = [Path(d).absolute() for d in args.archive]
    tasks = [(log, output_folder(log, roots, out)) for log in todo]
    copies = same_run_logs(tasks)
    tasks = distinct_outputs(tasks, copies)
    if not args.quiet:
        for earlier, later in sorted(parts.items()):
            print(f"{earlier}: an earlier log of a resumed run, solved with {later.name}")
        for group in copies:
            print(f"{', '.join(str(log) for log in group)}: {len(group)} logs of one run (a copy?), each solved "
                  f"into a folder of its own")
        already = len(skipped)
        print(f"{len(logs)} log(s), {already} already solved by {__version__} (skipped), "
              f"{len(parts)} earlier log(s) of resumed runs, {len(todo)} to solve on "
              f"{describe(args.scheduler, args.workers)}")
    failed: list[ArchiveItem] = []
    not_recorded: list[str] = []
    start = time.monotonic()
    progress = CountProgress(len(tasks), quiet=args.quiet)

    def on_done(item: ArchiveItem) -> None:
        if not item.ok:
            failed.append(item)
            progress.item(f"FAILED {item.log}: {item.error}", problem=True)
            return
        if item.failures:
            failed.append(item)
        progress.item(f"{item.result}" + (f"  (failed checks: {'; '.join(item.failures)})" if item.failures else ""))
        if not args.no_db and item.result is not None:
            reason = record(item)
            if reason is not None:
                not_recorded.append(item.result)
                progress.note(f"{PROG}: {item.result}: NOT recorded ({reason})")

    def record(item: ArchiveItem) -> str | None:
        """Record the item's result and log; why not, if not."""
        nonlocal records, record_error
        if records is None:
            return record_error
        try:
            log_sha = shas.get(Path(item.log)) or sha256_of(item.log)
            import_file(records, str(item.result), log_sha256=log_sha)
            import_file(records, item.log)
        except RecordsError as exc:     # the database failed: the results from here on are not recorded either
            record_error = str(exc)
            records.close()
            records = None
            return record_error
        except (BenchError, OSError, ValueError, ArithmeticError, RecursionError) as exc:
            return exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        return None

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
          f"check; {len(skipped)} skipped, {len(parts)} solved with their resumed run"
          + (f"; {len(not_recorded)} result(s) NOT recorded" if not_recorded else ""))
    if failed or not_recorded:
        what = [f"{len(failed)} log(s) failed or failed a quality check" if failed else "",
                f"{len(not_recorded)} result(s) not recorded in the records database (`bench db import` them)"
                if not_recorded else ""]
        return fail(PROG, "; ".join(w for w in what if w) + " (listed above)", ExitCode.QUALITY)
    return ExitCode.OK
