"""`bench replay LOG.mcap`: play a run log back through the live run's progress output, without hardware.

Exit codes: 0 replayed (a damaged log replays what is readable; the damage is printed
first, on stderr); 2 the file cannot be read as a run log (one line); 130 stopped by
Ctrl-C, SIGTERM or SIGHUP (the summary still says how far it got), also when started
with SIGINT ignored (`bench replay LOG &` in a script).
"""

from __future__ import annotations

import argparse
import sys
import threading

from bench.cli.common import ExitCode, fail, speed_factor, stop_signals
from bench.cli.progress import ProgressPrinter
from bench.log.events import Event, Fault

PROG = "bench replay"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "replay",
        description="Play a run log's events, table states, CAN frames and IMU samples (decoded from the raw "
                    "frames with the layout recorded in the log) back through the listeners a live run uses. "
                    "A damaged log replays what is readable. Exit codes: 0 replayed, 2 not a readable run log, "
                    "130 interrupted.")
    parser.add_argument("log", metavar="LOG", help="the run's .mcap file")
    parser.add_argument("--speed", type=speed_factor, metavar="X",
                        help="X times real time (default: as fast as possible)")
    parser.add_argument("--quiet", action="store_true", help="no progress output (faults and the summary only)")
    parser.set_defaults(func=cmd_replay)


def cmd_replay(args: argparse.Namespace) -> ExitCode:
    stop = threading.Event()
    # from the start (reading a large log takes a while): SIGINT even when the shell ignored it, SIGTERM, SIGHUP
    with stop_signals(lambda _signum: stop.set()):
        return _replay(args, stop)


def _replay(args: argparse.Namespace, stop: threading.Event) -> ExitCode:
    # heavy (scipy, python-can, mcap): imported when the command runs, not for its --help
    from bench.log.reader import LogError, read_log
    from bench.log.replay import replay
    from bench.log.run_info import is_manual_log, steps_from_log

    try:
        log = read_log(args.log)
    except LogError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    # what the walk found is said now; damage in the frames' chunks after the replay, which reads them (reading
    # `log.scan()` here would read every chunk once more first)
    told = list(log.damage_found)
    for line in told:
        print(f"bench replay: damaged log: {line}", file=sys.stderr)
    try:
        steps = steps_from_log(log)
    except LogError as exc:
        why = f"{log.path}: a log of manual moves (bench tui), no plan" if is_manual_log(log) else str(exc)
        print(f"bench replay: {why}; progress without step names", file=sys.stderr)
        steps = ()
    progress = TolerantProgress(steps, quiet=args.quiet,
                                simulated=log.metadata.get("run", {}).get("mode") == "simulator")
    if not args.quiet:   # the frames as recorded: the replay reads them (once), then says what it found
        print(log.summary(read_frames=False), file=sys.stderr, flush=True)
    stats = replay(log, [progress], speed=args.speed, stop=stop)
    for line in log.scan().damage[len(told):]:
        print(f"bench replay: damaged log: {line}", file=sys.stderr)
    for note in stats.notes:
        print(f"bench replay: {note}", file=sys.stderr)
    print(stats.summary())
    return ExitCode.INTERRUPTED if stats.stopped else ExitCode.OK


class TolerantProgress(ProgressPrinter):
    """The live progress printer; a step index the recorded plan lacks (damaged metadata) becomes a plain line."""

    def on_event(self, event: Event) -> None:
        if event.step_index is not None and not 0 <= event.step_index < len(self.steps):
            if isinstance(event, Fault) or not self.quiet:
                self._print(f"{event.kind}: {event.message}")
            return
        super().on_event(event)
