"""IMU over CAN: CRC, DBC layouts, signal compilation and the encoder (the pure codec)."""

from __future__ import annotations

import cantools
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import ImuConfigError, ImuFrameError
from drivers.imu import (
    DEFAULT_DBC,
    DEFAULT_FD_DBC,
    DEFAULT_PACKED_DBC,
    DEFAULT_SPEC,
    EXTENDED_ID_FLAG,
    ImuEncoder,
    ImuFrameSpec,
    ImuLayout,
    StreamDecoder,
    decode_frames,
    default_fd_layout,
    default_layout,
    default_packed_layout,
    encode_block,
)
from drivers.imu.crc import LinearCrc, crc8, frame_crc
from drivers.imu.encoder import OVER_RANGE_BIT


def crc8_bitwise(data: bytes) -> int:
    """CRC-8/SAE-J1850 straight from its definition, one bit at a time (no table)."""
    crc = 0xFF
    for byte in data:
        for bit in range(7, -1, -1):
            top = ((crc >> 7) ^ (byte >> bit)) & 1
            crc = ((crc << 1) & 0xFF) ^ (0x1D if top else 0)
    return crc ^ 0xFF


# -- CRC ------------------------------------------------------------------------------

def test_crc_check_value_and_table_match_definition():
    assert crc8(b"123456789") == 0x4B == crc8_bitwise(b"123456789")
    rng = np.random.default_rng(1)
    for n in (0, 1, 9, 65):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert crc8(data) == crc8_bitwise(data)


def test_crc_worked_example_from_can_md():
    # IMU_GYRO_X (id 0x100), counter 0x1234, increment 100.5 counts (raw 25728 = 0x6480):
    covered = bytes.fromhex("01 00 34 12 80 64 00 00 00")
    assert crc8_bitwise(covered) == 0x8D
    assert frame_crc(0x100, False, bytes.fromhex("34 12 80 64 00 00 00 8d"), 7) == 0x8D
    # the same data on another id fails: the id is covered
    assert frame_crc(0x101, False, bytes.fromhex("34 12 80 64 00 00 00 8d"), 7) != 0x8D


@pytest.mark.parametrize("length, crc_byte", [(8, 7), (8, 0), (5, 2), (64, 63), (12, 4)])
def test_linear_crc_equals_bytewise(length, crc_byte):
    lin = LinearCrc(length, crc_byte)
    rng = np.random.default_rng(length * 100 + crc_byte)
    for frame_id, ext in ((0x100, False), (0x7FF, False), (0x1ABCDEF0, True)):
        constant = lin.id_constant(frame_id, ext)
        for _ in range(50):
            data = rng.integers(0, 256, length, dtype=np.uint8).tobytes()
            assert lin.compute(int.from_bytes(data, "little"), constant) == frame_crc(frame_id, ext, data, crc_byte)


# -- the shipped layouts --------------------------------------------------------------

def test_default_layout_is_the_documented_one():
    lay = default_layout()
    assert [m.frame_id for m in lay.messages] == list(range(0x100, 0x107))
    assert [m.name for m in lay.messages] == ["IMU_GYRO_X", "IMU_GYRO_Y", "IMU_GYRO_Z", "IMU_ACC_X", "IMU_ACC_Y",
                                              "IMU_ACC_Z", "IMU_AUX"]
    assert all(m.length == 8 and m.crc_byte == 7 and not m.is_extended_id and not m.is_fd for m in lay.messages)
    assert lay.counter_bits == 16
    assert lay.scale[:6] == (1 / 256,) * 6 and lay.scale[6] == 0.01
    fd = default_fd_layout()
    (m,) = fd.messages
    assert (m.frame_id, m.length, m.is_fd, m.crc_byte, fd.counter_bits) == (0x110, 64, True, 63, 32)
    assert fd.scale[:6] == (2.0 ** -16,) * 6


def test_frames_as_the_manual_prints_them():
    frames = ImuEncoder().encode_sample(0x1234, [100.5, -2.25, 0.0], [40.0, -1.0, 39.99609375], 23.45, 0x0011)
    assert [(k, d.hex(" ")) for k, d in frames] == [
        (0x100, "34 12 80 64 00 00 00 8d"),
        (0x101, "34 12 c0 fd ff ff 00 13"),
        (0x102, "34 12 00 00 00 00 00 80"),
        (0x103, "34 12 00 28 00 00 00 09"),
        (0x104, "34 12 00 ff ff ff 00 b6"),
        (0x105, "34 12 ff 27 00 00 00 51"),
        (0x106, "34 12 29 09 11 00 00 ab"),
    ]
    decoder = StreamDecoder()
    for k, d in frames:
        decoder.feed([k], np.frombuffer(d, np.uint8).reshape(1, 8), timestamps=[1.5])
    block = decoder.take_block()
    assert block.counter.tolist() == [0x1234]
    assert block.gyro_counts.tolist() == [[100.5, -2.25, 0.0]]
    assert block.acc_counts.tolist() == [[40.0, -1.0, 39.99609375]]
    assert block.temperature_c[0] == pytest.approx(23.45) and block.status.tolist() == [0x11]
    assert block.receive_time_s.tolist() == [1.5]


@pytest.mark.parametrize("fd", [False, True])
def test_encoder_agrees_with_cantools(fd):
    layout, path = (default_fd_layout(), DEFAULT_FD_DBC) if fd else (default_layout(), DEFAULT_DBC)
    db = cantools.database.load_file(path)
    rng = np.random.default_rng(7)
    gyro, acc = rng.normal(0, 5000, (20, 3)), rng.normal(0, 50, (20, 3))
    counters = np.arange(70000, 70020)
    frames = ImuEncoder(layout).encode(counters, gyro, acc, -12.34, 5)
    block, stats = decode_frames(frames.ids, frames.data, frames.lengths, layout=layout)
    assert stats.samples == 20
    names = ("GyroX", "GyroY", "GyroZ", "AccX", "AccY", "AccZ")
    for i in range(len(frames)):
        key, data = frames.frame(i)
        decoded = db.decode_message(key, data)
        s = int(frames.sample[i])
        assert decoded["Counter"] == counters[s] % (1 << layout.counter_bits)
        assert decoded["CRC"] == data[-1]
        for c, name in enumerate(names):
            if name in decoded:
                assert decoded[name] == pytest.approx(np.concatenate([block.gyro_counts, block.acc_counts], 1)[s, c],
                                                      abs=1e-12)
        if "Temperature" in decoded:
            assert decoded["Temperature"] == pytest.approx(-12.34) and decoded["Status"] == 5


# -- encoder quantisation -------------------------------------------------------------

def test_sigma_delta_sums_are_exact_to_one_step():
    rng = np.random.default_rng(3)
    true = rng.normal(0, 300, (2000, 3))
    enc = ImuEncoder()
    pieces = [enc.encode(np.arange(a, b), true[a:b], true[a:b]) for a, b in ((0, 700), (700, 701), (701, 2000))]
    raw = np.concatenate([decode_frames(p.ids, p.data, p.lengths)[0].gyro_counts for p in pieces])
    step = 1 / 256
    assert np.abs(raw - true).max() <= step + 1e-9                 # each increment within one step
    err = np.cumsum(raw - true, axis=0)
    assert np.abs(err).max() <= 0.5 * step + 1e-9                  # any prefix sum within half a step
    # any span [i, j) is within one step (difference of two prefix errors)
    assert np.abs(err[1500] - err[200]).max() <= step + 1e-9
    # one call gives the same frames as three
    whole = ImuEncoder().encode(np.arange(2000), true, true)
    assert np.array_equal(whole.data, np.concatenate([p.data for p in pieces]))


def test_integral_increments_are_exact_and_blocks_round_trip():
    counts = np.arange(-30, 30, dtype=float).reshape(20, 3) * 37
    frames = ImuEncoder().encode(np.arange(20), counts, counts / 7 * 256 // 1 / 256)
    block, _ = decode_frames(frames.ids, frames.data, frames.lengths)
    assert np.array_equal(block.gyro_counts, counts)
    again = encode_block(block)
    assert np.array_equal(again.data, frames.data)


def test_encoder_rejects_what_does_not_fit():
    enc = ImuEncoder()
    with pytest.raises(ImuFrameError, match="GyroY"):
        enc.encode([0], [[0.0, 2.0 ** 23, 0.0]], [[0, 0, 0]])
    with pytest.raises(ImuFrameError, match="finite"):
        enc.encode([0], [[np.nan, 0, 0]], [[0, 0, 0]])
    with pytest.raises(ImuFrameError, match="Status"):
        enc.encode([0], [[0, 0, 0]], [[0, 0, 0]], status=70000)
    # a failed call leaves the carried remainder as it was
    frames = enc.encode([0], [[0.001, 0, 0]], [[0, 0, 0]])
    assert decode_frames(frames.ids, frames.data, frames.lengths)[0].gyro_counts[0, 0] == 0.0


# -- users' own DBC files -------------------------------------------------------------

USER_DBC = '''VERSION ""
NS_ :
BS_:
BU_: IMU
BO_ 2566834432 RATES: 8 IMU
 SG_ Crc : 7|8@0+ (1,0) [0|255] "" IMU
 SG_ Rx : 15|16@0- (0.5,0) [0|0] "" IMU
 SG_ Ry : 31|16@0- (0.5,0) [0|0] "" IMU
 SG_ Rz : 47|16@0- (0.5,0) [0|0] "" IMU
 SG_ Seq : 56|5@1+ (1,0) [0|31] "" IMU
BO_ 2566834433 ACCEL: 8 IMU
 SG_ Seq : 0|5@1+ (1,0) [0|31] "" IMU
 SG_ Ax : 5|17@1- (0.125,-3) [0|0] "" IMU
 SG_ Ay : 22|17@1- (0.125,0) [0|0] "" IMU
 SG_ Az : 39|17@1- (0.125,0) [0|0] "" IMU
 SG_ Chk : 56|8@1+ (1,0) [0|255] "" IMU
'''

USER_MAPPING = {"gyro_x": "RATES.Rx", "gyro_y": "RATES.Ry", "gyro_z": "RATES.Rz",
                "acc_x": "ACCEL.Ax", "acc_y": "ACCEL.Ay", "acc_z": "ACCEL.Az",
                "counter": "Seq", "crc": {"RATES": "Crc", "ACCEL": "Chk"}}


def test_user_dbc_with_motorola_extended_ids_and_a_5_bit_counter():
    layout = ImuLayout.from_dbc_string(USER_DBC, ImuFrameSpec.from_dict(USER_MAPPING))
    assert layout.counter_bits == 5
    assert all(m.is_extended_id for m in layout.messages)
    assert layout.messages[0].crc_byte == 0 and layout.messages[1].crc_byte == 7
    rng = np.random.default_rng(5)
    gyro = rng.integers(-32768, 32768, (80, 3)) * 0.5
    acc = rng.integers(-65536, 65536, (80, 3)) * 0.125 + np.array([-3.0, 0.0, 0.0])   # Ax has offset -3
    frames = ImuEncoder(layout).encode(np.arange(80), gyro, acc)
    # DBC files write a 29-bit id with bit 31 set, exactly as the keys carry EXTENDED_ID_FLAG
    assert set(frames.ids.tolist()) == {0x18FEC900 | EXTENDED_ID_FLAG, 0x18FEC901 | EXTENDED_ID_FLAG}
    assert 0x18FEC900 | EXTENDED_ID_FLAG == 2566834432
    db = cantools.database.load_string(USER_DBC)
    for i in range(len(frames)):
        key, data = frames.frame(i)
        decoded = db.decode_message(key & ~EXTENDED_ID_FLAG, data)
        s = int(frames.sample[i])
        assert decoded["Seq"] == s % 32
        for name, value in zip(("Rx", "Ry", "Rz", "Ax", "Ay", "Az"), np.concatenate([gyro[s], acc[s]])):
            if name in decoded:
                assert decoded[name] == value
    block, stats = decode_frames(frames.ids, frames.data, frames.lengths, layout=layout)
    assert stats.samples == 80 and stats.frame_faults == 0
    assert np.array_equal(block.gyro_counts, gyro) and np.array_equal(block.acc_counts, acc)
    assert block.counter.tolist() == list(range(80))     # the 5-bit counter unwrapped
    assert np.isnan(block.temperature_c).all() and not block.status.any()
    decoder = StreamDecoder(layout)
    for i in range(len(frames)):
        key, data = frames.frame(i)
        row = np.frombuffer(data, np.uint8).reshape(1, -1)
        decoder.feed([key], row)
        decoder.feed([key & ~EXTENDED_ID_FLAG], row)   # same number, 11-bit: unknown
    live, stats = decoder.finish()
    assert np.array_equal(live.acc_counts, acc) and stats.unknown_id == len(frames)


def _spec(**override):
    mapping = dict(USER_MAPPING)
    mapping.update(override)
    return ImuFrameSpec.from_dict(mapping)


@pytest.mark.parametrize("dbc_edit, mapping, message", [
    (None, {"gyro_w": "RATES.Rx"}, "unknown key"),
    (None, {"gyro_x": "RATES"}, "MESSAGE.Signal"),
    (None, {"gyro_x": "NOPE.Rx"}, "no message 'NOPE'"),
    (None, {"gyro_x": "RATES.Nope"}, "no gyro_x signal 'Nope'"),
    (None, {"gyro_y": "RATES.Rx"}, "both map to RATES.Rx"),
    (None, {"counter": "Nope"}, "no counter signal"),
    (None, {"counter": {"RATES": "Seq"}}, "no counter signal given for message"),
    (None, {"crc": "Rx"}, "CRC signal Rx of RATES must be one whole unsigned byte"),
    (None, {"counter": {"RATES": "Seq", "ACCEL": "Ax"}}, "counter signal Ax of ACCEL must be unsigned"),
    (('IMU\n SG_ Chk : 56|8@1+ (1,0) [0|255] "" IMU\n',
      'IMU\n SG_ Chk : 56|8@1+ (1,0) [0|255] "" IMU\nBO_ 100 OTHER: 2 IMU\n SG_ X : 0|16@1+ (1,0) [0|0] "" IMU\n'),
     {}, None),
    (("Seq : 0|5@1+", "Seq : 0|4@1+"), {}, "one width"),
])
def test_config_errors_name_the_problem(dbc_edit, mapping, message):
    text = USER_DBC if dbc_edit is None else USER_DBC.replace(*dbc_edit)
    if message is None:      # other messages in the DBC are fine and not part of the sample
        assert [m.name for m in ImuLayout.from_dbc_string(text, _spec(**mapping)).messages] == ["RATES", "ACCEL"]
        assert "OTHER" in text
        return
    with pytest.raises(ImuConfigError, match=message):
        ImuLayout.from_dbc_string(text, _spec(**mapping))


TINY_DBC = """VERSION ""
NS_ :
BS_:
BU_: IMU
BO_ 16 ONE: 40 IMU
 SG_ Seq : 0|8@1+ (1,0) [0|255] "" IMU
 SG_ G1 : 8|32@1- (1,0) [0|0] "" IMU
 SG_ G2 : 40|8@1- (1,0) [0|0] "" IMU
 SG_ G3 : 48|8@1- (1,0) [0|0] "" IMU
 SG_ A1 : 56|8@1- (1,0) [0|0] "" IMU
 SG_ A2 : 64|8@1- (1,0) [0|0] "" IMU
 SG_ A3 : 72|8@1- (1,0) [0|0] "" IMU
 SG_ Big : 128|64@1+ (1,0) [0|0] "" IMU
 SG_ Wide : 197|60@1- (1,0) [0|0] "" IMU
"""
TINY = {"gyro_x": "ONE.G1", "gyro_y": "ONE.G2", "gyro_z": "ONE.G3", "acc_x": "ONE.A1", "acc_y": "ONE.A2",
        "acc_z": "ONE.A3", "counter": "Seq", "crc": ""}


@pytest.mark.parametrize("mapping, extra, message", [
    ({}, "", None),
    ({}, "SIG_VALTYPE_ 16 G1 : 1;", "signal G1 of ONE .gyro_x. is a float signal"),
    ({"acc_z": "ONE.Big"}, "", "signal Big of ONE .acc_z. is an unsigned 64-bit signal"),
    ({"acc_z": "ONE.Wide"}, "", "signal Wide of ONE .acc_z. spans 9 bytes; signals must lie within 8 consecutive"),
])
def test_unsupported_signal_kinds(mapping, extra, message):
    spec = ImuFrameSpec.from_dict({**TINY, **mapping})
    if message is None:
        layout = ImuLayout.from_dbc_string(TINY_DBC, spec)
        assert layout.messages[0].crc_byte is None and layout.counter_bits == 8
        return
    with pytest.raises(ImuConfigError, match=message):
        ImuLayout.from_dbc_string(TINY_DBC + extra + "\n", spec)


def test_missing_or_unreadable_dbc(tmp_path):
    with pytest.raises(ImuConfigError, match="cannot read"):
        ImuLayout.from_dbc(tmp_path / "nope.dbc", DEFAULT_SPEC)
    bad = tmp_path / "bad.dbc"
    bad.write_text("BO_ this is not a DBC\n")
    with pytest.raises(ImuConfigError, match="bad.dbc"):
        ImuLayout.from_dbc(bad, DEFAULT_SPEC)
    with pytest.raises(ImuConfigError):
        ImuFrameSpec.from_dict(["gyro_x"])
    with pytest.raises(ImuConfigError, match="lacks acc_z"):
        ImuFrameSpec.from_dict({k: v for k, v in USER_MAPPING.items() if k != "acc_z"})


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(st.text(max_size=400) | st.builds(lambda cut, junk: USER_DBC[:cut] + junk,
                                         st.integers(0, len(USER_DBC)), st.text(max_size=40)))
def test_random_dbc_text_compiles_or_raises_config_error(text):
    try:
        ImuLayout.from_dbc_string(text, _spec())
    except ImuConfigError:
        pass


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=64, max_size=64), st.sampled_from([0x100, 0x103, 0x106, 0x110]))
def test_signal_extraction_of_random_bytes_matches_cantools(data, frame_id):
    """Random frames through the compiled signals agree with cantools' own decoding."""
    fd = frame_id == 0x110
    msg = (default_fd_layout() if fd else default_layout()).message(frame_id)
    data = data[:msg.length]
    db = _FD_DB if fd else _DB
    decoded = db.decode_message(frame_id, data, scaling=False)
    assert msg.counter.raw(data) == decoded["Counter"]
    for _, sig in msg.values:
        assert sig.raw(data) == decoded[sig.name]


_DB = cantools.database.load_file(DEFAULT_DBC)
_FD_DB = cantools.database.load_file(DEFAULT_FD_DBC)


def test_packed_layout_round_trip_and_cantools_agree():
    """The shipped packed layout: 3 frames per sample, whole counts, sums exact to one count."""
    layout = default_packed_layout()
    db = cantools.database.load_file(str(DEFAULT_PACKED_DBC))
    rng = np.random.default_rng(3)
    gyro, acc = rng.normal(0, 3000, (500, 3)), rng.normal(0, 30, (500, 3))
    frames = ImuEncoder(layout).encode(np.arange(65530, 66030), gyro, acc, 36.25, 0x11)
    assert len(frames) == 1500 and set(frames.ids.tolist()) == {0x120, 0x121, 0x122}
    block, stats = decode_frames(frames.ids, frames.data, frames.lengths, layout=layout, rate_hz=2000.0)
    assert stats.samples == 500 and stats.lost_samples == 0 and block.counter[0] == 65530
    assert np.abs(np.cumsum(block.gyro_counts, 0) - np.cumsum(gyro, 0)).max() <= 0.5
    assert np.abs(np.cumsum(block.acc_counts, 0) - np.cumsum(acc, 0)).max() <= 0.5
    assert np.all(block.temperature_c == 36.0) and np.all(block.status == 0x11)    # 0.5 degC steps
    decoded = db.decode_message(0x121, bytes(frames.data[1, :8]))
    assert decoded["GyroZ"] == block.gyro_counts[0, 2] and decoded["Temperature"] == 36.0


def test_a_saturating_encoder_clips_and_flags_over_range():
    layout = default_packed_layout()
    gyro = np.array([[100.0, 0, 0], [40000.0, -50000.0, 0], [100.0, 0, 0]])
    with pytest.raises(ImuFrameError, match="GyroX"):
        ImuEncoder(layout).encode(np.arange(3), gyro, np.zeros((3, 3)))
    encoder = ImuEncoder(layout, saturate=True)
    frames = encoder.encode(np.arange(3), gyro, np.zeros((3, 3)), status=0)
    block, _ = decode_frames(frames.ids, frames.data, frames.lengths, layout=layout)
    assert block.gyro_counts[:, :2].tolist() == [[100, 0], [32767, -32768], [100, 0]]
    assert block.status.tolist() == [0, OVER_RANGE_BIT, 0] and encoder.saturated_samples == 1


def test_the_status_bits_that_make_a_sample_unusable_come_with_the_layout():
    from drivers.imu.layout import STATUS_INVALID, ImuStatus, describe_status

    assert default_packed_layout().status_invalid == STATUS_INVALID == 0b11011    # faults, over-range, initialising
    assert not STATUS_INVALID & ImuStatus.TEMPERATURE_RANGE                         # a warning, not unusable data
    assert describe_status(OVER_RANGE_BIT | ImuStatus.GYRO_FAULT) == "gyro-fault, over-range"
    own = ImuLayout.from_dbc_string(USER_DBC, _spec(status_invalid=0x80))
    assert own.status_invalid == 0 and _spec(status_invalid=0x80).status_invalid == 0x80   # no status signal mapped
    assert describe_status(0x80, 0x80) == "status bits 0x0080"
    for bad in (-1, 1.5, "8", True, 1 << 40):
        with pytest.raises(ImuConfigError, match="status_invalid"):
            _spec(status_invalid=bad)
