"""The devices bundle (`bench.run.devices`): the simulator's opener, the close order, a failed open."""

from __future__ import annotations

import dataclasses

import pytest

import bench.run.devices as devices_module
from bench.config.load import parse_config
from bench.errors import BenchError
from bench.run.devices import DRIVERS, SIMULATOR, device_opener
from bench.sim.world import PumpedReceiver, SimWorld
from drivers.imu.receiver import ImuReceiver
from tests.helpers.run import config_text, thermal_config_text


@pytest.fixture
def closed(monkeypatch) -> list[str]:
    """The devices' closes, in order, as the opener's bundle makes them."""
    closes: list[str] = []

    def recording(name, close):
        def wrapped():
            closes.append(name)
            close()
        return wrapped

    def wrap_opener(name, opener):
        def opened(*args, **kwargs):
            device = opener(*args, **kwargs)
            device.close = recording(name, device.close)
            return device
        return opened

    class Receiver(ImuReceiver):
        def close(self) -> None:
            closes.append("receiver")
            super().close()

    class World(SimWorld):
        def close(self) -> None:
            closes.append("world")
            super().close()

    monkeypatch.setattr(devices_module, "open_turntable", wrap_opener("table", devices_module.open_turntable))
    monkeypatch.setattr(devices_module, "open_chamber", wrap_opener("chamber", devices_module.open_chamber))
    monkeypatch.setattr(devices_module, "ImuReceiver", Receiver)
    monkeypatch.setattr(devices_module, "SimWorld", World)
    return closes


def _config(text, tmp_path):
    return parse_config(text, source=str(tmp_path / "bench.toml"), base_dir=tmp_path)


def test_the_openers_are_chosen_by_sim_once():
    assert device_opener(True) is SIMULATOR and SIMULATOR.simulated
    assert device_opener(False) is DRIVERS and not DRIVERS.simulated


def test_the_simulator_opens_its_world_and_closes_each_device_once_last_opened_first(tmp_path, closed):
    devices = SIMULATOR.open(_config(thermal_config_text(), tmp_path), True)
    try:
        assert devices.simulated and devices.world is not None and devices.chamber is not None
        assert devices.clock is devices.world.clock and devices.imu_check == ""
        assert isinstance(devices.imu_source(), PumpedReceiver)
        before_s = devices.clock.now()
        devices.let_idle_time_pass(2.5)
        assert devices.clock.now() == before_s + 2.5
        devices.table.read_state()          # the driver talks to the simulated controller
    finally:
        devices.close()
    devices.close()                         # a second close closes nothing again
    assert closed == ["chamber", "receiver", "table", "world"]


def test_a_thermal_plan_without_a_chamber_closes_what_the_opener_opened(tmp_path, closed):
    with pytest.raises(BenchError, match=r"a thermal plan needs a \[chamber\]"):
        SIMULATOR.open(_config(config_text(), tmp_path), True)
    assert closed == ["receiver", "table", "world"]


def _units_config(channels: list[str]) -> str:
    """A configuration of one [[imu]] unit per channel of python-can's virtual interface (ids +16 on a shared one)."""
    text = config_text()
    start, end = text.index("[imu]"), text.index("[plan]")
    seen: dict[str, int] = {}
    entries = ""
    for k, channel in enumerate(channels):
        offset = 16 * seen.get(channel, 0)
        seen[channel] = seen.get(channel, 0) + 1
        entries += (f'[[imu]]\ninterface = "virtual"\nchannel = "{channel}"\nrate_hz = 100.0\nid_offset = {offset}\n'
                    f'identity = {{ model = "sim", serial = "U{k}" }}\n\n')
    return text[:start] + entries + text[end:]


def test_units_on_several_buses_of_one_clock_map_their_frames_with_the_reference_units_offset():
    """The reference unit alone on bus a, units 1 and 2 sharing bus b (one opened bus, a view each), every interface
    stamping frames with this host's clock: one time base for all, its offset from the reference unit's first frame.
    A frame of unit 1 read late keeps its own time (its own offset, taken at its first read, made it as late as the
    read: its windows, cut by receive time in the reference unit's, were shifted by that)."""
    import contextlib
    import uuid

    import can

    from bench.run.devices import _clock_of, _UnitBuses
    from drivers.imu.shared_bus import BusView

    a, b = f"devices-a-{uuid.uuid4().hex[:8]}", f"devices-b-{uuid.uuid4().hex[:8]}"
    config = parse_config(_units_config([a, b, b]))
    now = [1000.0]
    senders = {channel: can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) for channel in (a, b)}
    with contextlib.ExitStack() as stack:
        for sender in senders.values():
            stack.callback(sender.shutdown)
        buses = _UnitBuses(config, lambda: now[0], stack)
        (bus_a, time_base), (view_1, base_1), (view_2, base_2) = buses[0], buses[1], buses[2]
        assert isinstance(bus_a, dict) and isinstance(view_1, BusView) and isinstance(view_2, BusView)
        assert base_1 is time_base and base_2 is time_base
        reference = ImuReceiver(bus_a, config.units[0].layout, 100.0, time_base=time_base)
        stack.callback(reference.close)
        unit = ImuReceiver(view_1, config.units[1].layout, 100.0, time_base=base_1)
        for channel, layout, stamp in ((a, config.units[0].layout, 10.0), (b, config.units[1].layout, 11.0)):
            senders[channel].send(can.Message(timestamp=stamp, arbitration_id=layout.keys[0], data=bytes(8),
                                              is_extended_id=False))
        seen: list[float] = []
        unit.on_frames = lambda batch: seen.extend(batch.timestamps.tolist())
        reference.poll(timeout_s=1.0)
        assert time_base.offset_s == 10.0 - 1000.0
        now[0] = 2000.0                          # unit 1's frame is read long after it came
        unit.poll(timeout_s=1.0)
        assert seen == [1001.0]
    assert _clock_of(config.units[1]) == "host"
    socketcand = dataclasses.replace(config.units[1], interface="socketcand", bus_options={"host": "10.0.0.7"})
    assert _clock_of(socketcand) == "socketcand host 10.0.0.7"
    pcan = dataclasses.replace(config.units[1], interface="pcan", channel="PCAN_USBBUS1")
    assert _clock_of(pcan) != _clock_of(dataclasses.replace(pcan, channel="PCAN_USBBUS2"))   # each its own clock
