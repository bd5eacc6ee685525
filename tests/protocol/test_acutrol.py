"""The ACUTROL3000 (ACL) client: exact exchanges, and end to end against the simulator over TCP and a pty."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.sim.acutrol_server import AcutrolSimHandler, serve_acutrol
from bench.sim.controller import SimController
from bench.sim.serve import LineServer
from drivers.clock import ManualClock
from drivers.errors import (
    TurntableCommandError,
    TurntableEStop,
    TurntableFault,
    TurntableLimitError,
    TurntableProtocolError,
    TurntableTimeout,
)
from drivers.turntable import acutrol_codec as ac
from drivers.turntable import open_turntable
from drivers.turntable.acutrol import AcutrolTurntable
from drivers.turntable.base import AxisLimits, AxisMode, AxisStatus, TurntableLimits
from tests.helpers.exchange import Exchange

ABS = b":LIM:ABS? 1;:LIM:ABS? 2;:LIM:ABS? 3\n"
FACTORY = "200.0,50.0,5000.0,-170.0,170.0,240.0,10.0"
OK = b"\x00\x00\x00\x00\x00\x00\x00\x00\x00"       # error code 0, no text, NUL
CLOSED = b"\x00\x00\x00\x00\x05\x00\x00\x00Close\x00"


def frame(text: str = "", code: int = 0) -> bytes:
    return ac.frame_response(code, text)


def client(pairs, **kw) -> tuple[AcutrolTurntable, Exchange]:
    asked = ABS.replace(b"LIM:ABS", b"LIMIT:ABSOLUTE") if kw.get("long_form") else ABS
    ex = Exchange([(asked, frame(";".join([FACTORY] * 3)))] + pairs)
    kw.setdefault("timeout_s", 0.05)
    return AcutrolTurntable(ex, **kw).connect(), ex


STATE_QUERY = (b":READ:POS? 1;:READ:POS? 2;:READ:POS? 3;:READ:RATE? 1;:READ:RATE? 2;:READ:RATE? 3;:MODE? 1;:MODE? 2;"
               b":MODE? 3;:INT? 1;:INT? 2;:INT? 3;:STAT:CSR? A1INTLK;:STAT:CSR? A2INTLK;:STAT:CSR? A3INTLK;"
               b":STAT:CSR? A1DYN;:STAT:CSR? A2DYN;:STAT:CSR? A3DYN\n")


# -- exact exchanges ---------------------------------------------------------------------------------------------

def test_every_command_is_one_message_confirmed_by_its_framed_response():
    table, ex = client([
        (b":MODE:OFF 1;:MODE:OFF 2;:MODE:OFF 3;:INT:CLOS 1;:INT:CLOS 2;:INT:CLOS 3\n", OK),
        (b":MODE:POS 1;:INT? 1\n", CLOSED),
        (b":MODE:POS 3;:INT? 3\n", CLOSED),
        (b":LIM:RATE P,1,20.000000;:DEM:POS 1,90.000000;:LIM:RATE P,3,20.000000;:DEM:POS 3,-10.500000\n", OK),
        (b":MODE? 2;:INT? 2\n", frame("Off;Close")),
        (b":DEM:RATE 2,0.000000;:MODE:RATE 2\n", OK),
        (b":DEM:RATE 2,-10.500000\n", OK),
        (b":MODE? 2;:INT? 2\n", frame("Rate;Close")),        # already turning: no stop on the way to 5 deg/s
        (b":DEM:RATE 2,5.000000\n", OK),
        (b":MODE:OFF 1;:MODE:OFF 2;:MODE:OFF 3\n", OK),
        (b":INT:RES\n", OK),
        (b":INT:OPEN 1;:INT:OPEN 2;:INT:OPEN 3\n", OK),
    ])
    with ex:
        table.enable()
        table.move_to([90.0, None, -10.5], rate_dps=20.0)
        table.set_rate("middle", -10.5)
        table.set_rate("middle", 5.0)
        table.stop()
        table.reset_faults()
        table.abort()


def test_long_mnemonics_on_request():
    table, ex = client([(b":MODE? 1;:INTERLOCK? 1\n", frame("P;Close")),
                        (b":DEMAND:RATE 1,0.000000;:MODE:RATE 1\n", OK),
                        (b":DEMAND:RATE 1,5.000000\n", OK)], long_form=True)
    with ex:
        table.set_rate(0, 5.0)


def test_the_state_is_one_message_of_reads_answered_from_one_frame():
    reply = ("10.000000;0.000000;-5.500000;0.000000;12.000000;0.000000;Position;Rate;P;Close;Close;Open;"
             "0;0;0;256;0;0")
    table, ex = client([(STATE_QUERY, frame(reply))], clock=ManualClock(3.0))
    with ex:
        state = table.read_state()
    assert state.time_s == 3.0 and state.angles_deg == (10.0, 0.0, -5.5) and state.rates_dps == (0.0, 12.0, 0.0)
    assert state.modes == (AxisMode.POSITION, AxisMode.RATE, AxisMode.POSITION)
    assert state.axes[0].status == AxisStatus.ENABLED | AxisStatus.IN_POSITION
    assert state.axes[1].status == AxisStatus.ENABLED | AxisStatus.MOVING      # rate profile not complete
    assert state.axes[2].status == AxisStatus(0) and state.fault_text == ""


def test_interlock_faults_map_to_limit_fault_and_estop():
    reply = ("1.0;0.0;2.0;0.0;0.0;0.0;Off;Off;Off;Fault;Fault;Fault;128;64;512;0;0;0")
    table, ex = client([(STATE_QUERY, frame(reply))])
    with ex:
        state = table.read_state()
    assert [a.status for a in state.axes] == [AxisStatus.LIMIT, AxisStatus.FAULT, AxisStatus.ESTOP]
    assert "limit switch string open (INTLK1)" in state.fault_text and "master interlock" in state.fault_text
    with pytest.raises(TurntableEStop):
        table.check_state(state)


def test_an_acl_error_names_the_command_sent_and_the_controllers_text():
    table, ex = client([(b":INT:RES\n", frame("Interlock fault latched: emergency stop still active", 7))])
    with ex, pytest.raises(TurntableCommandError) as info:
        table.reset_faults()
    message = str(info.value)
    assert info.value.code == 7 and "':INT:RES'" in message and "Interlock fault latched" in message
    assert "\n" not in message


@pytest.mark.parametrize("reply", [
    "x;0;0;0;0;0;P;P;P;Close;Close;Close;0;0;0;0;0;0",          # a position that is not a number
    "0;0;0;0;0;0;Spin;P;P;Close;Close;Close;0;0;0;0;0;0",       # a wrong mode name
    "0;0;0;0;0;0;Synthesis;P;P;Close;Close;Close;0;0;0;0;0;0",  # a mode the bench does not drive
    "0;0;0;0;0;0;P;P;P;Shut;Close;Close;0;0;0;0;0;0",           # not an interlock state
    "0;0;0;0;0;0;P;P;P;Close;Close;Close;0;0;0;0;0",            # one response short
])
def test_a_state_that_does_not_parse_is_refused_after_the_retries(reply):
    table, ex = client([(STATE_QUERY, frame(reply))] * 3)
    with ex, pytest.raises(TurntableProtocolError):
        table.read_state()


def test_garbage_instead_of_a_frame_is_retried_then_refused():
    table, ex = client([(STATE_QUERY, b"garbage!garbage!\n")] * 3)
    with ex, pytest.raises(TurntableProtocolError):
        table.read_state()
    assert table.stats.protocol_errors == 3


def test_no_demand_goes_to_an_axis_that_is_not_servoed():
    table, ex = client([(b":MODE:POS 2;:INT? 2\n", frame("Open")),
                        (STATE_QUERY, frame("0;0;0;0;0;0;Off;Position;Off;Close;Open;Close;0;0;0;0;0;0"))])
    with ex, pytest.raises(TurntableCommandError, match="refused: middle axis not enabled") as info:
        table.move_to([None, 10.0, None])
    assert info.value.code == ac.NOT_SERVOED


def test_silence_is_a_timeout():
    table, ex = client([(b":INT:RES\n", None)] * 3)
    with ex, pytest.raises(TurntableTimeout):
        table.reset_faults()


# -- limits: the controller's absolute ones bound the configured ones ---------------------------------------------

def test_demands_beyond_the_absolute_limits_are_refused_before_anything_is_sent():
    table, ex = client([])      # continuous in the configuration, +-170 deg on the controller
    with ex:
        with pytest.raises(TurntableLimitError, match="outside its limits"):
            table.move_to([171.0, None, None])
        with pytest.raises(TurntableLimitError):
            table.set_rate("outer", 150.0)          # beyond the configured 100 deg/s
    assert table.limits.axes[0].min_deg == -170.0 and table.limits.axes[0].max_deg == 170.0


@pytest.mark.parametrize("axis, words", [
    (AxisLimits(max_rate_dps=500.0), "max_rate_dps 500.0 exceeds the controller's absolute limit 200.0"),
    (AxisLimits(max_accel_dps2=60.0), "max_accel_dps2 60.0 exceeds"),
    (AxisLimits(min_deg=-180.0, max_deg=0.0), "min_deg -180.0 is below"),
    (AxisLimits(min_deg=0.0, max_deg=175.0), "max_deg 175.0 is above"),
])
def test_configured_limits_beyond_the_controllers_are_refused_at_connect(axis, words):
    limits = TurntableLimits((AxisLimits(), axis, AxisLimits()))
    ex = Exchange([(ABS, frame(";".join([FACTORY] * 3)))])
    table = AcutrolTurntable(ex, limits=limits, timeout_s=0.05)
    with pytest.raises(TurntableLimitError, match=words) as info:
        table.connect()
    assert "middle" in str(info.value) and not table.transport.is_open


def test_tcp_urls_default_to_the_controllers_port():
    assert AcutrolTurntable("tcp://192.0.2.7").url == "tcp://192.0.2.7:9878"
    assert AcutrolTurntable("tcp://192.0.2.7:5000").url == "tcp://192.0.2.7:5000"
    gpib = AcutrolTurntable("visa://GPIB0::1::INSTR")
    socket = AcutrolTurntable("visa://TCPIP0::192.0.2.7::9878::SOCKET?backend=@py")
    assert (gpib.framing, socket.framing) == ("gpib", "tcp")


# -- end to end through the real transports ------------------------------------------------------------------------

@pytest.fixture
def sim():
    clock = ManualClock()
    controller = SimController(clock=clock)
    server = LineServer(AcutrolSimHandler(controller))
    yield controller, clock, server
    server.close()
    assert not [t for t in threading.enumerate() if t.name.startswith("sim-") and t.is_alive()]


REPLY_WAIT_S = 1.0


@pytest.fixture(params=["tcp", "pty"])
def table(request, sim):
    controller, clock, server = sim
    if request.param == "pty":
        url = server.open_pty()
    else:
        host, port = server.listen_tcp()
        url = f"tcp://{host}:{port}"
    driver = open_turntable(url, "acutrol", clock=clock, timeout_s=REPLY_WAIT_S, retries=2)
    with driver:
        yield driver, controller, clock


def test_session_end_to_end(table):
    driver, controller, clock = table
    assert driver.identify().startswith("turntable-bench,ACUTROL3000-SIM")
    assert driver.absolute_limits[2].rate_dps == controller.limits[2].max_rate_dps
    driver.enable()
    assert [a.mode for a in driver.read_state().axes] == [AxisMode.OFF] * 3
    driver.move_to([90.0, -45.0, 180.123456], rate_dps=[30.0, 30.0, 60.0])
    state = driver.wait_in_position([90.0, -45.0, 180.123456], tolerance_deg=1e-6, settle_s=0.5, timeout_s=30.0)
    assert state.angles_deg == pytest.approx((90.0, -45.0, 180.123456), abs=1e-6)
    assert all(a.in_position and a.mode is AxisMode.POSITION for a in state.axes)
    assert driver.read_position("inner") == pytest.approx(180.123456, abs=1e-6)
    driver.set_rate("outer", -20.0)
    clock.advance(5.0)
    state = driver.read_state()
    assert state.rates_dps[0] == -20.0 and state.modes[0] is AxisMode.RATE
    assert state.axes[0].status == AxisStatus.ENABLED | AxisStatus.MOVING     # turning: its angle changes
    assert driver.read_acceleration(0) == 0.0
    driver.stop()
    clock.advance(5.0)
    state = driver.read_state()
    assert state.rates_dps == (0.0, 0.0, 0.0) and state.modes == (AxisMode.OFF,) * 3
    driver.abort()
    assert not any(a.enabled for a in driver.read_state().axes)
    assert [driver.interlock_state(k) for k in range(3)] == ["Open"] * 3
    assert driver.status_byte() == 0 and driver.read_errors() == []
    assert driver.stats.timeouts == driver.stats.protocol_errors == 0


def test_several_reads_in_one_message_come_from_one_instant(sim):
    controller, clock, _ = sim
    handler = AcutrolSimHandler(controller)
    assert handler(b":INT:CLOS 1;:MODE:RATE 1;:DEM:RATE 1,50\n") == OK
    clock.advance(0.5)
    text = ac.parse_framed(handler(b":READ:POS? 1;RATE? 1;ACC? 1\n") or b"").text
    position, rate, accel = (float(v) for v in text.split(";"))
    theta, omega, alpha = controller.table.axis_at(controller.now(), 0)
    assert (position, rate, accel) == pytest.approx((theta * 57.29577951308232, omega * 57.29577951308232,
                                                     alpha * 57.29577951308232), abs=1e-6)
    assert accel > 0.0 and 0.0 < rate < 50.0                     # still ramping: a moving instant, read whole


def test_the_simulator_answers_the_manuals_mode_query_and_refuses_in_the_manuals_cases(sim):
    controller, _, _ = sim
    handler = AcutrolSimHandler(controller)
    handler(b":Mode:Position 1;Rate 2\n")
    assert ac.parse_framed(handler(b":M? 1;:M? 2;:M? 3\n") or b"") == ac.Response(0, "Position;Rate;Off")
    for message, code in [(b":Demand:Posn 3,10.5\n", ac.NOT_RECOGNIZED), (b":Dem;Pos 3,10.50000\n", ac.SYNTAX_ERROR),
                          (b":D:P,3,10.5\n", ac.SYNTAX_ERROR)]:
        response = ac.parse_framed(handler(message) or b"")
        assert response.code == code and response.text.startswith(ac.ERROR_TEXT[code])
    errors = ac.parse_framed(handler(b":STAT:MSG? QERROR,ALL\n") or b"").text.split(";")
    assert [int(e.split(",")[0]) for e in errors] == [ac.NOT_RECOGNIZED, ac.SYNTAX_ERROR, ac.SYNTAX_ERROR]
    assert ac.parse_framed(handler(b":QUER:ERR? 3\n") or b"").text == "Parameter out of range"


def test_a_position_demand_made_outside_position_mode_is_taken_up_by_the_mode(sim):
    """TM-8004 4.5.6's example: demand first, then reset, mode and close."""
    controller, clock, _ = sim
    handler = AcutrolSimHandler(controller)
    assert handler(b":D:P 2,30.0;:I:R;:M:P 2;:I:C 2\n") == OK
    clock.advance(60.0)
    assert controller.state().angles_deg[1] == pytest.approx(0.0)        # closed holding where it was
    assert handler(b":M:O 2;:D:P 2,30.0;:M:P 2\n") == OK                  # pending demand, then position mode
    clock.advance(60.0)
    assert controller.state().angles_deg[1] == pytest.approx(30.0)


def test_a_limit_trip_latches_until_reset_and_says_so_in_the_status(table):
    driver, controller, clock = table
    driver.enable()
    driver.set_rate("middle", 10.0)
    clock.advance(1.0)
    controller.trip_limit(1)
    state = driver.read_state()
    assert state.axes[1].status & AxisStatus.LIMIT and not state.axes[1].enabled
    assert driver.interlock_state(1) == "Fault" and driver.status_byte() & 0b1000_0001 == 0b1   # SI, no error queued
    with pytest.raises(TurntableFault):
        driver.check_state()
    with pytest.raises(TurntableCommandError, match="Interlock fault latched"):
        driver.enable(["middle"])
    assert driver.status_byte() & 0x80                               # the refusal is on the error queue
    assert driver.read_errors()[0].startswith(f"{ac.INTERLOCK_FAULT},")
    driver.reset_faults()
    driver.enable(["middle"])
    assert driver.read_state().axes[1].enabled and driver.interlock_state(1) == "Close"


def test_an_estop_refuses_the_reset_until_released(table):
    driver, controller, _ = table
    driver.enable()
    controller.trip_estop()
    with pytest.raises(TurntableEStop):
        driver.check_state()
    with pytest.raises(TurntableCommandError, match="error 7"):
        driver.reset_faults()
    controller.release_estop()
    driver.reset_faults()
    driver.enable()
    assert all(a.enabled for a in driver.read_state().axes)


@pytest.mark.parametrize("fault", ["garbage", "checksum", "timeout", "late"])
def test_wire_faults_are_survived(table, fault):
    driver, controller, _ = table
    setattr(controller.faults, fault, 1)
    driver.enable([0])
    assert controller.state().axes[0].enabled
    state = driver.read_state()
    assert state.axes[0].enabled and driver.read_state().angles_deg == state.angles_deg


def test_serve_acutrol_gives_urls_and_closes():
    server, urls = serve_acutrol(SimController(clock=ManualClock()), tcp=True, pty=True)
    try:
        assert urls["tcp"].startswith("tcp://127.0.0.1:") and urls["pty"].startswith("/dev/")
        with open_turntable(urls["tcp"], "acutrol", timeout_s=REPLY_WAIT_S) as driver:
            assert driver.read_state().modes == (AxisMode.OFF,) * 3
    finally:
        server.close()


def test_the_pages_example_session_is_what_the_simulator_sends(sim):
    """docs/hardware/acutrol.md, "Example session": each response's code, length and text as the simulator frames
    them."""
    controller, _, _ = sim
    handler = AcutrolSimHandler(controller)
    page = (Path(__file__).parents[2] / "docs" / "hardware" / "acutrol.md").read_text()
    block = page.split("## Example session")[1].split("```")[1].strip().splitlines()
    assert len(block) == 8
    for request, response in zip(block[0::2], block[1::2]):
        sent = request.removeprefix("host -> ").removesuffix("\\n").encode("ascii") + b"\n"
        code, length, *rest = [part.strip() for part in response.removeprefix("ctl  -> ").split(" | ")]
        got = handler(sent) or b""
        assert got[:4].hex(" ") == code and got[4:8].hex(" ") == length, request
        text = rest[0] if len(rest) == 2 else ""
        body = got[8:-1].decode("ascii")
        assert body.startswith(text.removesuffix("...")) and got.endswith(b"\0")


def test_gpib_framing_answers_queries_only_and_errors_come_from_the_queue():
    """IEEE-488 framing (`--acl-framing gpib`): commands are answered by nothing, queries by text and LF; the client
    confirms a command with the error queue and the status byte."""
    clock = ManualClock()
    controller = SimController(clock=clock)
    handler = AcutrolSimHandler(controller, framing="gpib")
    assert handler(b"*CLS\n") is None and handler(b":M? 1;:M? 2\n") == b"Off;Off\n"
    assert handler(b":Demand:Posn 3,10.5\n") is None                    # refused: queued, not answered
    assert handler(b":STAT:MSG? QERROR;:STAT:STB?\n") == (
        b"1,\"Command not recognized: 'Posn' is not a command under DEMAND\";0\n")
    server = LineServer(handler)
    try:
        host, port = server.listen_tcp()
        with open_turntable(f"tcp://{host}:{port}", "acutrol", framing="gpib", clock=clock, timeout_s=0.3) as driver:
            driver.enable()
            driver.move_to([10.0, None, None], rate_dps=50.0)
            assert driver.wait_in_position([10.0, None, None], timeout_s=30.0).angles_deg[0] == pytest.approx(10.0)
            controller.trip_estop()
            with pytest.raises(TurntableCommandError, match="':INT:RES': Interlock fault latched"):
                driver.reset_faults()
            assert driver.read_errors() == []                           # the client read the entry it raised
    finally:
        server.close()


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.binary(max_size=120),
                 st.lists(st.sampled_from([":", ";", ",", "?", " ", "*", "D", "dem", "POS", "1", "3", "-2.5e3",
                                           "MODE", "int", "ALL", "R", "#14", '"', "STAT:CSR", "A1INTLK", "P"]),
                          max_size=14).map(lambda parts: "".join(parts).encode())))
def test_the_simulator_answers_any_message_with_one_well_formed_frame(message):
    handler = AcutrolSimHandler(SimController(clock=ManualClock()))
    response = ac.parse_framed(handler(message) or b"")
    assert response.code in ac.ERROR_TEXT
    assert (response.code == ac.NO_ERROR) == (not handler.errors)


def test_moves_and_rate_changes_follow_the_modes_acceleration_limits(sim):
    controller, clock, _ = sim
    handler = AcutrolSimHandler(controller)
    assert handler(b":LIM:ACC P,1,10;ACC R,1,20;ACC O,1,5;:INT:CLOS 1;:MODE:POS 1;:DEM:POS 1,90\n") == OK
    clock.advance(0.5)
    assert ac.parse_framed(handler(b":READ:ACC? 1\n") or b"").text == "10.000000"
    clock.advance(60.0)
    assert handler(b":MODE:RATE 1;:DEM:RATE 1,30\n") == OK
    clock.advance(0.5)
    assert ac.parse_framed(handler(b":READ:ACC? 1\n") or b"").text == "20.000000"
    clock.advance(5.0)
    assert handler(b":MODE:OFF 1\n") == OK                         # Off: to zero rate at the Off mode's limit
    clock.advance(0.5)
    assert ac.parse_framed(handler(b":R:A? 1;R? 1\n") or b"").text == "-5.000000;27.500000"
