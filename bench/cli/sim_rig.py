"""`bench sim rig`: a whole simulated bench (table and IMU) in wall-clock time, for `bench run` in another process.

The table is served as `bench sim table` serves it (any dialect, TCP or a pty); the IMU's
CAN frames on a simulated SLCAN adapter (a pty), a simulated socketcand (TCP) or a real
SocketCAN interface, which `bench run` opens with python-can's own interfaces.
`--write-config FILE` writes the bench configuration that points at both. Runs until
Ctrl-C, SIGTERM or SIGHUP (exit 0); faults are typed on stdin.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from bench.cli.chamber import CHAMBER_LISTEN_HELP, apply_chamber_command, listen_chamber, register_sim_chamber
from bench.cli.common import ExitCode, fail
from bench.cli.sim_serving import (
    add_idle_timeout_option,
    host_port,
    refuse_remote,
    remote_hosts,
    run_console,
    run_until_stopped,
)
from bench.cli.table import FAULT_HELP, apply_fault_command, register_sim_table, start_listener
from bench.config.reader import ConfigError
from bench.config.register_map import load_register_map
from bench.errors import InputError
from bench.files import write_output_text
from bench.model.imu import NoiseModel
from drivers.chamber import DIALECTS as CHAMBER_DIALECTS
from drivers.imu import SHIPPED_LAYOUTS
from drivers.turntable import DIALECTS

if TYPE_CHECKING:
    from bench.config.load import BenchConfig

PROG = "bench sim rig"
#: the most units `--imus` serves (unit k's ids offset by 16 k stay in the classic 11-bit range)
MAX_RIG_IMUS = 16
IMU_LISTEN_HELP = ("slcan (a simulated SLCAN adapter on a new pty per bus: python-can interface slcan), "
                   "socketcand://127.0.0.1:PORT (a simulated socketcand per bus, serving can0, can1, ...: interface "
                   "socketcand; with several buses PORT is 0, a free port each), or socketcan:CHANNEL[,CHANNEL...] "
                   "(SocketCAN interfaces of this host, one per bus, e.g. socketcan:vcan0,vcan1); repeatable; "
                   "the written configuration points at the first; default slcan")
IMU_FAULT_HELP = """  imu off | imu on | imu drop N | imu corrupt N | imu length N | imu swap | imu status
      (the IMU stops/starts sending; the next N frames are dropped, sent with a bad CRC or one byte short;
       swap: the next sample's last frame comes after the frame that follows it)"""


CHAMBER_RIG_HELP = ("  chamber COMMAND: the chamber's console, e.g. chamber alarm door_open, chamber garbage 3 "
                    "(chamber help)")


def register_sim(subparsers: argparse._SubParsersAction) -> None:
    """`bench sim` and its devices, in the order `bench sim --help` lists them: table, rig, chamber."""
    kinds = register_sim_table(subparsers)
    register(kinds)
    register_sim_chamber(kinds)


def register(kinds: argparse._SubParsersAction) -> None:
    """`rig` under `bench sim` (`kinds` is what `bench.cli.table.register_sim_table` returns)."""
    rig = kinds.add_parser(
        "rig", help="serve a whole simulated bench (table and CAN IMU) in wall-clock time until Ctrl-C",
        description="Serve the simulated turntable in a controller dialect and the simulated IMU mounted on it "
                    "on a CAN transport that python-can opens from another process (SLCAN on a pty, "
                    "socketcand on TCP, SocketCAN), in wall-clock time. --write-config writes the bench "
                    "configuration that points at both (`bench run --config FILE` in another terminal). "
                    "The truth (site, black box, noise, IMU coefficients, IMU rate) comes from --config's "
                    "[site], [imu] and [sim] (default: `bench run --sim`'s), overridden by the flags. "
                    "--chamber-dialect/--chamber-listen also serve the simulated thermal chamber (its [chamber] "
                    "limits and safe setpoint from --config, written into the configuration). Prints "
                    "where it listens, then runs until Ctrl-C, SIGTERM or SIGHUP.\n\n" + FAULT_HELP + "\n"
                    + IMU_FAULT_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    rig.add_argument("--dialect", choices=sorted(DIALECTS),
                     help="the table's controller dialect (default: --config's, else scpi)")
    rig.add_argument("--table-listen", metavar="WHERE",
                     help="tcp://127.0.0.1:PORT (acutrol, scpi, mn), modbus+tcp://127.0.0.1:PORT (modbus) or pty "
                          "(RTU for modbus); port 0 picks a free port; default: TCP on a free loopback port")
    rig.add_argument("--imu-listen", action="append", metavar="WHERE", help=IMU_LISTEN_HELP)
    rig.add_argument("--chamber-dialect", choices=sorted(CHAMBER_DIALECTS),
                     help="also serve the simulated thermal chamber in this dialect (default with --chamber-listen: "
                          "--config's [chamber] dialect, else ascii)")
    rig.add_argument("--chamber-listen", metavar="WHERE", help="where the chamber listens: " + CHAMBER_LISTEN_HELP
                     + "; default with --chamber-dialect: TCP on a free loopback port")
    rig.add_argument("--allow-remote", action="store_true",
                     help="allow a listen address beyond loopback: anyone who can reach this machine can then "
                          "command the simulated table")
    add_idle_timeout_option(rig)
    rig.add_argument("--write-config", metavar="FILE",
                     help="write the bench configuration pointing at the rig (valid only while this rig runs: it "
                          "names the rig in [imu.rig], and `bench run` refuses it once the rig has stopped)")
    rig.add_argument("--config", metavar="FILE",
                     help="a bench configuration whose [site], [sim], imu.rate_hz and IMU layout the rig uses")
    rig.add_argument("--imus", type=int, default=1, metavar="N",
                     help="serve N simulated IMUs (1..16; default 1), each with its own truth and noise seed as "
                          "`bench run --sim` draws them; the written configuration has one [[imu]] entry per unit "
                          "(docs/how-to/several-imus.md)")
    rig.add_argument("--buses", type=int, default=1, metavar="B",
                     help="put the --imus units on B buses (1..N; default 1), consecutive units sharing a bus as "
                          "multi-imu.example.toml does: on each bus the units' ids offset by 16 in turn and their "
                          "faces z-up, x-up, y-up, z-down, x-down, y-down in turn; each bus its own SLCAN adapter "
                          "(pty), socketcand or SocketCAN interface, which the units on it share")
    rig.add_argument("--seed", type=int, help="[sim] seed (black-box draw and sensor noise)")
    rig.add_argument("--black-box-arcsec", type=float, help="[sim] RMS of the nine black-box angles, arcsec")
    rig.add_argument("--noise", choices=("on", "off"), help="[sim] noise on (default levels) or off")
    rig.add_argument("--imu-rate-hz", type=float, help="the IMU's sample rate, Hz")
    rig.add_argument("--latitude", type=float, help="site latitude, deg")
    rig.add_argument("--imu-layout", choices=sorted(SHIPPED_LAYOUTS),
                     help="the IMU's frame layout: classic (7 frames per sample), packed (3 frames per sample, "
                          "for rates up to 2 kHz on a 1 Mbit/s bus), fd (one CAN FD frame, socketcan only) or sbg-ecan "
                          "(SBG Systems' CAN IMU messages, a simulated MEMS IMU); default: --config's")
    rig.add_argument("--register-map", metavar="FILE",
                     help="modbus: the register map the simulated controller serves (a [modbus] table as in a "
                          "bench configuration; default: --config's [table], else the map of docs/hardware/modbus.md); "
                          "the written configuration carries it")
    rig.set_defaults(func=cmd_sim_rig)


def _truth_config(args: argparse.Namespace) -> BenchConfig:
    """--config (or the built-in sim configuration) with the flags applied, written out and read back
    through the configuration loader, so the rig's world is exactly what the written file says."""
    # heavy (scipy, python-can): the configuration's loader and the simulators load only when one is served
    from bench.config.load import default_sim_config, load_config, parse_config
    from bench.sim.rig import RigPeer, rig_config_text

    base = load_config(args.config) if args.config else default_sim_config()
    sim, site, imu = base.sim, base.site, base.imu
    if args.seed is not None:
        sim = dataclasses.replace(sim, seed=args.seed)
    if args.black_box_arcsec is not None:
        sim = dataclasses.replace(sim, black_box_arcsec=args.black_box_arcsec)
    if args.noise is not None:
        sim = dataclasses.replace(sim, noise=NoiseModel() if args.noise == "on" else NoiseModel.off())
    if args.latitude is not None:
        site = dataclasses.replace(site, latitude_deg=args.latitude, local_g_mps2=None)
    if args.imu_rate_hz is not None:
        imu = dataclasses.replace(imu, rate_hz=args.imu_rate_hz)
    if args.imu_layout is not None:     # a shipped layout with its own mapping (the text below compiles it)
        imu = dataclasses.replace(imu, layout_name=args.imu_layout, fd=args.imu_layout == "fd",
                                  spec=SHIPPED_LAYOUTS[args.imu_layout][1])
    table = dataclasses.replace(base.table, dialect=args.dialect or base.table.dialect)
    if args.register_map is not None:
        if table.dialect != "modbus":
            raise InputError(f"--register-map is for the modbus dialect only (the table speaks {table.dialect})")
        table = dataclasses.replace(table, register_map=load_register_map(args.register_map))
    elif table.dialect != "modbus":
        table = dataclasses.replace(table, register_map=None)   # --dialect overrides a modbus --config
    base = dataclasses.replace(base, sim=sim, site=site, imu=imu, table=table)
    placeholder = RigPeer("virtual", "", "virtual", "turntable-bench-rig", {})
    placeholders = [placeholder] if args.buses == 1 else [
        dataclasses.replace(placeholder, channel=f"turntable-bench-rig-{b}", bus=b) for b in range(args.buses)]
    text = rig_config_text(base, "sim", base.table.dialect, placeholders, imus=args.imus, buses=args.buses)
    # the chamber's limits, safe setpoint and register map come from --config as they are
    return dataclasses.replace(parse_config(text, source="<bench sim rig options>"), chamber=base.chamber)


def _check_imu_listen(where: str, buses: int) -> str | None:
    """Why `where` (an --imu-listen) cannot serve `buses` buses; None: it can."""
    if where == "slcan":
        return None
    if where.startswith("socketcan:"):
        channels = where.split(":", 1)[1].split(",")
        if len(channels) != buses or not all(channels):
            return f"{where!r} names {len(channels)} SocketCAN channel(s) for {buses} bus(es): one per bus"
        return None
    if where.startswith("socketcand://"):
        if buses > 1 and not where.endswith(":0"):
            return f"{where!r}: with {buses} buses socketcand listens on port 0 (a free port per bus)"
        return None
    return f"the IMU listens on slcan, socketcand://HOST:PORT or socketcan:CHANNEL, not {where!r}"


def _serve_imu(rig, where: str, idle_timeout_s: float) -> list:
    """The rig's peers (one per bus) on the transport `where` names."""
    buses = range(len(rig.buses))
    if where == "slcan":
        return [rig.serve_slcan(b) for b in buses]
    if where.startswith("socketcan:"):
        return [rig.serve_socketcan(channel, b) for b, channel in zip(buses, where.split(":", 1)[1].split(","))]
    host, port = host_port(where, "socketcand", "the IMU listens on slcan, socketcand://HOST:PORT or "
                                                  "socketcan:CHANNEL")
    return [rig.serve_socketcand(host, port, idle_timeout_s, b) for b in buses]


def cmd_sim_rig(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy, python-can): the configuration's loader and the simulators load only when one is served
    from bench.config.load import parse_config
    from bench.sim.rig import SimRig, apply_imu_command, rig_config_text, rig_units

    if not 1 <= args.imus <= MAX_RIG_IMUS:
        return fail(PROG, f"--imus must be 1..{MAX_RIG_IMUS}, not {args.imus}", ExitCode.USAGE)
    if not 1 <= args.buses <= args.imus:
        return fail(PROG, f"--buses must be 1..{args.imus} (the --imus units), not {args.buses}", ExitCode.USAGE)
    try:
        config = _truth_config(args)
    except (ConfigError, InputError) as exc:
        return fail(PROG, f"{exc}", ExitCode.USAGE)
    dialect = args.dialect or config.table.dialect
    table_listen = args.table_listen or ("modbus+tcp://127.0.0.1:0" if dialect == "modbus" else "tcp://127.0.0.1:0")
    imu_listen = args.imu_listen or ["slcan"]
    socket_addresses = [w.replace("socketcand://", "tcp://", 1) for w in imu_listen if w.startswith("socketcand://")]
    chamber_dialect, chamber_listen = _chamber_options(args, config)
    remote = remote_hosts([table_listen, *socket_addresses, *([chamber_listen] if chamber_listen else [])])
    if remote and not args.allow_remote:
        return refuse_remote(PROG, remote)
    for where in imu_listen:
        refused = _check_imu_listen(where, args.buses)
        if refused is not None:
            return fail(PROG, refused, ExitCode.USAGE)
    closers: list = []

    def serve() -> None:
        rig = SimRig(config)
        closers.append(rig.close)
        table_url = start_listener(rig.controller, dialect, table_listen, closers, config.table.register_map,
                                   idle_timeout_s=args.idle_timeout_s)
        print(f"simulated table ({dialect}) listening on {table_url}", flush=True)
        links = [_serve_imu(rig, where, args.idle_timeout_s) for where in imu_listen]
        for peer in (peer for peers in links for peer in peers):
            print(f"simulated IMU ({config.imu.rate_hz:g} Hz) on {peer.kind} {peer.where}: python-can "
                  f"interface {peer.interface!r}, channel {peer.channel!r}"
                  + "".join(f", {k} {v!r}" for k, v in peer.bus_options.items())
                  + (f" (bus {peer.bus + 1})" if args.buses > 1 else ""), flush=True)
        for b in range(args.buses if len(config.units) > 1 else 0):
            on_bus = [unit for unit, placed in zip(config.units, rig_units(args.imus, args.buses)) if placed.bus == b]
            print(("units on that bus: " if args.buses == 1 else f"units on bus {b + 1}: ") + ", ".join(
                f"{unit.identity.serial} ({unit.mounting_name}, ids +{unit.id_offset})" for unit in on_bus),
                flush=True)
        chamber, chamber_url = None, ""
        if chamber_listen:
            # heavy (scipy): the simulators load only when one is served
            from bench.sim.chamber import SimChamber

            chamber = SimChamber()
            register_map = config.chamber.register_map if config.chamber is not None else None
            chamber_url = listen_chamber(chamber, chamber_dialect, chamber_listen, closers, register_map,
                                         args.idle_timeout_s)
            print(f"simulated chamber ({chamber_dialect}) listening on {chamber_url}", flush=True)
        rig.start()
        if args.write_config:
            text = rig_config_text(config, table_url, dialect, links[0],
                                   (chamber_url, chamber_dialect) if chamber is not None else None, rig.identity,
                                   imus=args.imus, buses=args.buses)
            parse_config(text, source=args.write_config, base_dir=Path(args.write_config).resolve().parent)
            # never over the --config read, nor over a run log
            write_output_text(args.write_config, text, [args.config] if args.config else [], option="--write-config")
            print(f"bench configuration written to {args.write_config}", flush=True)
        run_console(lambda line: _console(rig, line, apply_imu_command, chamber))

    return run_until_stopped(PROG, serve, closers, usage_errors=(InputError, ConfigError, ValueError, OSError))


def _chamber_options(args: argparse.Namespace, config: BenchConfig) -> tuple[str, str | None]:
    """(dialect, where) of the rig's chamber; where None: no chamber."""
    configured = config.chamber.dialect if config.chamber is not None else "ascii"
    dialect = args.chamber_dialect or configured
    if args.chamber_listen is None and args.chamber_dialect is None:
        return dialect, None
    return dialect, args.chamber_listen or ("modbus+tcp://127.0.0.1:0" if dialect == "modbus" else "tcp://127.0.0.1:0")


def _console(rig, line: str, apply_imu_command, chamber=None) -> str:
    words = line.split()
    if not words:
        return ""
    if words[0].lower() == "imu":
        return apply_imu_command(rig, words[1:])
    if words[0].lower() == "chamber":
        if chamber is None:
            return "no chamber: start the rig with --chamber-dialect or --chamber-listen"
        return apply_chamber_command(chamber, " ".join(words[1:]))
    if words[0].lower() == "help":
        return FAULT_HELP + "\n" + IMU_FAULT_HELP + ("" if chamber is None else "\n" + CHAMBER_RIG_HELP)
    return apply_fault_command(rig.controller, line)


__all__ = ["cmd_sim_rig", "register", "register_sim"]
