"""The simulated controller behind every wire-level simulator."""

from __future__ import annotations

import pytest

from bench.sim.controller import ERR_FAULT, ERR_LIMIT, ERR_NOT_ENABLED, ERR_WRONG_MODE, SimCommandError, SimController
from drivers.clock import ManualClock
from drivers.turntable.base import AxisLimits, AxisMode, AxisStatus


@pytest.fixture
def ctl():
    return SimController(clock=ManualClock())


def _enable_all(ctl):
    for k in range(3):
        ctl.enable(k)


def test_refuses_demands_when_disabled_or_in_the_wrong_mode(ctl):
    with pytest.raises(SimCommandError) as err:
        ctl.demand_position(0, 10.0)
    assert err.value.code == ERR_NOT_ENABLED
    ctl.enable(0)
    with pytest.raises(SimCommandError) as err:
        ctl.demand_rate(0, 10.0)
    assert err.value.code == ERR_WRONG_MODE
    with pytest.raises(SimCommandError) as err:
        ctl.demand_position(0, 10.0, rate_dps=1e6)
    assert err.value.code == ERR_LIMIT
    assert ctl.state().angles_deg == (0.0, 0.0, 0.0)


def test_position_move_reports_moving_then_in_position(ctl):
    _enable_all(ctl)
    arrival = ctl.demand_position(1, 90.0, rate_dps=20.0)
    ctl.clock.advance(arrival / 2)
    mid = ctl.state().axes[1]
    assert mid.status & AxisStatus.MOVING and not mid.in_position and 0 < mid.angle_deg < 90
    ctl.clock.advance(arrival)
    done = ctl.state().axes[1]
    assert done.in_position and done.angle_deg == 90.0 and done.rate_dps == 0.0


def test_rate_mode_stop_and_abort(ctl):
    _enable_all(ctl)
    ctl.set_mode(2, AxisMode.RATE)
    ctl.demand_rate(2, -30.0)
    ctl.clock.advance(5.0)
    assert ctl.state().axes[2].rate_dps == pytest.approx(-30.0)
    rest = ctl.stop()
    ctl.clock.advance(rest)
    inner = ctl.state().axes[2]
    assert inner.rate_dps == 0.0 and inner.mode is AxisMode.POSITION and inner.in_position
    ctl.abort()
    assert all(not a.enabled and a.mode is AxisMode.OFF for a in ctl.state().axes)


def test_estop_latches_until_released_and_reset(ctl):
    _enable_all(ctl)
    ctl.demand_position(0, 180.0)
    ctl.clock.advance(1.0)
    ctl.trip_estop()
    state = ctl.state()
    assert state.estop and not any(a.enabled for a in state.axes) and "emergency" in state.fault_text
    with pytest.raises(SimCommandError) as err:
        ctl.enable(0)
    assert err.value.code == ERR_FAULT
    with pytest.raises(SimCommandError):
        ctl.reset(0)                                    # still pressed
    ctl.release_estop()
    for k in range(3):
        ctl.reset(k)
    ctl.enable(0)
    ctl.clock.advance(30.0)
    assert not ctl.state().estop and ctl.state().axes[0].rate_dps == 0.0


def test_limit_trip_and_travel_limits():
    ctl = SimController(clock=ManualClock(), limits=(AxisLimits(), AxisLimits(-90.0, 90.0), AxisLimits()))
    _enable_all(ctl)
    with pytest.raises(SimCommandError) as err:
        ctl.demand_position(1, 120.0)
    assert err.value.code == ERR_LIMIT
    ctl.trip_limit(1)
    state = ctl.state()
    assert state.fault and state.axes[1].status & AxisStatus.LIMIT and not state.axes[1].enabled
    assert "middle" in state.describe_fault()
    ctl.reset(1)
    assert not ctl.state().fault and ctl.fault_text == ""


def test_wire_faults_are_taken_in_order_and_counted(ctl):
    ctl.faults.timeout, ctl.faults.checksum = 1, 2
    assert [ctl.faults.take() for _ in range(4)] == ["timeout", "checksum", "checksum", None]
