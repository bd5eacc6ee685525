"""The TUI's chamber and soak panel (issue 18 item 4: "the TUI shows the chamber and soak progress").

A thermal plan's screen has a Chamber panel above the event log: which temperature of how
many, the chamber air against its setpoint, run/stop and alarms, the IMU's temperature, its
rate against the soak criterion and the time it has been steady against the time required,
all from the sequencer's listener calls (chamber states, the soak's own checks). One test
feeds the buffer (deterministic); one drives a short soak of the simulated chamber live.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.config.load import parse_config
from bench.log.events import RunState, SoakStatus, make_event
from drivers.chamber import ChamberAlarms, ChamberState
from drivers.imu import ImuSampleBlock
from tests.helpers.run import thermal_plan_text
from tests.helpers.tui import SIZE, press, run, snap, start_plan, wait_ended, wait_until

THERMAL = """
[plan.soak]
rate_c_per_min = 0.1
stable_min = 1.0
rate_window_s = 30.0

[chamber]
url = "sim"
dialect = "ascii"
poll_s = 2.0
safe_setpoint_c = 23.0

[sim.imu.thermal]
time_constant_s = 30.0
Kg_x = [0.36]
"""


def _app(tmp_path, temperatures="[30.0, 40.0]"):
    from bench.tui import create_app

    text = thermal_plan_text(temperatures, THERMAL)
    config = parse_config(text, source=str(tmp_path / "bench.toml"), base_dir=tmp_path)
    return create_app(config=config, sim=True, out_dir=tmp_path, refresh_hz=20.0, poll_s=0.05,
                      auto_connect=False)


def _imu(temperature_c: float) -> ImuSampleBlock:
    n = 10
    k = np.arange(n)
    return ImuSampleBlock(k.astype(np.int64), k / 50.0, np.zeros((n, 3)), np.zeros((n, 3)),
                          np.full(n, temperature_c), np.zeros(n, np.int64), 50.0)


def test_the_panel_shows_the_temperature_step_chamber_imu_rate_and_soak_time(tmp_path):
    async def body():
        app = _app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            panel = app.query_one("#chamber-panel")
            buf, steps = app.buffer, app.steps
            second_set = next(s for s in steps if s.kind == "set_temperature" and s.temperature_index == 2)
            soak = next(s for s in steps if s.kind == "soak" and s.temperature_index == 2)
            buf.on_event(make_event(0.0, "transition", "run started", state="running", data={"from": "idle"}))
            for s in steps[:soak.index]:
                buf.on_event(make_event(1.0, "step_started", s.kind, step_index=s.index, step_unit=s.unit))
                buf.on_event(make_event(2.0, "step_finished", s.kind, step_index=s.index, step_unit=s.unit))
            buf.on_event(make_event(100.0, "step_started", "T2 soak", step_index=soak.index, step_unit=soak.unit))
            buf.on_chamber_state(ChamberState(130.0, 39.6, 40.0, 0.0, True))
            buf.on_imu(_imu(37.25))
            buf.on_soak_status(SoakStatus(130.0, 37.25, 0.84, 39.6, True, 0.0, False))
            app.refresh_panels()
            await pilot.pause(0.1)
            lines = panel.plain.splitlines()
            assert lines[0] == "temperature 2/2 40 degC" and second_set.index < soak.index
            assert lines[1:4] == ["air 39.6  set 40.0 degC", "running, alarms: none", "IMU 37.25 degC"]
            assert lines[4] == "rate 0.840 degC/min (< 0.1)"
            assert lines[5] == "steady 0:00:00 / 0:01:00" and lines[6] == "soaking 0:00:30 (max 4:00:00)"
            # steady for 45 s of the 60 required, then done; an alarm shows in the panel
            buf.on_soak_status(SoakStatus(400.0, 39.98, 0.02, 40.0, True, 45.0, False))
            buf.on_chamber_state(ChamberState(400.0, 40.0, 40.0, 0.0, True, ChamberAlarms.DOOR_OPEN))
            app.refresh_panels()
            await pilot.pause(0.1)
            assert "rate 0.020 degC/min (< 0.1)" in panel.plain and "steady 0:00:45 / 0:01:00" in panel.plain
            assert "running, ALARM: door open" in panel.plain and "soaking 0:05:00" in panel.plain
            buf.on_soak_status(SoakStatus(415.0, 39.99, 0.01, 40.0, True, 60.0, True))
            app.refresh_panels()
            await pilot.pause(0.1)
            assert "soaked: steady 0:01:00" in panel.plain
            # the panel fits the events column of a 100-column screen: no line wider than its content
            assert max(map(len, panel.plain.splitlines())) <= panel.content_region.width
    run(body)


def test_a_plan_without_temperatures_has_no_chamber_panel(tmp_path):
    from tests.helpers.tui import make_app

    async def body():
        app = make_app(tmp_path, auto_connect=False)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause(0.05)
            assert not app.query("#chamber-panel")
    run(body)


@pytest.mark.slow
def test_a_live_soak_on_the_simulator_fills_the_panel_from_the_sequencer(tmp_path):
    """The simulated chamber goes to 25 degC (from its 23 degC room); the panel follows the sequencer's own
    soak checks to the end of the soak (then the run is aborted: the calibration is not this test's)."""
    async def body():
        app = _app(tmp_path, "[25.0]")
        async with app.run_test(size=SIZE) as pilot:
            panel = app.query_one("#chamber-panel")
            await press(pilot, "c")
            await wait_until(pilot, lambda: app.session.connected, "the connection")
            await start_plan(pilot)
            await wait_until(pilot, lambda: "steady 0:00:" in panel.plain and "/ 0:01:00" in panel.plain,
                             "the soak's steady time", timeout_s=30.0)
            assert panel.plain.startswith("temperature 1/1 25 degC") and "set 25.0 degC" in panel.plain
            await wait_until(pilot, lambda: (snap(app).soak or {}).get("done"), "the soak to end", timeout_s=30.0)
            await pilot.pause(0.1)
            assert "soaked: steady 0:01:00" in panel.plain
            soak = snap(app).soak
            assert abs(soak["imu_temperature_c"] - 25.0) < 1.0 and abs(soak["rate_c_per_min"]) < 0.1
            app.session.abort()
            await wait_ended(pilot)
            assert snap(app).run_state is RunState.FAILED
    run(body)
