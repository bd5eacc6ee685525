"""The SCPI-like turntable client: exact exchanges, and end to end against the simulator over TCP and a pty."""

from __future__ import annotations

import threading

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.sim import controller as simctl
from bench.sim.controller import SimController
from bench.sim.scpi_server import SIM_TO_SCPI, ScpiSimHandler, serve_scpi
from bench.sim.serve import LineServer
from drivers.clock import ManualClock
from drivers.errors import (
    TurntableChecksumError,
    TurntableCommandError,
    TurntableConnectionError,
    TurntableEStop,
    TurntableFault,
    TurntableLimitError,
    TurntableProtocolError,
    TurntableTimeout,
)
from drivers.turntable import scpi_codec as sc
from drivers.turntable.base import AxisLimits, AxisMode, AxisStatus, TurntableLimits
from drivers.turntable.scpi import ScpiTurntable
from tests.helpers.exchange import Exchange

OK = b'0,"No error"\r\n'
CLS = (b"*CLS\r\n", None)
STATE_HOME = b'0.0,0.0,1,3,0.0,0.0,1,3,0.0,0.0,1,3,""\r\n'


def client(pairs, **kw) -> tuple[ScpiTurntable, Exchange]:
    ex = Exchange([CLS] + pairs)
    kw.setdefault("timeout_s", 0.05)
    return ScpiTurntable(ex, **kw).connect(), ex


# -- exact exchanges ---------------------------------------------------------------------

def test_commands_go_out_confirmed_in_one_round_trip():
    table, ex = client([
        (b":I:C 1;:I:C 2;:I:C 3;:SYST:ERR?\r\n", OK),
        (b":M:P 1;:SYST:ERR?\r\n", OK),
        (b":M:P 3;:SYST:ERR?\r\n", OK),
        (b":D:P 1,90.0,20.0;:D:P 3,-180.000001,20.0;:SYST:ERR?\r\n", OK),
        (b":M:R 2;:SYST:ERR?\r\n", OK),
        (b":D:R 2,-10.5;:SYST:ERR?\r\n", OK),
        (b":S;:SYST:ERR?\r\n", OK),
        (b":M:O 2;:SYST:ERR?\r\n", OK),
        (b":I:R 1;:SYST:ERR?\r\n", OK),
        (b":I:O 1;:I:O 2;:SYST:ERR?\r\n", OK),
        (b":A;:SYST:ERR?\r\n", OK),
    ])
    with ex:
        table.enable()
        table.move_to([90.0, None, -180.000001], rate_dps=20.0)
        table.set_rate("middle", -10.5)
        table.stop()
        table.set_mode(1, "off")
        table.reset_faults([0])
        table.disable(["outer", "middle"])
        table.abort()


def test_default_move_rate_is_the_configured_limit_and_long_forms_work():
    limits = TurntableLimits((AxisLimits(max_rate_dps=30.0), AxisLimits(), AxisLimits()))
    table, ex = client([
        (b":MODE:POSITION 1;:SYSTEM:ERROR?\r\n", OK),
        (b":DEMAND:POSITION 1,45.0,30.0;:SYSTEM:ERROR?\r\n", OK),
        (b":READ:ALL?\r\n", STATE_HOME),
    ], limits=limits, long_form=True)
    with ex:
        table.move_to([45.0, None, None])
        table.read_state()


def test_state_poll_is_one_query():
    table, ex = client([(b":R:A?\r\n", b'90.0,0.0,1,3,-45.5,0.0,1,3,123.25,-30.0,2,5,""\r\n')],
                       clock=ManualClock(7.0))
    with ex:
        state = table.read_state()
    assert state.time_s == 7.0 and state.angles_deg == (90.0, -45.5, 123.25)
    assert state.modes == (AxisMode.POSITION, AxisMode.POSITION, AxisMode.RATE)
    assert state.axes[2].status == AxisStatus.ENABLED | AxisStatus.MOVING


def test_single_value_queries():
    table, ex = client([
        (b"*IDN?\r\n", b"Acutronic,ACUTROL3000,1234,4.2\r\n"),
        (b":R:P? 2\r\n", b"-45.123456\r\n"),
        (b":R:R? 3\r\n", b"10.0\r\n"),
        (b":R:S? 1\r\n", b"3\r\n"),
        (b":SYST:ERR?\r\n", b'-222,"Data out of range"\r\n'),
    ])
    with ex:
        assert table.identify() == "Acutronic,ACUTROL3000,1234,4.2"
        assert table.read_position("middle") == -45.123456
        assert table.read_rate(2) == 10.0
        assert table.read_status(0) == AxisStatus.ENABLED | AxisStatus.IN_POSITION
        assert table.read_error() == (-222, "Data out of range")


def test_error_reply_raises_the_command_error_without_retry():
    table, ex = client([(b":M:R 1;:SYST:ERR?\r\n", b'201,"Interlock open;outer axis is not enabled"\r\n')])
    with ex, pytest.raises(TurntableCommandError, match="201.*not enabled") as info:
        table.set_mode(0, AxisMode.RATE)
    assert info.value.code == 201 and table.stats.requests == 1


def test_every_error_of_a_multi_axis_line_is_reported_and_the_queue_emptied():
    table, ex = client([
        (b":I:C 1;:I:C 2;:I:C 3;:SYST:ERR?\r\n", b'202,"Fault latched;outer"\r\n'),
        (b":SYST:ERR?\r\n", b'202,"Fault latched;middle"\r\n'),
        (b":SYST:ERR?\r\n", OK),
    ])
    with ex, pytest.raises(TurntableCommandError, match="outer.*middle") as info:
        table.enable()
    assert info.value.code == 202


def test_a_refusal_survives_a_failed_error_queue_read_out():
    table, ex = client([(b":I:C 1;:I:C 2;:SYST:ERR?\r\n", b'202,"Fault latched"\r\n'),
                        (b":SYST:ERR?\r\n", None)], retries=0)
    with ex, pytest.raises(TurntableCommandError, match="202.*error queue not read") as info:
        table.enable([0, 1])
    assert info.value.code == 202

def test_no_reply_retries_then_times_out():
    request = b":R:A?\r\n"
    table, ex = client([(request, None)] * 3, retries=2)
    with ex, pytest.raises(TurntableTimeout, match="3 attempts"):
        table.read_state()
    assert table.stats.timeouts == 3


def test_garbage_is_retried_then_raised():
    table, ex = client([(b":R:A?\r\n", b"\xa5Z#?garbage\xfe\r\n"), (b":R:A?\r\n", STATE_HOME)])
    with ex:
        table.read_state()
    assert table.stats.protocol_errors == 1
    table, ex = client([(b":S;:SYST:ERR?\r\n", b"OK\r\n")] * 2, retries=1)
    with ex, pytest.raises(TurntableProtocolError, match="expected <code>"):
        table.stop()


def test_lost_link_is_reopened_and_cleared():
    table, ex = client([(b":R:A?\r\n", STATE_HOME), CLS, (b":R:A?\r\n", STATE_HOME)])
    with ex:
        table.read_state()
        ex.close()                      # the link drops between requests
        table.read_state()
    assert table.stats.reconnects == 1 and ex.opened == 2


def test_limits_are_refused_before_anything_is_sent():
    limits = TurntableLimits((AxisLimits(-10.0, 10.0, 20.0), AxisLimits(), AxisLimits()))
    table, ex = client([], limits=limits)
    with ex:
        with pytest.raises(TurntableLimitError, match="outer position 20"):
            table.move_to([20.0, 0.0, 0.0])
        with pytest.raises(TurntableLimitError, match="outer rate 25"):
            table.move_to([5.0, None, None], rate_dps=25.0)
        with pytest.raises(TurntableLimitError, match="outer rate -21"):
            table.set_rate(0, -21.0)
    assert ex.sent == [b"*CLS\r\n"]


def test_estop_status_during_a_wait_stops_and_raises():
    estop = b'1.0,0.0,0,64,0.0,0.0,0,64,0.0,0.0,0,64,"emergency stop pressed"\r\n'
    table, ex = client([(b":R:A?\r\n", estop), (b":S;:SYST:ERR?\r\n", OK)], clock=ManualClock())
    with ex, pytest.raises(TurntableEStop, match="emergency stop"):
        table.wait_in_position([90.0, None, None])


# -- the simulator's handler -----------------------------------------------------------------

@pytest.fixture
def handler():
    return ScpiSimHandler(SimController(clock=ManualClock()))


def test_handler_answers_queries_and_queues_command_errors(handler):
    assert handler(b"*IDN?") == b"turntable-bench,SCPI-SIM,0,1.0\r\n"
    assert handler(b":D:P 1,90.0") is None                                  # no query, no reply
    assert handler(b":SYST:ERR?") == b'201,"Interlock open;outer axis is not enabled"\r\n'
    assert handler(b":SYST:ERR?") == OK
    assert handler(b":R:P? 4") == b'-222,"Data out of range;axis 4 is not 1, 2 or 3"\r\n'
    assert handler(b":Interlock:Close 1;:L:R 1,12.5;:L:R? 1;:R:M? 1;:R:S? 1;:SYST:ERR?") == \
        b'12.5;1;3;0,"No error"\r\n'
    assert handler(b":L:R 1,500;:SYST:ERR?").startswith(b"-222,")
    # a move rate <= 0 is an illegal value (-224) as the page says, not out of range (it said -222)
    assert handler(b":L:R 1,0;:SYST:ERR?").startswith(b"-224,")
    assert handler(b":L:R 1,-5;:SYST:ERR?").startswith(b"-224,")
    assert handler(b":READ:POSITION? 1;:READ:FAULT?") == b'0.0;""\r\n'


def test_handler_error_queue_overflows_like_scpi(handler):
    for _ in range(20):
        handler(b":NOPE")
    entries = [handler(b":SYST:ERR?") for _ in range(17)]
    assert entries[:15] == [b'-113,"Undefined header;undefined header \':NOPE\'"\r\n'] * 15
    assert entries[15] == b'-350,"Queue overflow"\r\n' and entries[16] == OK


def test_every_controller_error_has_an_scpi_number():
    codes = {v for k, v in vars(simctl).items() if k.startswith("ERR_")}
    assert codes == set(SIM_TO_SCPI) and all(n in sc.ERROR_TEXT for n in SIM_TO_SCPI.values())


@settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=60))
def test_handler_survives_random_lines(handler, data):
    reply = handler(data)
    assert reply is None or reply.endswith(b"\r\n")


# -- end to end through the real transports ----------------------------------------------------

class TrippingClock(ManualClock):
    """A ManualClock that runs `action` once when its time passes `at_s` (to trip faults mid-move)."""

    def __init__(self):
        super().__init__()
        self.at_s, self.action = None, None

    def sleep(self, seconds: float) -> None:
        super().sleep(seconds)
        if self.at_s is not None and self.now() >= self.at_s:
            self.at_s, action = None, self.action
            action()


@pytest.fixture
def sim():
    clock = TrippingClock()
    controller = SimController(clock=clock)
    server = LineServer(ScpiSimHandler(controller))
    yield controller, clock, server
    server.close()
    assert not [t for t in threading.enumerate() if t.name.startswith("sim-") and t.is_alive()]


def _url(server: LineServer, kind: str) -> str:
    if kind == "pty":
        return server.open_pty()
    host, port = server.listen_tcp()
    return f"tcp://{host}:{port}"


#: how long the client waits for a reply that is due (long: see `table`), and where none will come
REPLY_WAIT_S, SILENT_WAIT_S = 1.0, 0.2


@pytest.fixture(params=["tcp", "pty"])
def table(request, sim):
    controller, clock, server = sim
    # long: a loaded machine must not turn a slow simulator into a timeout; the silence tests shorten it
    driver = ScpiTurntable(_url(server, request.param), clock=clock, timeout_s=REPLY_WAIT_S, retries=2)
    with driver:
        yield driver, controller, clock


def test_session_end_to_end(table):
    driver, controller, clock = table
    assert driver.identify().startswith("turntable-bench,SCPI-SIM")
    driver.enable()
    driver.move_to([90.0, -45.0, 180.123456], rate_dps=[30.0, 30.0, 60.0])
    state = driver.wait_in_position([90.0, -45.0, 180.123456], tolerance_deg=1e-6, settle_s=0.5, timeout_s=30.0)
    assert state.angles_deg == pytest.approx((90.0, -45.0, 180.123456), abs=1e-6)
    assert all(a.in_position and a.mode is AxisMode.POSITION for a in state.axes)
    assert driver.read_position("inner") == pytest.approx(180.123456, abs=1e-6)
    driver.set_rate("outer", -20.0)
    clock.advance(5.0)
    state = driver.read_state()
    assert state.rates_dps[0] == -20.0 and state.modes[0] is AxisMode.RATE
    assert driver.read_status(0) == AxisStatus.ENABLED | AxisStatus.MOVING
    driver.stop()
    clock.advance(5.0)
    state = driver.read_state()
    assert state.rates_dps == (0.0, 0.0, 0.0) and state.axes[0].in_position
    driver.abort()
    assert not any(a.enabled for a in driver.read_state().axes)
    assert driver.stats.timeouts == driver.stats.protocol_errors == 0


def test_reply_timeout_is_retried_then_raised(table):
    driver, controller, _ = table
    driver.timeout_s = SILENT_WAIT_S            # the silences cost it (a slow reply may cost a retry: >= below)
    controller.faults.timeout = 1
    driver.read_state()
    assert driver.stats.timeouts >= 1
    controller.faults.timeout = 3
    with pytest.raises(TurntableTimeout):
        driver.read_state()
    assert controller.faults.timeout == 0
    driver.read_state()


def test_a_late_reply_is_dropped_not_read_as_the_reply_to_the_next_request(table):
    """A controller that answers after the client gave up answers the retry too: that second reply
    must not answer the next request (every state would be one poll old from then on)."""
    driver, controller, clock = table
    driver.enable(["outer"])
    driver.set_rate("outer", 10.0)
    controller.faults.late = 1
    first = driver.read_state()
    assert driver.stats.timeouts == 1 and driver.stats.late_replies == 1
    clock.advance(2.0)
    second = driver.read_state()
    assert second.time_s == pytest.approx(first.time_s + 2.0)
    assert second.angles_deg == pytest.approx(controller.state().angles_deg, abs=1e-6)
    assert second.angles_deg[0] > first.angles_deg[0] + 10.0
    assert driver.stats.timeouts == 1


@pytest.mark.parametrize("fault", ["garbage", "checksum"])
def test_corrupted_replies_are_retried_then_raised(table, fault):
    driver, controller, _ = table
    setattr(controller.faults, fault, 1)
    driver.enable([0])
    assert driver.stats.protocol_errors == 1 and controller.state().axes[0].enabled
    setattr(controller.faults, fault, 3)
    with pytest.raises(TurntableProtocolError, match="not printable ASCII") as info:
        driver.read_state()
    assert not isinstance(info.value, TurntableChecksumError)  # plain SCPI carries no checksum


def test_exception_reply_is_a_command_error_and_nothing_runs(sim):
    controller, clock, server = sim
    with ScpiTurntable(_url(server, "tcp"), clock=clock, timeout_s=0.2) as driver:
        controller.faults.exception = 1
        with pytest.raises(TurntableCommandError, match="-221") as info:
            driver.enable()
        assert info.value.code == sc.SETTINGS_CONFLICT and not controller.state().axes[0].enabled
        controller.faults.exception, controller.faults.exception_code = 1, simctl.ERR_FAULT
        with pytest.raises(TurntableCommandError) as info:
            driver.read_state()
        assert info.value.code == sc.FAULT_LATCHED


def test_controller_refusals_come_back_as_scpi_errors(sim):
    controller, clock, server = sim
    controller.limits = (AxisLimits(-10.0, 10.0, 200.0, 50.0),) + controller.limits[1:]
    with ScpiTurntable(_url(server, "tcp"), clock=clock, timeout_s=0.2) as driver:
        with pytest.raises(TurntableCommandError, match="201") as info:
            driver.move_to([5.0, None, None])                 # servo off
        assert info.value.code == sc.INTERLOCK_OPEN
        driver.enable()
        with pytest.raises(TurntableCommandError, match="-222") as info:
            driver.move_to([20.0, None, None])                # beyond the controller's own travel
        with pytest.raises(TurntableCommandError, match="-221"):
            driver._demand_rate(1, 5.0)                       # rate demand in position mode
        assert driver.read_error() == (0, "No error")


def test_estop_aborts_a_move_and_the_table_ends_stopped(sim):
    controller, clock, server = sim
    with ScpiTurntable(_url(server, "tcp"), clock=clock, timeout_s=0.2) as driver:
        driver.enable()
        driver.move_to([90.0, 45.0, None], rate_dps=20.0)
        clock.at_s, clock.action = 1.5, controller.trip_estop
        with pytest.raises(TurntableEStop, match="emergency stop") as info:
            driver.wait_in_position([90.0, 45.0, None], timeout_s=30.0)
        assert info.value.state.estop
        clock.advance(10.0)
        stopped = driver.read_state()
        clock.advance(10.0)
        assert driver.read_state().angles_deg == stopped.angles_deg
        assert stopped.rates_dps == (0.0, 0.0, 0.0) and stopped.angles_deg[0] < 45.0
        assert not any(a.enabled or a.status & AxisStatus.MOVING for a in stopped.axes)
        with pytest.raises(TurntableCommandError, match="202"):
            driver.enable()
        controller.release_estop()
        driver.reset_faults()
        driver.enable()
        assert all(a.enabled for a in driver.read_state().axes)


def test_limit_trip_during_a_move_raises_a_fault_and_stops_the_rest(sim):
    controller, clock, server = sim
    with ScpiTurntable(_url(server, "tcp"), clock=clock, timeout_s=0.2) as driver:
        driver.enable()
        driver.move_to([90.0, 45.0, None], rate_dps=20.0)
        clock.at_s, clock.action = 1.5, lambda: controller.trip_limit(0)
        with pytest.raises(TurntableFault, match="outer: limit") as info:
            driver.wait_in_position([90.0, 45.0, None], timeout_s=30.0)
        assert not isinstance(info.value, TurntableEStop)
        clock.advance(10.0)
        state = driver.read_state()
        assert state.rates_dps == (0.0, 0.0, 0.0) and state.axes[1].enabled and state.axes[1].in_position
        assert state.axes[1].angle_deg < 45.0 and "limit" in state.fault_text
        driver.reset_faults([0])
        assert not driver.read_state().fault


def test_server_restart_is_survived_and_server_loss_reported(sim):
    controller, clock, server = sim
    handler = server.handle
    host, port = server.listen_tcp()
    driver = ScpiTurntable(f"tcp://{host}:{port}", clock=clock, timeout_s=0.2, retries=2).connect()
    try:
        driver.enable()
        server.close()                                        # the controller drops every connection
        restarted = LineServer(handler)
        try:
            restarted.listen_tcp(port=port)
            assert all(a.enabled for a in driver.read_state().axes)
            assert driver.stats.reconnects == 1
        finally:
            restarted.close()
        with pytest.raises(TurntableConnectionError):
            driver.read_state()
    finally:
        driver.close()


def test_serve_scpi_gives_urls_and_closes(sim):
    controller, clock, _ = sim
    server, urls = serve_scpi(controller, tcp=True, pty=True)
    try:
        for url in urls.values():
            with ScpiTurntable(url, clock=clock, timeout_s=0.2) as driver:
                assert driver.read_state().modes == (AxisMode.OFF,) * 3
    finally:
        server.close()
    assert set(urls) == {"tcp", "pty"} and urls["tcp"].startswith("tcp://127.0.0.1:")

