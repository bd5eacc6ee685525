"""$MN codec: frames as a controller manual prints them, malformed ones, and random bytes."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.sim import controller as simctl
from bench.sim.controller import SimController
from bench.sim.mn_server import MnSimHandler
from drivers.errors import DeviceError, TurntableChecksumError, TurntableCommandError, TurntableProtocolError
from drivers.turntable import mn_codec as codec
from drivers.turntable.base import AxisMode, AxisState, AxisStatus, TableState

DOC = Path(__file__).resolve().parents[3] / "docs" / "hardware" / "mn.md"


# -- checksum and frames -------------------------------------------------------------
def test_issue_vectors_exact():
    assert codec.checksum(b"MNCHK,1") == 0xCE
    assert codec.checksum(b"ASCHK,OK") == 0x30
    assert codec.encode_request(codec.Check()) == b"$MNCHK,1*CE"
    assert codec.encode_frame(b"MN", "CHK", ["1"]) == b"$MNCHK,1*CE"
    assert codec.encode_ok("CHK") == b"$ASCHK,OK*30"
    assert codec.decode_frame(b"$MNCHK,1*CE\r\n") == codec.Frame("MN", "CHK", ("1",))
    assert codec.decode_reply(b"$ASCHK,OK*30", "CHK") == ()
    assert codec.decode_request(b"$MNCHK,1*CE") == codec.Check(1)


def test_checksum_wraps_modulo_256():
    assert codec.checksum(b"") == 0
    assert codec.checksum(bytes([0xFF, 0x02])) == 0x01
    assert codec.checksum(b"z" * 100) == (0x7A * 100) % 256


def test_frames_with_and_without_fields():
    assert codec.decode_frame(b"$MNSTP*92") == codec.Frame("MN", "STP", ())
    assert codec.decode_frame(b"$MNPOS,,30.000000,,,5,*7B").fields == ("", "30.000000", "", "", "5", "")
    assert codec.encode_frame("AS", "STA", [None, 1, 2.5, "x"]) == b"$ASSTA,,1,2.500000,x*" + \
        f"{codec.checksum(b'ASSTA,,1,2.500000,x'):02X}".encode()


@pytest.mark.parametrize("line, match", [
    (b"", "empty line"),
    (b"\r\n", "empty line"),
    (b"MNCHK,1*CE", "must start with '\\$'"),
    (b"#MNCHK,1*CE", "must start with '\\$'"),
    (b"$MNCHK,1", "no '\\*'"),
    (b"$MNCHK,1*C", "two upper-case hex digits"),
    (b"$MNCHK,1*CEF", "two upper-case hex digits"),
    (b"$MNCHK,1*G0", "two upper-case hex digits"),
    (b"$MNCHK,1* CE", "two upper-case hex digits"),
    (b"$MNCHK,1\x00*CE", "byte 0x00 at offset 8"),
    (b"$MNCHK,\xb91*CE", "byte 0xB9 at offset 7"),
    (b"$MN$CHK*00", "stray '\\$'"),
    (b"$MNC*HK*00", "stray '\\*'"),
    (b"$" + b"A" * 600 + b"*00", "longer than any frame"),
])
def test_malformed_frames_name_the_problem(line, match):
    with pytest.raises(TurntableProtocolError, match=match) as info:
        codec.decode_frame(line)
    assert not isinstance(info.value, TurntableChecksumError)
    assert info.value.raw == line


def test_a_lower_case_checksum_is_a_checksum_error_answered_err_7():
    """The page says lower case is rejected as a checksum error (ERR 7); the simulator said ERR 1, command ERR."""
    with pytest.raises(codec.MnChecksumError, match="two upper-case hex digits after '\\*', got b'ce'") as info:
        codec.decode_frame(b"$MNCHK,1*ce")
    assert (info.value.expected, info.value.got) == (0xCE, 0xCE)
    handler = MnSimHandler(SimController())
    assert handler(b"$MNENA,1*ab") == codec.encode_error("ENA", codec.ERR_CHECKSUM) + codec.TERMINATOR
    assert handler(b"$MNSTA*8e") == b"$ASSTA,ERR,7*F4\r\n"


def test_checksum_mismatch_says_expected_and_got():
    with pytest.raises(codec.MnChecksumError, match="frame carries CF, its content sums to CE") as info:
        codec.decode_frame(b"$MNCHK,1*CF")
    assert (info.value.expected, info.value.got) == (0xCE, 0xCF)
    assert isinstance(info.value, TurntableChecksumError)
    with pytest.raises(TurntableChecksumError):
        codec.decode_reply(b"$ASCHK,OK*31", "CHK")
    with pytest.raises(TurntableChecksumError):   # one flipped bit in the body
        codec.decode_reply(b"$ASCHK,OJ*30", "CHK")


@pytest.mark.parametrize("body, match", [
    (b"XXCHK,1", "prefix must be MN or AS"),
    (b"MNchk,1", "three upper-case letters"),
    (b"MNCH", "three upper-case letters"),
    (b"MNCHK1", "expected ',' after command CHK"),
])
def test_bad_body_syntax(body, match):
    line = b"$" + body + b"*" + f"{codec.checksum(body):02X}".encode()
    with pytest.raises(TurntableProtocolError, match=match):
        codec.decode_frame(line)


def test_encoder_refuses_what_the_dialect_cannot_carry():
    for bad in (lambda: codec.encode_frame("XX", "CHK"), lambda: codec.encode_frame("MN", "chk"),
                lambda: codec.encode_frame("MN", "CHK", ["a,b"]), lambda: codec.encode_frame("MN", "CHK", ["*"]),
                lambda: codec.encode_frame("MN", "CHK", [float("nan")]),
                lambda: codec.encode_frame("MN", "CHK", [True]),
                lambda: codec.encode_request(codec.Enable(())),
                lambda: codec.encode_request(codec.Enable((0, 0))),
                lambda: codec.encode_request(codec.Enable((3,))),
                lambda: codec.encode_request(codec.MovePositions((None, None, None))),
                lambda: codec.encode_request(codec.MovePositions((float("inf"), None, None))),
                lambda: codec.encode_request(codec.SetRate(0, float("nan"))),
                lambda: codec.encode_request(codec.Check(0)),
                lambda: codec.encode_error("POS", 1000)):
        with pytest.raises(ValueError):
            bad()


# -- requests --------------------------------------------------------------------------
REQUESTS = [
    (codec.Check(), b"$MNCHK,1*CE"),
    (codec.Enable((0, 1, 2)), b"$MNENA,1,2,3*89"),
    (codec.Enable((2,)), b"$MNENA,3*CE"),
    (codec.Disable((0, 1, 2)), b"$MNDIS,1,2,3*95"),
    (codec.Reset((0, 1, 2)), b"$MNRST,1,2,3*AE"),
    (codec.Reset((1,)), b"$MNRST,2*F2"),
    (codec.SetMode(0, AxisMode.POSITION), b"$MNMOD,1,P*54"),
    (codec.SetMode(2, AxisMode.RATE), b"$MNMOD,3,R*58"),
    (codec.SetMode(0, AxisMode.OFF), b"$MNMOD,1,O*53"),
    (codec.MovePositions((90.0, None, 180.0), (10.0, None, 10.0)), b"$MNPOS,90.000000,,180.000000,10,,10*F5"),
    (codec.MovePositions((90.0, None, 180.0), (10.0, 10.0, 10.0)), b"$MNPOS,90.000000,,180.000000,10,10,10*56"),
    (codec.MovePositions((None, 30.0, None), (None, 5.0, None)), b"$MNPOS,,30.000000,,,5,*7B"),
    (codec.SetRate(2, -10.0), b"$MNRAT,3,-10*9B"),
    (codec.Stop(), b"$MNSTP*92"),
    (codec.Abort(), b"$MNABT*72"),
    (codec.ReadState(), b"$MNSTA*83"),
]


@pytest.mark.parametrize("request_, line", REQUESTS)
def test_requests_both_ways(request_, line):
    assert codec.encode_request(request_) == line
    assert codec.decode_request(line + b"\r\n") == request_


def test_number_formats():
    assert codec.format_angle(-0.0) == "0.000000"
    assert codec.format_angle(400) == "400.000000"        # absolute, never wrapped
    assert codec.format_angle(-12.3456789) == "-12.345679"
    assert [codec.format_rate(r) for r in (10, -2.5, 0.0, -0.0, 1e-9, 0.1234567)] == \
        ["10", "-2.5", "0", "0", "0", "0.123457"]
    assert codec.decode_request(b"$MNRAT,1,.5*" + f"{codec.checksum(b'MNRAT,1,.5'):02X}".encode()) == \
        codec.SetRate(0, 0.5)


def _framed(body: str) -> bytes:
    return codec.encode_frame(body[:2], body[2:5], body[6:].split(",") if len(body) > 5 else [])


@pytest.mark.parametrize("body, code, match", [
    ("MNFOO", codec.ERR_SYNTAX, "unknown command 'FOO'"),
    ("ASCHK,1", codec.ERR_SYNTAX, "must start with \\$MN"),
    ("MNCHK", codec.ERR_ARGUMENT, "CHK takes 1 fields, got 0"),
    ("MNCHK,0", codec.ERR_ARGUMENT, "station"),
    ("MNENA,4", codec.ERR_ARGUMENT, "axis must be 1, 2 or 3"),
    ("MNENA,1,1", codec.ERR_ARGUMENT, "axis listed twice"),
    ("MNENA,1,2,3,1", codec.ERR_ARGUMENT, "ENA takes 1-3 fields, got 4"),
    ("MNMOD,1,X", codec.ERR_ARGUMENT, "mode must be P, R or O"),
    ("MNPOS,1,2,3", codec.ERR_ARGUMENT, "POS takes 6 fields"),
    ("MNPOS,,,,1,1,1", codec.ERR_ARGUMENT, "at least one target"),
    ("MNPOS,1e3,,,,,", codec.ERR_ARGUMENT, "outer target must be a decimal number"),
    ("MNPOS,nan,,,,,", codec.ERR_ARGUMENT, "decimal number"),
    ("MNPOS,1,,,fast,,", codec.ERR_ARGUMENT, "outer move rate must be a decimal number"),
    ("MNRAT,2,", codec.ERR_ARGUMENT, "rate must be a decimal number"),
    ("MNRAT,2,1,", codec.ERR_ARGUMENT, "RAT takes 2 fields"),
    ("MNSTA,1", codec.ERR_ARGUMENT, "STA takes 0 fields"),
])
def test_bad_requests_carry_a_reply_code(body, code, match):
    with pytest.raises(codec.MnRequestError, match=match) as info:
        codec.decode_request(_framed(body))
    assert info.value.code == code


def test_huge_number_is_refused_not_infinite():
    with pytest.raises(codec.MnRequestError, match="out of range"):
        codec.decode_request(_framed("MNRAT,1," + "9" * 400))


def test_error_codes_are_the_simulators():
    for name in ("ERR_SYNTAX", "ERR_ARGUMENT", "ERR_NOT_ENABLED", "ERR_WRONG_MODE", "ERR_LIMIT", "ERR_FAULT"):
        assert getattr(codec, name) == getattr(simctl, name)


# -- replies ---------------------------------------------------------------------------
@pytest.mark.parametrize("line, code", [
    (b"$ASPOS,ERR,3*FA", 3), (b"$ASPOS,ERR,5*FC", 5), (b"$ASMOD,ERR,3*E8", 3), (b"$ASRAT,ERR,4*F0", 4),
    (b"$ASENA,ERR,6*DF", 6), (b"$ASENA,ERR,2*DB", 2),
])
def test_error_replies_raise_command_error_with_code(line, code):
    cmd = line[3:6].decode()
    with pytest.raises(TurntableCommandError, match=f"refused {cmd}: error {code}") as info:
        codec.decode_reply(line, cmd)
    assert info.value.code == code


def test_damaged_request_replies_are_protocol_errors_worth_a_retry():
    with pytest.raises(TurntableChecksumError, match="checksum error in the STA request"):
        codec.decode_reply(b"$ASSTA,ERR,7*F4", "STA")
    with pytest.raises(TurntableProtocolError, match="could not read the STA request"):
        codec.decode_reply(b"$ASERR,ERR,1*EF", "STA")


@pytest.mark.parametrize("line, cmd, n, match", [
    (b"$ASPOS,OK*4C", "STA", 13, "reply to POS where a reply to STA was expected"),
    (b"$MNCHK,1*CE", "CHK", 0, "expected a \\$AS reply to CHK, got a \\$MN frame"),
    (_framed("ASCHK"), "CHK", 0, "does not end in OK"),
    (_framed("ASCHK,DONE"), "CHK", 0, "does not end in OK"),
    (_framed("ASCHK,1,OK"), "CHK", 0, "1 data fields, expected 0"),
    (_framed("ASSTA,OK"), "STA", 13, "0 data fields, expected 13"),
    (_framed("ASPOS,ERR"), "POS", 0, "error reply must be ERR,<code"),
    (_framed("ASPOS,ERR,x"), "POS", 0, "error reply must be ERR,<code"),
    (_framed("ASPOS,ERR,1234"), "POS", 0, "error reply must be ERR,<code"),
])
def test_wrong_replies(line, cmd, n, match):
    with pytest.raises(TurntableProtocolError, match=match):
        codec.decode_reply(line, cmd, n)


STA_MOVING = (b"$ASSTA,29.000000,10.000000,P,0005,0.000000,0.000000,P,0003,"
              b"29.500000,10.000000,P,0005,,OK*8C")
STA_LIMIT = (b"$ASSTA,90.000000,0.000000,O,0000,0.000000,0.000000,O,0020,170.000000,0.000000,O,0000,"
             b"middle limit switch tripped,OK*BA")


def test_state_reply_as_printed():
    state = codec.decode_state(codec.decode_reply(STA_MOVING, "STA", codec.STATE_FIELDS), 12.5)
    assert state.time_s == 12.5
    assert state.angles_deg == (29.0, 0.0, 29.5)
    assert state.rates_dps == (10.0, 0.0, 10.0)
    assert state.modes == (AxisMode.POSITION,) * 3
    assert state.axes[0].status == AxisStatus.ENABLED | AxisStatus.MOVING
    assert state.axes[1].status == AxisStatus.ENABLED | AxisStatus.IN_POSITION
    assert state.fault_text == "" and not state.fault and not state.estop

    state = codec.decode_state(codec.decode_reply(STA_LIMIT, "STA", codec.STATE_FIELDS), 0.0)
    assert state.axes[1].status == AxisStatus.LIMIT and state.fault and not state.estop
    assert state.modes == (AxisMode.OFF,) * 3
    assert state.fault_text == "middle limit switch tripped"


def test_status_word_bits_and_reserved_bits():
    assert codec.axis_status(0x0001) == AxisStatus.ENABLED
    assert codec.axis_status(0x0002) == AxisStatus.IN_POSITION
    assert codec.axis_status(0x0004) == AxisStatus.MOVING
    assert codec.axis_status(0x0010) == AxisStatus.FAULT
    assert codec.axis_status(0x0020) == AxisStatus.LIMIT
    assert codec.axis_status(0x0080) == AxisStatus.ESTOP
    assert codec.axis_status(0xFF48) == AxisStatus(0)     # reserved bits only
    for flags in range(64):
        status = AxisStatus(flags)
        assert codec.axis_status(codec.status_word(status)) == status


@pytest.mark.parametrize("fields, match", [
    (["x", "0", "P", "0000"], "outer angle must be a decimal number"),
    (["0", "inf", "P", "0000"], "outer rate must be a decimal number"),
    (["0", "0", "Q", "0000"], "mode must be P, R or O"),
    (["0", "0", "P", "00000"], "outer status word must be four upper-case hex digits"),
    (["0", "0", "P", "00ff"], "outer status word"),
    (["0", "0", "P", ""], "outer status word"),
])
def test_bad_state_fields(fields, match):
    good = ["0.0", "0.0", "P", "0003"]
    with pytest.raises(TurntableProtocolError, match=match):
        codec.decode_state(fields + good + good + [""], 0.0)
    with pytest.raises(TurntableProtocolError, match=match.replace("outer", "inner")):
        codec.decode_state(good + good + fields + [""], 0.0)
    with pytest.raises(TurntableProtocolError, match="12 data fields, expected 13"):
        codec.decode_state(good * 3, 0.0)


def test_state_round_trip_sanitises_fault_text():
    state = TableState(0.0, (AxisState(400.0, -3.25, AxisMode.RATE, AxisStatus.ENABLED | AxisStatus.MOVING),
                             AxisState(-90.5, 0.0, AxisMode.POSITION, AxisStatus.ENABLED | AxisStatus.IN_POSITION),
                             AxisState(0.0, 0.0, AxisMode.OFF, AxisStatus.ESTOP | AxisStatus.FAULT)),
                       "inner: amp fault, code *3 $x\n")
    back = codec.decode_state(codec.decode_reply(codec.encode_state(state), "STA", 13), 0.0)
    assert back.axes == state.axes
    assert back.fault_text == "inner: amp fault; code x3 Sx?"


# -- the dialect page ----------------------------------------------------------------------
def test_every_frame_on_the_dialect_page_has_a_correct_checksum():
    text = DOC.read_text()
    frames = []
    for line in text.splitlines():
        for match in re.finditer(r"\$(?:MN|AS)[^`*<>\n]*\*[0-9A-Fa-f]{1,3}", line):
            frames.append((match.group(0), "(wrong)" in line[match.end():match.end() + 12]))
    assert len(frames) > 40
    for frame, wrong in frames:
        if wrong:
            with pytest.raises(TurntableProtocolError):
                codec.decode_frame(frame.encode())
        else:
            codec.decode_frame(frame.encode())
    for _request, line in REQUESTS:
        assert line.decode() in text


# -- random bytes -----------------------------------------------------------------------------
def _decoders():
    yield codec.decode_frame
    yield codec.decode_request
    for cmd, n in (("CHK", 0), ("STA", 13), ("POS", 0)):
        yield lambda line, cmd=cmd, n=n: codec.decode_reply(line, cmd, n)
    yield lambda line: codec.decode_state(codec.decode_reply(line, "STA", 13), 0.0)


def _check_decoders(data: bytes) -> None:
    for decode in _decoders():
        try:
            decode(data)
        except DeviceError:
            pass


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=120))
def test_random_bytes_decode_or_raise_turntable_error(data):
    _check_decoders(data)


_FIELD = st.text(alphabet="0123456789.-+,PROKERSTAMNCHX ", max_size=12)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(["MN", "AS"]), st.sampled_from(codec.COMMANDS + ("ERR", "XYZ")),
       st.lists(_FIELD, max_size=15))
def test_well_framed_random_fields_decode_or_raise_turntable_error(prefix, cmd, fields):
    body = (prefix + cmd + "".join("," + f for f in fields)).encode()
    _check_decoders(b"$" + body + b"*" + f"{codec.checksum(body):02X}".encode())
