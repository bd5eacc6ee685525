"""`bench table ...` (manual control of a real or simulated table) and `bench sim table` (serve one).

Exit codes of `bench table`: 0 done; 2 usage error, a demand refused by the limits or a
controller that cannot be reached (nothing was sent, as `bench run` says of a table it cannot
reach); 3 the controller reports a fault or e-stop, stops answering, the link fails, the table
is still moving when `stop` gives up waiting, or the command was interrupted (the table is then
commanded to stop).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from typing import Callable, TextIO

import numpy as np

from bench.cli.common import ExitCode, dialect_hint, drive_device, fail
from bench.cli.sim_serving import (
    IDLE_TIMEOUT_S,
    add_idle_timeout_option,
    apply_console_line,
    host_port,
    refuse_remote,
    remote_hosts,
    serve_until_stopped,
)
from bench.config.reader import ConfigError
from bench.config.register_map import load_register_map
from bench.errors import InputError
from bench.model.earth import Site
from bench.model.units import ARCSEC
from drivers.errors import DeviceConfigError, DeviceError, DeviceLimitError, TurntableTimeout
from drivers.transport import MODBUS_SCHEMES
from drivers.turntable import (
    DIALECTS,
    FRAMES,
    AxisLimits,
    AxisStatus,
    TableState,
    Turntable,
    TurntableLimits,
    frame_index,
    open_turntable,
)
from drivers.turntable.modbus_map import RegisterMap

# -- bench table ------------------------------------------------------------------

def register_table(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "table",
        description="Talk to a turntable controller. Exit codes: 0 done, 2 usage error, demand beyond "
                    "the limits or controller not reached (nothing sent), 3 fault, e-stop, no reply, link failure, "
                    "still moving after stop's wait, or interrupted.")
    parser.add_argument("--url", required=True, help="tcp://HOST:PORT, a serial device or pyserial URL, "
                                                      "modbus+tcp://HOST:PORT, modbus+rtu:///dev/ttyX?baud=N, "
                                                      "visa://RESOURCE (acutrol; tcp:// defaults to port 9878)")
    parser.add_argument("--dialect", choices=sorted(DIALECTS), help="controller dialect (implied by modbus+ URLs)")
    parser.add_argument("--timeout-s", type=float, default=1.0, help="reply timeout per attempt (default 1 s)")
    parser.add_argument("--retries", type=int, default=2, help="retries after a timeout or bad reply (default 2)")
    parser.add_argument("--max-rate-dps", type=float, default=100.0,
                        help="largest rate this command may demand on any axis (default 100 deg/s)")
    parser.add_argument("--register-map", metavar="FILE",
                        help="modbus: the controller's register map (a [modbus] table as in a bench configuration; "
                             "default: the map of docs/hardware/modbus.md)")
    parser.add_argument("--no-watchdog", action="store_true",
                        help="modbus: do not arm the controller's watchdog (by default it is fed while the command "
                             "runs and released when it ends)")
    commands = parser.add_subparsers(dest="table_command", metavar="COMMAND", required=True)
    commands.add_parser("status", help="print angles, rates, modes and status; exit 3 on a fault")
    for name, text in (("enable", "servo on"), ("disable", "servo off"), ("reset", "clear latched faults")):
        p = commands.add_parser(name, help=f"{text} (all frames, or the ones named)")
        p.add_argument("frames", nargs="*", choices=[*FRAMES, []], metavar="FRAME",
                       help="outer, middle or inner (default all)")
    goto = commands.add_parser("goto", help="move to absolute angles (deg) and wait until in position")
    for frame in FRAMES:
        goto.add_argument(frame, type=float, help=f"{frame} frame angle, deg")
    goto.add_argument("--rate-dps", type=float, help="move rate (default --max-rate-dps)")
    goto.add_argument("--tolerance-deg", type=float, default=0.001, help="in-position tolerance (default 0.001)")
    goto.add_argument("--settle-s", type=float, default=0.0, help="time in position before done (default 0)")
    goto.add_argument("--wait-s", type=float, default=300.0, help="give up (and stop) after this (default 300)")
    goto.add_argument("--no-wait", action="store_true", help="send the demand and return")
    rate = commands.add_parser("rate", help="rate mode on one frame at a signed rate d(angle)/dt, deg/s")
    rate.add_argument("frame", choices=FRAMES, help="the frame to turn: outer, middle or inner")
    rate.add_argument("rate_dps", type=float, metavar="RATE_DPS",
                      help="signed rate d(angle)/dt, deg/s (positive is the paper's clockwise: docs/hardware/index.md)")
    stop = commands.add_parser("stop", help="controlled stop of every axis (servo stays on); waits until every axis "
                                            "is at rest")
    stop.add_argument("--wait-s", type=float, default=60.0,
                      help="give up waiting for rest after this (exit 3; default 60)")
    stop.add_argument("--no-wait", action="store_true", help="send the stop and return")
    commands.add_parser("abort", help="every servo off at once")
    parser.set_defaults(func=cmd_table)


def format_state(state: TableState) -> str:
    lines = [f"{'frame':<7} {'angle deg':>14} {'rate deg/s':>12}  {'mode':<9} status"]
    for name, axis in zip(FRAMES, state.axes):
        lines.append(f"{name:<7} {axis.angle_deg:>14.6f} {axis.rate_dps:>12.6f}  {axis.mode.value:<9} "
                     f"{axis.status.describe()}")
    fault = state.describe_fault()
    lines.append(f"fault: {fault}" if fault else "fault: none")
    return "\n".join(lines)


class GotoProgress:
    """The angles and rates of a `goto` on one terminal line, redrawn at most 10 times a second."""

    def __init__(self, stream: TextIO, min_interval_s: float = 0.1):
        self.stream, self.min_interval_s = stream, min_interval_s
        self._drawn_at: float | None = None
        self._width = 0

    def __call__(self, state: TableState) -> None:
        now = time.monotonic()
        if self._drawn_at is not None and now - self._drawn_at < self.min_interval_s:
            return
        self._drawn_at = now
        text = "moving: " + "  ".join(f"{name} {axis.angle_deg:10.4f} deg {axis.rate_dps:8.3f} deg/s"
                                      for name, axis in zip(FRAMES, state.axes))
        # pad over what the last draw left on the line
        self.stream.write("\r" + text.ljust(self._width))
        self.stream.flush()
        self._width = len(text)

    def end(self) -> None:
        if self._drawn_at is not None:
            self.stream.write("\r" + " " * self._width + "\r")
            self.stream.flush()


#: an axis whose rate reads within this of zero, and that does not report moving, is at rest (deg/s)
AT_REST_DPS = 0.01


def at_rest(state: TableState) -> bool:
    """Every axis reads no rate (within `AT_REST_DPS`) and none reports moving."""
    return all(abs(axis.rate_dps) <= AT_REST_DPS and not axis.status & AxisStatus.MOVING for axis in state.axes)


def wait_at_rest(table: Turntable, timeout_s: float, poll_s: float = 0.05,
                 on_state: Callable[[TableState], None] | None = None) -> TableState:
    """Poll the table until it is at rest (`at_rest`); `TurntableTimeout` if it is not within `timeout_s`."""
    start = table.clock.now()
    while True:
        state = table.read_state()
        if on_state is not None:
            on_state(state)
        if at_rest(state):
            return state
        if table.clock.now() - start > timeout_s:
            raise TurntableTimeout(f"still moving {timeout_s:g} s after the stop (rates "
                                   f"{', '.join(f'{r:.3f}' for r in state.rates_dps)} deg/s)")
        table.clock.sleep(poll_s)


def _stop_line(args: argparse.Namespace) -> str:
    """The command that stops the table this command talks to."""
    dialect = f" --dialect {args.dialect}" if args.dialect else ""
    return f"bench table --url {args.url}{dialect} stop"


def _run_table_command(table: Turntable, args: argparse.Namespace, answered: list[bool]) -> ExitCode:
    """Run the command; `answered` gets an entry once the controller answered a request (a later timeout or
    unreadable reply is then no sign of a wrong dialect)."""
    command = args.table_command
    if command == "status":
        state = table.read_state()
        print(format_state(state))
        return ExitCode.FAULT if (state.fault or state.estop) else ExitCode.OK
    if command in ("enable", "disable", "reset"):
        frames = args.frames or FRAMES
        {"enable": table.enable, "disable": table.disable, "reset": table.reset_faults}[command](frames)
        answered.append(True)
    elif command == "goto":
        target = (args.outer, args.middle, args.inner)
        table.check_state()
        answered.append(True)
        table.move_to(target, rate_dps=args.rate_dps)
        if not args.no_wait:
            progress = GotoProgress(sys.stderr) if sys.stderr.isatty() else None
            try:
                state = table.wait_in_position(target, tolerance_deg=args.tolerance_deg, settle_s=args.settle_s,
                                               timeout_s=args.wait_s, poll_s=0.05, on_state=progress)
            finally:
                if progress is not None:
                    progress.end()
            print(format_state(state))
            return ExitCode.OK
    elif command == "rate":
        table.check_state()
        answered.append(True)
        table.set_rate(args.frame, args.rate_dps)
        print(format_state(table.read_state()))
        if args.rate_dps != 0.0:
            print(f"the {args.frame} frame keeps turning after this command ends: `{_stop_line(args)}` stops it")
        return ExitCode.OK
    elif command == "stop":
        table.stop()
        answered.append(True)
        if not args.no_wait:
            progress = GotoProgress(sys.stderr) if sys.stderr.isatty() else None
            try:
                state = wait_at_rest(table, args.wait_s, on_state=progress)
            finally:
                if progress is not None:
                    progress.end()
            print(format_state(state))
            return ExitCode.OK
    elif command == "abort":
        table.abort()
        answered.append(True)
    print(format_state(table.read_state()))
    return ExitCode.OK


def cmd_table(args: argparse.Namespace) -> ExitCode:
    prog = f"bench table {args.table_command}"
    try:
        outer, middle, inner = (AxisLimits(max_rate_dps=args.max_rate_dps) for _ in range(3))
        limits = TurntableLimits((outer, middle, inner))
        options: dict[str, object] = {}
        if args.register_map is not None or args.no_watchdog:
            if (args.dialect or ("modbus" if args.url.startswith(MODBUS_SCHEMES) else None)) != "modbus":
                return fail(prog, "--register-map and --no-watchdog are for the modbus dialect only", ExitCode.USAGE)
            register_map = (load_register_map(args.register_map) if args.register_map is not None
                            else RegisterMap.default())
            options["register_map"] = replace(register_map, watchdog_s=0.0) if args.no_watchdog else register_map
        table = open_turntable(args.url, args.dialect, limits=limits, timeout_s=args.timeout_s,
                               retries=args.retries, **options)
    except (DeviceConfigError, ConfigError) as exc:
        return fail(prog, f"{exc}", ExitCode.USAGE)
    answered: list[bool] = []
    dialect = args.dialect or "modbus"       # open_turntable took the dialect from a modbus+ URL when not given
    return drive_device(prog, table, lambda: _run_table_command(table, args, answered), errors=DeviceError,
                        refused=(DeviceLimitError,), refused_at_connect=(DeviceLimitError,),
                        unreachable="cannot reach the controller",
                        make_safe=lambda: _stop_table(table), note_faults=False,
                        hint=lambda exc: "" if answered else dialect_hint(exc, dialect, f"--dialect {dialect}"))


def _stop_table(table: Turntable) -> str:
    """The table's controlled stop (abort if that fails); says what was done (TABLE STATE UNKNOWN if nothing)."""
    return table.safe_stop().describe()


# -- bench sim table --------------------------------------------------------------

FAULT_HELP = """fault console (one command per line on stdin):
  estop | release | limit FRAME | fault FRAME | reset
  timeout N | garbage N | checksum N | late N | exception N [CODE]   (next N replies)
  state | help"""


def register_sim_table(subparsers: argparse._SubParsersAction) -> argparse._SubParsersAction:
    """`bench sim` and its `table`; returns the `sim` subcommands for the others (`bench sim rig`)."""
    sim = subparsers.add_parser("sim")
    kinds = sim.add_subparsers(dest="sim_command", metavar="DEVICE", required=True)
    table = kinds.add_parser(
        "table", help="serve the simulated turntable in a controller dialect until Ctrl-C, SIGTERM or SIGHUP",
        description="Serve the simulated turntable (with black-box pointing errors) in a controller dialect. "
                    "Prints where it listens, then runs until Ctrl-C, SIGTERM or SIGHUP. Faults are injected by typing "
                    "commands on stdin.\n\n" + FAULT_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    table.add_argument("--dialect", required=True, choices=sorted(DIALECTS),
                       help="the controller dialect to serve (docs/hardware/: acutrol.md, scpi.md, mn.md, modbus.md)")
    table.add_argument("--acl-framing", choices=("tcp", "gpib"), default="tcp",
                       help="acutrol: 'tcp' answers every message with a framed response (error code, length; the "
                            "controller's TCP port and RS-232), 'gpib' answers queries only, LF terminated, as on "
                            "IEEE-488 (default tcp)")
    table.add_argument("--listen", action="append", required=True, metavar="WHERE",
                       help="tcp://127.0.0.1:PORT (acutrol, scpi, mn), modbus+tcp://127.0.0.1:PORT (modbus) or pty "
                            "(RTU for modbus); repeatable; port 0 picks a free port; a host other than "
                            "127.0.0.1, ::1 or localhost needs --allow-remote")
    table.add_argument("--allow-remote", action="store_true",
                       help="allow a --listen address beyond loopback (e.g. 0.0.0.0): anyone who can reach this "
                            "machine can then command the simulated table")
    add_idle_timeout_option(table)
    table.add_argument("--latitude", type=float, default=30.27, help="site latitude, deg (default 30.27)")
    table.add_argument("--black-box-arcsec", type=float, default=0.0,
                       help="RMS of the nine black-box pointing-error angles (default 0: ideal table)")
    table.add_argument("--seed", type=int, default=0, help="seed of the black-box angles (default 0)")
    table.set_defaults(func=cmd_sim_table)
    return kinds


def apply_fault_command(controller, line: str) -> str:
    """Execute one fault-console line on the simulated controller; returns what to print."""
    def table_command(cmd: str, rest: list[str]) -> str | None:
        if cmd == "estop":
            controller.trip_estop()
        elif cmd == "release":
            controller.release_estop()
        elif cmd in ("limit", "fault"):
            frame = frame_index(rest[0]) if rest else 0
            (controller.trip_limit if cmd == "limit" else controller.trip_fault)(frame)
        elif cmd == "reset":
            for k in range(3):
                controller.reset(k)
        else:
            return None
        return ""

    return apply_console_line(line, controller.faults, table_command, FAULT_HELP,
                              lambda: format_state(controller.state()))


def start_listener(controller, dialect: str, where: str, closers: list, register_map=None, framing: str = "tcp",
                   idle_timeout_s: float = IDLE_TIMEOUT_S) -> str:
    """Start one listener; returns the address a client uses. `register_map`: the Modbus simulator's
    (None: the default map); `framing`: the acutrol simulator's ('tcp' framed responses, 'gpib' query answers);
    `idle_timeout_s`: a TCP connection silent that long is closed."""
    if dialect == "modbus":
        # heavy (scipy, pymodbus): the simulators load only when one is served
        from bench.sim.modbus_server import ModbusSimServer

        modbus = ModbusSimServer(controller, register_map, idle_timeout_s=idle_timeout_s)
        closers.append(modbus.close)
        if where == "pty":
            return f"modbus+rtu://{modbus.start_rtu_pty()}"
        host, port = host_port(where, "modbus+tcp", "the modbus simulator listens on modbus+tcp://HOST:PORT or pty")
        host, port = modbus.start_tcp(host, port)
        return f"modbus+tcp://{host}:{port}"
    # heavy (scipy): the simulators load only when one is served
    from bench.sim.serve import Handler, LineServer

    handler: Handler
    if dialect == "acutrol":
        # heavy (scipy): the simulators load only when one is served
        from bench.sim.acutrol_server import AcutrolSimHandler

        handler = AcutrolSimHandler(controller, framing)
    elif dialect == "scpi":
        # heavy (scipy): the simulators load only when one is served
        from bench.sim.scpi_server import ScpiSimHandler

        handler = ScpiSimHandler(controller)
    else:
        # heavy (scipy): the simulators load only when one is served
        from bench.sim.mn_server import MnSimHandler

        handler = MnSimHandler(controller)
    server = LineServer(handler, idle_timeout_s=idle_timeout_s)
    closers.append(server.close)
    if where == "pty":
        return server.open_pty()
    host, port = host_port(where, "tcp", f"the {dialect} simulator listens on tcp://HOST:PORT or pty")
    host, port = server.listen_tcp(host, port)
    return f"tcp://{host}:{port}"


def cmd_sim_table(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy): the simulators load only when one is served
    from bench.sim.controller import SimController
    from bench.sim.table import SimTable

    try:
        site = Site(args.latitude)
    except InputError as exc:
        return fail("bench sim table", f"{exc}", ExitCode.USAGE)
    remote = remote_hosts(args.listen)
    if remote and not args.allow_remote:       # checked before anything binds or stdin is read
        return refuse_remote("bench sim table", remote)
    black_box = np.random.default_rng(args.seed).normal(0.0, args.black_box_arcsec * ARCSEC, (3, 3))
    controller = SimController(SimTable(site, black_box_rad=black_box))
    closers: list = []
    return serve_until_stopped("bench sim table", "table", args.dialect,
                               lambda where: start_listener(controller, args.dialect, where, closers,
                                                            framing=args.acl_framing,
                                                            idle_timeout_s=args.idle_timeout_s), args.listen, remote,
                               lambda line: apply_fault_command(controller, line), closers)
