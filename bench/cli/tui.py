"""`bench tui`: the lab-operator TUI (bench/tui) on hardware (--config), the simulator (--sim) or a
recorded run (--replay LOG, no hardware).

SIGINT, SIGTERM and SIGHUP end the app as quitting does, without asking: any run is
aborted, the table stopped (servos off) and the log closed; exit 3 (130 for a replay).
"""

from __future__ import annotations

import argparse

from bench.cli.common import ExitCode, fail, speed_factor
from bench.errors import BenchError

PROG = "bench tui"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "tui", help="the lab-operator terminal UI (live table, IMU, plan, events, results)",
        description="Interactive operator screen: connect, go to positions, start/pause/resume/abort the plan, "
                    "emergency stop (F12, on every screen). Runs record and solve exactly like `bench run`.")
    parser.add_argument("--config", metavar="FILE", help="bench configuration (see bench.example.toml)")
    parser.add_argument("--sim", action="store_true",
                        help="the simulator: the built-in simulated bench, or --config's plan and [sim]")
    parser.add_argument("--replay", metavar="LOG",
                        help="replay a run log (.mcap) in the TUI: no hardware; p/r pause and resume the playback")
    parser.add_argument("--speed", type=speed_factor, default=1.0, metavar="X",
                        help="with --replay: X times real time (default 1)")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the config's [output] folder)")
    parser.add_argument("--operator", default="", help="who runs it (recorded in the log)")
    parser.set_defaults(func=cmd_tui)


def cmd_tui(args: argparse.Namespace) -> ExitCode:
    # imported when the command runs: Textual and the bench core load only for `bench tui`
    from bench.config.load import default_sim_config, load_config
    from bench.tui import create_app

    if args.replay:
        if args.config or args.sim:
            return fail(PROG, "--replay plays a log without hardware: drop --config/--sim", ExitCode.USAGE)
        return _replay(args)
    if not args.config and not args.sim:
        return fail(PROG, "say --config FILE, --sim or --replay LOG", ExitCode.USAGE)
    try:
        config = load_config(args.config) if args.config else default_sim_config()
        app = create_app(config=config, sim=args.sim, out_dir=args.out, operator=args.operator)
    except (BenchError, OSError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    app.run()
    if app.stopped_by is not None:
        return fail(PROG, f"interrupted ({app.stopped_by}); any run aborted, the table stopped", ExitCode.FAULT)
    return ExitCode.OK


def _replay(args: argparse.Namespace) -> ExitCode:
    # imported when the command runs: `bench` starts without the bench core
    from bench.tui import create_app

    try:
        app = create_app(replay=args.replay, speed=args.speed)
    except (BenchError, OSError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    app.run()
    if app.stopped_by is not None:
        return fail(PROG, f"interrupted ({app.stopped_by})", ExitCode.INTERRUPTED)
    return ExitCode.OK
