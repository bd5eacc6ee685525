"""The SCPI-like dialect's pure codec, with lines as a controller manual prints them."""

from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.errors import DeviceError, TurntableCommandError, TurntableProtocolError
from drivers.turntable import scpi_codec as sc
from drivers.turntable.base import AxisMode, AxisState, AxisStatus, TableState

FUZZ = settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# -- keyword table ----------------------------------------------------------------------

def test_short_forms_are_unique_under_every_node():
    for node, children in sc._TREE.items():
        shorts = [sc.SHORT[c] for c in children]
        assert len(shorts) == len(set(shorts)), (node, shorts)


def test_every_command_has_short_and_long_headers_that_parse_back():
    for name, spec in sc.COMMANDS.items():
        args = ([0] if spec.axis else []) + [1.5] * spec.min_values
        for long_form in (False, True):
            line = sc.encode(name, *args[:1], *args[1:], long_form=long_form) if spec.axis else \
                sc.encode(name, None, *args, long_form=long_form)
            (request,) = sc.parse_program(line)
            assert isinstance(request, sc.ScpiRequest), (line, request)
            assert request.name == name and request.values == tuple(args[1:] if spec.axis else args)


# -- client side: requests ----------------------------------------------------------------

@pytest.mark.parametrize("name, frame, values, wire", [
    ("MODE:POSITION", 0, (), b":M:P 1"),
    ("MODE:RATE", 2, (), b":M:R 3"),
    ("MODE:OFF", 1, (), b":M:O 2"),
    ("DEMAND:POSITION", 0, (90.0,), b":D:P 1,90.0"),
    ("DEMAND:POSITION", 1, (-45.1234567, 10.0), b":D:P 2,-45.123457,10.0"),
    ("DEMAND:RATE", 0, (10.0,), b":D:R 1,10.0"),
    ("DEMAND:RATE", 2, (-0.000001,), b":D:R 3,-0.000001"),
    ("LIMIT:RATE", 1, (25.0,), b":L:R 2,25.0"),
    ("READ:POSITION?", 0, (), b":R:P? 1"),
    ("READ:STATUS?", 2, (), b":R:S? 3"),
    ("READ:ALL?", None, (), b":R:A?"),
    ("INTERLOCK:CLOSE", 0, (), b":I:C 1"),
    ("INTERLOCK:OPEN", 0, (), b":I:O 1"),
    ("INTERLOCK:RESET", 0, (), b":I:R 1"),
    ("STOP", None, (), b":S"),
    ("ABORT", None, (), b":A"),
    ("SYSTEM:ERROR?", None, (), b":SYST:ERR?"),
    ("*IDN?", None, (), b"*IDN?"),
])
def test_encode_short_forms(name, frame, values, wire):
    assert sc.encode(name, frame, *values) == wire


def test_encode_long_forms_and_confirmation():
    assert sc.encode("DEMAND:POSITION", 2, 180.0, long_form=True) == b":DEMAND:POSITION 3,180.0"
    assert sc.confirmed(b":I:C 1", b":I:C 2") == b":I:C 1;:I:C 2;:SYST:ERR?"
    assert sc.confirmed(b":STOP", long_form=True) == b":STOP;:SYSTEM:ERROR?"


@pytest.mark.parametrize("value, text", [
    (90.0, "90.0"), (0.0, "0.0"), (-0.0, "0.0"), (-1e-7, "0.0"), (1e-6, "0.000001"),
    (12.3456789, "12.345679"), (-720.5, "-720.5"), (123456.0000004, "123456.0"),
])
def test_numbers_resolve_a_micro_degree(value, text):
    assert sc.format_number(value) == text


@pytest.mark.parametrize("call", [
    lambda: sc.encode("DEMAND:POSITION", 3, 1.0),         # frame 0-2 only
    lambda: sc.encode("DEMAND:POSITION", True, 1.0),
    lambda: sc.encode("DEMAND:POSITION", 0),              # angle missing
    lambda: sc.encode("STOP", 0),                         # takes no axis
    lambda: sc.encode("DEMAND:POSITION", 0, math.nan),
    lambda: sc.encode("DEMAND:RATE", 0, math.inf),
    lambda: sc.encode("MOVE:FAST", 0),
])
def test_encode_refuses_what_it_cannot_say(call):
    with pytest.raises(ValueError):
        call()


# -- client side: replies ------------------------------------------------------------------

def test_confirmation_and_error_entries():
    assert sc.decode_confirmation(b'0,"No error"') is None
    assert sc.decode_error(b'+0,"No error"') == (0, "No error")
    assert sc.decode_error(b'-222,"Data out of range;outer position 400.0"') == (
        -222, "Data out of range;outer position 400.0")
    assert sc.decode_error(b'201,"Interlock open"') == (201, "Interlock open")
    assert sc.decode_error(b'-102,"Say ""hello"""') == (-102, 'Say "hello"')
    with pytest.raises(TurntableCommandError, match="-222") as info:
        sc.decode_confirmation(b'-222,"Data out of range"')
    assert info.value.code == -222


@pytest.mark.parametrize("line, what", [
    (b"", "empty"),
    (b'0,No error', "quoted string"),
    (b"0", "expected <code>"),
    (b'"No error"', "expected <code>"),
    (b'x,"No error"', "not an integer"),
    (b'0,"No error",1', "3 fields"),
    (b'0,"No error', "unterminated"),
    (b'0,"No error";0,"No error"', "several responses"),
    (b'0,"No \xe9rror"', "0xE9"),
    (b'0,"No error"\x00', "0x00"),
    (b'0,"No"error', "quoted string"),
])
def test_malformed_confirmations_name_the_problem(line, what):
    with pytest.raises(TurntableProtocolError, match=what) as info:
        sc.decode_confirmation(line)
    assert info.value.raw == line


def test_fields_split_around_quoted_strings():
    assert sc.split_fields(b' 1.5 , 2 ,"a, ""b"";c" , 3 ') == ["1.5", "2", '"a, ""b"";c"', "3"]
    assert sc.split_fields(b"1,,2 ") == ["1", "", "2"]
    assert sc.split_fields(b'1,x"y,z",2') == ["1", 'x"y,z"', "2"]
    with pytest.raises(TurntableProtocolError, match="several responses"):
        sc.split_fields(b'1;2,"x"')


def test_numbers_in_replies():
    assert sc.decode_number(b"90.000000") == 90.0
    assert sc.decode_number(b"-1.5E+01") == -15.0
    assert sc.decode_number(b" +.5 ") == 0.5
    assert sc.decode_number(b"720") == 720.0
    for bad, what in [(b"abc", "not a decimal"), (b"1,2", "expected 1 field"), (b"nan", "not a decimal"),
                      (b"inf", "not a decimal"), (b"1e999", "out of range"), (b"1_000", "not a decimal"),
                      (b"0x10", "not a decimal"), (b'"12.0"', "not a decimal")]:
        with pytest.raises(TurntableProtocolError, match=what):
            sc.decode_number(bad)


def test_a_query_answered_with_an_error_entry_raises_the_command_error():
    for decode in (sc.decode_number, sc.decode_status, sc.decode_mode, sc.decode_string, sc.decode_idn,
                   lambda line: sc.decode_state(line, 0.0)):
        with pytest.raises(TurntableCommandError) as info:
            decode(b'-221,"Settings conflict"')
        assert info.value.code == -221


def test_status_word_bits():
    assert sc.decode_status(b"0") == AxisStatus(0)
    assert sc.decode_status(b"3") == AxisStatus.ENABLED | AxisStatus.IN_POSITION
    assert sc.decode_status(b"5") == AxisStatus.ENABLED | AxisStatus.MOVING
    assert sc.decode_status(b"112") == AxisStatus.FAULT | AxisStatus.LIMIT | AxisStatus.ESTOP
    assert sc.decode_status(b"8") == AxisStatus(0)          # reserved bit ignored
    for bad, what in [(b"65536", "outside"), (b"-1", "outside"), (b"1.0", "not an integer"), (b"", "empty")]:
        with pytest.raises(TurntableProtocolError, match=what):
            sc.decode_status(bad)


def test_status_word_round_trip_for_every_combination():
    for value in range(64):
        status = AxisStatus(value)
        assert sc.status_from_word(sc.status_word(status)) == status


def test_modes():
    assert [sc.decode_mode(b) for b in (b"0", b"1", b"2")] == [AxisMode.OFF, AxisMode.POSITION, AxisMode.RATE]
    with pytest.raises(TurntableProtocolError, match="mode code 3"):
        sc.decode_mode(b"3")


MANUAL_STATE = b'90.000000,0.0,1,3,-45.5,0.0,1,3,123.25,-30.0,2,5,""'


def test_state_reply():
    state = sc.decode_state(MANUAL_STATE, time_s=12.5)
    assert state.time_s == 12.5
    assert state.angles_deg == (90.0, -45.5, 123.25)
    assert state.rates_dps == (0.0, 0.0, -30.0)
    assert state.modes == (AxisMode.POSITION, AxisMode.POSITION, AxisMode.RATE)
    assert state.axes[0].in_position and not state.axes[2].in_position
    assert state.fault_text == "" and not state.fault and not state.estop
    faulted = sc.decode_state(b'1.0,0.0,0,64,2.0,0.0,0,96,3.0,0.0,0,80,"emergency stop pressed"', 0.0)
    assert faulted.estop and faulted.fault and faulted.fault_text == "emergency stop pressed"


@pytest.mark.parametrize("line, what", [
    (MANUAL_STATE[:-3], "expected 13 field"),
    (MANUAL_STATE + b",1", "expected 13 field"),
    (MANUAL_STATE.replace(b"123.25", b"12x"), "axis 3 position"),
    (MANUAL_STATE.replace(b"-30.0", b""), "axis 3 rate"),
    (MANUAL_STATE.replace(b",2,5,", b",7,5,"), "mode code 7"),
    (MANUAL_STATE.replace(b",2,5,", b",2,99999,"), "outside"),
    (MANUAL_STATE[:-2] + b"x", "quoted string"),
    (MANUAL_STATE.replace(b"90.000000", b"9\xb0.0"), "0xB0"),
])
def test_malformed_state_replies(line, what):
    with pytest.raises(TurntableProtocolError, match=what):
        sc.decode_state(line, 0.0)


def test_idn_and_strings():
    assert sc.decode_idn(b"Acutronic,ACUTROL3000,12345,4.2") == "Acutronic,ACUTROL3000,12345,4.2"
    with pytest.raises(TurntableProtocolError, match="expected 4"):
        sc.decode_idn(b"Acutronic")
    assert sc.decode_string(b'"limit ""outer"" tripped"') == 'limit "outer" tripped'


# -- server side ---------------------------------------------------------------------------

@pytest.mark.parametrize("line, name, frame, values", [
    (b":M:P 1", "MODE:POSITION", 0, ()),
    (b":MODE:POSITION 1", "MODE:POSITION", 0, ()),
    (b":Mode:Position 1", "MODE:POSITION", 0, ()),
    (b":mode:p 1", "MODE:POSITION", 0, ()),
    (b"M:P 1", "MODE:POSITION", 0, ()),
    (b":D:P 1,90.0", "DEMAND:POSITION", 0, (90.0,)),
    (b":D:P 2, -45.5 , 10", "DEMAND:POSITION", 1, (-45.5, 10.0)),
    (b":DEMAND:RATE 3,1.0E+01", "DEMAND:RATE", 2, (10.0,)),
    (b":D:R 1,10.0", "DEMAND:RATE", 0, (10.0,)),
    (b":R:P? 1", "READ:POSITION?", 0, ()),
    (b":READ:STATUS? 3", "READ:STATUS?", 2, ()),
    (b":I:C 1", "INTERLOCK:CLOSE", 0, ()),
    (b":INTERLOCK:OPEN 1", "INTERLOCK:OPEN", 0, ()),
    (b":I:R 1", "INTERLOCK:RESET", 0, ()),
    (b":STOP", "STOP", None, ()),
    (b"  :S  ", "STOP", None, ()),
    (b":ABORT", "ABORT", None, ()),
    (b":syst:err?", "SYSTEM:ERROR?", None, ()),
    (b":SYSTEM:ERROR?", "SYSTEM:ERROR?", None, ()),
    (b"*idn?", "*IDN?", None, ()),
    (b":L:R? 2", "LIMIT:RATE?", 1, ()),
])
def test_parse_manual_lines(line, name, frame, values):
    assert sc.parse_program(line) == [sc.ScpiRequest(name, frame, values)]


def test_compound_lines_and_relative_headers():
    units = sc.parse_program(b":D:P 1,0.0;P 2,90.0,5;:I:C 3;O 3;*IDN?;R 1;:SYST:ERR?")
    assert units == [sc.ScpiRequest("DEMAND:POSITION", 0, (0.0,)), sc.ScpiRequest("DEMAND:POSITION", 1, (90.0, 5.0)),
                     sc.ScpiRequest("INTERLOCK:CLOSE", 2), sc.ScpiRequest("INTERLOCK:OPEN", 2),
                     sc.ScpiRequest("*IDN?"), sc.ScpiRequest("INTERLOCK:RESET", 0),  # *IDN? keeps the path
                     sc.ScpiRequest("SYSTEM:ERROR?")]
    assert sc.parse_program(b";;") == []


@pytest.mark.parametrize("line, code, query", [
    (b":X:Y 1", sc.UNDEFINED_HEADER, False),
    (b":M 1", sc.UNDEFINED_HEADER, False),                 # a node, not a command
    (b":MOD:POS 1", sc.UNDEFINED_HEADER, False),           # neither the short nor the long form
    (b":R:P 1", sc.UNDEFINED_HEADER, False),               # query-only header without '?'
    (b":M:P? 1", sc.UNDEFINED_HEADER, True),               # command-only header with '?'
    (b":M:P", sc.MISSING_PARAMETER, False),
    (b":D:P 1", sc.MISSING_PARAMETER, False),
    (b":M:P 1,2", sc.PARAMETER_NOT_ALLOWED, False),
    (b":S 1", sc.PARAMETER_NOT_ALLOWED, False),
    (b":D:P x,1", sc.DATA_TYPE_ERROR, False),
    (b":D:P 1.0,1", sc.DATA_TYPE_ERROR, False),
    (b":D:P 1,ninety", sc.DATA_TYPE_ERROR, False),
    (b":D:P 1,", sc.DATA_TYPE_ERROR, False),
    (b":D:P 1,nan", sc.DATA_TYPE_ERROR, False),
    (b":D:P 1,1e999", sc.DATA_OUT_OF_RANGE, False),
    (b":R:P? 4", sc.DATA_OUT_OF_RANGE, True),
    (b":D:P 0,1", sc.DATA_OUT_OF_RANGE, False),
    (b"::M:P 1", sc.SYNTAX_ERROR, False),
    (b":D:P1,90", sc.SYNTAX_ERROR, False),
    (b":M:P \xb01", sc.SYNTAX_ERROR, False),
    (b":R:A?\x00", sc.SYNTAX_ERROR, True),
])
def test_bad_units_become_typed_errors(line, code, query):
    (unit,) = sc.parse_program(line)
    assert isinstance(unit, sc.ScpiRequestError) and isinstance(unit, TurntableProtocolError)
    assert (unit.code, unit.query) == (code, query), str(unit)


def test_a_bad_unit_does_not_hide_the_next_ones():
    units = sc.parse_program(b":M:P 9;:SYST:ERR?")
    assert isinstance(units[0], sc.ScpiRequestError) and units[1] == sc.ScpiRequest("SYSTEM:ERROR?")


def test_reply_formatting():
    assert sc.format_error(0) == '0,"No error"'
    assert sc.format_error(-222, "outer at 400") == '-222,"Data out of range;outer at 400"'
    assert sc.format_error(999) == '999,"Device-specific error"'
    assert sc.format_string('a "b"\n') == '"a ""b""?"'
    assert sc.format_reply(["1.0", '0,"No error"']) == b'1.0;0,"No error"\r\n'


@FUZZ
@given(st.lists(st.tuples(st.floats(-1e5, 1e5), st.floats(-300, 300), st.sampled_from(list(AxisMode)),
                          st.integers(0, 63)), min_size=3, max_size=3),
       st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), max_size=40))
def test_state_round_trip(axes, text):
    state = TableState(1.0, tuple(AxisState(a, r, m, AxisStatus(s)) for a, r, m, s in axes), text)
    line = sc.format_reply([sc.format_state(state)])
    assert line.endswith(b"\r\n")
    back = sc.decode_state(line[:-2], 1.0)
    for got, want in zip(back.axes, state.axes):
        assert abs(got.angle_deg - want.angle_deg) <= 5e-7 and abs(got.rate_dps - want.rate_dps) <= 5e-7
        assert (got.mode, got.status) == (want.mode, want.status)
    assert back.fault_text == text


# -- random bytes at every decoder -----------------------------------------------------------

DECODERS = [sc.decode_confirmation, sc.decode_error, sc.decode_number, sc.decode_status, sc.decode_mode,
            sc.decode_string, sc.decode_idn, lambda line: sc.decode_state(line, 0.0), sc.split_fields]
REPLY_ALPHABET = st.sampled_from([b"0", b"1", b"-", b"+", b".", b",", b'"', b";", b"E", b" ", b"5", b"9", b"\xff"])


@FUZZ
@given(st.one_of(st.binary(max_size=80), st.lists(REPLY_ALPHABET, max_size=60).map(b"".join)))
def test_decoders_decode_or_raise_turntable_errors(data):
    for decode in DECODERS:
        try:
            decode(data)
        except DeviceError:
            pass


@FUZZ
@given(st.one_of(st.binary(max_size=80),
                 st.lists(st.sampled_from([b":", b"M", b"P", b"d", b"?", b" ", b",", b";", b"1", b"-", b".5",
                                           b"SYST", b"ERR", b"*IDN", b'"', b"\t", b"\x80", b"e9"]),
                          max_size=30).map(b"".join)))
def test_parse_program_never_raises(data):
    for unit in sc.parse_program(data):
        assert isinstance(unit, (sc.ScpiRequest, sc.ScpiRequestError))
        if isinstance(unit, sc.ScpiRequest):
            assert unit.name in sc.COMMANDS
