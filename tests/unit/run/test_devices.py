"""The devices bundle (`bench.run.devices`): the simulator's opener, the close order, a failed open."""

from __future__ import annotations

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


def test_a_shared_bus_without_the_reference_unit_takes_its_clock_offset_from_fresh_frames():
    """Units 1 and 2 share a bus the reference unit is not on. Their bus opens when unit 1 asks for it, so frames
    sent on it before (while the reference unit was checked) never reach their views: the time base's offset comes
    from the first frame read at once. (Opened with the others, the old frame, stamped 10 s before, was mapped to
    the run clock's now: every later sample 10 s early, and the units' dwell windows empty.)"""
    import contextlib
    import uuid

    import can

    from bench.run.devices import _UnitBuses

    a, b = f"devices-a-{uuid.uuid4().hex[:8]}", f"devices-b-{uuid.uuid4().hex[:8]}"
    config = parse_config(_units_config([a, b, b]))
    now = [1000.0]
    sender = can.Bus(interface="virtual", channel=b, preserve_timestamps=True)
    with contextlib.ExitStack() as stack:
        stack.callback(sender.shutdown)
        buses = _UnitBuses(config, lambda: now[0], stack)
        assert isinstance(buses[0][0], dict)           # alone on its bus: its receiver opens it
        key = config.units[1].layout.keys[0]
        sender.send(can.Message(timestamp=10.0, arbitration_id=key, data=bytes(8), is_extended_id=False))
        view, time_base = buses[1]
        now[0] = 2000.0
        sender.send(can.Message(timestamp=20.0, arbitration_id=key, data=bytes(8), is_extended_id=False))
        receiver = ImuReceiver(view, config.units[1].layout, 100.0, time_base=time_base)
        receiver.poll(timeout_s=1.0)
        assert receiver.frames_received == 1 and time_base.offset_s == 20.0 - 2000.0
        assert buses[2][1] is time_base                # the bus's units share its time base
