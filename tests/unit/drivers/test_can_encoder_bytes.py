"""The encoder's whole-frame packing (frames of up to 8 bytes built as one integer per byte order) writes the bytes
the signal-by-signal path writes, for every shipped layout and a user's Motorola DBC, at the signals' extremes."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.imu import encoder as encoder_module
from drivers.imu.encoder import ImuEncoder
from drivers.imu.layout import ImuFrameSpec, ImuLayout, shipped_layout
from tests.unit.drivers.test_can_codec import USER_DBC, USER_MAPPING

#: the user's DBC with a 7-byte Motorola message: its integer is the last 7 bytes of 8
SHORT_MOTOROLA_DBC = USER_DBC.replace("RATES: 8 IMU", "RATES: 7 IMU").replace(
    "Rz : 47|16@0- (0.5,0)", "Rz : 47|11@0- (0.5,0)").replace(
    "Seq : 56|5@1+ (1,0) [0|31] \"\" IMU\nBO_", "Seq : 52|5@0+ (1,0) [0|31] \"\" IMU\nBO_")


def _layouts():
    yield from ((name, shipped_layout(name)) for name in ("classic", "packed", "fd", "sbg-ecan"))
    yield "user-motorola", ImuLayout.from_dbc_string(USER_DBC, ImuFrameSpec.from_dict(USER_MAPPING))
    yield "user-motorola-7", ImuLayout.from_dbc_string(SHORT_MOTOROLA_DBC, ImuFrameSpec.from_dict(USER_MAPPING))


def _extreme_samples(layout: ImuLayout, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Increments whose raw values reach both ends of every value signal (first and last rows) and random ones."""
    lo, hi = np.zeros(6), np.zeros(6)
    for m in layout.messages:
        for column, sig in m.values:
            if column < 6:
                bits = min(sig.length, 40)    # (wider signals: ends beyond what a float increment holds exactly)
                lo[column] = -(1 << (bits - 1)) if sig.signed else 0
                hi[column] = (1 << (bits - 1)) - 1 if sig.signed else (1 << bits) - 1
    scale, offset = np.asarray(layout.scale[:6]), np.asarray(layout.offset[:6])
    raw = rng.integers(lo, hi, (n, 6), endpoint=True).astype(float)
    raw[0], raw[-1] = lo, hi
    values = raw * scale + offset
    if layout.time_stamp is None:
        # increments: the encoder sends the differences of the rounded running sum, so hand it the raw steps
        return values[:, :3], values[:, 3:]
    return values[:, :3] / 200.0, values[:, 3:] / 200.0


@pytest.mark.parametrize("name,layout", list(_layouts()), ids=[name for name, _ in _layouts()])
def test_whole_frame_packing_writes_the_signal_by_signal_bytes(name, layout, monkeypatch):
    rng = np.random.default_rng(11)
    n = 300
    gyro, acc = _extreme_samples(layout, n, rng)
    counters = np.arange(70_000 - n // 2, 70_000 + n - n // 2)     # the counter wraps in the middle
    status = rng.integers(0, 1 << 8, n)
    kwargs = {"rate_hz": 200.0} if layout.time_stamp is not None else {}
    fast = ImuEncoder(layout, saturate=True, **kwargs).encode(counters, gyro, acc, 21.5, status)
    monkeypatch.setattr(encoder_module, "_classic_frames", lambda length, signals: None)
    slow = ImuEncoder(layout, saturate=True, **kwargs).encode(counters, gyro, acc, 21.5, status)
    assert fast.data.tobytes() == slow.data.tobytes()
    assert np.array_equal(fast.ids, slow.ids) and np.array_equal(fast.lengths, slow.lengths)
    assert fast.data.any()
