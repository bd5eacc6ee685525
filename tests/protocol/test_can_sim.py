"""IMU over CAN end to end: SimCanImu -> python-can virtual bus -> ImuReceiver."""

from __future__ import annotations

import itertools
import threading
import time

import can
import numpy as np
import pytest

from bench.model.imu import NoiseModel, default_sim_imu
from bench.sim.can_imu import SimCanImu
from bench.sim.controller import SimController
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from drivers.clock import ManualClock
from drivers.errors import ImuConfigError, ImuConnectionError
from drivers.imu import ImuSampleBlock, decode_frames, default_fd_layout, default_layout, frames_from_messages
from drivers.imu.receiver import ImuReceiver
from tests.helpers.run import wait_for

_channels = itertools.count()
M = len(default_layout().messages)


@pytest.fixture
def buses():
    """Two virtual buses on a channel no other test uses; both shut down afterwards."""
    channel = f"test_can_sim_{next(_channels)}"
    tx = can.Bus(interface="virtual", channel=channel)
    rx = can.Bus(interface="virtual", channel=channel)
    yield tx, rx
    tx.shutdown()
    rx.shutdown()


def moving_table() -> SimTable:
    table = SimTable()
    table.move_to(0.0, (30.0, -20.0, 10.0), rate_dps=20.0, accel_dps2=40.0)
    table.turn(0.1, "inner", "ccw", 1, 30.0, 60.0)
    return table


def make_imu(noise: NoiseModel | None = None) -> SimImu:
    return SimImu(default_sim_imu(), NoiseModel() if noise is None else noise, rate_hz=1000.0, seed=11)


def receive_all(receiver: ImuReceiver) -> ImuSampleBlock:
    blocks = []
    for _ in range(100):       # bounded: the virtual bus delivers synchronously
        block = receiver.poll(timeout_s=0.0)
        blocks.append(block)
        if not len(block):
            break
    blocks.append(receiver.flush())
    return ImuSampleBlock.concatenate(blocks, receiver.rate_hz)


def test_increments_arrive_exactly_as_generated(buses):
    tx, rx = buses
    table = moving_table()
    sim = SimCanImu(table, make_imu(), tx)
    twin = make_imu().generate(moving_table(), 0.4)          # same seed: the same samples
    logged: list[can.Message] = []
    with ImuReceiver(rx, rate_hz=1000.0, on_frames=logged.extend) as receiver:
        sent = sim.step_to(0.2) + sim.step_to(0.4)
        block = receive_all(receiver)
        stats = receiver.stats
    assert sent == 400 * M == len(logged) == stats.frames
    assert stats.samples == 400 and stats.frame_faults == 0 and stats.lost_samples == 0
    assert block.counter.tolist() == twin.counter.tolist()
    assert np.array_equal(block.gyro_counts, twin.gyro_counts)   # quantised sim: integer counts, exact
    assert np.array_equal(block.acc_counts, twin.acc_counts)
    assert np.abs(block.gyro_rate).max() > 1e5                      # the turn is in there
    assert np.all(block.temperature_c == 25.0) and not block.status.any()
    # the logged raw frames decode in bulk to the same samples
    bulk_block, bulk_stats = decode_frames(*frames_from_messages(logged, width=8), rate_hz=1000.0)
    assert bulk_stats == stats
    assert np.array_equal(bulk_block.gyro_counts, block.gyro_counts)
    assert np.array_equal(bulk_block.receive_time_s, block.receive_time_s)


@pytest.mark.parametrize("fd", [False, True])
def test_unquantised_increments_to_the_encoding_resolution(buses, fd):
    tx, rx = buses
    layout = default_fd_layout() if fd else default_layout()
    step = layout.scale[0]
    sim = SimCanImu(moving_table(), make_imu(NoiseModel.off()), tx, layout=layout)
    twin = make_imu(NoiseModel.off()).generate(moving_table(), 0.3)
    with ImuReceiver(rx, layout, rate_hz=1000.0) as receiver:
        sim.step_to(0.3)
        block = receive_all(receiver)
    assert len(block) == 300
    assert np.abs(block.gyro_counts - twin.gyro_counts).max() <= step * (1 + 1e-6)
    assert np.abs(block.acc_counts - twin.acc_counts).max() <= step * (1 + 1e-6)
    # sums (what the solver integrates) carry the remainder: within half a step (+ float rounding)
    err = np.cumsum(block.gyro_counts - twin.gyro_counts, axis=0)
    assert np.abs(err).max() <= 0.5 * step + 1e-6


def _missing(block, n):
    return sorted(set(range(n)) - set(block.counter.tolist()))


@pytest.mark.parametrize("fault, expected, missing", [
    (lambda s: s.drop_frames(1), dict(incomplete_samples=1), [100]),
    (lambda s: s.drop_frames(M), dict(counter_gaps=1), [100]),
    (lambda s: s.drop_frames(2, frame_id=0x104), dict(incomplete_samples=2), [100, 101]),
    (lambda s: s.corrupt_crc(1), dict(crc_errors=1, incomplete_samples=1), [100]),
    (lambda s: s.wrong_length(1, frame_id=0x106), dict(wrong_length=1, incomplete_samples=1), [100]),
    (lambda s: s.swap_frames(), dict(out_of_order=1), []),
])
def test_faults_on_demand_are_counted_and_the_rest_intact(buses, fault, expected, missing):
    tx, rx = buses
    sim = SimCanImu(moving_table(), make_imu(), tx)
    twin = make_imu().generate(moving_table(), 0.2)
    with ImuReceiver(rx, rate_hz=1000.0) as receiver:
        sim.step_to(0.1)            # samples 0..99
        fault(sim)
        sim.step_to(0.2)            # the fault hits sample 100 onwards
        block = receive_all(receiver)
        stats = receiver.stats.as_dict()
    for name in ("crc_errors", "wrong_length", "unknown_id", "late", "duplicates", "out_of_order",
                 "incomplete_samples", "counter_gaps"):
        assert stats[name] == expected.get(name, 0), name
    assert _missing(block, 200) == missing
    keep = np.isin(twin.counter, block.counter)
    assert np.array_equal(block.gyro_counts, twin.gyro_counts[keep])
    assert np.array_equal(block.acc_counts, twin.acc_counts[keep])


def test_background_thread_with_a_controller_and_a_simulated_clock(buses):
    tx, rx = buses
    clock = ManualClock()
    controller = SimController(moving_table(), clock=clock)
    sim = SimCanImu(controller, make_imu(), tx)
    with ImuReceiver(rx, rate_hz=1000.0) as receiver:
        sim.start(period_s=0.002)
        try:
            blocks, deadline = [], time.monotonic() + 5.0
            for _ in range(30):
                clock.advance(0.01)
                blocks.append(receiver.poll(timeout_s=0.02))
                if time.monotonic() > deadline:
                    break
        finally:
            sim.stop()
        assert not sim.running
        assert not any(t.name == "SimCanImu" for t in threading.enumerate())
        assert sum(len(b) for b in blocks) > 0          # the thread did send while running
        sim.step()                                      # catch up with the simulated clock
        blocks.append(receive_all(receiver))
        block = ImuSampleBlock.concatenate(blocks, 1000.0)
        stats = receiver.stats
    assert len(block) == sim.samples_sent == round(controller.now() * 1000.0) == 300
    assert block.counter.tolist() == list(range(300))
    assert stats.lost_samples == 0 and stats.frame_faults == 0


def test_thread_in_real_time(buses):
    tx, rx = buses
    with ImuReceiver(rx, rate_hz=1000.0) as receiver:
        t0 = time.monotonic()
        sim = SimCanImu(SimTable(), make_imu(), tx)
        with sim:
            sim.start(period_s=0.005)
            # however slow the machine: wait for the thread to have sent 100 samples (it never runs ahead of time)
            wait_for(lambda: sim.samples_sent >= 100, 30.0, "100 samples sent")
        elapsed = time.monotonic() - t0
        block = receive_all(receiver)
    assert 100 <= len(block) <= elapsed * 1000.0 + 1
    assert receiver.stats.lost_samples == 0 and len(block) == sim.samples_sent


def test_feeding_something_that_is_not_a_frame():
    from drivers.errors import ImuFrameError
    from drivers.imu import StreamDecoder

    decoder = StreamDecoder()
    with pytest.raises(ImuFrameError):
        decoder.feed([0x100], [[None] * 8], None, [0.0])
    with pytest.raises(ImuFrameError):
        decoder.feed([0x100], ["abcdefgh"], None, [0.0])
    assert decoder.stats.frames == 0


def test_receiver_opens_and_closes_its_own_bus():
    channel = f"test_can_sim_{next(_channels)}"
    receiver = ImuReceiver({"interface": "virtual", "channel": channel}, rate_hz=1000.0)
    tx = can.Bus(interface="virtual", channel=channel)
    try:
        sim = SimCanImu(SimTable(), make_imu(), tx)
        sim.step_to(0.01)
        assert len(receiver.poll(timeout_s=0.1)) == 10
    finally:
        receiver.close()
        receiver.close()            # idempotent
        tx.shutdown()
    assert receiver.bus._open is False      # it owned the bus and shut it down
    with pytest.raises(ImuConnectionError, match="closed"):
        receiver.poll()


def test_receiver_leaves_a_callers_bus_open(buses):
    tx, rx = buses
    with ImuReceiver(rx) as receiver:
        assert receiver.poll(timeout_s=0.01).counter.size == 0
    tx.send(can.Message(arbitration_id=0x100, data=bytes(8), is_extended_id=False))
    assert rx.recv(timeout=0.1) is not None


def test_bus_that_cannot_open_names_interface_and_channel():
    with pytest.raises(ImuConnectionError, match=r"interface 'nosuchbus', channel 'can7'"):
        ImuReceiver({"interface": "nosuchbus", "channel": "can7"})
    with pytest.raises(ImuConnectionError, match=r"interface 'socketcan', channel 'nosuchcan9'"):
        ImuReceiver({"interface": "socketcan", "channel": "nosuchcan9"})
    with pytest.raises(ImuConfigError):
        ImuReceiver("socketcan")


def test_bus_failure_while_receiving(buses):
    tx, rx = buses
    receiver = ImuReceiver(rx)
    rx.shutdown()
    with pytest.raises(ImuConnectionError, match="failed while receiving"):
        receiver.poll()


def test_error_frames_are_logged_not_decoded(buses):
    tx, rx = buses
    logged = []
    with ImuReceiver(rx, on_frames=logged.extend) as receiver:
        tx.send(can.Message(arbitration_id=0x100, is_error_frame=True, data=bytes(8), is_extended_id=False))
        tx.send(can.Message(arbitration_id=0x101, is_remote_frame=True, is_extended_id=False))
        receiver.poll(timeout_s=0.1)
        assert len(logged) == 2 and receiver.non_data_frames == 2 and receiver.stats.frames == 0


def test_fault_arguments_are_checked(buses):
    tx, _ = buses
    sim = SimCanImu(SimTable(), make_imu(), tx)
    with pytest.raises(ValueError):
        sim.drop_frames(0)
    with pytest.raises(ValueError, match="0x7ff"):
        sim.corrupt_crc(1, frame_id=0x7FF)
    with pytest.raises(TypeError):
        SimCanImu(object(), make_imu(), tx)


def test_a_poll_returns_on_a_bus_that_never_runs_dry():
    """A bus delivering frames as fast as they are read (a saturated SLCAN link): the poll drained 'until
    empty' and never returned, starving the sequencer that checks the table between polls."""
    from drivers.imu import ImuEncoder, default_layout
    from drivers.imu.receiver import MAX_POLL_FRAMES, ImuReceiver

    encoded = ImuEncoder(default_layout()).encode(np.arange(1), np.zeros((1, 3)), np.zeros((1, 3)), 25.0, 0)
    key, data = encoded.frame(0)

    class EndlessBus(can.BusABC):
        def __init__(self):
            super().__init__(channel="endless")
            self.sent = 0

        def _recv_internal(self, timeout):
            self.sent += 1
            return can.Message(arbitration_id=key, data=data, is_extended_id=False), False

        def send(self, msg, timeout=None):
            raise NotImplementedError

    bus = EndlessBus()
    receiver = ImuReceiver(bus, rate_hz=100.0)
    receiver.poll(timeout_s=0.0)
    assert 0 < receiver.frames_received <= MAX_POLL_FRAMES
    receiver.poll(timeout_s=0.0)          # and again: each poll takes its share and returns
    assert receiver.frames_received <= 2 * MAX_POLL_FRAMES
    bus.shutdown()
