"""`bench export-can LOG --out FILE`: a run log's raw CAN frames in a format CAN tools read.

The format comes from the extension (`.asc`, `.blf`, `.log` candump, `.csv`; python-can's
writers); times are wall-clock, dated by the log's `run.started_utc` (`bench.log.can_export`).
Exit codes: 0 written; 2 a file that cannot be read as a run log, an unknown
format, an empty time range, CAN FD frames for `.csv`, or an output that cannot be written (one line).
"""

from __future__ import annotations

import argparse
import sys

from bench.cli.common import ExitCode, fail, number_type
from bench.errors import InputError
from bench.files import check_output, replaced_output

PROG = "bench export-can"


_seconds = number_type("a number of seconds >= 0", lambda value: value >= 0)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "export-can",
        description="Write the raw CAN frames recorded on /can/raw in the format the output's extension names: "
                    ".asc (Vector ASC), .blf (Vector BLF), .log (candump -L) or .csv (python-can CSV, which has "
                    "no CAN FD flag: CAN FD frames are refused). Times are wall-clock: the recorded run-clock "
                    "times moved so that the run's start is the log's run.started_utc (the BLF and ASC headers "
                    "carry that date). Exit codes: 0 written, 2 unreadable log, unknown format, empty range, "
                    "CAN FD frames for .csv or unwritable output.")
    parser.add_argument("log", metavar="LOG", help="the run's .mcap file")
    parser.add_argument("--out", required=True, metavar="FILE", help="the file to write (.asc, .blf, .log, .csv)")
    parser.add_argument("--from-s", type=_seconds, metavar="S",
                        help="first frame to write, seconds after the log's first frame (default: the first)")
    parser.add_argument("--to-s", type=_seconds, metavar="S",
                        help="last frame to write, seconds after the log's first frame (default: the last)")
    parser.add_argument("--force", action="store_true", help="replace --out even when it is a run log (never LOG)")
    parser.set_defaults(func=cmd_export_can)


def cmd_export_can(args: argparse.Namespace) -> ExitCode:
    # heavy (python-can, mcap): imported when the command runs, not for its --help
    from bench.log.can_export import MAX_FRAME_TIME_S, CanExportError, can_format, export_can, started_unix_s
    from bench.log.reader import LogError, read_log

    try:
        can_format(args.out)              # before reading a large log
        check_output(args.out, (args.log,), force=args.force)
        log = read_log(args.log)
        for line in log.scan().damage:
            print(f"{PROG}: damaged log: {line}", file=sys.stderr)
        if started_unix_s(log) is None:
            print(f"{PROG}: the log records no run.started_utc: times stay on the run clock (dated 1970)",
                  file=sys.stderr)
        with replaced_output(args.out, (args.log,), force=args.force) as temporary:
            count, left_out = export_can(log, temporary, args.from_s, args.to_s)
    except (LogError, CanExportError, InputError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    except OSError as exc:
        return fail(PROG, f"{args.out}: cannot write: {exc.strerror or exc}", ExitCode.USAGE)
    if left_out:
        print(f"{PROG}: {left_out} frames whose recorded time is no time (NaN, negative or past "
              f"{MAX_FRAME_TIME_S:g} s) left out", file=sys.stderr)
    print(f"wrote {count} CAN frames to {args.out}")
    return ExitCode.OK
