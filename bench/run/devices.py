"""A run's devices as one bundle, and the two ways to open it: the simulator, or the drivers by URL.

`Devices` holds what a run commands and reads (the turntable, the IMU receiver, the thermal plan's chamber,
the run clock) and, on the simulator, the simulated world behind them. `BenchRun` takes a `DeviceOpener`
(`SIMULATOR` or `DRIVERS`) and never decides between them itself. Closing the bundle closes each device once,
the last opened first: chamber, receiver, table, then the simulated world.
"""

from __future__ import annotations

import json
from contextlib import ExitStack
from dataclasses import dataclass, field
from typing import Callable

import can

from bench.config.chamber import ChamberConfig
from bench.config.load import BenchConfig, ImuConfig
from bench.config.units import FACES, bus_name, lever_arm_in_body_m
from bench.errors import BenchError
from bench.run.imu_check import check_imu_stream, check_rig_adapter, check_rig_running
from bench.run.units import UnitLink, unit_shares
from bench.sim.units import SimUnit, placed_terms, unit_seed, unit_truth
from bench.sim.world import PumpedReceiver, SimWorld
from drivers.chamber import Chamber, open_chamber
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.imu.receiver import ImuReceiver, TimeBase, open_bus
from drivers.imu.shared_bus import BusView, SharedBus
from drivers.turntable import Turntable, open_turntable

#: What the sequencer and the TUI poll for IMU samples: the receiver, or on the simulator the receiver with the
#: simulated IMU sending up to the run clock's now before each poll.
ImuSource = PumpedReceiver | ImuReceiver


@dataclass
class Devices:
    """The opened devices of a run (`open_simulator`, `open_drivers`); `close()` closes them."""

    table: Turntable
    receiver: ImuReceiver
    clock: Clock
    chamber: Chamber | None = None       # a thermal plan's chamber
    world: SimWorld | None = None        # the simulated world behind the devices (None: hardware)
    imu_check: str = ""                  # what the check of a hardware IMU found before the run
    units: list[UnitLink] = field(default_factory=list)   # a run of several IMUs: the units but the reference
    _stack: ExitStack = field(default_factory=ExitStack, repr=False)

    @property
    def simulated(self) -> bool:
        return self.world is not None

    def imu_source(self) -> ImuSource:
        """Where IMU samples are polled: the receiver, or on the simulator the receiver pumped by the simulated IMU."""
        return self.world.imu_source(self.receiver) if self.world is not None else self.receiver

    def let_idle_time_pass(self, seconds: float) -> None:
        """Between polls of an idle table: the simulated run clock advances by `seconds` (it only moves when told);
        on hardware the real time has passed by itself."""
        if self.world is not None:
            self.world.clock.advance(seconds)

    def close(self) -> None:
        """Close each device once, the last opened first (closing again is a no-op)."""
        self._stack.close()


@dataclass(frozen=True)
class DeviceOpener:
    """How a run's devices are opened: `open(config, with_chamber)` raises DeviceError/OSError/ValueError/
    BenchError with whatever it opened closed again; nothing moves."""

    simulated: bool
    open: Callable[[BenchConfig, bool], Devices]


def open_simulator(config: BenchConfig, with_chamber: bool) -> Devices:
    """The simulated world of `config` ([sim], the table's dialect, the IMU's rate and layout) and the drivers
    opened on it; with a chamber, a simulated one on the run clock whose air is the thermal IMU's ambient."""
    stack = ExitStack()
    try:
        # the reference unit of a run of several sits at its lever arm (none: the configured truth as it is)
        higher_order = placed_terms(config.sim.higher_order, lever_arm_in_body_m(config.imu)) if config.several \
            else config.sim.higher_order
        world = stack.enter_context(SimWorld(
            config.site.site, config.sim.imu, config.sim.noise, black_box_rad=config.sim.black_box_rad,
            dialect=config.table.dialect, imu_rate_hz=config.imu.rate_hz, layout=config.imu.layout,
            seed=config.sim.seed, register_map=config.table.register_map, imu_thermal=config.sim.thermal,
            higher_order=higher_order))
        clock, bus = world.clock, world.receiver_bus()
        table = _open_table(config, world.table_url, clock, stack)
        # the simulator's frames carry the run clock's time already; its IMU runs on that clock and always is there
        receiver = _open_receiver(config, bus, None, stack)
        devices = Devices(table, receiver, clock, world=world, _stack=stack)
        if config.several:
            devices.units = _sim_units(config, world, stack)
        if with_chamber:
            chamber_config = _chamber_config(config)
            # served in the configured dialect over the kind of link its url names (TCP, or a pty: RTU, serial)
            url = world.add_chamber(chamber_config.dialect, chamber_config.register_map,
                                    where=chamber_config.sim_link)
            if world.imu.case is not None:
                world.drive_imu_from_chamber()
            devices.chamber = _open_chamber(config, url, clock, stack)
        return devices
    except BaseException:
        stack.close()
        raise


def open_drivers(config: BenchConfig, with_chamber: bool) -> Devices:
    """The configured devices by their URLs on the system clock; the IMU stream is checked (rate and layout)
    before anything moves."""
    where = _where(config.imu, config.several)
    # a file a `bench sim rig` wrote names pty paths and ports valid only while that rig runs: checked before
    # any is opened (one may be someone's terminal now)
    check_rig_running(config.imu.rig, f"{config.imu.channel} ({config.table.url})")
    stack = ExitStack()
    try:
        clock = SYSTEM_CLOCK
        table = _open_table(config, config.table.url, clock, stack)
        buses = _UnitBuses(config, clock.now, stack)
        # the interface's frame timestamps are mapped onto the run clock (one time base in the log)
        receiver = _open_receiver(config, *buses[0], stack)
        asked: list[can.BusABC] = []        # each opened bus asked once whether it is the rig's
        _check_adapter(receiver, config.imu, where, asked)
        imu_check = check_imu_stream(receiver, config.imu.rate_hz, where)
        devices = Devices(table, receiver, clock, imu_check=imu_check, _stack=stack)
        shares = unit_shares(config)
        for k, unit in enumerate(config.units[1:], 1):   # several IMUs: each checked before anything moves
            unit_bus, time_base = buses[k]
            unit_receiver = ImuReceiver(unit_bus, unit.layout, unit.rate_hz, time_base=time_base, share=shares[k])
            stack.callback(unit_receiver.close)
            _check_adapter(unit_receiver, unit, _where(unit, True), asked)
            devices.imu_check += "; " + check_imu_stream(unit_receiver, unit.rate_hz, _where(unit, True))
            devices.units.append(UnitLink(unit.identity.serial, unit_receiver))
        if with_chamber:
            chamber_config = _chamber_config(config)
            if chamber_config.is_sim:
                raise BenchError('chamber url "sim" is the simulated chamber: run with --sim (or a simulated table)')
            devices.chamber = _open_chamber(config, chamber_config.url, clock, stack)
        return devices
    except BaseException:
        stack.close()
        raise


SIMULATOR = DeviceOpener(simulated=True, open=open_simulator)
DRIVERS = DeviceOpener(simulated=False, open=open_drivers)


def device_opener(sim: bool) -> DeviceOpener:
    """The simulator's opener when `sim` (`--sim`, or a simulated table), else the drivers'."""
    return SIMULATOR if sim else DRIVERS


def _open_table(config: BenchConfig, url: str, clock: Clock, stack: ExitStack) -> Turntable:
    options: dict[str, object] = {"limits": config.table.limits, "clock": clock,
                                  "timeout_s": config.table.timeout_s, "retries": config.table.retries}
    if config.table.dialect == "modbus" and config.table.register_map is not None:
        options["register_map"] = config.table.register_map
    table = open_turntable(url, config.table.dialect, **options)
    table.connect()
    stack.callback(table.close)
    return table


def _where(unit: ImuConfig, several: bool) -> str:
    """The bus a unit is on, for the IMU check's lines (with its serial in a run of several)."""
    where = f"interface {unit.interface} channel {unit.channel}"
    return f"{where} (unit {unit.identity.serial})" if several else where


#: python-can interfaces that stamp received frames with this host's clock (the epoch): python-can's and the
#: bench's SLCAN readers (time of the read), SocketCAN (the kernel's receive time), the in-process virtual bus
HOST_CLOCK_INTERFACES = frozenset({"slcan", "socketcan", "virtual"})


class _UnitBuses:
    """Each unit's bus and time base (`buses[k]`, k in the order of `config.units`).

    A unit alone on its bus gets its bus arguments (its receiver opens it); units sharing a bus each get a view of
    one `SharedBus` (an SLCAN adapter has one reader), opened when its first unit asks for it: the view of the bus's
    first unit, which keeps the frames of no unit's id, sees every frame on it, another unit's only its own ids.
    In a run of several units, the units whose frames are stamped on one clock (`_clock_of`) share one `TimeBase`:
    its offset is taken once, from the reference unit's first, fresh frames. Each unit's own offset, taken from its
    first frames, differed from the reference unit's by how late those came (up to the poll interval, more under
    load), and every other unit's windows, cut by receive time in the reference unit's, were shifted by that: the
    residual outliers of units on a second bus."""

    def __init__(self, config: BenchConfig, now: Callable[[], float], stack: ExitStack):
        self._units = config.units or (config.imu,)
        self._now, self._stack = now, stack
        self._sharers: dict[str, int] = {}
        for unit in self._units:
            self._sharers[_bus_key(unit)] = self._sharers.get(_bus_key(unit), 0) + 1
        self._shared: dict[str, SharedBus] = {}
        self._shares = unit_shares(config)
        self._time_bases: dict[str, TimeBase] = {}

    def __getitem__(self, k: int) -> tuple[can.BusABC | dict, Callable[[], float] | TimeBase]:
        unit = self._units[k]
        key = _bus_key(unit)
        time_base: Callable[[], float] | TimeBase = self._now
        if len(self._units) > 1:
            time_base = self._time_bases.setdefault(_clock_of(unit), TimeBase(self._now))
        if self._sharers[key] < 2:
            return unit.bus_kwargs(), time_base
        if key not in self._shared:
            self._shared[key] = SharedBus(open_bus(unit.bus_kwargs()))
            self._stack.callback(self._shared[key].shutdown)
        # the unit that keeps the bus's frames of no unit's id (`BusShare.takes_unknown`) sees every frame, its
        # receiver's share leaving the other units' ids to them; another unit sees its own ids only
        share = self._shares[k]
        view = self._shared[key].view(None if share is None or share.takes_unknown else unit.layout.keys)
        self._stack.callback(view.shutdown)
        return view, time_base


def _clock_of(unit: ImuConfig) -> str:
    """The clock a unit's interface stamps frames with: this host's, a socketcand daemon's host's, else its bus's
    own (an adapter with its own time stamps)."""
    if unit.interface in HOST_CLOCK_INTERFACES:
        return "host"
    if unit.interface == "socketcand":
        return f"socketcand host {unit.bus_options.get('host')}"
    return _bus_key(unit)


def _bus_key(unit: ImuConfig) -> str:
    """What names one bus: its interface, channel and options (a socketcand server's host and port)."""
    return json.dumps([unit.interface, str(unit.channel), unit.bus_options], sort_keys=True, default=str)


def _check_adapter(receiver: ImuReceiver, unit: ImuConfig, where: str, asked: list[can.BusABC]) -> None:
    """`check_rig_adapter` on the opened bus behind `receiver` (a view's shared bus), unless it was `asked`."""
    opened = receiver.bus.shared.bus if isinstance(receiver.bus, BusView) else receiver.bus
    if not any(opened is bus for bus in asked):
        asked.append(opened)
        check_rig_adapter(opened, unit.rig, where)


def _sim_units(config: BenchConfig, world: SimWorld, stack: ExitStack) -> list[UnitLink]:
    """The simulated units of a run of several IMUs: the reference unit is the world's own IMU (mounted as
    configured); each other unit its own truth (`unit_truth`), noise seed and mounting, on its configured bus
    (units naming one bus share one virtual bus)."""
    reference = config.units[0]
    if reference.mounting is not None and reference.mounting != FACES["z-up"]:
        world.mount_imu(reference.mounting)
    links, shares = [], unit_shares(config)
    for k, unit in enumerate(config.units[1:], 1):
        world.add_unit(SimUnit(unit_truth(config.sim.imu, k, config.sim.seed), config.sim.noise, unit.rate_hz,
                               unit.layout, unit_seed(config.sim.seed, k), unit.mounting, bus_name(unit),
                               placed_terms(None, lever_arm_in_body_m(unit))),
                       bus_name(reference))
        receiver = ImuReceiver(world.unit_receiver_bus(bus_name(unit), bus_name(reference)), unit.layout,
                               unit.rate_hz, share=shares[k])
        stack.callback(receiver.close)
        links.append(UnitLink(unit.identity.serial, receiver))
    return links


def _open_receiver(config: BenchConfig, bus: can.BusABC | dict, time_base: Callable[[], float] | TimeBase | None,
                   stack: ExitStack) -> ImuReceiver:
    """The reference unit's receiver (a single IMU's: every frame on its bus; on a bus shared with other units, its
    share of it)."""
    receiver = ImuReceiver(bus, config.imu.layout, config.imu.rate_hz, time_base=time_base,
                           share=unit_shares(config)[0])
    stack.callback(receiver.close)
    return receiver


def _chamber_config(config: BenchConfig) -> ChamberConfig:
    if config.chamber is None:
        raise BenchError("a thermal plan needs a [chamber]")
    return config.chamber


def _open_chamber(config: BenchConfig, url: str, clock: Clock, stack: ExitStack) -> Chamber:
    chamber_config = _chamber_config(config)
    chamber = open_chamber(url, chamber_config.dialect, clock=clock, **chamber_config.driver_options())
    chamber.connect()
    stack.callback(chamber.close)
    return chamber
