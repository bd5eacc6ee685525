"""The chamber's ASCII dialect: the codec with byte strings as docs/hardware/chamber.md prints them, and the client
over exact expected exchanges (limits, refusals, bad replies, alarms, a lost link)."""

from __future__ import annotations

import pytest

from drivers.chamber import ascii_codec as codec
from drivers.chamber import open_chamber
from drivers.chamber.ascii import AsciiChamber
from drivers.chamber.base import ChamberAlarms, ChamberLimits, ChamberState
from drivers.errors import (
    ChamberAlarm,
    ChamberCommandError,
    ChamberConfigError,
    ChamberConnectionError,
    ChamberLimitError,
    ChamberProtocolError,
    ChamberTimeout,
)
from tests.helpers.exchange import Exchange

MON_OK = b"23.4,25.0,2.0,RUN,0\r\n"


def client(pairs, **kw) -> tuple[AsciiChamber, Exchange]:
    ex = Exchange(pairs)
    kw.setdefault("timeout_s", 0.05)
    return AsciiChamber(ex, **kw).connect(), ex


# -- codec -----------------------------------------------------------------------------

def test_requests_are_encoded_as_the_page_prints_them():
    assert codec.encode_set_setpoint(25.0) == b"TEMP,S25.0"
    assert codec.encode_set_setpoint(-40.04) == b"TEMP,S-40.0"
    assert codec.encode_set_setpoint(-0.04) == b"TEMP,S0.0"
    assert codec.encode_set_ramp(2.0) == b"RAMP,2.0"
    assert codec.encode_mode(True) == b"MODE,RUN" and codec.encode_mode(False) == b"MODE,STOP"
    assert codec.CLEAR_ALARMS == b"ALARM,CLEAR" and codec.MONITOR == b"MON?"


def test_monitor_reply_decodes_with_and_without_alarms():
    state = codec.decode_monitor(b"23.4,25.0,2.0,RUN,0", 7.0)
    assert state == ChamberState(7.0, 23.4, 25.0, 2.0, True, ChamberAlarms(0), "")
    state = codec.decode_monitor(b"-39.8,-40.0,0.0,STOP,2,1,3")
    assert not state.running and state.ramp_c_per_min == 0.0
    assert state.alarms == ChamberAlarms.OVER_TEMPERATURE | ChamberAlarms.DOOR_OPEN
    assert state.describe_alarms() == "over-temperature, door open"
    unknown = codec.decode_monitor(b"20.0,20.0,0.0,RUN,1,42")
    assert unknown.alarm and unknown.alarms == ChamberAlarms(0) and unknown.alarm_text == "alarm code 42"


@pytest.mark.parametrize("line, words", [
    (b"23.4,25.0,2.0,RUN", "needs"),
    (b"23.4,25.0,2.0,HOLD,0", "not RUN or STOP"),
    (b"abc,25.0,2.0,RUN,0", "not a number"),
    (b"23.4,25.0,-1.0,RUN,0", "negative ramp"),
    (b"23.4,25.0,2.0,RUN,2,1", "2 but 1 codes"),
    (b"23.4,25.0,2.0,RUN,1.5,1", "not 0-32"),
    (b"23.4,25.0,2.0,RUN,1,-1", "whole number"),
    (b"1e999,25.0,2.0,RUN,0", "not finite"),
    (b"\xff\xfe", "non-ASCII"),
    (b"23.4,\x0725.0,2.0,RUN,0", "control characters"),
    (b"9" * 300, "longer than any reply"),
])
def test_malformed_monitor_replies_are_protocol_errors(line, words):
    with pytest.raises(ChamberProtocolError, match=words) as info:
        codec.decode_monitor(line)
    assert info.value.raw == line


def test_acks_must_echo_the_command_and_na_is_a_refusal():
    codec.decode_ack(b"OK:TEMP,S25.0", b"TEMP,S25.0")
    with pytest.raises(ChamberProtocolError, match="expected 'OK:TEMP,S25.0'"):
        codec.decode_ack(b"OK:TEMP,S26.0", b"TEMP,S25.0")
    with pytest.raises(ChamberCommandError, match="refused: OUT OF RANGE"):
        codec.decode_ack(b"NA:OUT OF RANGE", b"TEMP,S25.0")
    with pytest.raises(ChamberCommandError, match="refused: ALARM ACTIVE"):
        codec.decode_monitor(b"NA:ALARM ACTIVE")


def test_temperature_and_alarm_queries():
    assert codec.decode_temperature(b"23.4,25.0") == (23.4, 25.0)
    assert codec.decode_alarms(b"0") == (ChamberAlarms(0), "")
    assert codec.decode_alarms(b"2,4,5") == (ChamberAlarms.SENSOR_FAULT | ChamberAlarms.EQUIPMENT_FAULT, "")
    with pytest.raises(ChamberProtocolError):
        codec.decode_temperature(b"23.4")


def test_the_simulator_side_parses_what_the_client_sends_and_formats_what_it_reads():
    assert codec.parse_request(b"TEMP,S-40.0") == codec.ChamberRequest("TEMP,S", -40.0)
    assert codec.parse_request(b"ramp,2.5") == codec.ChamberRequest("RAMP", 2.5)
    assert codec.parse_request(b"MODE,RUN") == codec.ChamberRequest("MODE", "RUN")
    assert codec.parse_request(b"MON?") == codec.ChamberRequest("MON?")
    for bad, reason in ((b"TEMP,Sx", codec.NA_PARAMETER), (b"MODE,HOLD", codec.NA_PARAMETER),
                        (b"FLY", codec.NA_COMMAND), (b"\xff", codec.NA_COMMAND)):
        with pytest.raises(codec.RequestError) as info:
            codec.parse_request(bad)
        assert info.value.reason == reason
    state = ChamberState(0.0, -39.96, -40.0, 0.0, False, ChamberAlarms.DOOR_OPEN)
    line = codec.format_monitor(state)
    assert line == b"-40.0,-40.0,0.0,STOP,1,3\r\n"
    assert codec.decode_monitor(line.strip()).alarms == ChamberAlarms.DOOR_OPEN
    assert codec.format_ok(b"MODE,RUN") == b"OK:MODE,RUN\r\n" and codec.format_na("X") == b"NA:X\r\n"


# -- client over expected exchanges ------------------------------------------------------

def test_setpoint_with_ramp_run_poll_stop_in_exact_exchanges():
    chamber, ex = client([
        (b"RAMP,2.0\r\n", b"OK:RAMP,2.0\r\n"),
        (b"TEMP,S-20.0\r\n", b"OK:TEMP,S-20.0\r\n"),
        (b"MODE,RUN\r\n", b"OK:MODE,RUN\r\n"),
        (b"MON?\r\n", b"18.2,-20.0,2.0,RUN,0\r\n"),
        (b"TEMP?\r\n", b"18.2,-20.0\r\n"),
        (b"MODE,STOP\r\n", b"OK:MODE,STOP\r\n"),
        (b"ALARM,CLEAR\r\n", b"OK:ALARM,CLEAR\r\n"),
    ])
    with ex:
        chamber.set_setpoint(-20.0, ramp_c_per_min=2.0)
        chamber.run()
        state = chamber.check_state()
        assert (state.temperature_c, state.setpoint_c, state.running) == (18.2, -20.0, True)
        assert chamber.read_temperature() == (18.2, -20.0)
        chamber.stop()
        chamber.clear_alarms()


def test_limits_are_checked_before_anything_is_sent():
    chamber, ex = client([], limits=ChamberLimits(-40.0, 85.0, 3.0))
    with ex:
        for setpoint, ramp in ((90.0, None), (-41.0, None), (float("nan"), None), (25.0, 3.5), (25.0, -1.0)):
            with pytest.raises(ChamberLimitError):
                chamber.set_setpoint(setpoint, ramp)
    assert ex.sent == []


def test_bad_limits_are_config_errors():
    for kw in ({"min_setpoint_c": 50.0, "max_setpoint_c": 20.0}, {"max_ramp_c_per_min": 0.0},
               {"min_setpoint_c": -500.0}):
        with pytest.raises(ChamberConfigError):
            ChamberLimits(**kw)


def test_a_refusal_is_raised_at_once_not_retried():
    chamber, ex = client([(b"MODE,RUN\r\n", b"NA:ALARM ACTIVE\r\n")])
    with ex, pytest.raises(ChamberCommandError, match="ALARM ACTIVE"):
        chamber.run()
    assert chamber.stats.requests == 1


def test_garbage_is_retried_then_a_protocol_error():
    chamber, ex = client([(b"MON?\r\n", b"\x00\xffjunk\r\n")] * 3)
    with ex, pytest.raises(ChamberProtocolError, match="non-ASCII"):
        chamber.read_state()
    assert chamber.stats.protocol_errors == 3


def test_a_garbled_reply_then_a_good_one_succeeds():
    chamber, ex = client([(b"MON?\r\n", b"23.4,25.0\r\n"), (b"MON?\r\n", MON_OK)])
    with ex:
        assert chamber.read_state().temperature_c == 23.4
    assert chamber.stats.protocol_errors == 1


def test_silence_is_retried_then_a_timeout():
    chamber, ex = client([(b"MON?\r\n", None)] * 3)
    with ex, pytest.raises(ChamberTimeout, match="no reply to b'MON\\?'"):
        chamber.read_state()
    assert chamber.stats.timeouts == 3


def test_an_alarm_in_the_state_raises_chamber_alarm_with_the_state():
    chamber, ex = client([(b"MON?\r\n", b"92.0,85.0,0.0,STOP,1,1\r\n")])
    with ex, pytest.raises(ChamberAlarm, match="over-temperature") as info:
        chamber.check_state()
    assert info.value.state.temperature_c == 92.0


class _Dropping(Exchange):
    """An exchange whose link drops on every write (the controller's cable pulled)."""

    def write(self, data: bytes) -> None:
        self.sent.append(data)
        raise ConnectionError("cable pulled")


def test_a_lost_link_is_reopened_then_a_connection_error():
    ex = _Dropping([])
    chamber = AsciiChamber(ex, timeout_s=0.05).connect()
    with pytest.raises(ChamberConnectionError, match="lost") as info:
        chamber.read_state()
    assert isinstance(info.value.__cause__, ConnectionError)
    assert ex.opened == 3 and chamber.stats.reconnects == 2


def test_a_failing_path_stops_the_chamber_and_keeps_the_first_error():
    chamber, ex = client([(b"MODE,STOP\r\n", b"OK:MODE,STOP\r\n")])
    with ex, pytest.raises(RuntimeError, match="the first error"):
        with chamber:
            raise RuntimeError("the first error")


def test_make_safe_goes_to_the_safe_setpoint_or_falls_back_to_stop():
    chamber, ex = client([(b"TEMP,S23.0\r\n", b"OK:TEMP,S23.0\r\n"), (b"MODE,RUN\r\n", b"OK:MODE,RUN\r\n")])
    with ex:
        assert chamber.make_safe(23.0) == "setpoint 23 degC (safe setpoint), running"
    chamber, ex = client([(b"TEMP,S23.0\r\n", b"NA:OUT OF RANGE\r\n"), (b"MODE,STOP\r\n", b"OK:MODE,STOP\r\n")])
    with ex:
        assert chamber.make_safe(23.0).endswith("OUT OF RANGE); stopped")
    chamber, ex = client([(b"MODE,STOP\r\n", None)] * 3)
    with ex:
        assert chamber.make_safe(None) == "stop failed: the chamber may still be controlling"
    chamber, ex = client([], limits=ChamberLimits(0.0, 50.0))
    with ex:       # a safe setpoint beyond the limits is refused before sending; the stop still goes out
        ex.pairs.append((b"MODE,STOP\r\n", b"OK:MODE,STOP\r\n"))
        assert "ChamberLimitError" in chamber.make_safe(-10.0)


def test_open_chamber_picks_the_dialect_and_checks_the_url():
    assert isinstance(open_chamber("tcp://127.0.0.1:1", "ascii"), AsciiChamber)
    with pytest.raises(ChamberConfigError, match="say which dialect"):
        open_chamber("tcp://127.0.0.1:1")
    with pytest.raises(ChamberConfigError, match="Modbus url"):
        open_chamber("modbus+tcp://127.0.0.1:1", "ascii")
    with pytest.raises(ChamberConfigError, match="unknown chamber dialect"):
        open_chamber("tcp://127.0.0.1:1", "espec")
    with pytest.raises(ChamberConfigError, match="expected tcp://host:port"):
        open_chamber("tcp://nohost", "ascii")
    with pytest.raises(ChamberConfigError):
        AsciiChamber(Exchange([]), timeout_s=0.0)
