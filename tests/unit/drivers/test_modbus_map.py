"""The Modbus register map codec: configuration, value encodings, state decoding, reply checks."""

from __future__ import annotations

import math
import pathlib
import tomllib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import (
    DeviceChecksumError,
    DeviceError,
    DeviceProtocolError,
    TurntableLimitError,
    TurntableProtocolError,
)
from drivers.modbus_frames import crc16, exception_name, explain_bad_reply
from drivers.turntable.base import AxisMode, AxisState, AxisStatus, TableState
from drivers.turntable.modbus_map import (
    RegisterMap,
    RegisterMapError,
    axis_mask,
    contiguous_runs,
    mask_axes,
)

DEFAULT = RegisterMap.default()


def test_default_map_reads_the_whole_state_in_one_request():
    assert DEFAULT.state_span == (0, 20)
    assert DEFAULT.unit == 1 and DEFAULT.encoding == "int32" and DEFAULT.watchdog_s == 2.0


def test_int32_encoding_as_the_manual_prints_it():
    assert DEFAULT.encode_value(90.0) == [0x000D, 0xBBA0]             # 900000 counts of 1e-4 deg
    assert DEFAULT.encode_value(-10.0) == [0xFFFE, 0x7960]
    assert DEFAULT.encode_value(10.5, "rate") == [0x0001, 0x9A28]
    assert DEFAULT.decode_value([0xFFF9, 0x0EA8]) == pytest.approx(-45.5)
    little = DEFAULT.with_changes(word_order="little")
    assert little.encode_value(90.0) == [0xBBA0, 0x000D]
    assert little.decode_value([0xBBA0, 0x000D]) == pytest.approx(90.0)


def test_float32_encoding_and_word_order():
    fmap = DEFAULT.with_changes(encoding="float32")
    assert fmap.encode_value(12.5) == [0x4148, 0x0000]
    assert fmap.with_changes(word_order="little").encode_value(12.5) == [0x0000, 0x4148]
    assert fmap.decode_value([0xC2B4, 0x0000]) == -90.0
    with pytest.raises(TurntableProtocolError, match="not a finite"):
        fmap.decode_value([0x7FC0, 0x0000])              # NaN
    with pytest.raises(TurntableLimitError, match="float32"):
        fmap.encode_value(1e39)


def test_values_the_encoding_cannot_carry_are_limit_errors():
    with pytest.raises(TurntableLimitError, match="int32"):
        DEFAULT.encode_value(214749.0)
    assert DEFAULT.decode_value(DEFAULT.encode_value(214748.0)) == pytest.approx(214748.0)
    with pytest.raises(TurntableLimitError, match="finite"):
        DEFAULT.encode_value(math.nan)


@pytest.mark.parametrize("regs", [[1], [1, 2, 3], [0x10000, 0], [-1, 0], [1.5, 0], ["a", 0], None])
def test_malformed_value_registers_are_protocol_errors(regs):
    with pytest.raises(TurntableProtocolError):
        DEFAULT.decode_value(regs)


def test_status_bits_and_modes_follow_the_map():
    assert DEFAULT.decode_status(0x0005) == AxisStatus.ENABLED | AxisStatus.IN_POSITION
    assert DEFAULT.decode_status(0xFFC0) == AxisStatus(0)              # bits the map does not use
    custom = DEFAULT.with_changes(status_bits=(15, 14, 13, 12, 11, 10))
    assert custom.decode_status(0x8000 | 0x0800) == AxisStatus.ENABLED | AxisStatus.ESTOP
    assert custom.encode_status(AxisStatus.LIMIT | AxisStatus.MOVING) == 0x0400 | 0x4000
    assert DEFAULT.decode_mode(2) is AxisMode.RATE and DEFAULT.mode_code(AxisMode.OFF) == 0
    with pytest.raises(TurntableProtocolError, match="mode register value 7"):
        DEFAULT.decode_mode(7)
    assert DEFAULT.command_code("abort") == 5 and DEFAULT.decode_command(3) == "reset"
    with pytest.raises(ValueError):
        DEFAULT.decode_command(9)


def test_decode_state_of_a_hand_written_block():
    block = [0x0005, 0x0003, 0x0011, 0x0001, 1, 2, 0, 0, 0x000D, 0xBBA0, 0xFFF9, 0x0EA8, 0x006D, 0xDD01,
             0, 0, 0x0001, 0x9A28, 0, 0]
    state = DEFAULT.decode_state(block, time_s=3.5)
    assert state.time_s == 3.5
    assert state.angles_deg == pytest.approx((90.0, -45.5, 720.0001))
    assert state.rates_dps == pytest.approx((0.0, 10.5, 0.0))
    assert state.modes == (AxisMode.POSITION, AxisMode.RATE, AxisMode.OFF)
    assert state.estop and state.fault_text == "fault code 1 (emergency stop)"
    with pytest.raises(TurntableProtocolError, match="expected 20 registers, got 19"):
        DEFAULT.decode_state(block[:-1])


def test_state_round_trip_through_the_registers():
    state = TableState(0.0, (AxisState(1.2345, -3.5, AxisMode.POSITION, AxisStatus.ENABLED | AxisStatus.MOVING),
                             AxisState(-1000.0, 0.0, AxisMode.OFF, AxisStatus.FAULT),
                             AxisState(36000.5, 200.0, AxisMode.RATE, AxisStatus.ENABLED)), "")
    for m in (DEFAULT, DEFAULT.with_changes(encoding="float32", word_order="little")):
        back = m.decode_state(m.state_block(state, fault_code=3))
        assert back.angles_deg == pytest.approx(state.angles_deg, abs=1e-3)
        assert back.rates_dps == pytest.approx(state.rates_dps, abs=1e-3)
        assert [a.status for a in back.axes] == [a.status for a in state.axes]
        assert back.modes == state.modes and back.fault_text == "fault code 3 (servo amplifier fault)"


def test_toml_example_from_the_dialect_page_is_accepted():
    text = (pathlib.Path(__file__).parents[3] / "docs" / "hardware" / "modbus.md").read_text(encoding="utf-8")
    example = text.split("```toml\n", 1)[1].split("```", 1)[0]
    m = RegisterMap.from_dict(tomllib.loads(example)["modbus"], source="modbus.md")
    assert m.encoding == "float32" and m.word_order == "little" and m.unit == 2
    assert m.status_bits[4] == 15 and m.state_span == (100, 20)
    assert m.fault_text(7) == "fault code 7 (drive overtemperature)"


def test_from_dict_round_trip_and_defaults():
    assert RegisterMap.from_dict(DEFAULT.to_dict()) == DEFAULT
    assert RegisterMap.from_dict({}) == DEFAULT
    m = RegisterMap.from_dict({"encoding": "FLOAT32", "watchdog_s": 0})
    assert m.encoding == "float32" and m.watchdog_s == 0


@pytest.mark.parametrize("d, words", [
    ({"unitt": 1}, "unknown key unitt"),
    ({"unit": 256}, "unit must be 0-255"),
    ({"unit": True}, "unit must be an integer"),
    ({"encoding": "int16"}, "encoding must be one of"),
    ({"word_order": 1}, "word_order must be a string"),
    ({"angle_scale_deg": 0}, "angle_scale_deg must be positive"),
    ({"watchdog_s": -1}, "watchdog_s must be >= 0"),
    ({"watchdog_s": "2"}, "watchdog_s must be a finite number"),
    ({"registers": {"status": [0, 1]}}, "registers.status must be three addresses"),
    ({"registers": {"speed": 5}}, "unknown key registers.speed"),
    ({"registers": {"watchdog": 9}}, "registers.watchdog at 9 overlaps registers.actual_position"),
    ({"registers": {"demand_rate": [34, 36, 65535]}}, "runs past 65535"),
    ({"registers": {"fault_code": 500}}, "span 501 registers from 0"),
    ({"status_bits": {"estop": 16}}, "status_bits.estop must be 0-15"),
    ({"status_bits": {"estop": 0}}, "status_bits must be distinct"),
    ({"command_codes": {"stop": 0}}, "0 means 'no command'"),
    ({"mode_codes": {"rate": 1}}, "mode_codes must be distinct"),
    ({"fault_codes": {"x": "bad"}}, "fault_codes.x: a fault code must be a number"),
    ({"fault_codes": {"3": ""}}, "fault_codes.3: the text"),
    ({"registers": []}, "registers must be a table"),
])
def test_bad_maps_name_the_key(d, words):
    with pytest.raises(RegisterMapError, match=words) as info:
        RegisterMap.from_dict(d, source="table.toml")
    assert str(info.value).startswith("table.toml: ")
    assert isinstance(info.value, ValueError) and isinstance(info.value, DeviceError)


def test_layout_helpers():
    assert axis_mask([0, 2]) == 0b101 and mask_axes(0) == [0, 1, 2] and mask_axes(0b110) == [1, 2]
    with pytest.raises(ValueError):
        mask_axes(8)
    assert contiguous_runs({5: 1, 3: 7, 4: 8, 9: 2}) == [(3, [7, 8, 1]), (9, [2])]
    names = DEFAULT.register_names()
    assert names[25] == ("demand_position", 0, 1) and names[20] == ("command", -1, 0)


def test_crc16_matches_the_modbus_specification_example():
    # "Read 10 holding registers from 0 of slave 1" as printed in Modbus over serial line guides.
    assert crc16(bytes.fromhex("01 03 00 00 00 0a")) == bytes.fromhex("c5 cd")


def test_explain_bad_reply():
    frame = bytes.fromhex("01 03 04 00 01 00 02")
    bad_crc = frame + bytes(2)
    assert isinstance(explain_bad_reply(bad_crc, "rtu", 1, 3), DeviceChecksumError)
    assert "garbage" in str(explain_bad_reply(b"\xde\xad", "rtu", 1, 3))
    assert "protocol id 7" in str(explain_bad_reply(bytes.fromhex("0001 0007 0003 01 03 00"), "tcp", 1, 3, 1))
    assert "length field 9" in str(explain_bad_reply(bytes.fromhex("0001 0000 0009 01 03 00"), "tcp", 1, 3, 1))
    assert "garbage" in str(explain_bad_reply(bytes.fromhex("0002 0000 0003 01 03 00"), "tcp", 1, 3, 1))
    assert exception_name(2) == "illegal data address" and exception_name(99) == "unknown exception"


# -- property-based -----------------------------------------------------------------------------
REGISTERS = st.lists(st.one_of(st.integers(0, 0xFFFF), st.integers(-5, 70000)), max_size=25)
MAPS = st.sampled_from([DEFAULT, DEFAULT.with_changes(encoding="float32"),
                        DEFAULT.with_changes(encoding="float32", word_order="little"),
                        DEFAULT.with_changes(status_bits=(15, 14, 13, 12, 11, 10), mode_codes=(7, 8, 9))])


@settings(max_examples=300, deadline=None)
@given(MAPS, REGISTERS)
def test_random_registers_decode_or_raise_a_turntable_error(m, regs):
    for decode in (lambda: m.decode_state(regs), lambda: m.decode_value(regs[:2]),
                   lambda: m.decode_value(regs[:2], "rate"), lambda: m.decode_status(regs[0] if regs else 0)):
        try:
            decode()
        except DeviceError:
            pass


@settings(max_examples=300, deadline=None)
@given(MAPS, st.lists(st.integers(0, 0xFFFF), min_size=20, max_size=20))
def test_any_full_state_block_of_valid_registers_decodes_or_raises_protocol_error(m, regs):
    try:
        state = m.decode_state(regs)
    except TurntableProtocolError:
        return
    assert all(math.isfinite(a) for a in state.angles_deg + state.rates_dps)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=80), st.sampled_from(["rtu", "tcp"]), st.integers(0, 255), st.integers(1, 127),
       st.one_of(st.none(), st.integers(0, 0xFFFF)))
def test_random_reply_bytes_always_explain_as_a_protocol_error(raw, framing, unit, fc, tid):
    error = explain_bad_reply(raw, framing, unit, fc, tid)
    assert isinstance(error, DeviceProtocolError) and error.raw == raw


@settings(max_examples=300, deadline=None)
@given(st.floats(-2e5, 2e5, allow_nan=False), st.sampled_from(["angle", "rate"]))
def test_int32_round_trip_within_half_a_count(value, kind):
    for m in (DEFAULT, DEFAULT.with_changes(word_order="little")):
        assert abs(m.decode_value(m.encode_value(value, kind), kind) - value) <= 0.5e-4 + 1e-9


@settings(max_examples=300, deadline=None)
@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_float32_round_trip_to_float32_precision(value):
    m = DEFAULT.with_changes(encoding="float32")
    assert m.decode_value(m.encode_value(value)) == pytest.approx(value, rel=1e-7, abs=1e-30)


KEYS = st.sampled_from(["unit", "encoding", "angle_scale_deg", "rate_scale_dps", "word_order", "watchdog_s",
                        "registers", "status_bits", "command_codes", "mode_codes", "fault_codes", "other"])
SUBKEYS = st.sampled_from(["status", "mode", "watchdog", "fault_code", "command", "estop", "enable", "rate",
                           "1", "x", "demand_rate"])
LEAVES = st.one_of(st.none(), st.booleans(), st.integers(-3, 70000), st.floats(allow_nan=True),
                   st.text(max_size=8), st.lists(st.integers(-1, 70000), max_size=4))
VALUES = st.one_of(LEAVES, st.dictionaries(SUBKEYS, LEAVES, max_size=4))


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(st.dictionaries(KEYS, VALUES, max_size=5))
def test_random_configuration_builds_a_map_or_raises_register_map_error(d):
    try:
        m = RegisterMap.from_dict(d, source="random.toml")
    except RegisterMapError as exc:
        assert str(exc).startswith("random.toml: ")
        return
    assert m.state_span[1] <= 125
