"""Both chamber dialects end to end against the simulated chamber over real transports (TCP on loopback, a pty;
Modbus TCP and RTU): control on the simulated clock, alarms, refusals, wire faults and a lost link end in clear
driver errors."""

from __future__ import annotations

import contextlib
import math

import pytest

from bench.sim.chamber import ChamberPhysics, SimChamber
from bench.sim.chamber_server import ChamberModbusServer, serve_chamber_ascii
from drivers.chamber import open_chamber
from drivers.chamber.base import ChamberAlarms, ChamberLimits
from drivers.chamber.modbus_map import ChamberRegisterMap
from drivers.clock import ManualClock
from drivers.errors import (
    ChamberAlarm,
    ChamberCommandError,
    ChamberConnectionError,
    ChamberLimitError,
    ChamberProtocolError,
    ChamberTimeout,
    DeviceError,
)
from tests.protocol.test_bounded_errors import SHORT, WAIT_S, GarbagePeer

TRANSPORTS = ["ascii-tcp", "ascii-pty", "modbus-tcp", "modbus-rtu"]
WIDE = ChamberLimits(-100.0, 200.0, 30.0)    # wider than the simulated controller's own range
#: How long a client waits for a reply where one is due: long, so that a loaded machine never turns a slow
#: simulator into a timeout, a retry and a late reply read as the next answer (RTU has no transaction id;
#: seen once at load 13 with 0.3 s: a setpoint write's reply read as the state).
REPLY_WAIT_S = 3.0
#: How long a client waits where no reply will come (silence, garbage that never decodes): each attempt costs it
SILENT_WAIT_S = 0.3


@contextlib.contextmanager
def impatient(chamber):
    """`chamber`'s controller through a client that gives up after SILENT_WAIT_S (`chamber` reconnected
    after it: a serial port has one client): a test of what never answers does not wait REPLY_WAIT_S
    per attempt."""
    dialect = "modbus" if chamber.url.startswith("modbus+") else "ascii"
    other = open_chamber(chamber.url, dialect, limits=WIDE, timeout_s=SILENT_WAIT_S, retries=2)
    chamber.close()
    other.connect()
    try:
        yield other
    finally:
        other.close()
        chamber.connect()


@contextlib.contextmanager
def served(kind: str, sim: SimChamber, register_map=None):
    """(url, dialect, server) of `sim` served over `kind` (modbus: `register_map`, default the F4P's)."""
    if kind.startswith("ascii"):
        server, urls = serve_chamber_ascii(sim, tcp=kind == "ascii-tcp", pty=kind == "ascii-pty")
        try:
            yield next(iter(urls.values())), "ascii", server
        finally:
            server.close()
        return
    modbus = ChamberModbusServer(sim, register_map)
    try:
        if kind == "modbus-tcp":
            host, port = modbus.start_tcp()
            url = f"modbus+tcp://{host}:{port}"
        else:
            url = f"modbus+rtu://{modbus.start_rtu_pty()}?baud=115200"
        yield url, "modbus", modbus
    finally:
        modbus.close()


@pytest.fixture(params=TRANSPORTS)
def rig(request):
    clock = ManualClock()
    sim = SimChamber(ChamberPhysics(), clock)
    with served(request.param, sim) as (url, dialect, server):
        chamber = open_chamber(url, dialect, limits=WIDE, timeout_s=REPLY_WAIT_S, retries=2)
        chamber.connect()
        try:
            yield chamber, sim, clock, server, request.param
        finally:
            chamber.close()


def test_setpoint_ramp_run_and_the_air_follows_on_the_simulated_clock(rig):
    chamber, sim, clock, _, _ = rig
    chamber.set_setpoint(-20.0, ramp_c_per_min=2.0)
    chamber.run()
    clock.advance(900.0)
    state = chamber.check_state()
    truth = sim.state()
    assert state.running and state.setpoint_c == pytest.approx(-20.0)
    assert state.ramp_c_per_min == pytest.approx(2.0)
    assert state.temperature_c == pytest.approx(truth.temperature_c, abs=0.051)   # one decimal on the wire
    # the air lags the 2 degC/min ramp: T0 - r (t - tau (1 - exp(-t/tau))) with tau 240 s
    lagging = 23.0 - (900.0 - 240.0 * (1 - math.exp(-900.0 / 240.0))) / 30.0
    assert truth.temperature_c == pytest.approx(lagging, abs=0.05)
    clock.advance(4 * 3600.0)
    assert chamber.read_state().temperature_c == pytest.approx(-20.0, abs=0.051)
    chamber.stop()
    assert not chamber.read_state().running and not sim.state().running


def test_an_alarm_is_reported_and_run_is_refused_until_cleared(rig):
    chamber, sim, clock, _, _ = rig
    chamber.set_setpoint(40.0)
    chamber.run()
    clock.advance(60.0)
    sim.trip_alarm(ChamberAlarms.SENSOR_FAULT)     # one every dialect names (the F4P: its input 1 error register)
    with pytest.raises(ChamberAlarm, match="sensor fault") as info:
        chamber.check_state()
    assert not info.value.state.running
    with pytest.raises(ChamberCommandError):
        chamber.run()
    chamber.clear_alarms()
    chamber.run()
    assert chamber.check_state().running


def test_a_setpoint_beyond_the_controllers_range_is_refused_by_the_controller(rig):
    chamber, sim, _, _, kind = rig
    if kind.startswith("modbus"):
        # the F4P's map reads the controller's set point limits (602, 603) at connect: refused before sending
        with pytest.raises(ChamberLimitError, match=r"set point limits \[-70, 180\] degC"):
            chamber.set_setpoint(-75.0)   # within the bench's (wide) limits, beyond the controller's -70
        with pytest.raises(ChamberCommandError) as info:     # and the controller refuses it too (03)
            chamber._write_single(300, (-750) & 0xFFFF, "set point 1 -75.0 degC")
        assert info.value.code == 3
    else:
        with pytest.raises(ChamberCommandError, match="OUT OF RANGE"):
            chamber.set_setpoint(-75.0)
    assert sim.state().setpoint_c == 23.0


@pytest.mark.slow
def test_one_garbled_reply_is_retried_three_are_a_protocol_error(rig):
    chamber, sim, _, _, _ = rig
    sim.faults.garbage = 1
    assert chamber.read_state().temperature_c == pytest.approx(23.0)
    with impatient(chamber) as other, pytest.raises(ChamberProtocolError):
        sim.faults.garbage = 3          # once connected (the F4P's map reads its settings at connect)
        other.read_state()
    assert chamber.read_state().temperature_c == pytest.approx(23.0)     # the link recovers


@pytest.mark.slow
def test_a_corrupted_reply_is_retried(rig):
    chamber, sim, _, _, _ = rig
    sim.faults.checksum = 1
    assert not chamber.read_state().running


@pytest.mark.slow
def test_silence_is_a_timeout(rig):
    chamber, sim, _, _, _ = rig
    with impatient(chamber) as other, pytest.raises(ChamberTimeout):
        sim.faults.timeout = 3
        other.read_state()
    assert chamber.read_state().temperature_c == pytest.approx(23.0)


def test_an_injected_refusal_is_a_command_error(rig):
    chamber, sim, _, _, _ = rig
    sim.faults.exception = 1
    with pytest.raises(ChamberCommandError):
        chamber.stop()


@pytest.mark.parametrize("rig", ["ascii-tcp", "modbus-tcp"], indirect=True)   # a pty has no connection to lose
def test_a_lost_link_is_a_connection_error_and_make_safe_does_not_raise(rig):
    chamber, _, _, server, _ = rig
    server.close()
    with pytest.raises(ChamberConnectionError) as info:
        chamber.read_state()
    assert isinstance(info.value, DeviceError)
    assert chamber.make_safe(23.0).endswith("stop failed: the chamber may still be controlling")


@pytest.mark.parametrize("register_map, refusals", [
    # the F4P's numbers (docs/hardware/chamber.md): input 1 value and error, alarm 1 status and the decimal setting are
    # read only, 500 is not served; auto/manual 9, ramp rate 0 counts and ramp mode 7 are out of range
    (None, ((100, 5, 2), (101, 5, 2), (102, 0, 2), (606, 2, 2), (500, 1, 2), (200, 9, 3), (1101, 0, 3),
            (1100, 7, 3))),
    (ChamberRegisterMap(), ((100, 5, 2), (101, 5, 2), (103, 1, 2), (200, 9, 3), (301, 0x8000, 3))),
])
def test_the_modbus_simulator_refuses_writes_as_the_page_says(register_map, refusals):
    sim = SimChamber(ChamberPhysics(), ManualClock())
    with served("modbus-tcp", sim, register_map) as (url, _, _):
        with open_chamber(url, "modbus", timeout_s=REPLY_WAIT_S, register_map=register_map) as chamber:
            for address, value, code in refusals:
                with pytest.raises(ChamberCommandError) as info:
                    chamber._write_single(address, value, f"write {value} at {address}")
                assert info.value.code == code, (address, info.value)
            assert chamber.read_state().temperature_c == pytest.approx(23.0)


@pytest.mark.parametrize("dialect, chunk, needle", [
    ("ascii", b"x", "longer than any reply"),                      # no terminator: cut at max_line, then refused
    ("modbus", bytes.fromhex("de ad be ef 00 ff 13 37 42"), "no Modbus reply in more than"),
])
def test_a_peer_streaming_garbage_ends_in_a_short_chamber_error(dialect, chunk, needle):
    with GarbagePeer(chunk) as peer:
        host, port = peer.address
        url = f"{'modbus+tcp' if dialect == 'modbus' else 'tcp'}://{host}:{port}"
        chamber = open_chamber(url, dialect, timeout_s=WAIT_S, retries=0)
        try:
            with pytest.raises(ChamberProtocolError) as info:
                chamber.connect()
                chamber.read_state()
        finally:
            chamber.close()
    message = str(info.value)
    assert needle in message and len(message) < SHORT, f"{len(message):,} characters: {message[:200]}..."


@pytest.mark.parametrize("dialect", ["ascii", "modbus"])
def test_the_simulated_world_serves_a_chamber_on_its_clock(dialect):
    from bench.config.load import default_sim_config
    from bench.sim.world import SimWorld

    config = default_sim_config()
    with SimWorld(config.site.site, config.sim.imu, config.sim.noise) as world:
        url = world.add_chamber(dialect)
        with open_chamber(url, dialect, timeout_s=1.0) as chamber:
            chamber.set_setpoint(50.0)
            chamber.run()
            world.clock.advance(2 * 3600.0)          # the run clock: the chamber's time with the table's
            assert chamber.check_state().temperature_c == pytest.approx(50.0, abs=0.051)
            assert world.chamber.state().time_s == pytest.approx(2 * 3600.0)
