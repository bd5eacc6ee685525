"""Several IMUs on one CAN bus (`BusShare`): each receiver takes its own frames, the other units' are not its faults,
and a frame of an id no unit has is an unknown id of the bus's first unit only (counted and passed on once)."""

from __future__ import annotations

import uuid

import can
import numpy as np

from bench.log.shared_bus import recorded_share
from drivers.imu import default_layout
from drivers.imu.encoder import ImuEncoder
from drivers.imu.layout import EXTENDED_ID_FLAG
from drivers.imu.receiver import BusShare, ImuReceiver, bus_shares

STRAY_ID = 0x7AB


def _frames(layout, n: int) -> list[can.Message]:
    encoded = ImuEncoder(layout).encode(np.arange(n), np.zeros((n, 3)), np.zeros((n, 3)))
    frames = [encoded.frame(i) for i in range(len(encoded))]
    return [can.Message(arbitration_id=key, data=data, is_extended_id=False) for key, data in frames]


def test_bus_shares_name_the_others_ids_and_the_bus_first_unit_takes_the_unknown_ones():
    a, b, c = default_layout(), default_layout().with_id_offset(16), default_layout()
    shares = bus_shares([("can0", a.keys), ("can0", b.keys), ("can1", c.keys)])
    assert shares[0] == BusShare(frozenset(b.keys), takes_unknown=True)
    assert shares[1] == BusShare(frozenset(a.keys), takes_unknown=False)
    assert shares[2] is None                               # alone on its bus: every frame its own, as a single IMU


def test_receivers_on_a_shared_bus_take_their_own_frames_and_one_the_unknown_ids():
    a, b = default_layout(), default_layout().with_id_offset(16)
    share_a, share_b = bus_shares([("bus", a.keys), ("bus", b.keys)])
    channel = f"bus-share-{uuid.uuid4().hex[:8]}"
    sender = can.Bus(interface="virtual", channel=channel)
    recorded: dict[str, list[int]] = {"a": [], "b": [], "whole": []}
    receivers = {name: ImuReceiver(can.Bus(interface="virtual", channel=channel), layout, share=share,
                                   on_frames=lambda batch, name=name: recorded[name].extend(batch.ids.tolist()))
                 for name, layout, share in (("a", a, share_a), ("b", b, share_b), ("whole", a, None))}
    try:
        for frames in (_frames(a, 5), _frames(b, 5), [can.Message(arbitration_id=STRAY_ID, data=bytes(8),
                                                                   is_extended_id=False)]):
            for message in frames:
                sender.send(message)
        for receiver in receivers.values():
            receiver.poll(timeout_s=0.5)
        sa, sb, whole = (receivers[name].stats for name in ("a", "b", "whole"))
        assert (sa.unknown_id, sb.unknown_id) == (1, 0)                  # the stray frame: the bus's first unit's
        assert sa.frames == 5 * len(a.keys) + 1 and sb.frames == 5 * len(b.keys)
        assert sorted(recorded["a"]) == sorted([*a.keys] * 5 + [STRAY_ID])   # each frame passed on once
        assert sorted(recorded["b"]) == sorted([*b.keys] * 5)
        assert receivers["a"].other_unit_frames == 5 * len(b.keys)
        assert receivers["b"].other_unit_frames == 5 * len(a.keys) + 1
        assert whole.unknown_id == 5 * len(b.keys) + 1 and len(recorded["whole"]) == 10 * len(a.keys) + 1
    finally:
        for receiver in receivers.values():
            receiver.bus.shutdown()
            receiver.close()
        sender.shutdown()


def test_a_log_units_record_gives_each_unit_its_share_older_records_by_their_ids():
    import json

    units = [{"serial": "A1", "reference": True, "bus": "virtual:a", "frame_ids": ["0x100", "0x101"]},
             {"serial": "A2", "reference": False, "bus": "virtual:a", "frame_ids": ["0x110", "0x18ff0010"]},
             {"serial": "B1", "reference": False, "bus": "virtual:b", "frame_ids": ["0x100"], "frame_keys": [256]}]
    metadata = {"units": {"units_json": json.dumps(units), "reference": "A1"}}
    reference = recorded_share(metadata, None)
    assert reference == BusShare(frozenset({0x110, 0x18FF0010 | EXTENDED_ID_FLAG}), takes_unknown=True)
    assert recorded_share(metadata, "A2") == BusShare(frozenset({0x100, 0x101}), takes_unknown=False)
    assert recorded_share(metadata, "B1") is None
    assert recorded_share({}, None) is None                            # a single IMU's log: decoded whole
    assert recorded_share({"units": {"units_json": "[{}]"}}, None) is None    # unreadable: decoded whole
