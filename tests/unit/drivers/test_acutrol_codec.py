"""The ACL codec against the examples TM-8004 prints (the bytes as the manual shows them) and its error cases."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.errors import TurntableProtocolError
from drivers.turntable import acutrol_codec as ac


def parsed(message: bytes) -> list[ac.Unit]:
    units, refused = ac.parse_message(message)
    assert refused is None, refused
    return units


def refused(message: bytes) -> ac.AclError:
    _, error = ac.parse_message(message)
    assert error is not None, f"{message!r} was taken"
    return error


# -- TM-8004 2.1: three spellings of one command, three that fail -------------------------------------------------

@pytest.mark.parametrize("message", [b":Demand:Position 3,10.5", b":Dem:Pos 3,10.50000", b":D:P 3,10.5"])
def test_the_manuals_three_spellings_of_one_position_demand(message):
    assert parsed(message) == [ac.Unit(("DEMAND", "POSITION"), False, (3, 10.5))]


@pytest.mark.parametrize("message, code, words", [
    (b":Demand:Posn 3,10.5", ac.NOT_RECOGNIZED, "'Posn' is not a command under DEMAND"),        # spelling
    (b":Dem;Pos 3,10.50000", ac.SYNTAX_ERROR, "misplaced ';'"),                               # misused semicolon
    (b":D:P,3,10.5", ac.SYNTAX_ERROR, "comma between the command and its data"),             # comma after header
])
def test_the_manuals_three_errors(message, code, words):
    error = refused(message)
    assert error.code == code and words in str(error)
    assert str(error).startswith(ac.ERROR_TEXT[code])


def test_mnemonics_are_case_insensitive_and_every_terminator_the_manual_allows_ends_a_message():
    expected = [ac.Unit(("DEMAND", "POSITION"), False, (1, 10.0))]
    for message in (b":dem:pos 1,10", b":DEM:POS 1,10", b":DeM:pOs 1,10"):
        for end in (b"", b"\n", b"\r", b"\r\n"):
            assert parsed(message + end) == expected


# -- TM-8004 2.2 / 2.3: subsystems, ';' and ';:' ------------------------------------------------------------------

def test_semicolon_stays_in_the_subsystem_and_semicolon_colon_goes_back_to_the_root():
    assert parsed(b":Mode:Position 1;Rate 2") == [ac.Unit(("MODE", "POSITION"), False, (1,)),
                                                           ac.Unit(("MODE", "RATE"), False, (2,))]
    assert parsed(b":Demand:Pos 2,0.01;Rate 3,100") == [ac.Unit(("DEMAND", "POSITION"), False, (2, 0.01)),
                                                        ac.Unit(("DEMAND", "RATE"), False, (3, 100.0))]
    assert parsed(b":Dem:Pos 2,0.01;:Mode:Pos 2;Rate 1") == [ac.Unit(("DEMAND", "POSITION"), False, (2, 0.01)),
                                                             ac.Unit(("MODE", "POSITION"), False, (2,)),
                                                             ac.Unit(("MODE", "RATE"), False, (1,))]


def test_the_first_colon_is_optional_but_a_command_outside_the_subsystem_is_not_found():
    assert parsed(b"Dem:Pos 2,0.01") == parsed(b":Dem:Pos 2,0.01")
    error = refused(b":Dem:Pos 2,0.01;Mode:Pos 2")          # no ':' back to the root: MODE is not under DEMAND
    assert error.code == ac.NOT_RECOGNIZED


def test_the_manuals_chained_examples_parse():
    assert [u.name for u in parsed(b":I:C 1;C 2")] == ["INTERLOCK:CLOSE", "INTERLOCK:CLOSE"]
    assert [u.name for u in parsed(b":I:O 1;O 2;O 3")] == ["INTERLOCK:OPEN"] * 3
    assert [u.name for u in parsed(b":INT:RES;CLOS 1")] == ["INTERLOCK:RESET", "INTERLOCK:CLOSE"]
    assert [u.name for u in parsed(b":M:O 2;O 3")] == ["MODE:OFF", "MODE:OFF"]
    assert [u.name for u in parsed(b":M:P 1;P 2")] == ["MODE:POSITION", "MODE:POSITION"]
    assert [u.name for u in parsed(b":D:R 1,1.11111;R 3,45.125")] == ["DEMAND:RATE", "DEMAND:RATE"]
    assert parsed(b":DEM:Delta 1,-45.0;") == [ac.Unit(("DEMAND", "DELTAPOSITION"), False, (1, -45.0))]
    assert [u.name for u in parsed(b":L:R R,3,100.0;R R,2,10.0")] == ["LIMIT:RATE", "LIMIT:RATE"]
    assert parsed(b":LIM:ACC P,1,1500.0") == [ac.Unit(("LIMIT", "ACCELERATION"), False, ("Position", 1, 1500.0))]
    assert parsed(b":LIM:ACC? P,1") == [ac.Unit(("LIMIT", "ACCELERATION"), True, ("Position", 1))]
    assert parsed(b":LIM:HPOS P,2,179.0")[0].path == ("LIMIT", "HIGHPOSITION")
    assert parsed(b":LIM:LPOS S,2,-179.0")[0].args == ("Synthesis", 2, -179.0)
    assert [u.args[0] for u in parsed(b":M? 1;:M? 2;:M? 3")] == [1, 2, 3]
    assert [u.name for u in parsed(b":DEM:POS? 2;POS? 1")] == ["DEMAND:POSITION?", "DEMAND:POSITION?"]


def test_the_manuals_examples_for_a_bigger_system_name_an_axis_this_table_does_not_have():
    assert refused(b":LIM:H P,4,180.0;L P,4,-180.0").code == ac.OUT_OF_RANGE      # a fourth axis


def test_reads_answer_with_or_without_the_question_mark():
    """TM-8004 4.10: the '?' of a read is optional, for ACT2000 compatibility."""
    assert parsed(b":READ:POS? 1;POS 2;POS 3") == [ac.Unit(("READ", "POSITION"), True, (k,)) for k in (1, 2, 3)]
    assert [u.name for u in parsed(b":R:A 2;R 2;P 2")] == ["READ:ACCELERATION?", "READ:RATE?", "READ:POSITION?"]
    assert parsed(b":READ:ACC 1")[0].query


def test_all_is_for_commands_and_an_axis_is_a_plain_digit_string():
    assert parsed(b":Mode:Position ALL")[0].args == ("ALL",)
    assert parsed(b":m:p all")[0].args == ("ALL",)
    assert refused(b":Read:Position? ALL").code == ac.OUT_OF_RANGE
    assert refused(b":Mode:Off -1").code == ac.OUT_OF_RANGE       # <command arg> has no sign
    assert refused(b":Mode:Off 1.0").code == ac.OUT_OF_RANGE
    assert refused(b":Mode:Off 0").code == ac.OUT_OF_RANGE


@pytest.mark.parametrize("text, value", [  # TM-8004 2.6.1.2 <NRf>, with ASCII minus signs
    (".123", 0.123), ("1.23", 1.23), ("+12.3", 12.3), (".123 E - 45", 0.123e-45), ("+12.3e+45", 12.3e45),
    ("0.123 E + 4", 0.123e4), ("+12.3e-4", 12.3e-4), ("-.123", -0.123), ("12", 12.0)])
def test_nrf_numbers(text, value):
    assert parsed(b":D:R 1," + text.encode())[0].args == (1, pytest.approx(value, rel=1e-12))


@pytest.mark.parametrize("text", ["1,5", "abc", "1e", "--1", "0x10", "nan", "inf", "1.5V"])
def test_what_is_not_a_number(text):
    assert refused(b":D:R 1," + text.encode()).code in (ac.INVALID_NUMBER, ac.PARAMETER_COUNT)


def test_binary_blocks_are_refused_not_misread():
    assert refused(b":DEM:POS 1,#14\x01\x02\x03\x04").code in (ac.INVALID_NUMBER, ac.SYNTAX_ERROR)
    assert refused(b":DEM:POS 1,#14abcd").code == ac.INVALID_NUMBER


def test_modes_by_letter_or_leading_part():
    assert [ac.resolve_mode(m) for m in ("P", "pos", "Position", "rate", "R", "synt", "O", "off", "A", "Ar")] == [
        "Position", "Position", "Position", "Rate", "Rate", "Synthesis", "Off", "Off", "Abort", "Arate"]
    assert ac.resolve_mode("x") is None and ac.resolve_mode("") is None
    assert refused(b":Mode 1,Spin").code == ac.OUT_OF_RANGE


def test_headers_the_manuals_drafts_misprint_are_refused():
    """`:Mode:Rate1` (no space) and `:I C 2` (space for a colon) appear in the manual's examples; the syntax
    chapter rules both out."""
    assert refused(b":Mode:Rate1").code == ac.NOT_RECOGNIZED
    assert refused(b":D:P 2,0.0;:I:R;:M:P 2;:I C 2").code == ac.NOT_AVAILABLE
    units, _ = ac.parse_message(b":D:P 2,0.0;:I:R;:M:P 2;:I C 2")
    assert [u.name for u in units] == ["DEMAND:POSITION", "INTERLOCK:RESET", "MODE:POSITION"]   # the part before


def test_ambiguous_leading_parts_are_refused():
    assert refused(b":S:STB?").code == ac.NOT_RECOGNIZED                 # Status or System
    assert parsed(b":STAT:STB?") == [ac.Unit(("STATUS", "STB"), True, ())]
    assert parsed(b":L:A? P,1")[0].path == ("LIMIT", "ACCELERATION")


def test_common_commands_and_the_public_clients_forms():
    for message, name in [(b"*idn?", "*IDN?"), (b"*stb?", "*STB?"), (b"*CLS", "*CLS"),
                          (b":interlock? 1", "INTERLOCK?"), (b":Interlock:Reset", "INTERLOCK:RESET"),
                          (b":mode 1,pos", "MODE"), (b":mode? 1", "MODE?"), (b":limit:absolute? 1", "LIMIT:ABSOLUTE?"),
                          (b":lim:rate pos,1,50", "LIMIT:RATE"), (b":dem:delta 1,5", "DEMAND:DELTAPOSITION"),
                          (b":int:close 1", "INTERLOCK:CLOSE"), (b":read:pos? 1;rate? 1;acc? 1", "READ:POSITION?")]:
        assert parsed(message)[0].name == name


def test_characters_outside_ascii_and_oversized_messages_are_syntax_errors():
    assert refused(b":D:P 1,\xb05").code == ac.SYNTAX_ERROR
    assert refused(b":D:P 1,5\n:D:P 2,5").code == ac.SYNTAX_ERROR
    assert refused(b":D:P 1," + b"1" * ac.MAX_MESSAGE).code == ac.SYNTAX_ERROR


# -- responses ------------------------------------------------------------------------------------------------

def test_framed_responses_carry_code_length_text_and_nul():
    assert ac.frame_response(0) == b"\x00\x00\x00\x00\x00\x00\x00\x00\x00"
    assert ac.frame_response(0, "P;R;P") == b"\x00\x00\x00\x00\x05\x00\x00\x00P;R;P\x00"
    assert ac.frame_response(3, "x") == b"\x03\x00\x00\x00\x01\x00\x00\x00x\x00"
    assert ac.parse_framed(ac.frame_response(0, "170.00000;-32.19877")) == ac.Response(0, "170.00000;-32.19877")
    # a controller that counts the NUL in the length is read the same
    assert ac.parse_framed(b"\x00\x00\x00\x00\x06\x00\x00\x00P;R;P\x00") == ac.Response(0, "P;R;P")


@pytest.mark.parametrize("frame", [
    b"", b"\x00" * 8, b"\x00\x00\x00\x00\x05\x00\x00\x00P;R;P", b"\x00\x00\x00\x00\x02\x00\x00\x00P;R;P\x00",
    b"\x00\x00\x00\x00\x01\x00\x00\x00\xff\x00"])
def test_frames_that_break_the_rules_are_protocol_errors(frame):
    with pytest.raises(TurntableProtocolError):
        ac.parse_framed(frame)


def test_a_header_no_controller_sends_is_not_taken_for_a_length():
    assert ac.frame_size(b"garbage!") is None                      # would announce ~560 MB
    assert ac.frame_size(ac.frame_response(0, "abc")[:8]) == 12


def test_the_manuals_responses_decode():
    assert ac.split_responses("170.00000;-32.19877", 2, "demands") == ["170.00000", "-32.19877"]
    assert [ac.decode_mode(m) for m in ac.split_responses("P;R;P", 3, "modes")] == ["Position", "Rate", "Position"]
    assert ac.decode_mode("Position") == ac.decode_mode("P") == ac.decode_mode("position") == "Position"
    assert ac.decode_number("10.0001", "position") == 10.0001
    assert ac.decode_number("1.23E+45", "x") == 1.23e45 and ac.decode_number("-12", "x") == -12.0
    assert ac.decode_register("65", "stb") == 65
    assert ac.decode_interlock("Fault") == "Fault" and ac.decode_interlock("close") == "Close"
    limits = ac.decode_absolute_limits("1000.0,8300.0,50000.0,-180.0,180.0,1100.0")     # the client's six fields
    assert (limits.rate_dps, limits.pos_lo_deg, limits.velocity_trip_dps) == (1000.0, -180.0, 1100.0)
    assert ac.decode_absolute_limits("1.0,2.0,3.0,-4.0,4.0,5.0,6.0").accel_dps2 == 2.0   # the manual's seven


@pytest.mark.parametrize("bad", ["Spin", "", "Positionx", "PR"])
def test_a_wrong_mode_name_is_refused(bad):
    with pytest.raises(TurntableProtocolError):
        ac.decode_mode(bad)


@pytest.mark.parametrize("bad", ["1,2,3", "a,b,c,d,e", "10,10,10,5,-5", "-1,10,10,-5,5", "1,2,3,4,5,6,7,8"])
def test_absolute_limits_that_make_no_sense_are_refused(bad):
    with pytest.raises(TurntableProtocolError):
        ac.decode_absolute_limits(bad)


def test_the_client_encodes_short_and_long_forms():
    assert ac.unit("DEMAND:POSITION", 3, 10.5) == ":DEM:POS 3,10.500000"
    assert ac.unit("DEMAND:POSITION", 3, 10.5, long_form=True) == ":DEMAND:POSITION 3,10.500000"
    assert ac.unit("LIMIT:ABSOLUTE", 1, query=True) == ":LIM:ABS? 1"
    assert ac.unit("*IDN", query=True) == "*IDN?"
    assert ac.format_number(-0.0000001) == "0.000000" and ac.format_number(-32.19877) == "-32.198770"
    for text in (ac.unit("DEMAND:RATE", 2, -150.1234), ac.unit("LIMIT:RATE", "P", 1, 120.0),
                 ac.unit("INTERLOCK:CLOSE", 1), ac.unit("STATUS:CSR", "A1INTLK", query=True)):
        assert len(parsed(text.encode())) == 1          # what the client sends, the controller side takes
    with pytest.raises(ValueError):
        ac.unit("DEMAND:SPEED", 1, 2.0)


def _spellings(word: str, node: tuple[str, ...]) -> st.SearchStrategy[str]:
    """Any spelling the codec must take for `word` under `node`: a leading part fitting only it, in any case."""
    shortest = next(n for n in range(1, len(word) + 1) if ac.resolve(node, word[:n]) == word)
    return st.integers(shortest, len(word)).flatmap(
        lambda n: st.lists(st.booleans(), min_size=n, max_size=n).map(
            lambda upper: "".join(c if u else c.lower() for c, u in zip(word[:n], upper))))


@given(st.sampled_from([("DEMAND", "POSITION"), ("DEMAND", "RATE"), ("DEMAND", "DELTAPOSITION")]).flatmap(
           lambda path: st.tuples(st.just(path), _spellings(path[0], ()), _spellings(path[1], path[:1]))),
       st.integers(1, 3), st.floats(-1e6, 1e6, allow_nan=False), st.booleans())
def test_any_spelling_of_a_demand_parses_to_the_value_sent(spelled, axis, value, colon):
    path, first, second = spelled
    text = f"{':' if colon else ''}{first}:{second} {axis},{ac.format_number(value)}"
    [unit] = parsed(text.encode())
    assert unit.path == path and unit.args[0] == axis and abs(unit.args[1] - value) <= 5e-7
