"""The chamber codecs on random input: a reply or request either decodes or raises the dialect's one error; a
random configuration builds a register map or raises ChamberMapError naming its source."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.chamber import ascii_codec as codec
from drivers.chamber.base import ChamberState
from drivers.chamber.modbus_map import ChamberMapError, ChamberRegisterMap
from drivers.chamber.presets import chamber_map_from_dict
from drivers.chamber.watlow_f4 import WatlowF4Map, is_f4p_register
from drivers.errors import ChamberCommandError, ChamberProtocolError

FIELDS = st.one_of(st.sampled_from(["23.4", "-40.0", "RUN", "STOP", "0", "1", "3", "42", "", "1e999", "NA:X"]),
                   st.text(max_size=6))
LINES = st.one_of(st.binary(max_size=300), st.lists(FIELDS, max_size=9).map(lambda f: ",".join(f).encode("utf-8",
                                                                                                         "replace")))


@pytest.mark.slow
@settings(max_examples=400, deadline=None)
@given(LINES)
def test_random_monitor_replies_decode_or_raise_the_dialects_error(line):
    try:
        state = codec.decode_monitor(line)
    except (ChamberProtocolError, ChamberCommandError):
        return
    assert isinstance(state, ChamberState) and state.ramp_c_per_min >= 0


@settings(max_examples=300, deadline=None)
@given(LINES)
def test_random_request_lines_parse_or_raise_request_error(line):
    try:
        request = codec.parse_request(line)
    except codec.RequestError as exc:
        assert exc.reason in (codec.NA_COMMAND, codec.NA_PARAMETER)
        return
    assert request.name in (*codec.QUERIES, "ALARM,CLEAR", "MODE", "TEMP,S", "RAMP")


KEYS = st.sampled_from(["unit", "temperature_scale_c", "ramp_scale_c_per_min", "registers", "status_bits",
                        "alarm_bits", "command_codes", "other"])
SUBKEYS = st.sampled_from(["process_value", "setpoint", "ramp_rate", "status", "alarms", "command", "running",
                           "door_open", "run", "x"])
LEAVES = st.one_of(st.none(), st.booleans(), st.integers(-3, 70000), st.floats(allow_nan=True), st.text(max_size=8))
VALUES = st.one_of(LEAVES, st.dictionaries(SUBKEYS, LEAVES, max_size=4))


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(st.dictionaries(KEYS, VALUES, max_size=5))
def test_random_configuration_builds_a_map_or_raises_chamber_map_error(d):
    try:
        m = ChamberRegisterMap.from_dict(d, source="random.toml")
    except ChamberMapError as exc:
        assert str(exc).startswith("random.toml: ")
        return
    reads = m.state_reads
    assert all(count <= 125 for _, count in reads) and len(reads) <= 5
    covered = {start + i for start, count in reads for i in range(count)}
    names = [n for n in ("process_value", "setpoint", "ramp_rate", "status", "alarms") if getattr(m, n) >= 0]
    assert {getattr(m, n) for n in names} <= covered


F4_KEYS = st.sampled_from(["preset", "unit", "registers", "temperature_scale_c", "other"])
F4_SUBKEYS = st.sampled_from(["process_value", "setpoint", "ramp_rate", "mode", "decimal", "alarm_1", "status", "x"])
F4_LEAVES = st.one_of(st.sampled_from(["watlow-f4", "generic", "watlow-f5"]), st.sampled_from([100, 300, 1103, 40101]),
                      LEAVES)
F4_VALUES = st.one_of(F4_LEAVES, st.dictionaries(F4_SUBKEYS, F4_LEAVES, max_size=4))


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(F4_KEYS, F4_VALUES, max_size=4))
def test_random_preset_tables_build_a_map_or_raise_chamber_map_error(d):
    """Through the preset dispatcher (the F4P's map by default): a map whose registers are all the F4P's, or one
    ChamberMapError naming the source."""
    try:
        m = chamber_map_from_dict(d, source="random.toml")
    except ChamberMapError as exc:
        assert str(exc).startswith("random.toml: ")
        return
    if isinstance(m, WatlowF4Map):
        assert all(is_f4p_register(n) for n in m.registers.values())
        assert len(set(m.registers.values())) == len(m.registers)
