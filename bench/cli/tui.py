"""`bench tui`: the lab-operator TUI (bench/tui) on hardware (--config), the simulator (--sim) or a
recorded run (--replay LOG, no hardware).

SIGINT, SIGTERM and SIGHUP end the app as quitting does, without asking: any run is
aborted, the table stopped (servos off) and the log closed; exit 3 (130 for a replay).
Quitting says where the last run's log is (one line) and exits with that run's code
(`exit_status`): 0 done (or no run), 4 quality check failed or not solvable, 3 aborted or
failed with the table stopped (the line adds the `bench run --resume LOG` that continues it);
a session that moved the table by hand also names its logs of manual moves (`bench.tui.manual_log`).
It needs a terminal: without one (stdin or stdout not a TTY) it refuses to start (exit 2) instead of
drawing into nothing.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from bench.cli.common import ExitCode, fail, speed_factor
from bench.cli.equipment import run_lab_record
from bench.errors import BenchError
from bench.tui import create_app

if TYPE_CHECKING:
    from bench.tui.app import BenchApp

PROG = "bench tui"
NO_TERMINAL = "needs a terminal (stdin and stdout must be one); for an unattended run use `bench run`"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "tui",
        description="Interactive operator screen: connect, go to positions, start/pause/resume/abort the plan, "
                    "emergency stop (F12, on every screen). Runs record and solve exactly like `bench run`.")
    parser.add_argument("--config", metavar="FILE", help="bench configuration (see bench.example.toml)")
    parser.add_argument("--sim", action="store_true",
                        help="the simulator: the built-in simulated bench, or --config's plan and [sim]")
    parser.add_argument("--replay", metavar="LOG",
                        help="replay a run log (.mcap) in the TUI: no hardware; p/r pause and resume the playback")
    parser.add_argument("--speed", type=speed_factor, default=None, metavar="X",
                        help="with --replay only: X times real time (default 1)")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the config's [output] folder)")
    parser.add_argument("--operator", default="", help="who runs it (recorded in the log)")
    parser.set_defaults(func=cmd_tui)


def cmd_tui(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy, python-can): imported when the command runs, not for its --help
    from bench.config.load import default_sim_config, load_config

    if args.replay:
        if args.config or args.sim:
            return fail(PROG, "--replay plays a log without hardware: drop --config/--sim", ExitCode.USAGE)
        return _replay(args)
    if not args.config and not args.sim:
        return fail(PROG, "say --config FILE, --sim or --replay LOG", ExitCode.USAGE)
    if args.speed is not None:
        return fail(PROG, "--speed is for --replay LOG only: a live run, also on the simulator, runs in real time",
                    ExitCode.USAGE)
    try:
        config = load_config(args.config) if args.config else default_sim_config()
    except (BenchError, OSError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    # the configured equipment is checked against the register as `bench run` checks it, once, before the app
    # opens anything (refused: exit 2); the session's logs name the configured tags
    checked = run_lab_record(args, config, PROG)
    if isinstance(checked, ExitCode):
        return checked
    try:
        app = create_app(config=config, sim=args.sim, out_dir=args.out, operator=args.operator)
    except (BenchError, OSError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    if not has_terminal():
        return fail(PROG, NO_TERMINAL, ExitCode.USAGE)
    app.run()
    return exit_status(app)


def has_terminal() -> bool:
    """stdin and stdout are a terminal (without one the app would spin drawing into nothing)."""
    try:
        return sys.stdin is not None and sys.stdout is not None and sys.stdin.isatty() and sys.stdout.isatty()
    except (OSError, ValueError):           # a closed stream
        return False


def exit_status(app: BenchApp) -> ExitCode:
    """What `bench tui` says and returns once the live app has ended: the last run's log (one line) and
    its exit code (`ExitCode`: 0 done or no run, 4 quality check failed or not solvable, 3 aborted or
    failed with the table stopped, 3 after a stop signal)."""
    # heavy (scipy, python-can, mcap, matplotlib): imported when the command runs, not for its --help
    from bench.tui.session import EndKind

    session = app.session
    manual = getattr(session, "manual", None)           # (a replay session has no logs of manual moves)
    if manual is not None and manual.paths:
        cut = manual.failures
        _say(f"{PROG}: manual moves logged to "
             + ", ".join(f"{path}" + (f" (cut short: {cut[path]})" if path in cut else "") for path in manual.paths))
    end = getattr(session, "last_end", None)
    log = f". Log: {end.log_path}" if end is not None and end.log_path is not None else ""
    if end is not None and end.resume:      # an aborted or failed run: how to continue it, as `bench run` says
        log += f" (continue with: {end.resume})"
    if app.stopped_by is not None:
        return fail(PROG, f"interrupted ({app.stopped_by}); any run aborted, the table stopped{log}", ExitCode.FAULT)
    if session.running:                     # the run did not end within the session's bounded wait
        return fail(PROG, "the run had not ended when the app closed; the table was commanded to stop",
                    ExitCode.FAULT)
    if end is None:
        return ExitCode.OK
    if end.kind == EndKind.DONE:
        _say(f"{PROG}: last run done{log}")
        return ExitCode.OK
    if end.kind in (EndKind.QUALITY, EndKind.UNSOLVED):
        return fail(PROG, f"last run finished: {end.reason}{log}", ExitCode.QUALITY)
    return fail(PROG, f"last run {end.kind} ({end.reason}); the table was stopped{log}", ExitCode.FAULT)


def _say(line: str) -> None:
    """A line on stdout; a closed stdout loses it (the exit code still says how the session ended)."""
    try:
        print(line, flush=True)
    except OSError:
        pass


def _replay(args: argparse.Namespace) -> ExitCode:
    try:
        app = create_app(replay=args.replay, speed=args.speed if args.speed is not None else 1.0)
    except (BenchError, OSError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    if not has_terminal():
        return fail(PROG, NO_TERMINAL, ExitCode.USAGE)
    app.run()
    if app.stopped_by is not None:
        return fail(PROG, f"interrupted ({app.stopped_by})", ExitCode.INTERRUPTED)
    return ExitCode.OK
