"""One CAN bus read by several receivers (`drivers.imu.shared_bus`): each view gets the frames of its ids, from
whichever view read the bus; a view nobody reads holds a bounded number. python-can's in-process virtual bus."""

from __future__ import annotations

import uuid

import can
import numpy as np
import pytest

from drivers.imu import EXTENDED_ID_FLAG, ImuEncoder, default_layout
from drivers.imu.receiver import ImuReceiver
from drivers.imu.shared_bus import SharedBus


@pytest.fixture
def wire():
    """(a sender, a SharedBus over a receiver) on a fresh virtual channel."""
    channel = f"shared-bus-{uuid.uuid4().hex[:8]}"
    sender = can.Bus(interface="virtual", channel=channel)
    shared = SharedBus(can.Bus(interface="virtual", channel=channel))
    yield sender, shared
    shared.shutdown()
    sender.shutdown()


def _send(sender, ids: list[int]) -> None:
    for arbitration_id in ids:
        sender.send(can.Message(arbitration_id=arbitration_id, data=bytes(8), is_extended_id=False))


def test_each_view_gets_its_own_ids_whichever_view_reads(wire):
    sender, shared = wire
    everything, first, second = shared.view(), shared.view([0x100, 0x101]), shared.view([0x110])
    _send(sender, [0x100, 0x110, 0x101, 0x222, 0x110])
    got = second.recv_frames(1.0)             # reads the bus: the others' frames wait in their views
    assert got is not None and got.ids.tolist() == [0x110, 0x110]
    assert first.recv_frames(0.0).ids.tolist() == [0x100, 0x101]
    assert everything.recv_frames(0.0).ids.tolist() == [0x100, 0x110, 0x101, 0x222, 0x110]
    assert first.recv_frames(0.0) is None and everything.recv_frames(0.01) is None


def test_a_view_waits_for_its_own_frames_within_its_timeout(wire):
    sender, shared = wire
    mine = shared.view([0x100])
    _send(sender, [0x200] * 3)               # someone else's: not a frame for this view
    assert mine.recv_frames(0.05) is None
    _send(sender, [0x200, 0x100])
    assert mine.recv_frames(1.0).ids.tolist() == [0x100]
    _send(sender, [0x100] * 5)
    assert len(mine.recv_frames(1.0, limit=2)) == 2 and len(mine.recv_frames(0.0)) == 3


def test_a_view_nobody_reads_holds_a_bounded_number_of_frames(wire):
    sender, _ = wire
    shared = SharedBus(wire[1].bus, max_pending_frames=4)
    read, unread = shared.view([0x100]), shared.view([0x100])
    for _ in range(3):
        _send(sender, [0x100, 0x100])
        assert len(read.recv_frames(1.0)) == 2
    assert unread.frames_dropped == 2 and len(unread.recv_frames(0.0)) == 4
    unread.shutdown()                         # detached: handed nothing more
    _send(sender, [0x100])
    assert len(read.recv_frames(1.0)) == 1 and unread.frames_dropped == 2


def test_two_units_decode_their_own_samples_from_one_bus(wire):
    """Two units of one layout, the second's ids offset by 16, on one bus: each receiver decodes its own samples
    and sees no other id."""
    sender, shared = wire
    layouts = [default_layout(), default_layout().with_id_offset(16)]
    receivers = [ImuReceiver(shared.view(layout.keys), layout, 100.0) for layout in layouts]
    n = 20
    for layout in layouts:
        frames = ImuEncoder(layout, rate_hz=100.0).encode(np.arange(n), np.ones((n, 3)), np.ones((n, 3)))
        for i in range(len(frames)):
            key, data = frames.frame(i)
            sender.send(can.Message(arbitration_id=key & ~EXTENDED_ID_FLAG, data=data,
                                    is_extended_id=bool(key & EXTENDED_ID_FLAG)))
    for k, receiver in enumerate(receivers):
        got = 0
        for _ in range(50):                   # bounded: each poll waits at most 0.1 s
            got += len(receiver.poll(timeout_s=0.1))
            if got >= n:
                break
        assert got == n and receiver.stats.unknown_id == 0, (k, receiver.stats)
