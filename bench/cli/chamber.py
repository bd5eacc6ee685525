"""`bench chamber ...` (drive a real or simulated thermal chamber by hand) and `bench sim chamber` (serve one).

Exit codes of `bench chamber`: 0 done; 2 usage or configuration error, a demand refused
by the limits, or a chamber that cannot be reached (nothing was sent); 3 the chamber reports an
alarm, refuses, stops answering, the link fails, or the command was interrupted (the chamber is
then made safe: sent to the configuration's safe setpoint, else stopped).
"""

from __future__ import annotations

import argparse

from bench.cli.common import ExitCode, drive_device, fail
from bench.cli.sim_serving import (
    IDLE_TIMEOUT_S,
    add_idle_timeout_option,
    apply_console_line,
    host_port,
    refuse_remote,
    remote_hosts,
    serve_until_stopped,
)
from bench.config.chamber import ChamberConfig
from bench.config.reader import ConfigError
from bench.config.register_map import load_chamber_register_map
from bench.errors import InputError
from drivers.chamber import ALARM_NAMES, DIALECTS, Chamber, ChamberLimits, ChamberState, open_chamber
from drivers.errors import ChamberConfigError, DeviceConfigError, DeviceError, DeviceLimitError
from drivers.transport import MODBUS_SCHEMES

# -- bench chamber ----------------------------------------------------------------------

def register_chamber(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "chamber",
        description="Talk to a thermal chamber controller (docs/hardware/chamber.md), given by --config's [chamber] "
                    "or by --url. Exit codes: 0 done, 2 usage error, demand beyond the limits or chamber not reached "
                    "(nothing sent), 3 alarm, refusal, no reply, link failure or interrupted (the chamber is then "
                    "made safe).")
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
    parser.add_argument("--register-map", metavar="NAME|FILE",
                        help="with --url, modbus: the controller's register map: a preset (watlow-f4, generic) or a "
                             "file holding a [modbus] table (default: watlow-f4, docs/hardware/chamber.md)")
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
        # heavy (scipy, python-can): the whole configuration's loader, only for --config
        from bench.config.load import load_config

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
        if chamber.stop_caveat():
            print(f"note: {chamber.stop_caveat()}")
    elif command == "clear":
        chamber.clear_alarms()
    print(format_chamber_state(chamber.read_state()))
    return ExitCode.OK


def cmd_chamber(args: argparse.Namespace) -> ExitCode:
    prog = f"bench chamber {args.chamber_command}"
    try:
        config = _chamber_config(args)
        chamber = open_chamber(config.url, config.dialect, **config.driver_options())
    except (DeviceConfigError, ConfigError, InputError) as exc:
        return fail(prog, f"{exc}", ExitCode.USAGE)
    return drive_device(prog, chamber, lambda: _run_chamber_command(chamber, args), errors=DeviceError,
                        refused=(DeviceLimitError, DeviceConfigError), unreachable="cannot reach the chamber",
                        make_safe=lambda: f"chamber: {chamber.make_safe(config.safe_setpoint_c)}")


# -- bench sim chamber --------------------------------------------------------------

CHAMBER_FAULT_HELP = """chamber fault console (one command per line on stdin):
  alarm over_temperature|under_temperature|door_open|sensor_fault|equipment_fault | clear
  timeout N | garbage N | checksum N | late N (ascii) | exception N [CODE]   (next N replies)
  state | help"""


def register_sim_chamber(kinds: argparse._SubParsersAction) -> None:
    """`chamber` under `bench sim` (`kinds` is what `bench.cli.table.register_sim_table` returns)."""
    sim = kinds.add_parser(
        "chamber", help="serve the simulated thermal chamber in a controller dialect until Ctrl-C",
        description="Serve the simulated chamber (first-order air with heating and cooling rate limits, in "
                    "wall-clock time) in the ascii or modbus dialect (docs/hardware/chamber.md). Prints where it "
                    "listens, then runs until Ctrl-C, SIGTERM or SIGHUP. Alarms and wire faults are injected by typing "
                    "commands on stdin.\n\n" + CHAMBER_FAULT_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    sim.add_argument("--dialect", required=True, choices=sorted(DIALECTS), help="the controller dialect to serve")
    sim.add_argument("--listen", action="append", required=True, metavar="WHERE",
                     help=CHAMBER_LISTEN_HELP + "; repeatable")
    sim.add_argument("--allow-remote", action="store_true",
                     help="allow a --listen address beyond loopback: anyone who can reach this machine can then "
                          "command the simulated chamber")
    sim.add_argument("--register-map", metavar="NAME|FILE",
                     help="modbus: the register map to serve: a preset (watlow-f4, generic) or a file holding a "
                          "[modbus] table (default: watlow-f4, docs/hardware/chamber.md)")
    add_idle_timeout_option(sim)
    sim.add_argument("--ambient-c", type=float, default=23.0, help="room (and starting) temperature (default 23)")
    sim.add_argument("--time-constant-s", type=float, default=240.0,
                     help="the air's time constant toward the working setpoint (default 240 s)")
    sim.add_argument("--max-heat-c-per-min", type=float, default=5.0, help="heating rate limit (default 5)")
    sim.add_argument("--max-cool-c-per-min", type=float, default=3.0, help="cooling rate limit (default 3)")
    sim.set_defaults(func=cmd_sim_chamber)


CHAMBER_LISTEN_HELP = ("tcp://127.0.0.1:PORT (ascii), modbus+tcp://127.0.0.1:PORT (modbus) or pty (RTU for "
                       "modbus); port 0 picks a free port; a host other than loopback needs --allow-remote")


def listen_chamber(sim, dialect: str, where: str, closers: list, register_map=None,
                   idle_timeout_s: float = IDLE_TIMEOUT_S) -> str:
    """Serve `sim` on one --listen address; returns the URL a client opens (InputError for a bad address)."""
    # heavy (scipy, pymodbus): the simulators load only when one is served
    from bench.sim.chamber_server import serve_chamber

    if where == "pty":
        close, url = serve_chamber(sim, dialect, "pty", register_map=register_map, idle_timeout_s=idle_timeout_s)
    else:
        scheme = "modbus+tcp" if dialect == "modbus" else "tcp"
        host, port = host_port(where, scheme, f"the {dialect} chamber simulator listens on {scheme}://HOST:PORT "
                                               "or pty")
        close, url = serve_chamber(sim, dialect, "tcp", host, port, register_map, idle_timeout_s)
    closers.append(close)
    return url


def apply_chamber_command(sim, line: str) -> str:
    """One chamber fault-console line on the simulated chamber; returns what to print."""
    def chamber_command(cmd: str, rest: list[str]) -> str | None:
        if cmd == "alarm":
            name = rest[0].lower() if rest else ""
            if name not in ALARM_NAMES:
                return f"alarm needs one of {', '.join(ALARM_NAMES)}"
            sim.trip_alarm(ALARM_NAMES[name])
        elif cmd == "clear":
            sim.clear_alarms()
        else:
            return None
        return ""

    return apply_console_line(line, sim.faults, chamber_command, CHAMBER_FAULT_HELP, lambda: sim.state().describe())


def cmd_sim_chamber(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy): the simulators load only when one is served
    from bench.sim.chamber import ChamberPhysics, SimChamber

    prog = "bench sim chamber"
    remote = remote_hosts(args.listen)
    if remote and not args.allow_remote:       # checked before anything binds or stdin is read
        return refuse_remote(prog, remote)
    try:
        physics = ChamberPhysics(ambient_c=args.ambient_c, time_constant_s=args.time_constant_s,
                                 max_heat_c_per_min=args.max_heat_c_per_min,
                                 max_cool_c_per_min=args.max_cool_c_per_min)
        if args.register_map is not None and args.dialect != "modbus":
            raise ChamberConfigError("--register-map is for the modbus dialect only")
        register_map = load_chamber_register_map(args.register_map) if args.register_map is not None else None
    except (ValueError, ConfigError) as exc:      # DeviceConfigError is a ValueError
        return fail(prog, f"{exc}", ExitCode.USAGE)
    sim = SimChamber(physics)
    closers: list = []
    return serve_until_stopped(prog, "chamber", args.dialect,
                               lambda where: listen_chamber(sim, args.dialect, where, closers, register_map,
                                                            idle_timeout_s=args.idle_timeout_s),
                               args.listen, remote,
                               lambda line: apply_chamber_command(sim, line), closers,
                               usage_errors=(InputError, OSError, ValueError))


__all__ = ["CHAMBER_FAULT_HELP", "apply_chamber_command", "cmd_chamber", "cmd_sim_chamber", "format_chamber_state",
           "listen_chamber", "register_chamber", "register_sim_chamber"]
