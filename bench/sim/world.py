"""The whole simulated bench: table served over loopback, IMU on a virtual CAN bus, one simulated clock.

`SimWorld` is what `bench run --sim` (and a config whose table url is "sim") runs
against: the simulated controller is served in the configured dialect on 127.0.0.1
(Modbus TCP for modbus) and driven by the real driver through the real transport; the
simulated IMU sends DBC frames on a python-can virtual bus that the real receiver
reads. Time is a `SimClock`: it advances only when the sequencer sleeps, and each poll
of the IMU receiver first makes the simulated IMU send every sample up to the current
simulated time (`imu_source`), so a plan with realistic timing finishes far faster
than real time and the log carries simulated timestamps.
"""

from __future__ import annotations

import collections
import copy
import queue
import time
import uuid

import can
import numpy as np
from can.interfaces.virtual import VirtualBus, channels_lock

from bench.model.earth import Site
from bench.model.higher_order import HigherOrderTerms
from bench.model.imu import ImuCoefficients, NoiseModel
from bench.model.thermal import ImuThermal
from bench.sim.can_imu import SimCanImu
from bench.sim.controller import SimController
from bench.sim.imu import SimImu
from bench.sim.scpi_server import ScpiSimHandler
from bench.sim.serve import ClosedOnExit, Handler, LineServer
from bench.sim.table import SimTable, TableLimits
from bench.sim.units import SimUnit, mounted_view
from drivers.clock import ManualClock
from drivers.imu.frames import CanFrameBatch
from drivers.imu.layout import ImuLayout


class _BatchQueue(queue.Queue):
    """The receive queue of a `SimVirtualBus`: holds `Message`s and whole `CanFrameBatch`es."""


class SimVirtualBus(VirtualBus):
    """python-can's virtual bus with batch transfer, for both ends of the simulated IMU's link.

    python-can's `VirtualBus.send` deep-copies every message for every receiver, which
    costs more than everything else the simulator does per frame. `send_frames` puts a
    whole `CanFrameBatch` (arrays, never changed once made) on the queue of every
    `SimVirtualBus` receiver as one item, and `recv_frames` takes what is queued as one
    batch: no `Message` is built on the way. A plain python-can virtual bus on the same
    channel still gets `Message`s, and `recv` here still returns one frame at a time.
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        with channels_lock:
            plain = self.queue
            self.queue = _BatchQueue(plain.maxsize)
            self.channel[self.channel.index(plain)] = self.queue

    def _receivers(self) -> list[queue.Queue]:
        return [q for q in self.channel if q is not self.queue or self.receive_own_messages]

    def send_frames(self, batch: CanFrameBatch) -> None:
        """Send a batch of frames: one item and one wake-up per receiver (a plain virtual bus gets messages)."""
        self._check_if_open()
        if not len(batch):
            return
        if not self.preserve_timestamps:
            batch = batch.restamped(np.full(len(batch), time.time()))
        for bus_queue in self._receivers():
            if isinstance(bus_queue, _BatchQueue):
                items: list = [batch]
            else:
                items = batch.messages()
                for m in items:
                    m.channel, m.is_rx = self.channel_id, bus_queue is not self.queue
            with bus_queue.mutex:                 # queue.Queue's own lock and condition
                bus_queue.queue.extend(items)
                bus_queue.unfinished_tasks += len(items)
                bus_queue.not_empty.notify()

    def send_batch(self, messages: list[can.Message]) -> None:
        """Send many frames at once: one lock and one wake-up per receiver instead of one per frame."""
        self._check_if_open()
        for k, bus_queue in enumerate(self._receivers()):
            batch = messages if k == 0 else [copy.copy(m) for m in messages]
            for m in batch:
                m.channel, m.is_rx = self.channel_id, bus_queue is not self.queue
            with bus_queue.mutex:
                bus_queue.queue.extend(batch)
                bus_queue.unfinished_tasks += len(batch)
                bus_queue.not_empty.notify()

    def _take(self, limit: int | None) -> list:
        """Queued items holding at most `limit` frames (a batch split if needed), under the queue's lock."""
        out: list = []
        with self.queue.mutex:
            pending = self.queue.queue
            room = limit
            while pending and (room is None or room > 0):
                item = pending.popleft()
                if isinstance(item, CanFrameBatch):
                    if room is not None and len(item) > room:
                        pending.appendleft(item[room:])
                        item = item[:room]
                    out.append(item)
                    size = len(item)
                else:
                    out.append(item)
                    size = 1
                if room is not None:
                    room -= size
            self.queue.not_full.notify()
        return out

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        self._check_if_open()
        try:
            item = self.queue.get(block=True, timeout=timeout)
        except queue.Empty:
            return None, False
        if isinstance(item, CanFrameBatch):
            if len(item) > 1:
                with self.queue.mutex:
                    self.queue.queue.appendleft(item[1:])
            return item.message(0), False
        return item, False

    def drain_messages(self, limit: int | None = None) -> list[can.Message]:
        """Every frame queued for this bus (at most `limit`), taken at once."""
        self._check_if_open()
        out: list[can.Message] = []
        for item in self._take(limit):
            if isinstance(item, CanFrameBatch):
                out += item.messages()
            else:
                out.append(item)
        return out

    def recv_frames(self, timeout: float | None = 0.0, limit: int | None = None) -> CanFrameBatch | None:
        """Wait up to `timeout` for a frame, then take every frame queued (at most `limit`) as one batch;
        None when nothing came."""
        self._check_if_open()
        if limit is not None and limit <= 0:
            return None
        try:
            first = self.queue.get(block=True, timeout=timeout) if timeout is None or timeout > 0 else \
                self.queue.get_nowait()
        except queue.Empty:
            return None
        with self.queue.mutex:
            self.queue.queue.appendleft(first)
        items = self._take(limit)
        batches: list[CanFrameBatch] = []
        loose: list[can.Message] = []
        for item in items:
            if isinstance(item, CanFrameBatch):
                if loose:
                    batches.append(CanFrameBatch.from_messages(loose))
                    loose = []
                batches.append(item)
            else:
                loose.append(item)
        if loose:
            batches.append(CanFrameBatch.from_messages(loose))
        return CanFrameBatch.concat(batches) if batches else None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        if not self.preserve_timestamps:
            msg.timestamp = time.time()
        first = True
        for bus_queue in self.channel:
            if bus_queue is self.queue and not self.receive_own_messages:
                continue
            out = msg if first else copy.copy(msg)
            first = False
            out.channel, out.is_rx = self.channel_id, bus_queue is not self.queue
            try:
                bus_queue.put(out, block=True, timeout=timeout)
            except queue.Full as exc:
                raise can.CanOperationError("the virtual bus queue of a receiver is full") from exc


class SimClock(ManualClock):
    """A manual clock that calls its hooks after every advance (outside its lock)."""

    def __init__(self, start_s: float = 0.0):
        super().__init__(start_s)
        self._hooks: list = []

    def add_hook(self, hook) -> None:
        self._hooks.append(hook)

    def advance(self, seconds: float) -> None:
        super().advance(seconds)
        for hook in self._hooks:
            hook()


class PumpedReceiver:
    """An IMU receiver that runs `pump()` (the simulated IMU sending up to now) before each poll."""

    def __init__(self, receiver, pump):
        self._receiver, self._pump = receiver, pump

    def poll(self, *args, **kwargs):
        self._pump()
        return self._receiver.poll(*args, **kwargs)

    def flush(self):
        return self._receiver.flush()

    @property
    def stats(self):
        return self._receiver.stats

    @property
    def on_frames(self):
        return self._receiver.on_frames

    @on_frames.setter
    def on_frames(self, callback) -> None:
        self._receiver.on_frames = callback

    def close(self) -> None:
        self._receiver.close()


_DEFAULT_TABLE_LIMITS = TableLimits()


class SimWorld(ClosedOnExit):
    """A simulated table (served in `dialect`) and IMU (on a virtual CAN bus) on one `SimClock`."""

    def __init__(self, site: Site, coefficients: ImuCoefficients, noise: NoiseModel, *,
                 black_box_rad: np.ndarray | None = None, dialect: str = "scpi", imu_rate_hz: float = 200.0,
                 layout: ImuLayout | None = None, seed: int = 0, table_limits: TableLimits = _DEFAULT_TABLE_LIMITS,
                 register_map=None, imu_thermal: ImuThermal | None = None,
                 higher_order: HigherOrderTerms | None = None):
        self.clock = SimClock()
        self.dialect = dialect
        self.table = SimTable(site, black_box_rad=black_box_rad, limits=table_limits)
        self.controller = SimController(self.table, self.clock)
        self._closers: list = []
        self.units: list[SimCanImu] = []      # the other units of a run of several (`add_unit`)
        self._unit_buses: dict[str, tuple[str, SimVirtualBus]] = {}   # bus name -> (channel, sender)
        try:
            self.table_url = self._serve(dialect, register_map)
            self.imu = SimImu(coefficients, noise, rate_hz=imu_rate_hz, seed=seed, thermal=imu_thermal,
                              higher_order=higher_order)
            self.can_channel = f"turntable-bench-sim-{uuid.uuid4().hex[:12]}"
            # Frames keep the simulated time they were sent at (the run clock's time base).
            self.sender_bus = SimVirtualBus(channel=self.can_channel, preserve_timestamps=True)
            self._closers.append(self.sender_bus.shutdown)
            self.can_imu = SimCanImu(self.controller, self.imu, self.sender_bus, layout)
        except BaseException:
            self.close()
            raise

    def add_unit(self, unit: SimUnit, reference_bus: str) -> SimCanImu:
        """Another simulated IMU on this world's table (a run of several units): `unit`'s truth, noise, rate, layout
        and mounting, sending on the virtual bus named `unit.bus` (the world's own IMU sends on `reference_bus`;
        every other name is a bus of its own). It is stepped with the world's IMU (`imu_source`)."""
        imu = SimImu(unit.coefficients, unit.noise, rate_hz=unit.rate_hz, seed=unit.seed,
                     higher_order=unit.higher_order)
        can_imu = SimCanImu(self.controller, imu, self._unit_sender(unit.bus, reference_bus), unit.layout)
        if unit.mounting is not None:
            can_imu.table = mounted_view(self.table, unit.mounting)
        self.units.append(can_imu)
        return can_imu

    def mount_imu(self, mounting) -> None:
        """The world's own IMU mounted with `mounting` (rows: its axes in fixture coordinates) on the fixture."""
        self.can_imu.table = mounted_view(self.table, mounting)

    def _unit_sender(self, bus: str, reference_bus: str) -> SimVirtualBus:
        if bus == reference_bus:
            return self.sender_bus
        if bus not in self._unit_buses:
            channel = f"turntable-bench-sim-{uuid.uuid4().hex[:12]}"
            sender = SimVirtualBus(channel=channel, preserve_timestamps=True)
            self._closers.append(sender.shutdown)
            self._unit_buses[bus] = (channel, sender)
        return self._unit_buses[bus][1]

    def unit_receiver_bus(self, bus: str, reference_bus: str) -> SimVirtualBus:
        """A receiver's bus on the virtual bus named `bus` (`add_unit`), closed with the world."""
        if bus == reference_bus:
            return self.receiver_bus()
        self._unit_sender(bus, reference_bus)
        receiver = SimVirtualBus(channel=self._unit_buses[bus][0])
        self._closers.append(receiver.shutdown)
        return receiver

    def step_imus(self) -> None:
        """Every simulated IMU sends what it produced up to now (the world's own, then each unit's)."""
        self.can_imu.step()
        for unit in self.units:
            unit.step()

    def imu_source(self, receiver) -> "PumpedReceiver":
        """`receiver` (reading this world's bus) wrapped so that every poll first sends the
        samples the simulated IMU produced up to now: the IMU is stepped in as few, as
        large, batches as the reader asks for."""
        return PumpedReceiver(receiver, self.step_imus if self.units else self.can_imu.step)

    @property
    def bus_config(self) -> dict:
        """python-can Bus arguments for a receiver on this world's virtual bus."""
        return {"interface": "virtual", "channel": self.can_channel}

    def receiver_bus(self) -> SimVirtualBus:
        """A bus for the IMU receiver on this world's channel (closed with the world)."""
        bus = SimVirtualBus(channel=self.can_channel)
        self._closers.append(bus.shutdown)
        return bus

    def _serve(self, dialect: str, register_map) -> str:
        if dialect == "modbus":
            # local: bench.sim.modbus_server imports pymodbus (heavy), needed only for a Modbus table
            from bench.sim.modbus_server import ModbusSimServer

            modbus_server = ModbusSimServer(self.controller, register_map)
            self._closers.append(modbus_server.close)
            host, port = modbus_server.start_tcp("127.0.0.1", 0)
            return f"modbus+tcp://{host}:{port}"
        handler: Handler
        if dialect == "acutrol":
            # local, as the MN one: a dialect's server and codec are imported for a table that speaks it
            from bench.sim.acutrol_server import AcutrolSimHandler

            handler = AcutrolSimHandler(self.controller)
        elif dialect == "scpi":
            handler = ScpiSimHandler(self.controller)
        elif dialect == "mn":
            # local: see the Acutrol one
            from bench.sim.mn_server import MnSimHandler

            handler = MnSimHandler(self.controller)
        else:
            raise ValueError(f"no simulator for dialect {dialect!r}")
        server = LineServer(handler)
        self._closers.append(server.close)
        host, port = server.listen_tcp("127.0.0.1", 0)
        return f"tcp://{host}:{port}"

    def add_chamber(self, dialect: str = "ascii", register_map=None, physics=None, where: str = "tcp") -> str:
        """A simulated thermal chamber on this world's clock (`self.chamber`), served in `dialect` over loopback
        TCP (`where` 'tcp': ascii lines, Modbus TCP) or a new pty ('pty': ascii lines, Modbus RTU); returns the
        URL its driver opens (closed with the world)."""
        # local: the chamber's Modbus server imports pymodbus, needed only for a world with a chamber
        from bench.sim.chamber import SimChamber
        from bench.sim.chamber_server import serve_chamber

        self.chamber = SimChamber(physics, self.clock)
        close, url = serve_chamber(self.chamber, dialect, where, register_map=register_map)
        self._closers.append(close)
        return url

    def drive_imu_from_chamber(self, history_s: float = 60.0) -> None:
        """The thermal IMU's ambient becomes the simulated chamber's air: after every advance of the clock
        the air is sampled, and the case follows the piecewise-linear air through those samples (the IMU
        is stepped at most `history_s` behind the clock). Needs `add_chamber` and an IMU with a case."""
        chamber, case = getattr(self, "chamber", None), self.imu.case
        if chamber is None or case is None:
            raise ValueError("driving the IMU from the chamber needs a chamber (add_chamber) and a thermal IMU")
        times: collections.deque[float] = collections.deque([self.clock.now()])
        air: collections.deque[float] = collections.deque([chamber.temperature_c])

        def sample() -> None:
            now = self.clock.now()
            if now > times[-1]:
                times.append(now)
                air.append(chamber.temperature_c)
                while len(times) > 2 and times[1] < now - history_s:
                    times.popleft()
                    air.popleft()

        def ambient(at_s: np.ndarray) -> np.ndarray:
            return np.interp(at_s, times, air)

        self.clock.add_hook(sample)
        case.set_ambient(ambient)

    def close(self) -> None:
        for close in reversed(self._closers):
            try:
                close()
            except Exception:  # noqa: BLE001 - closing everything matters more than the first failure
                pass
        self._closers.clear()
