"""A thermal plan (issue 18 item 3): [plan] temperatures_c and [plan.soak], the chamber steps, the soak
decided on the IMU's temperature, and the chamber in the sequencer's safe stop.

The soak and safety tests run the real sequencer against the simulated world: the table served
over loopback, the simulated chamber served in its ASCII dialect and driven by the real driver, the
thermal IMU's case following the chamber's air (`SimWorld.drive_imu_from_chamber`) on one simulated
clock.
"""

from __future__ import annotations

import dataclasses
import threading

import pytest

from bench.config.load import SIM_CONFIG_TOML, ConfigError, parse_config
from bench.log.events import Info, RunListener, RunState, StepFinished
from bench.model.earth import Site
from bench.model.imu import NoiseModel, default_sim_imu
from bench.model.thermal import ImuThermal
from bench.plan.steps import (
    DwellStep,
    SetTemperatureStep,
    SoakStep,
    step_from_dict,
    step_to_dict,
    thermal_block,
)
from bench.plan.thermal import SoakCriterion, ThermalPlan, block_observation_units, compile_thermal_plan
from bench.run.runner import compile_from_config
from bench.run.sequencer import Sequencer, SequencerError, SequencerOptions, SoakTimeout
from bench.sim.world import SimWorld
from drivers.chamber import ChamberAlarms, open_chamber
from drivers.errors import ChamberAlarm, ChamberTimeout
from drivers.imu.receiver import ImuReceiver
from drivers.turntable import open_turntable

CHAMBER = '\n[chamber]\nurl = "sim"\ndialect = "ascii"\nsafe_setpoint_c = 23.0\n'
THERMAL_PLAN = "temperatures_c = [-20.0, 0.0, 25.0, 50.0]\n"


def _config(plan_extra: str = THERMAL_PLAN, tail: str = CHAMBER):
    text = SIM_CONFIG_TOML.replace("dwell_s = 60.0", "dwell_s = 60.0\n" + plan_extra) + tail
    return parse_config(text, "bench.toml")


# --- configuration ---------------------------------------------------------------------

def test_the_plan_takes_temperatures_and_a_soak_criterion():
    config = _config(THERMAL_PLAN + "ramp_c_per_min = 2.0\n",
                     "\n[plan.soak]\nrate_c_per_min = 0.02\nstable_min = 15.0\nmax_soak_min = 300.0\n" + CHAMBER)
    thermal = config.plan.thermal
    assert thermal.temperatures_c == (-20.0, 0.0, 25.0, 50.0) and thermal.ramp_c_per_min == 2.0
    assert thermal.soak == SoakCriterion(rate_c_per_min=0.02, stable_min=15.0, max_soak_min=300.0)
    # without temperatures_c nothing changes
    assert parse_config(SIM_CONFIG_TOML).plan.thermal is None


@pytest.mark.parametrize("plan_extra, tail, where, words", [
    (THERMAL_PLAN, "", "plan.temperatures_c", "needs a [chamber] section"),
    ("temperatures_c = [-20.0, 90.0]\n", CHAMBER, "plan.temperatures_c[1]", "outside the chamber limits [-40, 85]"),
    ("temperatures_c = [0.0, 25.0, 0]\n", CHAMBER, "plan.temperatures_c[2]", "listed twice"),
    ("temperatures_c = [0.0, \"hot\"]\n", CHAMBER, "plan.temperatures_c[1]", "must be a temperature"),
    ("temperatures_c = []\n", CHAMBER, "plan.temperatures_c", "array of 1 to 50"),
    ("ramp_c_per_min = 2.0\n", CHAMBER, "plan.ramp_c_per_min", "only with plan.temperatures_c"),
    (THERMAL_PLAN + "ramp_c_per_min = 9.0\n", CHAMBER, "plan.ramp_c_per_min", "exceeds the chamber limit 5"),
    (THERMAL_PLAN, "\n[plan.soak]\nrate_c_per_minute = 0.1\n" + CHAMBER, "plan.soak.rate_c_per_minute",
     "unknown key"),
    (THERMAL_PLAN, "\n[plan.soak]\nstable_min = 30.0\nmax_soak_min = 20.0\n" + CHAMBER, "plan.soak.max_soak_min",
     "must be at least stable_min"),
    (THERMAL_PLAN, "\n[plan.soak]\nrate_c_per_min = 0\n" + CHAMBER, "plan.soak.rate_c_per_min", "must be > 0"),
    (THERMAL_PLAN, "\n[imu.signals]\ngyro_x = \"IMU_GYRO_X.GyroX\"\ngyro_y = \"IMU_GYRO_Y.GyroY\"\n"
     "gyro_z = \"IMU_GYRO_Z.GyroZ\"\nacc_x = \"IMU_ACC_X.AccX\"\n"
     "acc_y = \"IMU_ACC_Y.AccY\"\nacc_z = \"IMU_ACC_Z.AccZ\"\n"
     + CHAMBER, "plan.temperatures_c", "has no temperature (imu.signals.temperature)"),
])
def test_a_bad_thermal_plan_is_one_line_with_file_line_and_key(plan_extra, tail, where, words):
    with pytest.raises(ConfigError) as info:
        _config(plan_extra, tail)
    message = str(info.value)
    assert message.startswith("bench.toml:") and f": {where}: " in message and words in message, message
    assert len(message.splitlines()) == 1


# --- compiling --------------------------------------------------------------------------

def test_the_plan_compiles_to_a_block_per_temperature_with_set_soak_and_the_calibration():
    config = _config()
    plan = compile_from_config(config)
    single = compile_from_config(dataclasses.replace(config, plan=dataclasses.replace(config.plan, thermal=None)))
    n = len(single.steps)
    assert len(plan.steps) == 4 * (n + 2)
    assert [s.index for s in plan.steps] == list(range(len(plan.steps)))
    for k, setpoint in enumerate((-20.0, 0.0, 25.0, 50.0), start=1):
        block = plan.steps[(k - 1) * (n + 2):k * (n + 2)]
        assert isinstance(block[0], SetTemperatureStep) and block[0].setpoint_c == setpoint and block[0].unit == f"T{k}"
        assert isinstance(block[1], SoakStep) and block[1].setpoint_c == setpoint and block[1].stable_s == 600.0
        assert all(s.unit.startswith(f"T{k}-") and thermal_block(s.unit) == k for s in block[2:])
        assert sorted(s.unit.split("-", 1)[1] for s in block[2:]) == sorted(s.unit for s in single.steps)
        assert len(block_observation_units(plan.steps, k)) == 30
    # procedures are data: every step goes through the log's form and back
    assert all(step_from_dict(step_to_dict(s)) == s for s in plan.steps)
    assert "chamber to -20 degC" in plan.format_dry_run() and "soak: IMU rate < 0.05 degC/min" in plan.format_dry_run()
    assert plan.estimated_total_s > 4 * single.estimated_total_s


def test_a_plan_without_temperatures_compiles_as_before():
    config = parse_config(SIM_CONFIG_TOML)
    plan = compile_from_config(config)
    assert not any(isinstance(s, (SetTemperatureStep, SoakStep)) for s in plan.steps)
    assert all(thermal_block(s.unit) is None for s in plan.steps)


# --- the soak and the safe stop, on the simulated world ---------------------------------------

class Listener(RunListener):
    def __init__(self):
        self.events, self.chamber_states, self.soak_statuses, self.hooks = [], [], [], {}

    def on_event(self, event):
        self.events.append(event)
        hook = self.hooks.get((event.kind, event.step_unit))
        if hook:
            hook()

    def on_chamber_state(self, state):
        self.chamber_states.append(state)

    def on_soak_status(self, status):
        self.soak_statuses.append(status)


RATE_HZ = 20.0
OPTIONS = SequencerOptions(move_poll_s=0.1, imu_poll_s=0.5, state_period_s=1.0, chamber_poll_s=2.0,
                           chamber_safe_setpoint_c=23.0)


@pytest.fixture
def world_with_chamber():
    """(open a world for an IMU of case time constant tau_s) -> world, table, imu source, chamber driver."""
    opened = []

    def make(tau_s: float, *, chamber_timeout_s: float = 1.0):
        thermal = ImuThermal(reference_c=25.0, time_constant_s=tau_s, polynomials={}, ambient_c=23.0)
        world = SimWorld(Site(30.27), default_sim_imu(), NoiseModel.off(), imu_rate_hz=RATE_HZ, imu_thermal=thermal)
        opened.append(world.close)
        url = world.add_chamber("ascii")
        world.drive_imu_from_chamber()
        table = open_turntable(world.table_url, "scpi", clock=world.clock, timeout_s=1.0)
        table.connect()
        opened.append(table.close)
        receiver = ImuReceiver(world.receiver_bus(), rate_hz=RATE_HZ)
        opened.append(receiver.close)
        chamber = open_chamber(url, "ascii", clock=world.clock, timeout_s=chamber_timeout_s, retries=0)
        chamber.connect()
        opened.append(chamber.close)
        table.enable()
        return world, table, world.imu_source(receiver), chamber

    yield make
    for close in reversed(opened):
        close()


def _soak_steps(setpoint_c: float = 40.0, stable_s: float = 120.0, max_soak_s: float = 6 * 3600.0):
    return (SetTemperatureStep(index=0, unit="T1", temperature_index=1, setpoint_c=setpoint_c, ramp_c_per_min=None,
                               estimated_s=0.0),
            SoakStep(index=1, unit="T1", temperature_index=1, setpoint_c=setpoint_c, rate_c_per_min=0.05,
                     stable_s=stable_s, max_soak_s=max_soak_s, chamber_tolerance_c=1.0, rate_window_s=60.0,
                     estimated_s=0.0))


def _soak(make, tau_s: float):
    world, table, imu, chamber = make(tau_s)
    listener = Listener()
    seq = Sequencer(_soak_steps(), table, imu, world.clock, [listener], OPTIONS, chamber=chamber)
    assert seq.run() is RunState.DONE, seq.error
    done = next(e for e in listener.events if isinstance(e, StepFinished) and e.step_kind == "soak")
    air_at = next(s.time_s for s in listener.chamber_states if abs(s.temperature_c - 40.0) <= 1.0)
    return world, listener, done, air_at


@pytest.mark.slow
def test_the_soak_waits_for_the_imu_not_the_chamber(world_with_chamber):
    """The chamber's air reaches 40 degC long before an IMU with a 600 s case time constant does: the soak
    ends only once the IMU's own temperature has settled (its rate below 0.05 degC/min for 2 min), and
    an IMU that follows the air closely (30 s) is soaked far sooner in the same chamber."""
    world, listener, slow, air_at = _soak(world_with_chamber, 600.0)
    soak_infos = [e.soak for e in listener.events if isinstance(e, Info) and e.soak is not None]
    decisions = [s.decision for s in soak_infos]
    assert decisions[:2] == ["chamber_approaching", "imu_settling"] and decisions[-1] == "done"
    settling_at = next(s.time_s for s in soak_infos if s.decision == "imu_settling")
    assert settling_at == pytest.approx(air_at, abs=OPTIONS.chamber_poll_s + 1e-6)
    # at the chamber's arrival the IMU was still far from it; at the soak's end it is there
    imu_at_arrival = next(s.imu_temperature_c for s in soak_infos if s.decision == "imu_settling")
    assert 40.0 - imu_at_arrival > 3.0
    assert slow.soak.imu_temperature_c == pytest.approx(40.0, abs=0.6)
    assert abs(slow.soak.rate_c_per_min) < 0.05 and slow.soak.steady_for_s >= 120.0
    # every check of the soak reached the listeners (the TUI's chamber panel), the last one the decision's
    statuses = listener.soak_statuses
    assert len(statuses) > 100 and [s.time_s for s in statuses] == sorted(s.time_s for s in statuses)
    assert statuses[-1].done and statuses[-1].as_dict() == slow.soak.as_dict()
    slow_after_air = slow.time_s - air_at
    assert slow_after_air > 3 * 600.0 * 0.5        # the IMU's lag, not the air's, set the soak's length
    # the chamber was logged as it went, and made safe at the end of the run
    assert listener.chamber_states and listener.chamber_states[-1].setpoint_c == 40.0
    assert world.chamber.state().setpoint_c == 23.0 and world.chamber.state().running
    world.close()

    _, _, fast, fast_air_at = _soak(world_with_chamber, 30.0)
    assert fast.time_s - fast_air_at < slow_after_air / 3


@pytest.mark.slow
def test_a_soak_past_its_maximum_is_a_fault_and_the_chamber_is_made_safe(world_with_chamber):
    world, table, imu, chamber = world_with_chamber(600.0)
    listener = Listener()
    seq = Sequencer(_soak_steps(max_soak_s=1200.0), table, imu, world.clock, [listener], OPTIONS, chamber=chamber)
    assert seq.run() is RunState.FAILED and isinstance(seq.error, SoakTimeout)
    assert "did not soak at 40 degC within 20 min" in str(seq.error)
    made_safe = [e for e in listener.events if e.to_dict()["data"].get("chamber") == "made_safe"]
    assert len(made_safe) == 1 and "setpoint 23 degC (safe setpoint), running" in made_safe[0].message
    assert world.chamber.state().setpoint_c == 23.0
    assert not any(a.enabled for a in table.read_state().axes)        # servos off


def _with_a_dwell(steps):
    dwell = DwellStep(index=2, unit="T1-P01", schedule="t", schedule_index=0, angles_deg=(0.0, 0.0, 0.0),
                      target_deg=(0.0, 0.0, 0.0), dwell_s=60.0, estimated_s=60.0)
    return steps + (dwell,)


@pytest.mark.slow
def test_a_chamber_alarm_during_the_run_is_a_fault_the_table_stops_and_the_chamber_is_made_safe(
        world_with_chamber):
    world, table, imu, chamber = world_with_chamber(30.0)
    listener = Listener()
    listener.hooks[("step_started", "T1-P01")] = lambda: world.chamber.trip_alarm(ChamberAlarms.DOOR_OPEN)
    seq = Sequencer(_with_a_dwell(_soak_steps(stable_s=60.0)), table, imu, world.clock, [listener], OPTIONS,
                    chamber=chamber)
    assert seq.run() is RunState.FAILED and isinstance(seq.error, ChamberAlarm)
    assert "door open" in str(seq.error)
    fault = next(e for e in listener.events if e.kind == "fault")
    assert fault.step_unit == "T1-P01" and fault.error == "ChamberAlarm"
    # the controller refuses to run with the alarm latched: the safe setpoint fails, the chamber is stopped
    made_safe = next(e for e in listener.events if e.to_dict()["data"].get("chamber") == "made_safe")
    assert made_safe.message.endswith("stopped") and not world.chamber.state().running
    assert not any(a.enabled for a in table.read_state().axes)
    kinds = [e.kind for e in listener.events]
    assert kinds.index("fault") < kinds.index("info", kinds.index("fault"))


@pytest.mark.slow
def test_a_lost_chamber_link_is_a_fault_and_the_table_still_stops(world_with_chamber):
    world, table, imu, chamber = world_with_chamber(30.0, chamber_timeout_s=0.2)
    listener = Listener()

    def lose_link():
        world.chamber.faults.timeout = 10 ** 6       # the controller never answers again

    listener.hooks[("step_started", "T1-P01")] = lose_link
    seq = Sequencer(_with_a_dwell(_soak_steps(stable_s=60.0)), table, imu, world.clock, [listener], OPTIONS,
                    chamber=chamber)
    assert seq.run() is RunState.FAILED and isinstance(seq.error, ChamberTimeout)
    made_safe = next(e for e in listener.events if e.to_dict()["data"].get("chamber") == "made_safe")
    assert "failed" in made_safe.message          # best effort, reported; the run still ends
    assert not any(a.enabled for a in table.read_state().axes)
    assert [e.state for e in listener.events if e.kind == "transition"][-2:] == ["aborting", "failed"]


@pytest.mark.slow
def test_an_abort_during_the_soak_makes_the_chamber_safe(world_with_chamber):
    world, table, imu, chamber = world_with_chamber(600.0)
    listener = Listener()
    seq = Sequencer(_soak_steps(), table, imu, world.clock, [listener], OPTIONS, chamber=chamber)
    listener.hooks[("info", "T1")] = lambda: seq.abort("operator") if any(
        e.to_dict()["data"].get("soak") == "imu_settling" for e in listener.events) else None
    assert seq.run() is RunState.FAILED
    assert str(seq.error) == "operator"
    assert world.chamber.state().setpoint_c == 23.0 and world.chamber.state().running
    assert not any(a.enabled for a in table.read_state().axes)


def test_chamber_steps_need_a_chamber(world_with_chamber):
    world, table, imu, _ = world_with_chamber(30.0)
    with pytest.raises(SequencerError, match="no chamber"):
        Sequencer(_soak_steps(), table, imu, world.clock, [], OPTIONS)


def test_a_thermal_plan_value_checks():
    with pytest.raises(Exception, match="one temperature at least"):
        ThermalPlan(())
    plan = compile_thermal_plan(None, parse_config(SIM_CONFIG_TOML).plan.rotations, parse_config(SIM_CONFIG_TOML).plan,
                                ThermalPlan((10.0, 30.0)))
    assert [s.kind for s in plan.steps[:2]] == ["set_temperature", "soak"]


@pytest.mark.slow
def test_resume_skips_the_chamber_steps_of_a_temperature_whose_units_are_all_done(world_with_chamber):
    world, table, imu, chamber = world_with_chamber(30.0)
    listener = Listener()
    steps = _with_a_dwell(_soak_steps())
    seq = Sequencer(steps, table, imu, world.clock, [listener], OPTIONS, completed_units={"T1-P01"}, chamber=chamber)
    assert seq.run() is RunState.DONE
    assert [e.step_unit for e in listener.events if e.kind == "step_skipped"] == ["T1", "T1", "T1-P01"]
    assert not any(e.to_dict()["data"].get("soak") for e in listener.events)
    # a block with a unit left is soaked again (its chamber steps run)
    world2, table2, imu2, chamber2 = world_with_chamber(30.0)
    listener2 = Listener()
    seq2 = Sequencer(steps, table2, imu2, world2.clock, [listener2], OPTIONS, completed_units={"T9-P01"},
                     chamber=chamber2)
    assert seq2.run() is RunState.DONE
    assert any(e.to_dict()["data"].get("soak") == "done" for e in listener2.events)


@pytest.mark.slow
def test_a_pause_holds_the_chamber_and_an_alarm_raised_meanwhile_ends_the_run_while_paused(world_with_chamber):
    """The simulated clock stands still while paused, yet the chamber is still polled (on the wall clock too):
    an alarm raised during the pause ends the run then, without waiting for a resume (before, only after it)."""
    world, table, imu, chamber = world_with_chamber(30.0)
    listener = Listener()
    seq = Sequencer(_with_a_dwell(_soak_steps(stable_s=60.0)), table, imu, world.clock, [listener],
                    dataclasses.replace(OPTIONS, chamber_poll_s=0.5), chamber=chamber)
    paused = []
    guard = threading.Timer(20.0, seq.abort, ("the alarm was not seen while paused",))   # bounds a failing test

    def on_transition():
        state = listener.events[-1].state
        if state == "paused" and not paused:
            paused.append(world.chamber.state())
            world.chamber.trip_alarm(ChamberAlarms.EQUIPMENT_FAULT)
            guard.start()

    listener.hooks[("step_finished", "T1")] = lambda: seq.pause() if listener.events[-1].step_kind == "soak" \
        else None
    listener.hooks[("transition", None)] = on_transition
    try:
        assert seq.run() is RunState.FAILED and isinstance(seq.error, ChamberAlarm), seq.error
    finally:
        guard.cancel()
    assert paused and paused[0].setpoint_c == 40.0 and paused[0].running      # the pause kept the chamber at it
    assert [e.state for e in listener.events if e.kind == "transition"] == ["running", "paused", "aborting", "failed"]
    assert "equipment fault" in str(seq.error)
    assert not world.chamber.state().running and not any(a.enabled for a in table.read_state().axes)
