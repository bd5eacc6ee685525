"""`CanFrameBatch`: python-can messages <-> arrays without loss, the log's bytes from the arrays, and the simulator's
virtual bus carrying whole batches (a plain python-can bus on the same channel still gets messages)."""

from __future__ import annotations

import uuid

import can
import numpy as np
import pytest

from bench.log.format import encode_can_batch, encode_can_frames
from bench.sim.world import SimVirtualBus
from drivers.imu import ImuSampleBlock, default_layout
from drivers.imu.encoder import ImuEncoder
from drivers.imu.frames import CanFrameBatch
from drivers.imu.receiver import ImuReceiver


def _messages(n: int = 300, seed: int = 3) -> list[can.Message]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        fd = bool(rng.random() < 0.3)
        size = int(rng.choice([0, 1, 5, 8, 12, 64])) if fd else int(rng.integers(0, 9))
        remote = (not fd) and bool(rng.random() < 0.05)
        out.append(can.Message(timestamp=float(rng.random() * 100), arbitration_id=int(rng.integers(0, 1 << 29)),
                               is_extended_id=bool(rng.random() < 0.5), is_fd=fd,
                               bitrate_switch=fd and bool(rng.random() < 0.5),
                               error_state_indicator=fd and bool(rng.random() < 0.2), is_remote_frame=remote,
                               is_error_frame=bool(rng.random() < 0.03),
                               data=None if remote else bytes(rng.integers(0, 256, size, dtype=np.uint8)),
                               check=False))
    return out


def _same(a: can.Message, b: can.Message) -> bool:
    return (a.timestamp, a.arbitration_id, a.is_extended_id, a.is_fd, a.bitrate_switch, a.error_state_indicator,
            a.is_remote_frame, a.is_error_frame, bytes(a.data or b"")) == \
        (b.timestamp, b.arbitration_id, b.is_extended_id, b.is_fd, b.bitrate_switch, b.error_state_indicator,
         b.is_remote_frame, b.is_error_frame, bytes(b.data or b""))


def test_messages_round_trip_and_the_log_bytes_match():
    messages = _messages()
    batch = CanFrameBatch.from_messages(messages)
    assert len(batch) == len(messages)
    assert all(_same(a, b) for a, b in zip(messages, batch))
    assert _same(batch[-1], messages[-1]) and len(batch[10:20]) == 10
    with pytest.raises(IndexError):
        batch[len(messages)]
    # mixed lengths and flags, then one length only: the records the message-by-message encoder writes
    assert encode_can_batch(batch) == encode_can_frames(messages)
    eights = [m for m in messages if len(m.data or b"") == 8]
    assert encode_can_batch(CanFrameBatch.from_messages(eights)) == encode_can_frames(eights)
    assert encode_can_batch(batch)[1] == max(m.timestamp for m in messages)


def test_data_frames_leave_error_and_remote_frames_out():
    messages = _messages()
    kept = CanFrameBatch.from_messages(messages).data_frames()
    expected = [m for m in messages if not (m.is_error_frame or m.is_remote_frame)]
    assert len(kept) == len(expected) and all(_same(a, b) for a, b in zip(expected, kept))


def _encoded_batch(n_samples: int, t0: float = 0.0) -> CanFrameBatch:
    layout = default_layout()
    frames = ImuEncoder(layout, rate_hz=200.0).encode(np.arange(n_samples), np.ones((n_samples, 3)),
                                                      np.ones((n_samples, 3)))
    return CanFrameBatch(t0 + frames.sample * 0.005, frames.ids, frames.data, frames.lengths)


def test_the_sim_bus_carries_batches_and_a_plain_bus_gets_messages():
    channel = f"test-batches-{uuid.uuid4().hex[:8]}"
    sender = SimVirtualBus(channel=channel, preserve_timestamps=True)
    batched = SimVirtualBus(channel=channel)
    one_by_one = SimVirtualBus(channel=channel)
    plain = can.Bus(interface="virtual", channel=channel)
    try:
        batch = _encoded_batch(10)
        sender.send_frames(batch)
        sender.send(batch[0])                       # a single message after the batch: order kept
        got = batched.recv_frames(0.0, None)
        assert got is not None and len(got) == len(batch) + 1
        assert encode_can_batch(got) == encode_can_frames(list(batch) + [batch[0]])
        assert batched.recv_frames(0.0, None) is None
        # recv still hands out one frame at a time; a limit splits a batch and keeps the rest queued
        first = one_by_one.recv(0.0)
        assert first is not None and _same(first, batch[0])
        part = one_by_one.recv_frames(0.0, 5)
        assert part is not None and len(part) == 5 and _same(part[0], batch[1])
        assert len(one_by_one.drain_messages()) == len(batch) - 6 + 1
        plain_got = [plain.recv(0.0) for _ in range(len(batch) + 1)]
        assert all(m is not None for m in plain_got) and _same(plain_got[3], batch[3])
    finally:
        for bus in (sender, batched, one_by_one, plain):
            bus.shutdown()


def test_the_receiver_decodes_batches_as_it_decodes_messages():
    channel = f"test-receiver-{uuid.uuid4().hex[:8]}"
    sender = SimVirtualBus(channel=channel, preserve_timestamps=True)
    batched, plain = SimVirtualBus(channel=channel), can.Bus(interface="virtual", channel=channel)
    try:
        seen: list = []
        fast = ImuReceiver(batched, rate_hz=200.0, on_frames=seen.append, time_base=lambda: 0.5)
        slow = ImuReceiver(plain, rate_hz=200.0, time_base=lambda: 0.5)
        sender.send_frames(_encoded_batch(50, t0=100.0))
        blocks = [fast.poll(), fast.flush()], [slow.poll(), slow.flush()]
        merged = [ImuSampleBlock.concatenate(b) for b in blocks]
        assert len(merged[0]) == 50
        for name in ("counter", "receive_time_s", "gyro_counts", "acc_counts", "status"):
            assert np.array_equal(getattr(merged[0], name), getattr(merged[1], name))
        assert fast.stats.as_dict() == slow.stats.as_dict()
        assert isinstance(seen[0], CanFrameBatch) and seen[0].timestamps[0] == 0.5   # re-stamped on the run clock
    finally:
        for bus in (sender, batched, plain):
            bus.shutdown()
