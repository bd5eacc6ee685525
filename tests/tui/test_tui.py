"""The lab-operator TUI (bench/tui): buffer logic, pilot tests against the simulator, snapshots.

Pilot tests drive the real app (`App.run_test`, 100x30) against a simulated bench (the
short test plan of tests/helpers/run.py): every wait is bounded. pytest-asyncio is not
installed: each test runs its coroutine with `asyncio.run`. Snapshot tests render
states fed straight into the UI buffer (no wall-clock text, no run ids), so they are
deterministic; the SVGs live in tests/__snapshots__/test_tui/.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from bench.log.events import RunState, make_event
from bench.log.reader import read_log
from bench.run.runner import compile_from_config
from bench.tui.buffer import (
    ImuScales,
    StepState,
    UiBuffer,
    progress,
)
from drivers.imu import ImuSampleBlock
from drivers.turntable import AxisMode, AxisState, AxisStatus, TableState
from tests.helpers.run import assert_disabled
from tests.helpers.tui import (
    SIZE,
    connected,
    dialog_open,
    events_text,
    feed_result,
    feed_running,
    make_app,
    make_config,
    press,
    run,
    snap,
    start_plan,
    submit,
    wait_ended,
    wait_until,
)

# -- the buffer (no Textual) -------------------------------------------------------------------

def _block(counter0: int, n: int, gyro: float, acc: float, rate_hz: float = 50.0) -> ImuSampleBlock:
    counter = np.arange(counter0, counter0 + n, dtype=np.int64)
    g = np.full((n, 3), gyro / rate_hz)
    a = np.full((n, 3), acc / rate_hz)
    return ImuSampleBlock(counter, counter / rate_hz, g, a, np.full(n, 25.0), np.zeros(n, np.int64), rate_hz)


#: No status bits set: the default of _state().
NO_STATUS = AxisStatus(0)


def _state(t: float, angles=(0.0, 0.0, 0.0), status=NO_STATUS, mode=AxisMode.OFF) -> TableState:
    return TableState(t, tuple(AxisState(a, 0.0, mode, status) for a in angles))


def test_buffer_step_states_progress_and_countdown(tmp_path):
    plan = compile_from_config(make_config(tmp_path))
    steps = plan.steps
    buf = UiBuffer(steps)
    dwell = next(s for s in steps if s.kind == "dwell")
    buf.on_event(make_event(0.0, "transition", "run started", state="running", data={"from": "idle"}))
    for s in steps[:dwell.index]:
        buf.on_event(make_event(1.0, "step_started", "", step_index=s.index, step_unit=s.unit))
        buf.on_event(make_event(2.0, "step_finished", "", step_index=s.index, step_unit=s.unit))
    buf.on_event(make_event(10.0, "step_started", "", step_index=dwell.index, step_unit=dwell.unit))
    buf.on_table_state(_state(11.0))
    s = buf.snapshot()
    assert s.run_state is RunState.RUNNING
    assert s.step_states[:dwell.index] == (StepState.DONE,) * dwell.index
    assert s.step_states[dwell.index] == StepState.RUNNING and s.step_states[dwell.index + 1] == StepState.PENDING
    p = progress(s, steps)
    assert p.step_left_s == pytest.approx(dwell.estimated_s - 1.0)
    done = sum(x.estimated_s for x in steps[:dwell.index]) + 1.0
    assert p.fraction == pytest.approx(done / plan.estimated_total_s)
    assert p.remaining_s == pytest.approx(plan.estimated_total_s - done)
    buf.on_event(make_event(12.0, "fault", "TurntableLimitError", step_index=dwell.index, step_unit=dwell.unit))
    buf.on_event(make_event(12.0, "transition", "stop", state="aborting", data={"from": "running"}))
    buf.on_event(make_event(13.0, "transition", "ended", state="failed", data={"from": "aborting"}))
    s = buf.snapshot()
    assert s.run_state is RunState.FAILED and s.step_states[dwell.index] == StepState.FAILED
    assert s.current_step is None and s.event_count == 2 * dwell.index + 5
    assert [e.kind for e in buf.events_after(s.event_count - 2)] == ["transition", "transition"]
    buf.begin_run(steps)
    assert set(buf.snapshot().step_states) == {StepState.PENDING}


def test_buffer_tells_an_aborted_run_from_a_failed_one(tmp_path):
    """The sequencer ends both in `failed`; a fault event comes before the failure it was not asked for,
    none before a requested abort (operator, e-stop, quit): the TUI says `aborted` for those (issue 19)."""
    steps = compile_from_config(make_config(tmp_path)).steps
    for fault, shown, step_shown in ((False, "aborted", StepState.ABORTED), (True, "failed", StepState.FAILED)):
        buf = UiBuffer(steps)
        buf.on_event(make_event(0.0, "transition", "run started", state="running", data={"from": "idle"}))
        buf.on_event(make_event(1.0, "step_started", "", step_index=0, step_unit=steps[0].unit))
        if fault:
            buf.on_event(make_event(2.0, "fault", "TurntableLimitError: limit", step_index=0, step_unit=steps[0].unit))
        buf.on_event(make_event(2.0, "transition", "aborted by the operator", state="aborting",
                                data={"from": "running"}))
        buf.on_event(make_event(3.0, "transition", "run ended early", state="failed", data={"from": "aborting"}))
        s = buf.snapshot()
        assert s.run_state is RunState.FAILED and s.run_state_text == shown and s.step_states[0] == step_shown
        buf.begin_run(steps)
        assert buf.snapshot().run_state_text == "idle" and not buf.snapshot().aborted


def test_buffer_keeps_the_last_samples_per_channel():
    buf = UiBuffer(history=8)
    buf.on_imu(_block(0, 5, 100.0, 200.0))
    s = buf.snapshot()
    assert [len(h) for h in s.imu.history] == [5] * 6 and s.imu.samples == 5
    buf.on_imu(_block(5, 20, 300.0, 400.0))
    s = buf.snapshot()
    assert s.imu.history[0] == (300.0,) * 8 and s.imu.history[5] == (400.0,) * 8
    # the mean over the last second (50 samples at 50 Hz): both blocks, 25 samples
    assert s.imu.gyro_cps == pytest.approx(((5 * 100.0 + 20 * 300.0) / 25,) * 3) and s.imu.mean_s == 0.5
    assert s.imu.last_counter == 24 and s.imu.samples == 25
    assert s.imu.rate_hz == 50.0 and s.imu.temperature_c == 25.0
    buf.on_imu(_block(25, 0, 1.0, 1.0))            # an empty block changes nothing
    assert buf.snapshot().imu.samples == 25
    with pytest.raises(ValueError, match="history"):
        UiBuffer(history=1)


def test_buffer_concurrent_writers_and_reader():
    buf = UiBuffer(history=50)
    stop = threading.Event()

    def writer():
        k = 0
        while not stop.is_set() and k < 2000:
            buf.on_imu(_block(k * 10, 10, float(k), float(k)))
            buf.on_table_state(_state(float(k)))
            k += 1

    threads = [threading.Thread(target=writer) for _ in range(2)]
    for t in threads:
        t.start()
    for _ in range(200):
        s = buf.snapshot()
        assert all(len(h) == len(s.imu.history[0]) for h in s.imu.history)
    stop.set()
    for t in threads:
        t.join(10)
    assert buf.snapshot().table_states > 0


def test_event_log_shows_an_event_added_between_snapshot_and_draw_once(tmp_path):
    """The sequencer's thread may add an event after the UI took its snapshot and before it fetched the
    new events: the event log showed that event twice ("P01 move done" twice; issue 19)."""
    async def body():
        app = make_app(tmp_path, auto_connect=False, refresh_hz=1.0)
        async with app.run_test(size=SIZE) as pilot:
            buf = app.buffer
            real_snapshot = buf.snapshot
            late = [make_event(1.0, "step_finished", "P01 move done in 0.0 s", step_index=0, step_unit="P01")]

            def snapshot_then_an_event():
                s = real_snapshot()
                if late:
                    buf.on_event(late.pop())         # what the run's thread does between the two calls
                return s
            buf.snapshot = snapshot_then_an_event
            buf.on_event(make_event(0.0, "transition", "run started: 3 steps", state="running", data={"from": "idle"}))
            for _ in range(3):
                app.refresh_panels()
                await pilot.pause(0.05)
            assert events_text(app).count("P01 move done") == 1, events_text(app)
            assert events_text(app).count("run started") == 1
    run(body)


def test_event_log_times_count_from_the_run_start_not_the_machines_uptime(tmp_path):
    """A hardware run's clock is the monotonic clock: its event lines said [0:53:50] (issue 14, item 3). A line
    outside a run carries the local time (issue 33: timed from the session's first line, it went back when the
    run started)."""
    import time

    wall_s = 1_795_773_600.0

    async def body():
        app = make_app(tmp_path, auto_connect=False, refresh_hz=1.0, wall_clock=lambda: wall_s)
        async with app.run_test(size=SIZE) as pilot:
            buf = app.buffer
            buf.on_event(make_event(3230.0, "info", "connected (scpi at tcp://lab:5025)"))
            buf.on_event(make_event(3290.0, "transition", "run started: 3 steps", state="running",
                                    data={"from": "idle"}))
            buf.on_event(make_event(3305.0, "transition", "paused", state="paused", data={"from": "running"}))
            buf.on_event(make_event(3320.0, "transition", "resumed", state="running", data={"from": "paused"}))
            buf.on_event(make_event(3351.0, "step_finished", "P01 move done in 2.0 s", step_index=0, step_unit="P01"))
            app.refresh_panels()
            await pilot.pause(0.05)
            text = events_text(app)
            for line in (f"[{time.strftime('%H:%M:%S', time.localtime(wall_s))}] info: connected",
                         "[+0:00:00] transition: run started", "[+0:00:15] transition: paused",
                         "[+0:00:30] transition: resumed", "[+0:01:01] step_finished: P01 move done"):
                assert line in text, text
    run(body)


def test_imu_values_are_means_over_the_last_second_of_whole_blocks():
    """The panel showed the mean of the last block (0.1 s at idle): whole-count increments then move it in
    steps of 1 count / 0.1 s, about 1 deg/h. It now shows the mean over the last whole blocks covering 1 s."""
    buf = UiBuffer()
    rate_hz = 50.0
    for k in range(20):                                  # 0.1 s blocks: 5 samples of 10 or 11 counts/s
        buf.on_imu(_block(5 * k, 5, 10.0 + (k % 2), 0.0, rate_hz))
    s = buf.snapshot()
    assert s.imu.mean_s == pytest.approx(1.0)            # the last 10 blocks
    assert s.imu.gyro_cps == pytest.approx((10.5,) * 3)
    buf.on_imu(_block(100, 75, 20.0, 0.0, rate_hz))      # one block longer than the window: that block alone
    assert buf.snapshot().imu.mean_s == pytest.approx(1.5) and buf.snapshot().imu.gyro_cps == pytest.approx((20.0,) * 3)


def test_imu_panel_shows_the_decimals_the_data_resolve(tmp_path):
    """The simulated IMU counts whole pulses (quantisation on in the built-in --sim bench): a 1 s mean resolves
    1 count/s, 0.1 deg/h at 36000 counts/s per deg/s; the panel showed 3 decimals of deg/h (issue 19)."""
    import re

    from bench.config.load import default_sim_config

    config = default_sim_config()
    scales = ImuScales.from_config(config, sim=True)
    assert config.sim.noise.quantise and scales.step_counts == (1.0, 1.0)
    kg = scales.gyro_cps_per_dps[0]
    assert scales.decimals(True, 3600.0 / kg, 3) == 1           # 1/36000 deg/s = 0.1 deg/h
    assert scales.decimals(True, 1.0 / kg, 5) == 5              # 2.8e-5 deg/s
    assert scales.decimals(False, 1.0 / scales.acc_cps_per_g[0], 6) == 5      # 2.5e-5 g
    fine = ImuScales.from_config(make_config(tmp_path), sim=True)      # noise off: the DBC's 1/256 count steps
    assert fine.step_counts == (1.0 / 256, 1.0 / 256) and fine.decimals(True, 3600.0 / kg, 3) == 3
    raw = ImuScales.from_config(config, sim=False)
    assert raw.step_counts == (1.0 / 256, 1.0 / 256) and raw.decimals(True, 1.0, 3) == 3   # the DBC's resolution

    async def body():
        app = make_app(tmp_path, config=config)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            await wait_until(pilot, lambda: snap(app).imu.mean_s >= 1.0, "a second of IMU data")
            await pilot.pause(0.15)
            imu = app.query_one("#imu-panel").plain
            for ch in ("gx", "gy", "gz"):
                line = next(x for x in imu.splitlines() if x.startswith(ch))
                assert re.fullmatch(rf"{ch} +-?\d+\.\d{{5}} +-?\d+\.\d", line), line
            for ch in ("ax", "ay", "az"):
                line = next(x for x in imu.splitlines() if x.startswith(ch))
                assert re.fullmatch(rf"{ch} +-?\d+\.\d{{5}} g", line), line
            assert "IMU: means over 1 s" in imu
    run(body)


def test_imu_scales_are_the_sim_truth_or_raw(tmp_path):
    config = make_config(tmp_path)
    sim = ImuScales.from_config(config, sim=True)
    assert sim.gyro_cps_per_dps == pytest.approx((36000.0,) * 3, rel=1e-2)
    assert sim.acc_cps_per_g == pytest.approx((40000.0,) * 3, rel=1e-2)
    assert sim.source == "deg/s deg/h g (the simulator's scale)"      # it said "sim truth" (issue 33)
    raw = ImuScales.from_config(config, sim=False)
    assert raw.gyro_cps_per_dps is None and raw.source == "counts/s (no scale factors known)"


# -- pilot tests against the simulator -----------------------------------------------------------

@pytest.mark.slow
def test_connect_shows_table_and_imu_then_go_to_position(tmp_path):
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            table = app.query_one("#table-panel").plain
            assert "link: connected (scpi, simulator)" in table and "outer  0.0000  0.0000  off  off" in table, table
            imu = app.query_one("#imu-panel").plain
            assert "50 Hz" in imu and "lost 0  bad frames 0" in imu and "deg/h" in imu, imu
            az = float(imu.split("az")[1].split()[0])
            assert abs(abs(az) - 1.0) < 0.01, imu         # one axis senses gravity, in g
            await press(pilot, "g")
            dialog = await dialog_open(pilot, "GotoScreen", "#goto-inner")
            dialog.query_one("#goto-middle").value = "abc"
            await submit(pilot, dialog)
            await wait_until(pilot, lambda: "not a number" in str(dialog.query_one("#goto-error").render()),
                             "the not-a-number message")
            dialog.query_one("#goto-middle").value = "nan"
            await submit(pilot, dialog)
            await wait_until(pilot, lambda: "finite" in str(dialog.query_one("#goto-error").render()),
                             "the must-be-finite message")
            assert app.screen is dialog                     # an invalid entry keeps the dialog open
            dialog.query_one("#goto-outer").value = "10"
            dialog.query_one("#goto-middle").value = "-20"
            dialog.query_one("#goto-inner").value = "5.5"
            await submit(pilot, dialog)
            await wait_until(pilot, lambda: type(app.screen).__name__ != "GotoScreen", "the dialog to close")

            def arrived():
                s = snap(app).table_state
                return s is not None and all(abs(a - t) < 1e-3 and ax.in_position for a, t, ax in
                                             zip(s.angles_deg, (10.0, -20.0, 5.5), s.axes))
            await wait_until(pilot, arrived, "the table to reach the position")
            await pilot.pause(0.15)
            assert "outer  10.0000" in app.query_one("#table-panel").plain
            # the event-log panel is redrawn at 20 Hz: it may show the event a refresh later
            await wait_until(pilot, lambda: "moving to 10, -20, 5.5 deg" in events_text(app), "the event log")
            controller = app.session.run.world.controller
        assert_disabled(controller, at_rest=True)           # leaving the app stops the table, servos off
    run(body)


@pytest.mark.slow
def test_start_pause_resume_abort_ends_stopped(tmp_path):
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            await press(pilot, "s")
            await dialog_open(pilot, "ConfirmScreen", "#no")
            await press(pilot, "n")                          # cancelled: nothing starts
            await pilot.pause(0.2)
            assert not app.session.running and snap(app).run_state is RunState.IDLE
            await start_plan(pilot)
            await wait_until(pilot, lambda: snap(app).step_states.count(StepState.DONE) >= 2, "two steps done")
            await press(pilot, "p")
            await wait_until(pilot, lambda: snap(app).run_state is RunState.PAUSED, "the pause")
            done = snap(app).step_states.count(StepState.DONE)
            await pilot.pause(0.3)
            assert snap(app).step_states.count(StepState.DONE) == done     # paused: no progress
            assert snap(app).current_step is None
            await pilot.pause(0.1)
            assert "run paused" in app.query_one("#plan-panel").plain
            await press(pilot, "r")
            await wait_until(pilot, lambda: snap(app).step_states.count(StepState.DONE) > done, "progress after resume")
            # Paused again: what follows acts on a run that cannot end under it, however fast the simulator runs
            # (the run used to finish between the keys of an abort on a loaded machine).
            await press(pilot, "p")
            await wait_until(pilot, lambda: snap(app).run_state is RunState.PAUSED, "the second pause")
            for key in ("v", "right_square_bracket", "g", "h"):   # manual commands are refused during a run
                await press(pilot, key)
            assert len(app.screen_stack) == 1
            await wait_until(pilot, lambda: events_text(app).count("refused: a run is active") == 4,
                             "four refusals")
            await press(pilot, "a")                          # abort asks first (issue 19): no keeps the run
            dialog = await dialog_open(pilot, "ConfirmScreen", "#no")
            assert "Abort the run?" in str(dialog.query_one(".title").render())
            await press(pilot, "n")
            await wait_until(pilot, lambda: len(app.screen_stack) == 1, "the dialog to close")
            await pilot.pause(0.2)
            assert app.session.running and snap(app).run_state is RunState.PAUSED     # not aborted
            await press(pilot, "a")
            await dialog_open(pilot, "ConfirmScreen", "#no")
            await press(pilot, "y")
            await wait_ended(pilot)
            s = snap(app)
            assert s.run_state is RunState.FAILED and StepState.PENDING in s.step_states
            # (the step under way, if the abort came within one rather than at a step boundary, reads aborted)
            assert s.run_state_text == "aborted" and StepState.FAILED not in s.step_states, s.step_states
            assert set(s.step_states) <= {StepState.DONE, StepState.PENDING, StepState.ABORTED}
            await wait_until(pilot, lambda: "run aborted" in app.query_one("#plan-panel").plain, "the plan panel")
            assert "run failed" not in app.query_one("#plan-panel").plain
            log = events_text(app)
            assert "aborted by the operator" in log and "table stopped and servos off" in log
            assert s.outcome_text.startswith("aborted: aborted by the operator; table stopped. Log: "), s.outcome_text
            controller = app.session.run.world.controller
            assert_disabled(controller, at_rest=True)
            assert "servo" in app.query_one("#table-panel").plain and " on " not in app.query_one("#table-panel").plain
    run(body)


@pytest.mark.slow
def test_estop_from_the_main_screen_during_a_run(tmp_path):
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            await start_plan(pilot)
            await wait_until(pilot, lambda: snap(app).step_states.count(StepState.DONE) >= 1, "a step done")
            await press(pilot, "f12")                        # never asks (issue 19: `a` asks, F12 does not)
            assert len(app.screen_stack) == 1
            await wait_ended(pilot)
            assert len(app.screen_stack) == 1
            assert snap(app).run_state is RunState.FAILED and snap(app).run_state_text == "aborted"
            assert_disabled(app.session.run.world.controller, at_rest=False)
            log = events_text(app)
            assert "EMERGENCY STOP" in log and "servos off" in log
    run(body)


@pytest.mark.slow
@pytest.mark.parametrize("dialog_key, dialog", [("g", "GotoScreen"), ("question_mark", "HelpScreen"),
                                                ("s", "ConfirmScreen")])
def test_estop_from_an_open_dialog(tmp_path, dialog_key, dialog):
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            app.session.enable().join(5)                    # servos on: the e-stop must switch them off
            await wait_until(pilot, lambda: all(a.enabled for a in snap(app).table_state.axes), "servos on")
            await press(pilot, dialog_key)
            await dialog_open(pilot, dialog, "Button" if dialog != "HelpScreen" else "#help-text")
            await press(pilot, "f12")
            await wait_until(pilot, lambda: len(app.screen_stack) == 1, "the dialog to close")
            await wait_until(pilot, lambda: not any(a.enabled for a in snap(app).table_state.axes), "servos off")
            assert_disabled(app.session.run.world.controller, at_rest=False)
            # the event-log panel is redrawn at 20 Hz: it may show the event a refresh later
            await wait_until(pilot, lambda: "EMERGENCY STOP" in events_text(app), "the event log")
            assert not app.session.running                   # the confirmation never started the plan
    run(body)


@pytest.mark.slow
def test_a_limit_fault_mid_run_shows_in_the_table_panel_and_the_log(tmp_path):
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            await start_plan(pilot)
            await wait_until(pilot, lambda: (snap(app).current_step or 0) >= 3, "step 4 under way")
            app.session.run.world.controller.trip_limit(1)
            await wait_ended(pilot)
            assert snap(app).run_state is RunState.FAILED and StepState.FAILED in snap(app).step_states
            table = app.query_one("#table-panel").plain
            assert "FAULT" in table and "middle: limit" in table, table
            # the event-log panel is redrawn at 20 Hz: it may show the event a refresh later
            await wait_until(pilot, lambda: ("fault: TurntableLimitError" in events_text(app)
                                             or "fault: Turntable" in events_text(app)), "the event log")
            assert_disabled(app.session.run.world.controller, at_rest=False)
    run(body)


@pytest.mark.slow
def test_quit_while_running_asks_then_stops_the_table(tmp_path):
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            await start_plan(pilot)
            await press(pilot, "q")
            await dialog_open(pilot, "ConfirmScreen", "#no")
            await press(pilot, "n")
            await pilot.pause(0.1)
            assert app.is_running and app.session.running
            controller = app.session.run.world.controller
            await press(pilot, "q")
            await dialog_open(pilot, "ConfirmScreen", "#no")
            await press(pilot, "y")
            await wait_until(pilot, lambda: not app.is_running, "the app to exit")
        assert not app.session.running and app.session.run is None
        assert_disabled(controller, at_rest=True)
    run(body)


# -- snapshots (deterministic: states fed into the buffer) -------------------------------------------

#: the snapshots' session clocks stand still: the IMU values never turn stale while one is taken, and a line
#: outside a run would carry this wall-clock time
SNAPSHOT_CLOCKS = dict(clock=lambda: 0.0, wall_clock=lambda: 1_795_773_600.0)


def _snapshot_app(tmp_path):
    return make_app(tmp_path, auto_connect=False, refresh_hz=10.0, **SNAPSHOT_CLOCKS)


@pytest.mark.slow
def test_snapshot_idle(tmp_path, snap_compare):
    assert snap_compare(_snapshot_app(tmp_path), terminal_size=SIZE)


@pytest.mark.slow
def test_snapshot_running(tmp_path, snap_compare):
    async def before(pilot):
        feed_running(pilot.app)
        pilot.app.refresh_panels()
        await pilot.pause(0.2)
    assert snap_compare(_snapshot_app(tmp_path), terminal_size=SIZE, run_before=before)


@pytest.mark.slow
def test_snapshot_results(tmp_path, snap_compare):
    async def before(pilot):
        app = pilot.app
        feed_running(app)
        feed_result(app)
        app.refresh_panels()
        await pilot.pause(0.2)
    assert snap_compare(_snapshot_app(tmp_path), terminal_size=SIZE, run_before=before)


def test_cli_needs_config_or_sim(tmp_path):
    from tests.helpers.run import cli

    rc, _, err = cli(["tui"])
    assert rc == 2 and "--config FILE, --sim or --replay LOG" in err
    rc, _, err = cli(["tui", "--config", str(tmp_path / "missing.toml")])
    assert rc == 2 and "missing.toml" in err
    rc, _, err = cli(["tui", "--replay", str(tmp_path / "missing.mcap")])
    assert rc == 2 and "missing.mcap" in err
    rc, _, err = cli(["tui", "--replay", str(tmp_path / "x.mcap"), "--sim"])
    assert rc == 2 and "drop --config/--sim" in err
    with pytest.raises(SystemExit):
        cli(["tui", "--replay", "x.mcap", "--speed", "0"])


# -- connect / enable keys, rate mode, jog, theme --------------------------------------------------


@pytest.mark.slow
def test_snapshot_running_light_theme(tmp_path, snap_compare):
    async def before(pilot):
        feed_running(pilot.app)
        pilot.app.buffer.note("warning", "a warning line")
        pilot.app.buffer.note("fault", "a fault line")
        pilot.app.refresh_panels()
        await pilot.pause(0.2)
    app = make_app(tmp_path, auto_connect=False, refresh_hz=10.0, theme="textual-light", **SNAPSHOT_CLOCKS)
    assert snap_compare(app, terminal_size=SIZE, run_before=before)


# -- replay: a recorded run, no hardware ------------------------------------------------------------


# -- the run's log starts with the plan (issue 19) ---------------------------------------------------

@pytest.mark.slow
def test_connecting_writes_no_log_a_manual_move_and_a_plan_each_write_theirs(tmp_path):
    """Every session wrote an .mcap at connect, even when nothing was run. Now connecting writes nothing, the
    first manual move starts a log of manual moves, a plan closes it and writes its own log, and a manual move
    after the plan starts a new log of manual moves (tests/tui/test_tui_manual_log.py: its contents)."""
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            assert list(tmp_path.glob("*.mcap")) == []
            app.session.go_to((5.0, 0.0, 0.0)).join(10)
            await wait_until(pilot, lambda: abs(snap(app).table_state.angles_deg[0] - 5.0) < 1e-3
                             and snap(app).table_state.axes[0].in_position, "the manual move")
            [manual] = list(tmp_path.glob("*.mcap"))
            assert manual.name.endswith("-manual.mcap") and app.session.manual_logs == [manual]
            await start_plan(pilot)
            log = app.session.run.log_path
            assert sorted(tmp_path.glob("*.mcap")) == sorted([manual, log])
            await wait_until(pilot, lambda: f"info: log {log}" in events_text(app), "the log's name in the events")
            await press(pilot, "a")
            await dialog_open(pilot, "ConfirmScreen", "#no")
            await press(pilot, "y")
            await wait_ended(pilot)
            closing = [e for e in read_log(str(manual)).events if e.message.startswith("manual log closed")]
            assert [e.message for e in closing] == [f"manual log closed: a plan starts; it writes its own log, "
                                                    f"{log.name}"]
            app.session.enable().join(10)
            await wait_until(pilot, lambda: all(a.enabled for a in snap(app).table_state.axes), "servos on")
            await press(pilot, "right_square_bracket")          # a jog after the plan: a new log of manual moves
            await wait_until(pilot, lambda: len(app.session.manual_logs) == 2, "the second log of manual moves")
        assert sorted(tmp_path.glob("*.mcap")) == sorted([manual, log, app.session.manual_logs[1]])
        assert app.session.last_end.log_path == log
        assert len(read_log(str(log)).events) > 0 and read_log(str(log)).metadata["run"]["kind"] == "calibration"
    run(body)


def test_a_session_that_runs_nothing_leaves_no_file(tmp_path):
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            await press(pilot, "d")
            await wait_until(pilot, lambda: app.session.run is None, "the disconnect")
            await press(pilot, "c")
            await connected(pilot)
    run(body)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_a_plan_whose_log_cannot_be_written_does_not_move_the_table(tmp_path):
    """The output folder is checked again when the plan starts: gone since the connect (a file in its place,
    which stops root too), the start is refused and nothing moves."""
    import shutil

    out = tmp_path / "out"

    async def body():
        app = make_app(tmp_path, out_dir=out)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            controller = app.session.run.world.controller
            shutil.rmtree(out)
            out.write_text("not a folder\n", encoding="utf-8")
            await press(pilot, "s")
            await dialog_open(pilot, "ConfirmScreen", "#no")
            await press(pilot, "y")
            await wait_until(pilot, lambda: "refused: cannot start the run's log: output folder" in events_text(app),
                             "the refusal")
            assert "nothing moved" in events_text(app)
            assert not app.session.running and snap(app).run_state is RunState.IDLE
            state = controller.state()
            assert not any(a.enabled for a in state.axes) and state.angles_deg == (0.0, 0.0, 0.0)
            assert app.session.last_end is None
    run(body)
