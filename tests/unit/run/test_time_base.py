"""One time base in a hardware run's log: CAN frame timestamps mapped onto the run clock (issue 14, item 2).

With a real python-can interface, /can/raw and /imu/samples carried the interface's epoch
timestamps (~1.8e9 s) while everything else carried the monotonic run clock (~1.7e3 s):
`mcap info` reported a duration of half a million hours.
"""

from __future__ import annotations

import time
import uuid

import can
import numpy as np
import pytest

from bench.config.load import parse_config
from bench.log.reader import read_log
from bench.model.imu import default_sim_imu
from bench.run.devices import DRIVERS
from bench.run.runner import BenchRun, compile_from_config
from bench.sim.can_imu import SimCanImu
from bench.sim.controller import SimController
from bench.sim.imu import SimImu
from bench.sim.scpi_server import ScpiSimHandler
from bench.sim.serve import LineServer
from drivers.clock import ManualClock
from drivers.imu import ImuEncoder, default_layout
from drivers.imu.receiver import ImuReceiver
from tests.helpers.run import RATE_HZ, config_text


@pytest.mark.slow        # about 2 s of a live IMU stream
def test_frames_and_samples_are_re_stamped_on_the_run_clock():
    channel = f"turntable-bench-time-base-{uuid.uuid4().hex[:8]}"
    run_clock = ManualClock(1234.5)
    logged: list[can.Message] = []
    with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as sender, \
            ImuReceiver({"interface": "virtual", "channel": channel}, rate_hz=100.0, time_base=run_clock.now,
                        on_frames=logged.extend) as receiver:
        encoded = ImuEncoder(default_layout()).encode(np.arange(20), np.zeros((20, 3)), np.zeros((20, 3)), 25.0, 0)
        epoch = time.time()
        for i in range(len(encoded)):          # stamped as an interface does: its own clock (the epoch here)
            key, data = encoded.frame(i)
            sender.send(can.Message(arbitration_id=key, data=data, is_extended_id=False, timestamp=epoch + i * 1e-3))
        blocks = [receiver.poll(timeout_s=1.0) for _ in range(3)]
    samples = sum(len(b) for b in blocks)
    assert samples == 20 and len(logged) == len(encoded)
    stamps = np.array([m.timestamp for m in logged])
    assert abs(stamps[0] - 1234.5) < 1e-9          # the first frame anchors the map at the run clock's now
    assert np.allclose(np.diff(stamps), 1e-3, atol=1e-6)    # the interface's own spacing (to float precision)
    receive = np.concatenate([b.receive_time_s for b in blocks if len(b)])
    assert receive.min() >= 1234.5 and receive.max() < 1234.5 + 1.0
    base = receiver.time_base
    assert base is not None and base.offset_s == pytest.approx(epoch - 1234.5)
    assert base.as_dict()["can_lag_min_s"] <= base.as_dict()["can_lag_max_s"]


@pytest.mark.slow
def test_a_hardware_run_records_the_offset_and_logs_on_the_run_clock(tmp_path):
    """The IMU sends with the epoch stamps of python-can's virtual bus; the run's clock is monotonic."""
    channel = f"turntable-bench-time-base-{uuid.uuid4().hex[:8]}"
    controller = SimController()
    with LineServer(ScpiSimHandler(controller)) as server, \
            can.Bus(interface="virtual", channel=channel) as bus:
        host, port = server.listen_tcp("127.0.0.1", 0)
        imu = SimCanImu(controller, SimImu(default_sim_imu(), rate_hz=RATE_HZ), bus)
        imu.start()
        try:
            text = config_text(url=f"tcp://{host}:{port}").replace('"turntable-bench-test"', f'"{channel}"')
            config = parse_config(text, source=str(tmp_path / "bench.toml"), base_dir=tmp_path)
            with BenchRun(config, compile_from_config(config), devices=DRIVERS, out_dir=tmp_path / "out") as run:
                run.open()                   # checks the IMU stream: the time base is anchored by then
                log_path = run.log_path
        finally:
            imu.stop()
    offset = float(read_log(log_path).metadata["imu"]["can_time_offset_s"])
    # interface time = run time + offset: the epoch minus the monotonic clock, to the frames' latency
    assert offset == pytest.approx(time.time() - time.monotonic(), abs=5.0)
