"""`bench apply`: compensate a run log's IMU samples with a calibration (logic in `bench.calibration.apply`).

Exit codes: 0 written; 2 usage error, a result or log that cannot be used, an output that
cannot be written.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from bench.calibration.compensation import compensation_of, load_result
from bench.cli.common import ExitCode, fail
from bench.cli.progress import CountProgress
from bench.errors import InputError
from bench.files import check_output, replaced_output

PROG = "bench apply"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "apply",
        description="Decode a run log's IMU samples from its raw CAN frames, compensate them with a result's "
                    "calibration (u = C (y - b)) and write them: a new MCAP (--out FILE.mcap: the raw samples on "
                    "/imu/samples and the compensated ones on /imu/compensated; the log itself is not changed) or "
                    "CSV (--out FILE.csv). --out is never the LOG or RESULT read, nor a run log (unless --force); "
                    "it is replaced only once written in full. Exit codes: 0 written, 2 usage error, unusable "
                    "result or log, or unwritable output.")
    parser.add_argument("result", metavar="RESULT", help="a result file (<run-id>.result.json)")
    parser.add_argument("log", metavar="LOG", help="a run log (.mcap)")
    parser.add_argument("--out", metavar="FILE", required=True, help="output file: .mcap or .csv")
    parser.add_argument("--format", choices=("mcap", "csv"), help="output format (default: from --out's suffix)")
    parser.add_argument("--rate-unit", choices=("deg/s", "rad/s"), default="deg/s",
                        help="unit of the angular rates (default %(default)s)")
    parser.add_argument("--force-unit", choices=("g", "m/s^2"), default="g",
                        help="unit of the specific force (default %(default)s)")
    parser.add_argument("--force", action="store_true",
                        help="replace --out even when it is a run log (never the LOG or RESULT read)")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    parser.set_defaults(func=cmd_apply)


def cmd_apply(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy, python-can, mcap): imported when the command runs, not for its --help
    from bench.calibration.apply import apply_to_log, write_csv, write_mcap
    from bench.log.reader import LogError

    out = Path(args.out)
    fmt = args.format or {".mcap": "mcap", ".csv": "csv"}.get(out.suffix.lower())
    if fmt is None:
        return fail(PROG, f"say --format mcap|csv: {args.out!r} ends in neither .mcap nor .csv", ExitCode.USAGE)
    if _is_mcap(args.result) and not _is_mcap(args.log):
        return fail(PROG, f"RESULT {args.result!r} is a log and LOG {args.log!r} is not: they look swapped "
                    "(bench apply RESULT LOG)", ExitCode.USAGE)
    try:
        compensation = compensation_of(load_result(args.result))
    except InputError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    except OSError as exc:
        return fail(PROG, f"{args.result}: cannot read: {exc.strerror or exc}", ExitCode.USAGE)
    inputs = (args.result, args.log)
    try:
        check_output(out, inputs, force=args.force)   # before reading a large log
    except InputError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    try:
        samples, _log = apply_to_log(compensation, args.log, rate_unit=args.rate_unit, force_unit=args.force_unit)
    except (LogError, InputError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    if not len(samples):
        return fail(PROG, f"{args.log}: no IMU samples to compensate", ExitCode.USAGE)
    # writing a long log takes seconds to minutes: a bar on a terminal (stderr), in percent of the samples written
    bar = CountProgress(100, stream=sys.stderr, quiet=args.quiet)

    def written(done: int, total: int) -> None:
        bar.advance_to(100 * done // max(total, 1))

    try:
        with replaced_output(out, inputs, force=args.force) as temporary:
            if fmt == "csv":
                write_csv(samples, temporary, progress=written)
            else:
                write_mcap(samples, temporary, compensation=compensation, source_log=args.log, progress=written)
    except InputError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    except OSError as exc:
        return fail(PROG, f"{args.out}: cannot write: {exc.strerror or exc}", ExitCode.USAGE)
    finally:
        bar.close()
    if not args.quiet:
        print(f"compensated {len(samples)} samples of {Path(args.log).name} with the calibration of run "
              f"{compensation.run_id or '(unnamed)'}: {out} ({args.rate_unit}, {args.force_unit})")
    return ExitCode.OK


def _is_mcap(path: str) -> bool:
    """Whether `path` is a regular file that opens as an MCAP file (its magic); False when it is not a regular file
    (a FIFO or device would block the read: the loaders refuse those in one line) or cannot be read."""
    from bench.log.mcap.records import MAGIC  # with the log reader: not loaded for --help

    if not os.path.isfile(path):
        return False
    try:
        with open(path, "rb") as f:
            return f.read(len(MAGIC)) == MAGIC
    except OSError:
        return False
