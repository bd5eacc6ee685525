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
