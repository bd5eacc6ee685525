"""Before anything moves, a hardware run checks the IMU stream (issue 14, item 3).

A silent IMU was found at the first dwell, after the servos were on and the table had moved.
The table here is the simulator served over loopback as real hardware would be (`url` a TCP
address, not "sim"); the IMU is on python-can's in-process virtual bus, silent, sending frames
nothing decodes, or the simulated IMU sending in wall-clock time at some rate.
"""

from __future__ import annotations

import uuid

import can
import pytest

from bench.config.load import parse_config
from bench.model.imu import default_sim_imu
from bench.run.imu_check import ImuCheckError, check_imu_stream
from bench.sim.can_imu import SimCanImu
from bench.sim.controller import SimController
from bench.sim.imu import SimImu
from bench.sim.scpi_server import ScpiSimHandler
from bench.sim.serve import LineServer
from bench.sim.world import SimVirtualBus
from drivers.imu import default_packed_layout
from drivers.imu.receiver import ImuReceiver
from tests.helpers.run import RATE_HZ, cli, config_text


@pytest.fixture
def served_table():
    controller = SimController()
    with LineServer(ScpiSimHandler(controller)) as server:
        host, port = server.listen_tcp("127.0.0.1", 0)
        yield controller, f"tcp://{host}:{port}"


@pytest.fixture
def channel():
    return f"turntable-bench-imu-check-{uuid.uuid4().hex[:8]}"


def _config(tmp_path, url: str, channel: str):
    text = config_text(url=url).replace('channel = "turntable-bench-test"', f'channel = "{channel}"')
    assert channel in text
    path = tmp_path / "bench.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _sender(controller, channel: str, rate_hz: float, layout=None):
    """The simulated IMU on the table, sending in wall-clock time on `channel` from a thread. Its frames
    keep the times the IMU stamped them with, so the measured rate does not depend on how promptly the
    thread runs on a loaded machine."""
    bus = SimVirtualBus(channel=channel, preserve_timestamps=True)
    imu = SimCanImu(controller, SimImu(default_sim_imu(), rate_hz=rate_hz), bus, layout)
    imu.start()
    return imu, bus


def _run_refused(tmp_path, controller, url, channel, fragment):
    out = tmp_path / "out"
    rc, _, stderr = cli(["run", "--config", str(_config(tmp_path, url, channel)), "--out", str(out)])
    assert rc == 2, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bench run: cannot start: ") and "nothing moved" in lines[0]
    assert fragment in lines[0], lines[0]
    assert not any(axis.enabled for axis in controller.state().axes)     # the servos were never switched on
    assert not list(tmp_path.rglob("*.mcap"))


@pytest.mark.slow
def test_a_silent_imu_stops_the_run_before_anything_moves(tmp_path, served_table, channel):
    controller, url = served_table
    _run_refused(tmp_path, controller, url, channel,
                 f"no IMU frames on interface virtual channel {channel} in 3 s: is the IMU powered and on this bus?")


def test_frames_that_do_not_decode_stop_the_run_before_anything_moves(tmp_path, served_table, channel):
    controller, url = served_table
    with can.Bus(interface="virtual", channel=channel) as bus:
        import threading

        stop = threading.Event()

        def chatter():                        # another device on the bus: frames, but no IMU
            for _ in range(2000):
                if stop.wait(0.002):
                    return
                bus.send(can.Message(arbitration_id=0x321, data=b"\x01\x02", is_extended_id=False))

        thread = threading.Thread(target=chatter, daemon=True)
        thread.start()
        try:
            _run_refused(tmp_path, controller, url, channel, "but no IMU sample decodes with the configured layout "
                         "(classic: 7 frames per sample, ids 0x100..0x106): ")
        finally:
            stop.set()
            thread.join(timeout=10)


def test_an_imu_at_another_rate_stops_the_run_before_anything_moves(tmp_path, served_table, channel):
    controller, url = served_table
    imu, bus = _sender(controller, channel, rate_hz=4 * RATE_HZ)
    try:
        _run_refused(tmp_path, controller, url, channel,
                     f"samples/s, the configuration says imu.rate_hz = {RATE_HZ:g}")
    finally:
        imu.stop()
        bus.shutdown()


@pytest.mark.slow
def test_an_imu_at_its_rate_passes_the_check(channel):
    controller = SimController()
    imu, bus = _sender(controller, channel, rate_hz=RATE_HZ)
    receiver = ImuReceiver({"interface": "virtual", "channel": channel}, rate_hz=RATE_HZ)
    try:
        finding = check_imu_stream(receiver, RATE_HZ, "the test bus")
        assert finding.startswith("IMU on the test bus: ") and "samples/s" in finding
        with pytest.raises(ImuCheckError, match="the configuration says imu.rate_hz = 200"):
            check_imu_stream(receiver, 200.0, "the test bus")
    finally:
        receiver.close()
        imu.stop()
        bus.shutdown()


def test_an_imu_sending_another_shipped_layout_is_named_before_anything_moves(tmp_path, served_table, channel):
    # the rig (or a real IMU) sends the packed layout, the configuration says classic: the one line says which
    # layout the frames are and what to set
    controller, url = served_table
    imu, bus = _sender(controller, channel, rate_hz=RATE_HZ, layout=default_packed_layout())
    try:
        _run_refused(tmp_path, controller, url, channel,
                     "the frames on the bus are those of the shipped layout 'packed' (packed: 3 frames per sample, "
                     'ids 0x120..0x122): set imu.layout = "packed"')
    finally:
        imu.stop()
        bus.shutdown()


def test_the_packed_layout_configured_passes_the_check(channel):
    controller = SimController()
    imu, bus = _sender(controller, channel, rate_hz=RATE_HZ, layout=default_packed_layout())
    config = parse_config(config_text().replace("rate_hz =", 'layout = "packed"\nrate_hz ='))
    receiver = ImuReceiver({"interface": "virtual", "channel": channel}, config.imu.layout, rate_hz=RATE_HZ)
    try:
        assert check_imu_stream(receiver, RATE_HZ, "the test bus").startswith("IMU on the test bus: ")
        assert receiver.stats.unknown_id == 0 and receiver.on_frames is None   # the check's id probe is gone
    finally:
        receiver.close()
        imu.stop()
        bus.shutdown()
