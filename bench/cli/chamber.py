"""`bench chamber ...` (drive a real or simulated thermal chamber by hand) and `bench sim chamber` (serve one).

Exit codes of `bench chamber`: 0 done; 2 usage or configuration error, or a demand refused
by the limits (nothing was sent); 3 the chamber reports an alarm, refuses, does not answer,
the link fails, or the command was interrupted (the chamber is then made safe: sent to the
configuration's safe setpoint, else stopped).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from bench.cli.common import ExitCode, fail, raise_interrupted, stop_signals
from bench.cli.table import _host_port, _remote_hosts
from bench.config.chamber import ChamberConfig
from bench.config.load import ConfigError, load_config
from bench.config.register_map import load_chamber_register_map
from bench.errors import InputError
from drivers.chamber import ALARM_NAMES, DIALECTS, Chamber, ChamberLimits, ChamberState, open_chamber
from drivers.errors import ChamberConfigError, ChamberError, ChamberLimitError
from drivers.transport import MODBUS_SCHEMES

# -- bench chamber ----------------------------------------------------------------------

def register_chamber(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "chamber", help="manual control of a thermal chamber: status, set, run, stop, clear",
        description="Talk to a thermal chamber controller (drivers/CHAMBER.md), given by --config's [chamber] "
                    "or by --url. Exit codes: 0 done, 2 usage error or demand beyond the limits (nothing sent), "
                    "3 alarm, refusal, no reply, link failure or interrupted (the chamber is then made safe).")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--config", metavar="FILE", help="a bench configuration with a [chamber] section")
    where.add_argument("--url", help="tcp://HOST:PORT, a serial device or pyserial URL (ascii), "
                                     "modbus+tcp://HOST:PORT, modbus+rtu:///dev/ttyX?baud=N (modbus)")
    parser.add_argument("--dialect", choices=sorted(DIALECTS), help="with --url: ascii or modbus (implied by "
                                                                     "modbus+ URLs)")
    parser.add_argument("--timeout-s", type=float, default=1.0, help="with --url: reply timeout per attempt "
                                                                     "(default 1 s)")
    parser.add_argument("--retries", type=int, default=2, help="with --url: retries after a timeout or bad reply "
                                                               "(default 2)")
    parser.add_argument("--register-map", metavar="FILE",
                        help="with --url, modbus: the controller's register map (a [modbus] table; default: the "
                             "map of drivers/CHAMBER.md)")
    default = ChamberLimits()
    parser.add_argument("--min-setpoint-c", type=float, default=default.min_setpoint_c,
                        help=f"with --url: lowest setpoint this command may send (default {default.min_setpoint_c:g})")
    parser.add_argument("--max-setpoint-c", type=float, default=default.max_setpoint_c,
                        help=f"with --url: highest setpoint (default {default.max_setpoint_c:g})")
    parser.add_argument("--max-ramp-c-per-min", type=float, default=default.max_ramp_c_per_min,
                        help=f"with --url: largest ramp rate, degC/min (default {default.max_ramp_c_per_min:g})")
    commands = parser.add_subparsers(dest="chamber_command", metavar="COMMAND", required=True)
    commands.add_parser("status", help="print temperature, setpoint, ramp, mode and alarms; exit 3 on an alarm")
    setter = commands.add_parser("set", help="set the setpoint (and ramp rate); --run also starts control")
    setter.add_argument("temperature_c", type=float, metavar="TEMP_C", help="setpoint, degC")
    setter.add_argument("--ramp-c-per-min", type=float, metavar="R",
                        help="ramp rate toward it, degC/min (0: step; default: leave the controller's)")
    setter.add_argument("--run", action="store_true", help="start temperature control after setting")
    commands.add_parser("run", help="start temperature control toward the setpoint")
    commands.add_parser("stop", help="stop temperature control (heating and cooling off)")
    commands.add_parser("clear", help="acknowledge latched alarms")
    parser.set_defaults(func=cmd_chamber)


def format_chamber_state(state: ChamberState) -> str:
    ramp = "none (no ramp register)" if state.ramp_c_per_min is None else (
        "0 (steps)" if state.ramp_c_per_min == 0 else f"{state.ramp_c_per_min:g} degC/min")
    return "\n".join([f"temperature  {state.temperature_c:.1f} degC", f"setpoint     {state.setpoint_c:.1f} degC",
                      f"ramp         {ramp}", f"mode         {'running' if state.running else 'stopped'}",
                      f"alarms       {state.describe_alarms() or 'none'}"])


def _chamber_config(args: argparse.Namespace) -> ChamberConfig:
    if args.config is not None:
        config = load_config(args.config).chamber
        if config is None:
            raise InputError(f"{args.config} has no [chamber] section")
        if config.is_sim:
            raise InputError(f"{args.config}: [chamber] url is \"sim\" (served by the run itself); to drive a "
                             "simulated chamber by hand, serve one with `bench sim chamber` and give its --url")
        return config
    dialect = args.dialect or ("modbus" if args.url.startswith(MODBUS_SCHEMES) else None)
    if dialect is None:
        raise ChamberConfigError(f"say which dialect {args.url!r} speaks (--dialect ascii or modbus)")
    if args.register_map is not None and dialect != "modbus":
        raise ChamberConfigError("--register-map is for the modbus dialect only")
    register_map = load_chamber_register_map(args.register_map) if args.register_map is not None else None
    limits = ChamberLimits(args.min_setpoint_c, args.max_setpoint_c, args.max_ramp_c_per_min)
    return ChamberConfig(args.url, dialect, args.timeout_s, args.retries, 1.0, limits, None, register_map)


def _run_chamber_command(chamber: Chamber, args: argparse.Namespace) -> ExitCode:
    command = args.chamber_command
    if command == "status":
        state = chamber.read_state()
        print(format_chamber_state(state))
        return ExitCode.FAULT if state.alarm else ExitCode.OK
    if command == "set":
        chamber.set_setpoint(args.temperature_c, args.ramp_c_per_min)
        if args.run:
            chamber.check_state()
            chamber.run()
    elif command == "run":
        chamber.check_state()
        chamber.run()
    elif command == "stop":
        chamber.stop()
    elif command == "clear":
        chamber.clear_alarms()
    print(format_chamber_state(chamber.read_state()))
    return ExitCode.OK


def cmd_chamber(args: argparse.Namespace) -> ExitCode:
    prog = f"bench chamber {args.chamber_command}"
    try:
        config = _chamber_config(args)
        chamber = open_chamber(config.url, config.dialect, **config.driver_options())
    except (ChamberConfigError, ConfigError, InputError) as exc:
        return fail(prog, f"{exc}", ExitCode.USAGE)
    try:
        chamber.connect()
    except ChamberError as exc:
        return fail(prog, f"cannot reach the chamber: {exc}", ExitCode.FAULT)
    try:
        # SIGTERM and SIGHUP end the command like Ctrl-C (an `Interrupted`, a KeyboardInterrupt)
        with stop_signals(raise_interrupted):
            return _run_chamber_command(chamber, args)
    except (ChamberLimitError, ChamberConfigError) as exc:
        return fail(prog, f"refused, nothing sent: {exc}", ExitCode.USAGE)
    except ChamberError as exc:
        done = _make_safe(chamber, config)
        return fail(prog, f"{type(exc).__name__}: {exc}; chamber: {done}", ExitCode.FAULT)
    except KeyboardInterrupt as exc:
        done = _make_safe(chamber, config)
        return fail(prog, f"interrupted ({exc or 'Ctrl-C'}); chamber: {done}", ExitCode.FAULT)
    finally:
        chamber.close()


def _make_safe(chamber: Chamber, config: ChamberConfig) -> str:
    """The chamber to its safe setpoint (else stopped); a second stop signal cannot cut it short (it is bounded
    by the driver's timeouts and retries)."""
    with stop_signals(lambda _signum: None):
        return chamber.make_safe(config.safe_setpoint_c)


# -- bench sim chamber --------------------------------------------------------------

CHAMBER_FAULT_HELP = """chamber fault console (one command per line on stdin):
  alarm over_temperature|under_temperature|door_open|sensor_fault|equipment_fault | clear
  timeout N | garbage N | checksum N | late N (ascii) | exception N [CODE]   (next N replies)
  state | help"""


def register_sim_chamber(kinds: argparse._SubParsersAction) -> None:
    """`chamber` under `bench sim` (`kinds` is what `bench.cli.table.register_sim` returns)."""
    sim = kinds.add_parser(
        "chamber", help="serve the simulated thermal chamber in a controller dialect until Ctrl-C",
        description="Serve the simulated chamber (first-order air with heating and cooling rate limits, in "
                    "wall-clock time) in the ascii or modbus dialect (drivers/CHAMBER.md). Prints where it listens, "
                    "then runs until Ctrl-C, SIGTERM or SIGHUP. Alarms and wire faults are injected by typing "
                    "commands on stdin.\n\n" + CHAMBER_FAULT_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    sim.add_argument("--dialect", required=True, choices=sorted(DIALECTS), help="the controller dialect to serve")
    sim.add_argument("--listen", action="append", required=True, metavar="WHERE",
                     help=CHAMBER_LISTEN_HELP + "; repeatable")
    sim.add_argument("--allow-remote", action="store_true",
                     help="allow a --listen address beyond loopback: anyone who can reach this machine can then "
                          "command the simulated chamber")
    sim.add_argument("--ambient-c", type=float, default=23.0, help="room (and starting) temperature (default 23)")
    sim.add_argument("--time-constant-s", type=float, default=240.0,
                     help="the air's time constant toward the working setpoint (default 240 s)")
    sim.add_argument("--max-heat-c-per-min", type=float, default=5.0, help="heating rate limit (default 5)")
    sim.add_argument("--max-cool-c-per-min", type=float, default=3.0, help="cooling rate limit (default 3)")
    sim.set_defaults(func=cmd_sim_chamber)


CHAMBER_LISTEN_HELP = ("tcp://127.0.0.1:PORT (ascii), modbus+tcp://127.0.0.1:PORT (modbus) or pty (RTU for "
                       "modbus); port 0 picks a free port; a host other than loopback needs --allow-remote")


def listen_chamber(sim, dialect: str, where: str, closers: list, register_map=None) -> str:
    """Serve `sim` on one --listen address; returns the URL a client opens (InputError for a bad address)."""
    from bench.sim.chamber_server import serve_chamber  # the simulators: only for `bench sim`

    if where == "pty":
        close, url = serve_chamber(sim, dialect, "pty", register_map=register_map)
    else:
        scheme = "modbus+tcp" if dialect == "modbus" else "tcp"
        host, port = _host_port(where, scheme, f"the {dialect} chamber simulator listens on {scheme}://HOST:PORT "
                                               "or pty")
        close, url = serve_chamber(sim, dialect, "tcp", host, port, register_map)
    closers.append(close)
    return url


def apply_chamber_command(sim, line: str) -> str:
    """One chamber fault-console line on the simulated chamber; returns what to print."""
    words = line.split()
    if not words:
        return ""
    cmd, rest = words[0].lower(), words[1:]
    try:
        if cmd == "alarm":
            name = rest[0].lower() if rest else ""
            if name not in ALARM_NAMES:
                return f"alarm needs one of {', '.join(ALARM_NAMES)}"
            sim.trip_alarm(ALARM_NAMES[name])
        elif cmd == "clear":
            sim.clear_alarms()
        elif cmd in ("timeout", "garbage", "checksum", "exception", "late"):
            count = int(rest[0]) if rest else 1
            if cmd == "exception" and len(rest) > 1:
                sim.faults.exception_code = int(rest[1])
            setattr(sim.faults, cmd, count)
        elif cmd == "state":
            return sim.state().describe()
        elif cmd == "help":
            return CHAMBER_FAULT_HELP
        else:
            return f"unknown command {cmd!r}; type help"
    except Exception as exc:  # noqa: BLE001 - a console typo must not stop the simulator
        return f"error: {exc}"
    return "ok"


def cmd_sim_chamber(args: argparse.Namespace) -> ExitCode:
    # the simulators load only for `bench sim`
    from bench.sim.chamber import ChamberPhysics, SimChamber

    prog = "bench sim chamber"
    remote = _remote_hosts(args.listen)
    if remote and not args.allow_remote:       # checked before anything binds or stdin is read
        return fail(prog, f"{remote[0]} is reachable from the network, not only from this machine; add "
                          "--allow-remote to serve it there, or listen on 127.0.0.1", ExitCode.USAGE)
    try:
        physics = ChamberPhysics(ambient_c=args.ambient_c, time_constant_s=args.time_constant_s,
                                 max_heat_c_per_min=args.max_heat_c_per_min,
                                 max_cool_c_per_min=args.max_cool_c_per_min)
    except ValueError as exc:
        return fail(prog, f"{exc}", ExitCode.USAGE)
    sim = SimChamber(physics)
    closers: list = []
    # Ctrl-C (SIGINT) stops the server even when it was started with SIGINT ignored (`... &` in a script)
    previous_handler = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with stop_signals(raise_interrupted):
            for where in args.listen:
                url = listen_chamber(sim, args.dialect, where, closers)
                print(f"simulated chamber ({args.dialect}) listening on {url}", flush=True)
                if where in remote:
                    print(f"WARNING: {prog}: {url} is reachable from the NETWORK (--allow-remote): anyone who can "
                          "reach this machine can command the simulated chamber; there is no authentication",
                          file=sys.stderr, flush=True)
            print("Ctrl-C stops; type 'help' for the fault console", flush=True)
            for line in sys.stdin:               # the fault console; on EOF keep serving until a stop signal
                reply = apply_chamber_command(sim, line)
                if reply:
                    print(reply, flush=True)
            threading.Event().wait()
    except (InputError, OSError, ValueError) as exc:
        return fail(prog, f"{exc}", ExitCode.USAGE)
    except KeyboardInterrupt:
        return fail(prog, "stopped", ExitCode.OK)
    finally:
        signal.signal(signal.SIGINT, previous_handler)
        for close in reversed(closers):
            close()
    return ExitCode.OK


__all__ = ["CHAMBER_FAULT_HELP", "apply_chamber_command", "cmd_chamber", "cmd_sim_chamber", "format_chamber_state",
           "listen_chamber", "register_chamber", "register_sim_chamber"]
