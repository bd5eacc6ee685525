"""A whole simulated bench in wall-clock time, for another process to run against (`bench sim rig`).

`SimRig` holds the simulated controller (kinematics on the system clock; the CLI serves it
in a dialect as `bench sim table` does) and the simulated IMU mounted on its table
(`SimCanImu`, a thread that catches up with wall-clock time every few milliseconds). The
IMU's frames go onto `RigBus`, which hands them to every CAN peer the rig serves: a
simulated SLCAN adapter on a pty (`bench.sim.slcan_server`), a simulated socketcand on
127.0.0.1 (`bench.sim.socketcand_server`) or a real SocketCAN interface. Another process
opens those with python-can's own interfaces (`slcan`, `socketcand`, `socketcan`). A rig of
several IMUs (`config.units`) has one `RigBus` per bus its units name, each served by its
own peers (`rig_units` lays out `bench sim rig --imus N --buses B`).

`rig_config_text` writes the bench configuration that points at what the rig serves, with
the rig's simulated truth in `[sim]` (so the written file rebuilds the same world; a
hardware run ignores the section).
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields
from typing import Any, Protocol

import can
import numpy as np

from bench.config.chamber import ChamberConfig
from bench.config.load import BenchConfig, SimConfig
from bench.config.rig import RigIdentity, this_rig
from bench.config.units import FACES, bus_name, lever_arm_in_body_m
from bench.model.imu import NoiseModel
from bench.model.units import DEG
from bench.sim.can_imu import SimCanImu
from bench.sim.controller import SimController
from bench.sim.imu import SimImu
from bench.sim.serve import IDLE_TIMEOUT_S
from bench.sim.slcan_server import SlcanPeer, SlcanPtyServer
from bench.sim.socketcand_server import SocketcandServer
from bench.sim.table import SimTable, TableLimits
from bench.sim.units import mounted_view, placed_terms, unit_seed, unit_truth
from drivers.chamber import ChamberLimits
from drivers.imu import SHIPPED_LAYOUTS, ImuFrameSpec
from drivers.imu.layout import CHANNELS

#: how often the IMU thread catches up with the wall clock, s
IMU_PERIOD_S = 0.005


class FramePeer(Protocol):
    """Something that puts the IMU's frames on a wire (an SLCAN pty, a socketcand server, a SocketCAN bus)."""

    def send(self, messages: Iterable[can.Message]) -> None: ...

    def close(self) -> None: ...


class SocketcanPeer:
    """A real SocketCAN interface (e.g. vcan0) as a peer: every frame is sent on it."""

    def __init__(self, channel: str):
        self.bus = can.Bus(interface="socketcan", channel=channel)
        self.frames_sent = 0
        self.frames_dropped = 0

    def send(self, messages: Iterable[can.Message]) -> None:
        for msg in messages:
            try:
                self.bus.send(msg, timeout=0.01)
                self.frames_sent += 1
            except can.CanError:
                self.frames_dropped += 1

    def close(self) -> None:
        self.bus.shutdown()


class RigBus(can.BusABC):
    """The simulated IMU's own bus: what it sends goes to every peer; `silent` swallows it (IMU off)."""

    def __init__(self) -> None:
        super().__init__(channel="sim-rig")
        self.peers: list[FramePeer] = []
        self.silent = False
        self.frames_silenced = 0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.send_batch([msg])

    def send_batch(self, messages: list[can.Message]) -> None:
        if self.silent:
            self.frames_silenced += len(messages)
            return
        for peer in self.peers:
            peer.send(messages)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return None, False


@dataclass(frozen=True)
class RigPeer:
    """One CAN transport the rig serves and how a bench configuration reaches it."""

    kind: str                 # "slcan", "socketcand", "socketcan"
    where: str                # what to print: the pty path, tcp://host:port, the interface
    interface: str            # python-can interface name
    channel: str
    bus_options: dict
    bitrate: int | None = None
    bus: int = 0              # which of the rig's buses it carries (`SimRig.buses`)


@dataclass(frozen=True)
class RigUnit:
    """Where one unit of `bench sim rig --imus N --buses B` sits: its serial, bus (from 0), id offset and face."""

    serial: str
    bus: int
    id_offset: int
    face: str


def rig_units(imus: int, buses: int = 1) -> list[RigUnit]:
    """The units of a rig of `imus` units on `buses` buses, as multi-imu.example.toml lays them out: consecutive
    units share a bus (the buses as even as they divide), on each bus the units' ids offset by RIG_ID_OFFSET in turn
    and their faces RIG_FACES in turn (two units on two buses: z-up and x-up on each)."""
    if not 1 <= buses <= imus:
        raise ValueError(f"a rig of {imus} unit(s) has 1..{imus} buses, not {buses}")
    units: list[RigUnit] = []
    first = 0
    for k in range(imus):
        bus = k * buses // imus
        if k and bus != units[-1].bus:
            first = k
        units.append(RigUnit(f"RIG-{k + 1:04d}", bus, RIG_ID_OFFSET * (k - first), RIG_FACES[(k - first) % 6]))
    return units


def _check_gyro_range(config: BenchConfig) -> None:
    """ValueError when one axis turning at its fastest ([table.limits]) drives a gyro beyond its signal's range
    at this sample rate (the packed layout's 16-bit increments at a low rate): every turn would saturate."""
    layout, rate_hz = config.imu.layout, config.imu.rate_hz
    fastest_dps = max(axis.max_rate_dps for axis in config.table.limits.axes)
    scale = float(np.max(config.sim.imu.gyro_scale)) * DEG      # counts/s per deg/s
    per_sample = 1.0 if layout.time_stamp is not None else rate_hz   # sbg-ecan sends rates, not increments
    need = fastest_dps * scale / per_sample
    for message in layout.messages:
        for column, sig in message.values:
            if column < 3:
                top = ((1 << (sig.length - 1)) - 1 if sig.signed else sig.mask) * sig.scale
                if need > top:
                    raise ValueError(
                        f"at {rate_hz:g} Hz a gyro turning at {fastest_dps:g} deg/s ([table.limits]) sends "
                        f"{need:,.0f} counts per sample, beyond the {top:,.0f} that signal {sig.name} of the IMU "
                        f"layout holds: raise imu.rate_hz to at least {fastest_dps * scale / top:,.0f} Hz, lower "
                        "the limits, or use a layout with wider signals")


class SimRig:
    """The simulated controller and IMU of `config` (its site, [sim] truth, IMU rate and layout), in wall-clock time."""

    def __init__(self, config: BenchConfig, identity: RigIdentity | None = None):
        self.config = config
        #: who this rig is (the written configuration's [imu.rig]; its SLCAN adapters answer `identity.id`)
        self.identity = identity if identity is not None else this_rig()
        sim = config.sim
        # the simulated table moves as fast as [table.limits] allows (its rates and accelerations)
        axes = config.table.limits.axes
        outer, middle, inner = axes
        table_limits = TableLimits((outer.max_rate_dps, middle.max_rate_dps, inner.max_rate_dps),
                                   (outer.max_accel_dps2, middle.max_accel_dps2, inner.max_accel_dps2))
        self.controller = SimController(SimTable(config.site.site, black_box_rad=sim.black_box_rad,
                                                 limits=table_limits), limits=axes)
        _check_gyro_range(config)
        # the first unit of several sits at its lever arm (none: the configured truth as it is)
        self.imu = SimImu(sim.imu, sim.noise, rate_hz=config.imu.rate_hz, seed=sim.seed, thermal=sim.thermal,
                           higher_order=placed_terms(sim.higher_order, lever_arm_in_body_m(config.imu))
                           if config.units else sim.higher_order)
        #: the rig's buses: one per bus the units name (`bench.config.units.bus_name`), in the order of the units
        names = list(dict.fromkeys(bus_name(unit) for unit in config.units)) or [""]
        self.buses = [RigBus() for _ in names]
        self.bus = self.buses[0]            # the reference unit's
        self.can_imu = SimCanImu(self.controller, self.imu, self.bus, config.imu.layout)
        #: a rig of several IMUs (`config.units`, `bench sim rig --imus N`): every unit but the first, each with its
        #: own truth and noise seed (as `bench run --sim` draws them), ids and mounting, on its bus
        self.units: list[SimCanImu] = []
        for k, unit in enumerate(config.units):
            if k == 0:
                can_imu = self.can_imu
            else:
                imu = SimImu(unit_truth(sim.imu, k, sim.seed), sim.noise, rate_hz=unit.rate_hz,
                             seed=unit_seed(sim.seed, k), higher_order=placed_terms(None, lever_arm_in_body_m(unit)))
                can_imu = SimCanImu(self.controller, imu, self.buses[names.index(bus_name(unit))], unit.layout)
                self.units.append(can_imu)
            if unit.mounting is not None and unit.mounting != FACES["z-up"]:
                can_imu.table = mounted_view(self.controller.table, unit.mounting)
        self.peers: list[RigPeer] = []
        self._servers: list[Any] = []

    def _classic_only(self, kind: str) -> None:
        if any(m.is_fd for m in self.config.imu.layout.messages):
            raise ValueError(f"{kind} carries classic CAN frames only and the IMU layout has CAN FD frames: use a "
                             "classic layout (imu.fd = false and a classic DBC) or serve the IMU on socketcan")

    def serve_slcan(self, bus: int = 0) -> RigPeer:
        """A simulated SLCAN adapter on a new pty, on the rig's bus `bus` (one adapter per bus: the units on it
        share the pty, each with its own ids)."""
        self._classic_only("SLCAN")
        server = SlcanPtyServer(SlcanPeer(serial=self.identity.id))
        return self._add(server, RigPeer("slcan", server.path, "slcan", server.path, {}, 1_000_000, bus))

    def serve_socketcand(self, host: str = "127.0.0.1", port: int = 0,
                         idle_timeout_s: float = IDLE_TIMEOUT_S, bus: int = 0) -> RigPeer:
        """A simulated socketcand on TCP serving the rig's bus `bus` as `can<bus>` (`can0` for the first; a
        connection silent for `idle_timeout_s` is closed)."""
        self._classic_only("socketcand (as python-can reads it)")
        server = SocketcandServer(host, port, idle_timeout_s=idle_timeout_s, bus=f"can{bus}")
        return self._add(server, RigPeer(
            "socketcand", f"socketcand://{server.host}:{server.port}", "socketcand", server.bus,
            {"host": server.host, "port": server.port}, bus=bus))

    def serve_socketcan(self, channel: str, bus: int = 0) -> RigPeer:
        """A real SocketCAN interface (vcan0, can0) of this host, carrying the rig's bus `bus`."""
        peer = SocketcanPeer(channel)
        return self._add(peer, RigPeer("socketcan", channel, "socketcan", channel, {}, bus=bus))

    def _add(self, server: Any, peer: RigPeer) -> RigPeer:
        if not 0 <= peer.bus < len(self.buses):
            server.close()
            raise ValueError(f"the rig has {len(self.buses)} bus(es), no bus {peer.bus}")
        self._servers.append(server)
        self.buses[peer.bus].peers.append(server)
        self.peers.append(peer)
        return peer

    def server(self, index: int = 0) -> Any:
        """The server behind `peers[index]` (its counters: frames_sent, frames_dropped, clients)."""
        return self._servers[index]

    def start(self) -> None:
        """The IMU starts sending (in wall-clock time, from its own thread)."""
        self.can_imu.start(IMU_PERIOD_S)
        for unit in self.units:
            unit.start(IMU_PERIOD_S)

    def close(self) -> None:
        """Stop the IMU, then the peers; re-raises what stopped the IMU's thread, if anything did."""
        try:
            with contextlib.ExitStack() as stack:       # every unit stopped, even when one's thread failed
                for can_imu in (self.can_imu, *self.units):
                    stack.callback(can_imu.stop)
        finally:
            for server in reversed(self._servers):
                try:
                    server.close()
                except Exception:  # noqa: BLE001 - closing everything matters more than the first failure
                    pass
            self._servers.clear()
            for bus in self.buses:
                bus.shutdown()

    def __enter__(self) -> "SimRig":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _imu_entries(bus_lines: list[tuple[list[str], str]], units: list[RigUnit]) -> str:
    """The written configuration's [imu] (one unit), or one [[imu]] entry per unit; `bus_lines[b]`: the [imu] keys
    and the [imu.*] tables (bus options, rig) of bus b."""
    identity = '[imu.identity]\nmodel = "simulated FOG IMU (bench sim rig)"\n'
    if len(units) <= 1:
        imu_lines, options = bus_lines[0]
        return f"[imu]\n{chr(10).join(imu_lines)}\n{options}\n{identity}serial = \"RIG-0001\"\n"
    return "\n".join(f"[[imu]]\n{chr(10).join(bus_lines[u.bus][0])}\nid_offset = {u.id_offset}\n"
                      f"mounting = {_toml(u.face)}\n{bus_lines[u.bus][1]}\n{identity}serial = {_toml(u.serial)}\n"
                      for u in units)


# -- the IMU's fault console ---------------------------------------------------------

def apply_imu_command(rig: SimRig, words: list[str]) -> str:
    """One `imu ...` console line (without the word `imu`); returns what to print."""
    if not words:
        return "imu: say off, on, drop N, corrupt N, length N, swap or status"
    cmd, rest = words[0].lower(), words[1:]
    try:
        if cmd in ("off", "on"):
            for bus in rig.buses:
                bus.silent = cmd == "off"
        elif cmd in ("drop", "corrupt", "length"):
            count = int(rest[0]) if rest else 1
            {"drop": rig.can_imu.drop_frames, "corrupt": rig.can_imu.corrupt_crc,
             "length": rig.can_imu.wrong_length}[cmd](count)
        elif cmd == "swap":
            rig.can_imu.swap_frames()
        elif cmd == "status":
            return imu_status(rig)
        else:
            return f"unknown imu command {cmd!r}; type help"
    except (ValueError, IndexError) as exc:
        return f"error: {exc}"
    return "ok"


def imu_status(rig: SimRig) -> str:
    """One line: samples and frames sent, and per peer what went out and what was dropped."""
    parts = [f"IMU {'off' if all(bus.silent for bus in rig.buses) else 'on'}: {rig.can_imu.samples_sent} samples, "
             f"{rig.can_imu.frames_sent} frames generated"]
    for peer, server in zip(rig.peers, rig._servers):
        backlog = getattr(server, "peak_pending", None)
        parts.append(f"{peer.kind} {peer.where}{f' (bus {peer.bus + 1})' if len(rig.buses) > 1 else ''}: "
                     f"{server.frames_sent} frames out, "
                     f"{server.frames_dropped} dropped (not read)"
                     + (f", longest backlog {backlog} bytes" if backlog is not None else ""))
    return "; ".join(parts)


# -- the configuration the rig writes ----------------------------------------------

def _bus_lines(peer: RigPeer, imu, rig: RigIdentity | None) -> tuple[list[str], str]:
    """The [imu] keys that reach `peer` (and rebuild `imu`'s layout and rate), and its [imu.bus_options] and
    [imu.rig] tables."""
    imu_lines = [f"interface = {_toml(peer.interface)}", f"channel = {_toml(peer.channel)}",
                 f"fd = {_toml(imu.fd)}", f"rate_hz = {imu.rate_hz!r}", *imu_layout_lines(imu)]
    if peer.bitrate is not None:
        imu_lines.insert(2, f"bitrate = {peer.bitrate}")
    if peer.interface == "slcan" and imu.slcan_client != "bench":
        imu_lines.append(f"slcan_client = {_toml(imu.slcan_client)}")
    options = "".join(f"{k} = {_toml(v)}\n" for k, v in peer.bus_options.items())
    if options:
        options = "\n[imu.bus_options]\n" + options
    if rig is not None:
        pid = f"pid = {rig.pid}\n" if rig.pid is not None else ""
        options += (f"\n[imu.rig]   # the rig this file points at; remove for the real bench\nid = {_toml(rig.id)}\n"
                    f"{pid}started_utc = {_toml(rig.started_utc)}\n")
    return imu_lines, options


def _toml(value: Any) -> str:
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_key(k)} = {_toml(v)}" for k, v in value.items()) + "}"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value) if math.isfinite(value) else "nan"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    raise TypeError(f"no TOML for {type(value).__name__}")


def _key(key: str) -> str:
    """A TOML key: bare when it may be, quoted otherwise."""
    return key if key and all(c.isalnum() or c in "_-" for c in key) and key.isascii() else json.dumps(key)


def _tables(prefix: str, table: dict) -> list[str]:
    """`table` as TOML lines under `[prefix]`: its plain values, then its sub-tables as `[prefix.key]`."""
    lines = ["", f"[{prefix}]"] + [f"{_key(k)} = {_toml(v)}" for k, v in table.items() if not isinstance(v, dict)]
    for k, v in table.items():
        if isinstance(v, dict):
            lines += _tables(f"{prefix}.{_key(k)}", v)
    return lines


def imu_layout_lines(imu) -> list[str]:
    """The `[imu]` keys that rebuild `imu`'s frame layout: the shipped layout's name or the DBC file, and
    `signals` (an inline table) when the mapping is not that layout's own."""
    if imu.layout_name is not None:
        lines = [f"layout = {_toml(imu.layout_name)}"]
        shipped_spec = SHIPPED_LAYOUTS[imu.layout_name][1]
    else:
        lines = [f"dbc = {_toml(str(imu.dbc.resolve()))}"]
        shipped_spec = None
    if imu.spec != shipped_spec:
        lines.append(f"signals = {_toml(_spec_table(imu.spec))}")
    return lines


def _spec_table(spec: ImuFrameSpec) -> dict:
    """An `[imu.signals]` table that `ImuFrameSpec.from_dict` reads back as `spec`."""
    table: dict = {c: spec.channels[c] for c in CHANNELS}
    if spec.counter is not None:
        table["counter"] = spec.counter if isinstance(spec.counter, str) else dict(spec.counter)
    if spec.time_stamp is not None:
        table["time_stamp"] = spec.time_stamp
    table["crc"] = "" if spec.crc is None else (spec.crc if isinstance(spec.crc, str) else dict(spec.crc))
    for key in ("temperature", "status"):
        if getattr(spec, key) is not None:
            table[key] = getattr(spec, key)
    if spec.status_invalid != ImuFrameSpec.from_dict(table).status_invalid:   # only where not the default
        table["status_invalid"] = spec.status_invalid
    if spec.status_required:
        table["status_required"] = spec.status_required
    return table


def sim_section(sim: SimConfig) -> str:
    """The `[sim]` section that rebuilds `sim` (seed, black box as written, noise, IMU overrides)."""
    lines = ["[sim]", "# The rig's simulated truth (a hardware run ignores this section; "
             "`bench run --sim` rebuilds the same world).",
             f"seed = {sim.seed}", f"black_box_arcsec = {_toml(sim.black_box_arcsec)}"]
    noise = sim.noise
    levels = {f.name: getattr(noise, f.name) for f in fields(NoiseModel) if f.name != "quantise"}
    on = any(v for k, v in levels.items() if k != "correlation_time_s")
    if noise == NoiseModel() or noise == NoiseModel.off():
        lines.append(f"noise = {_toml(noise == NoiseModel())}")
    else:
        lines += ["", "[sim.noise]", f"enabled = {_toml(on)}"]
        if on:
            lines += [f"{k} = {_toml(v)}" for k, v in levels.items()]
        lines.append(f"quantise = {_toml(noise.quantise)}")
    if sim.imu_overrides:
        lines += ["", "[sim.imu]"] + [f"{k} = {_toml(v)}" for k, v in sim.imu_overrides.items()]
    return "\n".join(lines) + "\n"


def chamber_section(url: str, dialect: str, chamber: ChamberConfig | None) -> str:
    """The `[chamber]` section pointing at a served chamber, with `chamber`'s limits, safe setpoint and register
    map (defaults: drivers' limits, safe setpoint 23 degC, the documented map)."""
    limits = chamber.limits if chamber is not None else ChamberLimits()
    safe = chamber.safe_setpoint_c if chamber is not None else 23.0
    lines = ["[chamber]", f"url = {_toml(url)}", f"dialect = {_toml(dialect)}"]
    if safe is not None:
        lines.append(f"safe_setpoint_c = {safe!r}   # on abort or fault the chamber goes here (absent: it stops)")
    lines += ["", "[chamber.limits]", f"min_setpoint_c = {limits.min_setpoint_c!r}",
              f"max_setpoint_c = {limits.max_setpoint_c!r}", f"max_ramp_c_per_min = {limits.max_ramp_c_per_min!r}"]
    if chamber is not None and chamber.register_map is not None:
        table = chamber.register_map.to_dict()
        lines += ["", "[chamber.modbus]"] + [f"{k} = {_toml(v)}" for k, v in table.items() if not isinstance(v, dict)]
        for key, sub in table.items():
            if isinstance(sub, dict):
                lines += ["", f"[chamber.modbus.{key}]"] + [f"{k} = {_toml(v)}" for k, v in sub.items()]
    return "\n".join(lines) + "\n"


#: the faces the units of `bench sim rig --imus N` sit on, in turn (unit k: RIG_FACES[k % 6]), and their ids' offset
RIG_FACES = ("z-up", "x-up", "y-up", "z-down", "x-down", "y-down")
RIG_ID_OFFSET = 16


def rig_config_text(config: BenchConfig, table_url: str, dialect: str, peer: RigPeer | Sequence[RigPeer],
                    chamber: tuple[str, str] | None = None, rig: RigIdentity | None = None, imus: int = 1,
                    buses: int = 1) -> str:
    """A bench configuration (bench.example.toml's format) pointing at the rig: its table and IMU, its site
    and truth, and a default plan to edit; `chamber` (url, dialect) adds the rig's chamber; `rig` marks the file
    valid only while that rig runs (a comment, and [imu.rig] for `bench run` to check). `imus` > 1: one [[imu]]
    entry per unit of `rig_units(imus, buses)`, each on the bus its `peer` (one per bus, in bus order) serves."""
    peers = [peer] if isinstance(peer, RigPeer) else list(peer)
    if len(peers) != buses:
        raise ValueError(f"{buses} bus(es) need one peer each, got {len(peers)}")
    site, imu = config.site, config.imu
    site_lines = [f"latitude_deg = {site.latitude_deg!r}", f"height_m = {site.height_m!r}"]
    if site.local_g_mps2 is not None:
        site_lines.append(f"local_g_mps2 = {site.local_g_mps2!r}")
    limit_lines = []
    for frame, axis in zip(("outer", "middle", "inner"), config.table.limits.axes):
        limit_lines += ["", f"[table.limits.{frame}]", f"max_rate_dps = {axis.max_rate_dps!r}",
                        f"max_accel_dps2 = {axis.max_accel_dps2!r}"]
        limit_lines += [f"{key} = {value!r}" for key, value in (("min_deg", axis.min_deg), ("max_deg", axis.max_deg))
                        if value is not None]
    if config.table.register_map is not None:      # the map the simulated controller serves, for the client
        limit_lines += _tables("table.modbus", config.table.register_map.to_dict())
    validity = ""
    if rig is not None:
        served = (*(p.where for p in peers if p.kind != "socketcan"), table_url, *(chamber[:1] if chamber else ()))
        places = ", ".join(dict.fromkeys(w for w in served if w and w != "sim"))
        validity = (f"# Valid only while the rig that wrote it runs: {rig.describe()}.\n"
                    f"# When it stops, the system gives {places} to other processes;\n"
                    "# `bench run` then refuses this file ([imu.rig]): start the rig again with --write-config.\n")
    bus_lines = [_bus_lines(p, imu, rig) for p in peers]
    return f"""\
# Written by `bench sim rig`: a bench configuration pointing at the simulated rig.
{validity}# For the real bench, change [table] url/dialect and [imu] interface/channel (see the docs,
# docs/tutorials/sim-rig.md and docs/tutorials/real-hardware.md); everything else stays.
format = "turntable-bench/config"
version = 1

[site]
{chr(10).join(site_lines)}

[table]
url = {_toml(table_url)}
dialect = {_toml(dialect)}
# what the bench may demand; the simulated table moves at these rates and accelerations
{chr(10).join(limit_lines).lstrip()}

{_imu_entries(bus_lines, rig_units(imus, buses))}
[plan]
positions = "optimal-24"
rotations = "optimal-5s6r"
dwell_s = 60.0
settle_s = 5.0
turn_rate_dps = 10.0
revolutions = 1

[output]
folder = "runs"

{sim_section(config.sim)}""" + ("" if chamber is None else "\n" + chamber_section(*chamber, config.chamber))


__all__ = ["RIG_FACES", "RIG_ID_OFFSET", "RigBus", "RigPeer", "RigUnit", "SimRig", "SocketcanPeer",
           "apply_imu_command", "chamber_section", "imu_layout_lines", "imu_status", "rig_config_text", "rig_units",
           "sim_section"]
