"""The simulated chamber's physics on the simulated clock: rate-limited first-order air, ramps, passive drift,
range refusals, alarms that latch and stop the run. No wall time anywhere."""

from __future__ import annotations

import math

import pytest

from bench.sim.chamber import (
    ERR_ALARM,
    ERR_RANGE,
    ChamberPhysics,
    SimChamber,
    SimChamberError,
    approach,
)
from drivers.chamber.base import ChamberAlarms
from drivers.clock import ManualClock


def euler(temperature_c, target_c, tau_s, up, down, dt_s, step_s=1e-2):
    for _ in range(round(dt_s / step_s)):
        rate = min(max((target_c - temperature_c) / tau_s, -down), up)
        temperature_c += rate * step_s
    return temperature_c


@pytest.mark.parametrize("start, target, dt", [(23.0, -20.0, 900.0), (23.0, 85.0, 300.0), (20.0, 21.0, 500.0),
                                               (-40.0, 25.0, 2000.0), (23.0, 23.0, 10.0)])
def test_approach_is_the_exact_solution_of_the_rate_limited_lag(start, target, dt):
    exact = approach(start, target, 240.0, 5 / 60, 3 / 60, dt)
    assert exact == pytest.approx(euler(start, target, 240.0, 5 / 60, 3 / 60, dt), abs=2e-3)


def chamber(**physics) -> tuple[SimChamber, ManualClock]:
    clock = ManualClock()
    return SimChamber(ChamberPhysics(**physics), clock), clock


def test_cooling_is_rate_limited_then_settles_on_the_setpoint():
    sim, clock = chamber()
    sim.set_setpoint(-20.0)
    sim.run()
    clock.advance(600.0)        # 3 degC/min for 10 min: the lag asks for more until 12 degC from the target
    assert sim.temperature_c == pytest.approx(23.0 - 30.0)
    clock.advance(6 * 3600.0)
    state = sim.state()
    assert state.temperature_c == pytest.approx(-20.0, abs=1e-6) and state.running and not state.alarm


def test_heating_is_limited_by_its_own_rate():
    sim, clock = chamber(max_heat_c_per_min=2.0)
    sim.set_setpoint(85.0)
    sim.run()
    clock.advance(300.0)
    assert sim.temperature_c == pytest.approx(23.0 + 10.0)


def test_a_ramp_moves_the_working_setpoint_and_the_air_lags_it():
    sim, clock = chamber()
    sim.set_ramp(1.0)
    sim.set_setpoint(33.0)
    sim.run()
    clock.advance(600.0)        # first-order lag behind a 1 degC/min ramp: T0 + r (t - tau (1 - exp(-t/tau)))
    expected = 23.0 + (600.0 - 240.0 * (1 - math.exp(-600.0 / 240.0))) / 60.0
    assert sim.temperature_c == pytest.approx(expected, abs=0.02)
    clock.advance(4 * 3600.0)
    assert sim.temperature_c == pytest.approx(33.0, abs=1e-6)


def test_stopped_the_air_drifts_to_ambient():
    sim, clock = chamber()
    sim.set_setpoint(-20.0)
    sim.run()
    clock.advance(6 * 3600.0)
    sim.stop()
    clock.advance(3600.0)
    assert sim.temperature_c == pytest.approx(23.0 - 43.0 * math.exp(-1.0), abs=1e-5)


def test_the_controller_refuses_a_setpoint_or_ramp_beyond_its_range():
    sim, _ = chamber(min_setpoint_c=-40.0, max_ramp_c_per_min=10.0)
    for call, value in ((sim.set_setpoint, -41.0), (sim.set_setpoint, math.nan), (sim.set_ramp, 11.0),
                        (sim.set_ramp, -1.0)):
        with pytest.raises(SimChamberError) as info:
            call(value)
        assert info.value.code == ERR_RANGE
    assert sim.state().setpoint_c == 23.0


def test_an_alarm_on_demand_latches_stops_the_run_and_refuses_run_until_cleared():
    sim, clock = chamber()
    sim.set_setpoint(60.0)
    sim.run()
    clock.advance(60.0)
    sim.trip_alarm(ChamberAlarms.DOOR_OPEN)
    state = sim.state()
    assert state.alarms == ChamberAlarms.DOOR_OPEN and not state.running
    with pytest.raises(SimChamberError) as info:
        sim.run()
    assert info.value.code == ERR_ALARM
    sim.clear_alarms()
    sim.run()
    assert sim.state().running


def test_over_temperature_trips_by_itself_and_stays_while_its_cause_remains():
    sim, clock = chamber(over_temperature_c=100.0, max_setpoint_c=95.0, passive_time_constant_s=600.0)
    sim = SimChamber(sim.physics, clock, temperature_c=120.0)
    clock.advance(1.0)
    assert sim.state().alarms == ChamberAlarms.OVER_TEMPERATURE
    sim.clear_alarms()
    assert sim.state().alarms == ChamberAlarms.OVER_TEMPERATURE      # still above the limit
    clock.advance(3600.0)                                            # stopped: cooled toward ambient
    sim.clear_alarms()
    assert not sim.state().alarm


def test_bad_physics_is_refused():
    for kw in ({"time_constant_s": 0.0}, {"max_cool_c_per_min": -1.0}, {"min_setpoint_c": 200.0},
               {"ambient_c": 500.0}):
        with pytest.raises(ValueError):
            ChamberPhysics(**kw)
