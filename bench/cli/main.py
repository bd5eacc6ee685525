"""The `bench` command line: one module per command in this package; this file wires them."""

from __future__ import annotations

import argparse
import sys

from bench import __version__
from bench.cli import check_table, evaluate, replay, run, schedules, solve, table, tui
from bench.cli.common import ExitCode
from bench.errors import BenchError
from drivers.errors import ImuError, TurntableConfigError, TurntableError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bench", description="IMU calibration on a three-axis turntable. Exit codes (every command): 0 done, "
                                  "1 a schedule file failed validation, 2 usage or configuration error (nothing "
                                  "moved), 3 hardware fault or aborted (table stopped), 4 finished but a quality "
                                  "check failed, 5 simulated truth missed (check-table), 130 interrupted (replay).")
    parser.add_argument("--version", action="version", version=f"turntable-bench {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    evaluate.register(sub)
    run.register(sub)
    tui.register(sub)
    replay.register(sub)
    solve.register(sub)
    schedules.register(sub)
    table.register_table(sub)
    table.register_sim(sub)
    check_table.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        print("bench: interrupted", file=sys.stderr)
        return ExitCode.INTERRUPTED
    except TurntableConfigError as exc:
        # a URL, dialect, option or limit the driver refused before sending anything: nothing moved
        print(f"bench {args.command}: {exc}", file=sys.stderr)
        return ExitCode.USAGE
    except (TurntableError, ImuError) as exc:
        # a command that moves hardware handles these itself (and stops the table); this is the backstop
        print(f"bench {args.command}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return ExitCode.FAULT
    except BenchError as exc:
        print(f"bench {args.command}: {exc}", file=sys.stderr)
        return ExitCode.USAGE


if __name__ == "__main__":
    sys.exit(main())
