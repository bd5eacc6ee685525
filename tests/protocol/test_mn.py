"""$MN client: exact exchanges, faults, and end to end against the simulator over TCP and a pty."""

from __future__ import annotations

import math
import threading

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.sim.controller import SimController
from bench.sim.mn_server import GARBAGE, MnSimHandler
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
from drivers.turntable import mn_codec as codec
from drivers.turntable.base import AxisLimits, AxisMode, AxisStatus, TurntableLimits
from drivers.turntable.mn import MnTurntable
from tests.helpers.exchange import Exchange

CRLF = b"\r\n"
CHK = (b"$MNCHK,1*CE\r\n", b"$ASCHK,OK*30\r\n")
STA = b"$MNSTA*83\r\n"
STA_MOVING = (b"$ASSTA,29.000000,10.000000,P,0005,0.000000,0.000000,P,0003,"
              b"29.500000,10.000000,P,0005,,OK*8C\r\n")
STA_BAD_SUM = STA_MOVING.replace(b"*8C", b"*8D")


@pytest.fixture(autouse=True)
def no_threads_left_behind():
    before = set(threading.enumerate())
    yield
    left = [t for t in threading.enumerate() if t not in before and t.is_alive()]
    assert not left, f"threads left running: {left}"


def connected(pairs, **kw) -> tuple[MnTurntable, Exchange]:
    ex = Exchange([CHK, *pairs])
    table = MnTurntable(ex, timeout_s=kw.pop("timeout_s", 0.05), **kw)
    table.connect()
    return table, ex


# -- exact exchanges ------------------------------------------------------------------
def test_connect_checks_the_link():
    table, ex = connected([])
    ex.assert_done()
    assert table.dialect == "mn" and ex.opened == 1


def test_every_interface_call_as_exact_bytes():
    table, ex = connected([
        (b"$MNENA,1,2,3*89\r\n", b"$ASENA,OK*2E\r\n"),
        (b"$MNMOD,1,P*54\r\n", b"$ASMOD,OK*3A\r\n"),
        (b"$MNMOD,3,P*56\r\n", b"$ASMOD,OK*3A\r\n"),
        (b"$MNPOS,90.000000,,180.000000,10,,10*F5\r\n", b"$ASPOS,OK*4C\r\n"),
        (STA, STA_MOVING),
        (b"$MNMOD,3,R*58\r\n", b"$ASMOD,OK*3A\r\n"),
        (b"$MNRAT,3,-10*9B\r\n", b"$ASRAT,OK*41\r\n"),
        (b"$MNSTP*92\r\n", b"$ASSTP,OK*51\r\n"),
        (b"$MNRST,2*F2\r\n", b"$ASRST,OK*53\r\n"),
        (b"$MNMOD,1,O*53\r\n", b"$ASMOD,OK*3A\r\n"),
        (b"$MNABT*72\r\n", b"$ASABT,OK*31\r\n"),
        (b"$MNDIS,1,2,3*95\r\n", b"$ASDIS,OK*3A\r\n"),
    ])
    with ex:
        table.enable()
        table.move_to([90.0, None, 180.0], 10.0)
        state = table.read_state()
        table.set_rate("inner", -10.0)
        table.stop()
        table.reset_faults(["middle"])
        table.set_mode(0, "off")
        table.abort()
        table.disable()
    assert state.angles_deg == (29.0, 0.0, 29.5)
    assert state.axes[0].status == AxisStatus.ENABLED | AxisStatus.MOVING
    assert state.axes[1].in_position and state.modes == (AxisMode.POSITION,) * 3
    assert table.stats.requests == 13 and table.stats.timeouts == 0


def test_state_time_is_the_drivers_clock():
    clock = ManualClock(41.5)
    ex = Exchange([CHK, (STA, STA_MOVING)])
    with ex:
        table = MnTurntable(ex, clock=clock, timeout_s=0.05).connect()
        assert table.read_state().time_s == 41.5


def test_move_rates_per_axis_and_default_rate():
    limits = TurntableLimits((AxisLimits(max_rate_dps=20.0), AxisLimits(max_rate_dps=20.0),
                              AxisLimits(max_rate_dps=30.0)))
    body = b"MNPOS,-45.500000,10.000000,400.000000,20,5,2.5"
    table, ex = connected([
        (b"$MNMOD,1,P*54\r\n", b"$ASMOD,OK*3A\r\n"),
        (b"$MNMOD,2,P*55\r\n", b"$ASMOD,OK*3A\r\n"),
        (b"$MNMOD,3,P*56\r\n", b"$ASMOD,OK*3A\r\n"),
        (b"$" + body + b"*" + f"{codec.checksum(body):02X}".encode() + CRLF, b"$ASPOS,OK*4C\r\n"),
    ], limits=limits)
    with ex:
        table.move_to([-45.5, 10.0, 400.0], [None, 5.0, 2.5])


def test_limits_refused_before_anything_is_sent():
    limits = TurntableLimits((AxisLimits(-10.0, 10.0, 20.0), AxisLimits(), AxisLimits(max_rate_dps=5.0)))
    table, ex = connected([], limits=limits)
    with ex:
        with pytest.raises(TurntableLimitError, match="outer position 11.0 deg is outside"):
            table.move_to([11.0, 0.0, 0.0], 1.0)
        with pytest.raises(TurntableLimitError, match="rate 21.0"):
            table.move_to([5.0, None, None], 21.0)
        with pytest.raises(TurntableLimitError, match="finite"):
            table.move_to([None, math.nan, None])
        with pytest.raises(TurntableLimitError, match="inner rate -6.0"):
            table.set_rate("inner", -6.0)
        with pytest.raises(TurntableLimitError, match="must be positive"):
            table.move_to([0.0, None, None], 0.0)
    assert ex.sent == [CHK[0]]          # nothing after the link check
    assert table.stats.requests == 1


def test_failed_link_check_closes_the_link():
    ex = Exchange([(CHK[0], b"$ASCHK,ERR,2*DD\r\n")])
    table = MnTurntable(ex, timeout_s=0.05)
    with ex, pytest.raises(TurntableCommandError) as info:
        table.connect()
    assert info.value.code == 2 and not ex.is_open


# -- faults through the exchange ---------------------------------------------------------
def test_reply_timeout_retries_then_raises():
    table, ex = connected([(STA, None)] * 3, retries=2)
    with ex, pytest.raises(TurntableTimeout, match="no reply to b'\\$MNSTA\\*83'"):
        table.read_state()
    assert table.stats.timeouts == 3


def test_one_timeout_then_a_reply_succeeds():
    table, ex = connected([(STA, None), (STA, STA_MOVING)])
    with ex:
        assert table.read_state().angles_deg[0] == 29.0
    assert table.stats.timeouts == 1


def test_garbage_is_retried():
    table, ex = connected([(STA, GARBAGE + CRLF), (STA, STA_MOVING)])
    with ex:
        table.read_state()
    assert table.stats.protocol_errors == 1
    table, ex = connected([(STA, GARBAGE + CRLF)] * 3)
    with ex, pytest.raises(TurntableProtocolError, match="not printable ASCII"):
        table.read_state()


def test_checksum_errors_after_retries_and_single_bad_reply_recovers():
    table, ex = connected([(STA, STA_BAD_SUM)] * 3)
    with ex, pytest.raises(TurntableChecksumError, match="frame carries 8D, its content sums to 8C"):
        table.read_state()
    assert table.stats.protocol_errors == 3
    table, ex = connected([(STA, STA_BAD_SUM), (STA, STA_MOVING)])
    with ex:
        assert table.read_state().rates_dps == (10.0, 0.0, 10.0)


def test_stale_reply_is_discarded_and_request_retried():
    table, ex = connected([(STA, b"$ASPOS,OK*4C\r\n"), (STA, STA_MOVING)])
    with ex:
        table.read_state()
    assert table.stats.protocol_errors == 1


def test_controller_checksum_complaint_is_retried():
    table, ex = connected([(b"$MNSTP*92\r\n", b"$ASSTP,ERR,7*03\r\n"), (b"$MNSTP*92\r\n", b"$ASSTP,OK*51\r\n")])
    with ex:
        table.stop()


def test_error_reply_raised_at_once_with_its_code():
    # after a refusal the driver reads the state to say why in common words; this one shows no reason
    table, ex = connected([(b"$MNMOD,1,P*54\r\n", b"$ASMOD,OK*3A\r\n"),
                           (b"$MNPOS,90.000000,,,10,,*AD\r\n", b"$ASPOS,ERR,5*FC\r\n"), (STA, STA_MOVING)])
    with ex, pytest.raises(TurntableCommandError, match="^controller refused POS: error 5 \\(beyond the controller's "
                                                        "limits\\)") as info:
        table.move_to([90.0, None, None], 10.0)
    assert info.value.code == 5


def test_lost_link_is_reopened():
    table, ex = connected([(STA, STA_MOVING)])
    ex.close()                                  # the link drops between requests
    with ex:
        table.read_state()
    assert ex.opened == 2 and table.stats.reconnects == 1


class _DeadLink(Exchange):
    def open(self) -> None:
        raise ConnectionError("port vanished")


def test_link_not_regained_raises_connection_error():
    ex = _DeadLink([])
    table = MnTurntable(ex, timeout_s=0.05, retries=2)
    with pytest.raises(TurntableConnectionError, match="port vanished"):
        table.connect()
    with pytest.raises(TurntableConnectionError):
        table.read_state()
    assert table.stats.reconnects == 3


# -- the simulator's handler on its own ----------------------------------------------------------
def test_handler_faults_and_refusals():
    ctl = SimController(clock=ManualClock())
    handle = MnSimHandler(ctl)
    assert handle(b"$MNCHK,1*CE") == b"$ASCHK,OK*30\r\n"
    assert handle(b"$MNCHK,1*CF") == b"$ASCHK,ERR,7*E2\r\n"
    assert handle(b"$MNCHK,2*CF") == b"$ASCHK,ERR,2*DD\r\n"
    assert handle(b"hello") == b"$ASERR,ERR,1*EF\r\n"
    ctl.faults.timeout = 1
    assert handle(b"$MNENA,1*CC") is None
    assert ctl.state().axes[0].enabled               # executed, only the reply was lost
    ctl.faults.garbage = 1
    assert handle(b"$MNCHK,1*CE") == GARBAGE + CRLF
    ctl.faults.checksum = 1
    with pytest.raises(TurntableChecksumError):
        codec.decode_reply(handle(b"$MNCHK,1*CE"), "CHK")
    ctl.faults.exception, ctl.faults.exception_code = 1, 6
    assert handle(b"$MNDIS,1*D8") == codec.encode_error("DIS", 6) + CRLF
    assert ctl.state().axes[0].enabled               # not executed
    assert handle(b"$MNCHK,1*CE") == b"$ASCHK,OK*30\r\n"   # faults used up


def test_refused_pos_moves_nothing():
    clock = ManualClock()
    ctl = SimController(clock=clock)
    handle = MnSimHandler(ctl)
    for request in (codec.Enable((0, 1, 2)), codec.SetMode(2, AxisMode.RATE)):
        assert codec.decode_reply(handle(codec.encode_request(request)), request.cmd) == ()
    with pytest.raises(TurntableCommandError) as info:
        codec.decode_reply(handle(codec.encode_request(codec.MovePositions((90.0, None, 10.0)))), "POS")
    assert info.value.code == codec.ERR_WRONG_MODE
    with pytest.raises(TurntableCommandError) as info:
        codec.decode_reply(handle(codec.encode_request(codec.MovePositions((90.0, None, None), (250.0, None, None)))),
                           "POS")
    assert info.value.code == codec.ERR_LIMIT
    clock.advance(10.0)
    assert ctl.state().angles_deg == (0.0, 0.0, 0.0)


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.binary(max_size=80),
                 st.builds(lambda c, f: b"$MN" + c.encode() + f, st.sampled_from(codec.COMMANDS),
                           st.binary(max_size=40))))
def test_handler_answers_any_line_with_a_valid_reply_frame(line):
    handle = MnSimHandler(SimController(clock=ManualClock()))
    reply = handle(line)
    assert reply is not None and reply.endswith(CRLF)
    assert codec.decode_frame(reply).prefix == "AS"


# -- end to end through the real transports -------------------------------------------------------
class HookClock(ManualClock):
    """A ManualClock that runs `hooks` (time, fn) once the time passes them (to trip faults mid-move)."""

    def __init__(self):
        super().__init__()
        self.hooks: list = []

    def sleep(self, seconds: float) -> None:
        super().sleep(seconds)
        due = [h for h in self.hooks if h[0] <= self.now()]
        self.hooks = [h for h in self.hooks if h[0] > self.now()]
        for _, fn in due:
            fn()


@pytest.fixture
def sim():
    clock = HookClock()
    ctl = SimController(clock=clock)
    server = LineServer(MnSimHandler(ctl))
    try:
        yield clock, ctl, server
    finally:
        server.close()


#: how long the live client waits for a reply that is due (long: see `live`), and where none will come
REPLY_WAIT_S, SILENT_WAIT_S = 1.0, 0.2


@pytest.fixture(params=["tcp", "pty"])
def live(request, sim):
    clock, ctl, server = sim
    if request.param == "tcp":
        host, port = server.listen_tcp()
        url = f"tcp://{host}:{port}"
    else:
        url = server.open_pty()
    # long: a loaded machine must not turn a slow simulator into a timeout; the silence tests shorten it
    table = MnTurntable(url, clock=clock, timeout_s=REPLY_WAIT_S, retries=2)
    table.connect()
    try:
        yield table, ctl, clock
    finally:
        table.close()


def test_move_and_wait_in_position(live):
    table, ctl, clock = live
    table.enable()
    targets = [90.0, -30.0, 180.0]
    table.move_to(targets, [20.0, 10.0, 30.0])
    moving = table.read_state()
    state = table.wait_in_position(targets, settle_s=0.5, poll_s=0.25)
    assert state.angles_deg == (90.0, -30.0, 180.0)
    assert all(a.in_position and a.mode is AxisMode.POSITION for a in state.axes)
    assert ctl.state().angles_deg == pytest.approx(state.angles_deg, abs=1e-6)
    # The inner frame is last: 180 deg at 30 deg/s with 100 deg/s^2 ramps takes 6.3 s;
    # then 0.5 s settle, polled every 0.25 s.
    assert 6.8 <= clock.now() <= 7.05
    assert all(a.status & AxisStatus.MOVING and not a.in_position for a in moving.axes)


def test_rate_mode_then_stop(live):
    table, ctl, clock = live
    table.enable(["inner"])
    table.set_rate("inner", -30.0)
    clock.advance(2.0)
    state = table.read_state()
    assert state.axes[2].mode is AxisMode.RATE and state.axes[2].rate_dps == pytest.approx(-30.0)
    assert state.axes[2].status & AxisStatus.MOVING
    assert state.axes[0].mode is AxisMode.OFF and not state.axes[0].enabled
    table.stop()
    clock.advance(1.0)
    state = table.read_state()
    assert state.rates_dps == (0.0, 0.0, 0.0) and state.axes[2].mode is AxisMode.POSITION


def test_refusal_end_to_end(live):
    table, ctl, clock = live
    with pytest.raises(TurntableCommandError) as info:
        table.move_to([10.0, None, None])
    assert info.value.code == codec.ERR_NOT_ENABLED


def test_wire_faults_end_to_end(live):
    table, ctl, clock = live
    table.timeout_s = SILENT_WAIT_S             # the silences cost it (a slow reply may cost a retry: >= below)
    ctl.faults.timeout = 1
    table.read_state()
    assert table.stats.timeouts >= 1
    ctl.faults.timeout = 3
    with pytest.raises(TurntableTimeout):
        table.read_state()
    ctl.faults.garbage = 1
    table.read_state()
    ctl.faults.checksum = 1
    table.read_state()
    ctl.faults.checksum = 3
    with pytest.raises(TurntableChecksumError):
        table.read_state()
    ctl.faults.garbage = 3
    with pytest.raises(TurntableProtocolError):
        table.read_state()
    ctl.faults.exception = 1
    with pytest.raises(TurntableCommandError) as info:
        table.stop()
    assert info.value.code == ctl.faults.exception_code
    table.check_link()                   # the link is fine again


def test_a_late_reply_is_dropped_not_read_as_the_reply_to_the_next_request(live):
    """See tests/protocol/test_scpi.py: the same over `$MN`, whose echo check cannot tell two STA replies apart."""
    table, ctl, clock = live
    table.enable(["outer"])
    table.set_rate("outer", 10.0)
    ctl.faults.late = 1
    first = table.read_state()
    assert table.stats.timeouts == 1 and table.stats.late_replies == 1
    clock.advance(2.0)
    second = table.read_state()
    assert second.angles_deg == pytest.approx(ctl.state().angles_deg, abs=1e-6)
    assert second.angles_deg[0] > first.angles_deg[0] + 10.0
    assert table.stats.timeouts == 1


def test_estop_aborts_a_move(live):
    table, ctl, clock = live
    table.enable()
    table.move_to([90.0, None, None], 10.0)
    clock.hooks.append((3.0, ctl.trip_estop))
    with pytest.raises(TurntableEStop, match="emergency stop") as info:
        table.wait_in_position([90.0, None, None], poll_s=0.25)
    assert info.value.state.estop
    clock.advance(5.0)
    state = table.read_state()
    assert state.rates_dps == (0.0, 0.0, 0.0)
    assert not any(a.enabled for a in state.axes)
    assert 5.0 < state.angles_deg[0] < 45.0           # stopped well short of the target


def test_limit_trip_during_a_move_then_recovery(live):
    table, ctl, clock = live
    table.enable()
    table.move_to([None, 40.0, None], 10.0)
    clock.hooks.append((2.0, lambda: ctl.trip_limit(1)))
    with pytest.raises(TurntableFault, match="middle: limit") as info:
        table.wait_in_position([None, 40.0, None], poll_s=0.25)
    assert not isinstance(info.value, TurntableEStop)
    clock.advance(3.0)
    assert table.read_state().rates_dps == (0.0, 0.0, 0.0)
    with pytest.raises(TurntableCommandError) as refused:
        table.enable(["middle"])
    assert refused.value.code == codec.ERR_FAULT
    table.reset_faults()
    table.enable(["middle"])
    table.move_to([None, 40.0, None], 10.0)
    assert table.wait_in_position([None, 40.0, None], poll_s=0.5).angles_deg[1] == 40.0


def test_connection_loss_and_reconnect_over_tcp():
    clock = ManualClock()
    ctl = SimController(clock=clock)
    first = LineServer(MnSimHandler(ctl))
    host, port = first.listen_tcp()
    table = MnTurntable(f"tcp://{host}:{port}", clock=clock, timeout_s=0.2, retries=2)
    second = None
    try:
        table.connect()
        table.enable()
        first.close()                                      # the controller drops the link
        second = LineServer(MnSimHandler(ctl))
        second.listen_tcp(host, port)                      # ... and comes back on the same port
        assert table.read_state().axes[0].enabled
        assert table.stats.reconnects >= 1
        second.close()
        with pytest.raises(TurntableConnectionError):      # gone for good
            table.read_state()
    finally:
        table.close()
        first.close()
        if second is not None:
            second.close()
