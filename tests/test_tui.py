"""The lab-operator TUI (bench/tui): buffer logic, pilot tests against the simulator, snapshots.

Pilot tests drive the real app (`App.run_test`, 100x30) against a simulated bench (the
short test plan of tests/run_helpers.py): every wait is bounded. pytest-asyncio is not
installed: each test runs its coroutine with `asyncio.run`. Snapshot tests render
states fed straight into the UI buffer (no wall-clock text, no run ids), so they are
deterministic; the SVGs live in tests/__snapshots__/test_tui/.
"""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from bench.config import parse_config
from bench.events import Event, RunState
from bench.result import CalibrationResult, coefficient_table
from bench.run_cli import compile_from_config
from bench.tui.buffer import STEP_DONE, STEP_FAILED, STEP_PENDING, STEP_RUNNING, ImuScales, UiBuffer, progress
from drivers.imu import ImuSampleBlock
from drivers.turntable import AxisMode, AxisState, AxisStatus, TableState
from run_helpers import assert_disabled, config_text

SIZE = (100, 30)


@pytest.fixture(autouse=True)
def no_leftover_threads():
    yield
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        left = [t.name for t in threading.enumerate() if t.name.startswith("bench-tui-")]
        if not left:
            return
        time.sleep(0.05)
    raise AssertionError(f"threads left running: {left}")


def make_config(tmp_path: Path, **kwargs):
    return parse_config(config_text(**kwargs), source=str(tmp_path / "bench.toml"), base_dir=tmp_path)


def make_app(tmp_path: Path, **kwargs):
    from bench.tui import create_app

    options = dict(config=make_config(tmp_path), sim=True, out_dir=tmp_path, refresh_hz=20.0, poll_s=0.05)
    options.update(kwargs)
    return create_app(**options)


async def wait_until(pilot, predicate, what: str, timeout_s: float = 15.0, period_s: float = 0.05):
    """Let the app run until `predicate()` is truthy (bounded in time and count)."""
    deadline = time.monotonic() + timeout_s
    for _ in range(int(timeout_s / period_s) + 1):
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            break
        await pilot.pause(period_s)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


async def press(pilot, key: str) -> None:
    """Send a key without waiting for the process to go idle: `Pilot.press` waits up to 2 s per
    key for that, and the simulator keeps the process busy."""
    pilot.app.simulate_key(key)
    await pilot.pause(0.05)


async def submit(pilot, dialog) -> None:
    """Enter in the go-to dialog's first field (what the Move button does)."""
    dialog.query_one("#goto-outer").focus()
    await press(pilot, "enter")


def run(coro_fn, *args):
    asyncio.run(coro_fn(*args))


def snap(app):
    return app.buffer.snapshot()


def events_text(app) -> str:
    return "\n".join(app.query_one("#event-log").plain_lines)


async def dialog_open(pilot, name: str, child: str):
    """Wait until dialog `name` is on top with its widgets mounted (`child` is one of them)."""
    app = pilot.app
    await wait_until(pilot, lambda: type(app.screen).__name__ == name and app.screen.query(child), f"the {name}")
    return app.screen


async def connected(pilot):
    app = pilot.app
    await wait_until(pilot, lambda: app.session.connected and snap(app).table_state is not None
                     and snap(app).imu.gyro_cps is not None, "connection and first table/IMU data")
    await pilot.pause(0.1)


async def start_plan(pilot):
    app = pilot.app
    await press(pilot, "s")
    await dialog_open(pilot, "ConfirmScreen", "#confirm-body")
    body = str(app.screen.query_one("#confirm-body").render())
    assert "ALL THREE AXES" in body and "steps" in body, body
    await press(pilot, "y")
    await wait_until(pilot, lambda: snap(app).run_state is RunState.RUNNING, "the run to start")


async def wait_ended(pilot):
    app = pilot.app
    await wait_until(pilot, lambda: not app.session.running, "the run to end", timeout_s=30.0)
    await pilot.pause(0.15)


# -- the buffer (no Textual) -------------------------------------------------------------------

def _block(counter0: int, n: int, gyro: float, acc: float, rate_hz: float = 50.0) -> ImuSampleBlock:
    counter = np.arange(counter0, counter0 + n, dtype=np.int64)
    g = np.full((n, 3), gyro / rate_hz)
    a = np.full((n, 3), acc / rate_hz)
    return ImuSampleBlock(counter, counter / rate_hz, g, a, np.full(n, 25.0), np.zeros(n, np.int64), rate_hz)


def _state(t: float, angles=(0.0, 0.0, 0.0), status=AxisStatus(0), mode=AxisMode.OFF) -> TableState:
    return TableState(t, tuple(AxisState(a, 0.0, mode, status) for a in angles))


def test_buffer_step_states_progress_and_countdown(tmp_path):
    plan = compile_from_config(make_config(tmp_path))
    steps = plan.steps
    buf = UiBuffer(steps)
    dwell = next(s for s in steps if s.kind == "dwell")
    buf.on_event(Event(0.0, "transition", "run started", state="running", data={"from": "idle"}))
    for s in steps[:dwell.index]:
        buf.on_event(Event(1.0, "step_started", "", step_index=s.index, step_unit=s.unit))
        buf.on_event(Event(2.0, "step_finished", "", step_index=s.index, step_unit=s.unit))
    buf.on_event(Event(10.0, "step_started", "", step_index=dwell.index, step_unit=dwell.unit))
    buf.on_table_state(_state(11.0))
    s = buf.snapshot()
    assert s.run_state is RunState.RUNNING
    assert s.step_states[:dwell.index] == (STEP_DONE,) * dwell.index
    assert s.step_states[dwell.index] == STEP_RUNNING and s.step_states[dwell.index + 1] == STEP_PENDING
    p = progress(s, steps)
    assert p.step_left_s == pytest.approx(dwell.estimated_s - 1.0)
    done = sum(x.estimated_s for x in steps[:dwell.index]) + 1.0
    assert p.fraction == pytest.approx(done / plan.estimated_total_s)
    assert p.remaining_s == pytest.approx(plan.estimated_total_s - done)
    buf.on_event(Event(12.0, "fault", "TurntableLimitError", step_index=dwell.index, step_unit=dwell.unit))
    buf.on_event(Event(12.0, "transition", "stop", state="aborting", data={"from": "running"}))
    buf.on_event(Event(13.0, "transition", "ended", state="failed", data={"from": "aborting"}))
    s = buf.snapshot()
    assert s.run_state is RunState.FAILED and s.step_states[dwell.index] == STEP_FAILED
    assert s.current_step is None and s.event_count == 2 * dwell.index + 5
    assert [e.kind for e in buf.events_after(s.event_count - 2)] == ["transition", "transition"]
    buf.begin_run(steps)
    assert set(buf.snapshot().step_states) == {STEP_PENDING}


def test_buffer_keeps_the_last_samples_per_channel():
    buf = UiBuffer(history=8)
    buf.on_imu(_block(0, 5, 100.0, 200.0))
    s = buf.snapshot()
    assert [len(h) for h in s.imu.history] == [5] * 6 and s.imu.samples == 5
    buf.on_imu(_block(5, 20, 300.0, 400.0))
    s = buf.snapshot()
    assert s.imu.history[0] == (300.0,) * 8 and s.imu.history[5] == (400.0,) * 8
    assert s.imu.gyro_cps == (300.0,) * 3 and s.imu.last_counter == 24 and s.imu.samples == 25
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


def test_imu_scales_are_the_sim_truth_or_raw(tmp_path):
    config = make_config(tmp_path)
    sim = ImuScales.from_config(config, sim=True)
    assert sim.gyro_cps_per_dps == pytest.approx((36000.0,) * 3, rel=1e-2)
    assert sim.acc_cps_per_g == pytest.approx((40000.0,) * 3, rel=1e-2)
    assert "sim truth" in sim.source
    raw = ImuScales.from_config(config, sim=False)
    assert raw.gyro_cps_per_dps is None and "raw counts/s" in raw.source


# -- pilot tests against the simulator -----------------------------------------------------------

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
            assert "moving to 10, -20, 5.5 deg" in events_text(app)
            controller = app.session.run.world.controller
        assert_disabled(controller, at_rest=True)           # leaving the app stops the table, servos off
    run(body)


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
            await wait_until(pilot, lambda: snap(app).step_states.count(STEP_DONE) >= 2, "two steps done")
            await press(pilot, "p")
            await wait_until(pilot, lambda: snap(app).run_state is RunState.PAUSED, "the pause")
            done = snap(app).step_states.count(STEP_DONE)
            await pilot.pause(0.3)
            assert snap(app).step_states.count(STEP_DONE) == done     # paused: no progress
            assert snap(app).current_step is None
            await pilot.pause(0.1)
            assert "run paused" in app.query_one("#plan-panel").plain
            await press(pilot, "r")
            await wait_until(pilot, lambda: snap(app).step_states.count(STEP_DONE) > done, "progress after resume")
            for key in ("v", "right_square_bracket", "g", "h"):   # manual commands are refused during a run
                await press(pilot, key)
            assert len(app.screen_stack) == 1
            await wait_until(pilot, lambda: events_text(app).count("refused: a run is active") == 4,
                             "four refusals")
            await press(pilot, "a")
            await wait_ended(pilot)
            s = snap(app)
            assert s.run_state is RunState.FAILED and STEP_PENDING in s.step_states
            assert "run failed" in app.query_one("#plan-panel").plain
            log = events_text(app)
            assert "aborted by the operator" in log and "table stopped and servos off" in log
            controller = app.session.run.world.controller
            assert_disabled(controller, at_rest=True)
            assert "servo" in app.query_one("#table-panel").plain and " on " not in app.query_one("#table-panel").plain
    run(body)


def test_estop_from_the_main_screen_during_a_run(tmp_path):
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            await start_plan(pilot)
            await wait_until(pilot, lambda: snap(app).step_states.count(STEP_DONE) >= 1, "a step done")
            await press(pilot, "f12")
            await wait_ended(pilot)
            assert snap(app).run_state is RunState.FAILED
            assert_disabled(app.session.run.world.controller, at_rest=False)
            log = events_text(app)
            assert "EMERGENCY STOP" in log and "servos off" in log
    run(body)


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
            await dialog_open(pilot, dialog, "Button")
            await press(pilot, "f12")
            await wait_until(pilot, lambda: len(app.screen_stack) == 1, "the dialog to close")
            await wait_until(pilot, lambda: not any(a.enabled for a in snap(app).table_state.axes), "servos off")
            assert_disabled(app.session.run.world.controller, at_rest=False)
            assert "EMERGENCY STOP" in events_text(app)
            assert not app.session.running                   # the confirmation never started the plan
    run(body)


def test_a_limit_fault_mid_run_shows_in_the_table_panel_and_the_log(tmp_path):
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            await start_plan(pilot)
            await wait_until(pilot, lambda: (snap(app).current_step or 0) >= 3, "step 4 under way")
            app.session.run.world.controller.trip_limit(1)
            await wait_ended(pilot)
            assert snap(app).run_state is RunState.FAILED and STEP_FAILED in snap(app).step_states
            table = app.query_one("#table-panel").plain
            assert "FAULT" in table and "middle: limit" in table, table
            assert "fault: TurntableLimitError" in events_text(app) or "fault: Turntable" in events_text(app)
            assert_disabled(app.session.run.world.controller, at_rest=False)
    run(body)


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

def _snapshot_app(tmp_path):
    return make_app(tmp_path, auto_connect=False, refresh_hz=10.0)


def test_snapshot_idle(tmp_path, snap_compare):
    assert snap_compare(_snapshot_app(tmp_path), terminal_size=SIZE)


def _feed_running(app) -> None:
    buf, steps = app.buffer, app.steps
    app.session.link, app.session.link_detail = "connected", "scpi, simulator"
    buf.on_event(Event(0.0, "transition", "run started: %d steps" % len(steps), state="running",
                       data={"from": "idle"}))
    t = 0.0
    dwell = [s for s in steps if s.kind == "dwell"][2]
    for s in steps[:dwell.index]:
        buf.on_event(Event(t, "step_started", f"{s.unit} {s.kind}", step_index=s.index, step_unit=s.unit))
        t += s.estimated_s
        buf.on_event(Event(t, "step_finished", f"{s.unit} {s.kind} done in {s.estimated_s:.1f} s",
                           step_index=s.index, step_unit=s.unit))
    buf.on_event(Event(t, "step_started", f"{dwell.unit} dwell", step_index=dwell.index, step_unit=dwell.unit))
    enabled = AxisStatus.ENABLED | AxisStatus.IN_POSITION
    buf.on_table_state(TableState(t + 1.0, tuple(AxisState(a, 0.0, AxisMode.POSITION, enabled)
                                                 for a in dwell.target_deg)))
    n = 40
    k = np.arange(n)
    g = (np.array([0.5, -0.25, 0.1]) * 36000.0)[None, :] + 50.0 * np.sin(k / 4.0)[:, None]
    a = (np.array([0.0, 0.0, 1.0]) * 40000.0)[None, :] + 20.0 * np.cos(k / 5.0)[:, None]
    block = ImuSampleBlock(k.astype(np.int64), k / 50.0, g / 50.0, a / 50.0, np.full(n, 24.5),
                           np.zeros(n, np.int64), 50.0)
    buf.on_imu(block)


def test_snapshot_running(tmp_path, snap_compare):
    async def before(pilot):
        _feed_running(pilot.app)
        pilot.app.refresh_panels()
        await pilot.pause(0.2)
    assert snap_compare(_snapshot_app(tmp_path), terminal_size=SIZE, run_before=before)


def test_snapshot_results(tmp_path, snap_compare):
    async def before(pilot):
        app = pilot.app
        _feed_running(app)
        truth = app.session.config.sim.imu.to_canonical()
        sigmas = {name: (abs(v) * 1e-6 if abs(v) > 1 else 1e-6) for name, v in truth.items()}
        result = CalibrationResult(coefficient_table(truth, sigmas), sim_truth=coefficient_table(truth))
        app.buffer.on_event(Event(300.0, "transition", "run complete", state="done", data={"from": "running"}))
        app.buffer.set_outcome(result, "done; result run.result.json")
        app.refresh_panels()
        await pilot.pause(0.2)
    assert snap_compare(_snapshot_app(tmp_path), terminal_size=SIZE, run_before=before)


def test_cli_needs_config_or_sim(tmp_path):
    from run_helpers import cli

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

def test_connect_enable_disable_disconnect_keys_and_theme(tmp_path):
    async def body():
        app = make_app(tmp_path, auto_connect=False)
        async with app.run_test(size=SIZE) as pilot:
            await press(pilot, "e")
            await wait_until(pilot, lambda: "refused: not connected" in events_text(app), "enable refused")
            await press(pilot, "c")
            await connected(pilot)
            controller = app.session.run.world.controller
            await press(pilot, "e")
            await wait_until(pilot, lambda: all(a.enabled for a in snap(app).table_state.axes), "servos on")
            await pilot.pause(0.1)
            assert app.query_one("#table-panel").plain.count("  on  ") == 3
            app.session.set_rate(1, 30.0).join(5)
            await wait_until(pilot, lambda: snap(app).table_state.axes[1].rate_dps > 29.0, "middle turning")
            await press(pilot, "h")                             # halt: decelerate and hold, servos on
            await wait_until(pilot, lambda: all(abs(r) < 1e-9 for r in snap(app).table_state.rates_dps)
                             and snap(app).table_state.axes[1].in_position, "the table at rest")
            assert all(a.enabled for a in controller.state().axes)
            await press(pilot, "x")
            await wait_until(pilot, lambda: not any(a.enabled for a in snap(app).table_state.axes), "servos off")
            assert_disabled(controller, at_rest=True)
            await press(pilot, "d")
            await wait_until(pilot, lambda: app.session.run is None, "the disconnect")
            await pilot.pause(0.1)
            assert "link: disconnected" in app.query_one("#table-panel").plain
            assert "disconnected" in events_text(app)
            assert app.theme == "textual-dark"
            await press(pilot, "t")
            assert app.theme == "textual-light" and not app.current_theme.dark
            await press(pilot, "t")
            assert app.theme == "textual-dark"
    run(body)


def test_rate_mode_stop_and_jog_on_the_simulator(tmp_path):
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            controller = app.session.run.world.controller
            await press(pilot, "right_square_bracket")          # jog with the servo off: refused
            await wait_until(pilot, lambda: "refused: outer servo is off" in events_text(app), "jog refused")
            await press(pilot, "v")
            dialog = await dialog_open(pilot, "RateScreen", "#rate-frame #label")
            dialog.query_one("#rate-frame").value = 2
            dialog.query_one("#rate-value").value = "250"       # beyond the 100 deg/s limit
            await press(pilot, "enter")
            await wait_until(pilot, lambda: "exceeds its limit" in str(dialog.query_one("#rate-error").render()),
                             "the over-limit message")
            assert app.screen is dialog
            dialog.query_one("#rate-value").value = "fast"
            await press(pilot, "enter")
            await wait_until(pilot, lambda: "not a number" in str(dialog.query_one("#rate-error").render()),
                             "the not-a-number message")
            assert all(ax.mode.value == "off" and not ax.enabled for ax in controller.state().axes)
            dialog.query_one("#rate-value").value = "-15"
            await press(pilot, "enter")
            await wait_until(pilot, lambda: len(app.screen_stack) == 1, "the dialog to close")

            def turning():
                s = snap(app).table_state
                return s is not None and abs(s.axes[2].rate_dps + 15.0) < 1e-6
            await wait_until(pilot, turning, "inner turning at -15 deg/s")
            await pilot.pause(0.15)
            assert "inner" in app.query_one("#table-panel").plain.split("-15.0000")[0].splitlines()[-1]
            assert "rate" in [line for line in app.query_one("#table-panel").plain.splitlines()
                              if line.startswith("inner")][0]
            assert "inner turning at -15 deg/s" in events_text(app)
            await press(pilot, "v")                             # the dialog's Stop all: decelerate and hold
            dialog = await dialog_open(pilot, "RateScreen", "#stop")
            dialog.query_one("#stop").press()

            def at_rest():
                s = snap(app).table_state
                return s is not None and all(abs(r) < 1e-9 for r in s.rates_dps) and s.axes[2].in_position
            await wait_until(pilot, at_rest, "the table at rest after Stop all")
            assert controller.state().axes[2].enabled
            # jog: the rate dialog chose inner; j cycles the frame (inner -> outer -> middle -> inner),
            # ] moves +1 deg, [ -1 deg
            assert app.jog_frame == 2
            start = snap(app).table_state.angles_deg[2]
            for key, frame in (("j", 0), ("j", 1), ("j", 2)):
                await press(pilot, key)
                assert app.jog_frame == frame
            await press(pilot, "right_square_bracket")
            await wait_until(pilot, lambda: abs(snap(app).table_state.angles_deg[2] - (start + 1.0)) < 1e-3
                             and snap(app).table_state.axes[2].in_position, "the jog to +1 deg")
            await press(pilot, "left_square_bracket")
            await wait_until(pilot, lambda: abs(snap(app).table_state.angles_deg[2] - start) < 1e-3
                             and snap(app).table_state.axes[2].in_position, "the jog back")
            app.jog_step_deg = 10.0                             # a longer move: time to try a second jog
            await press(pilot, "left_square_bracket")
            await wait_until(pilot, lambda: not snap(app).table_state.axes[2].in_position, "the jog under way")
            await press(pilot, "left_square_bracket")          # while the frame moves: refused
            await wait_until(pilot, lambda: "refused: inner is moving" in events_text(app), "a refused jog")
            await wait_until(pilot, lambda: abs(snap(app).table_state.angles_deg[2] - (start - 10.0)) < 1e-3
                             and snap(app).table_state.axes[2].in_position, "the jog to -10 deg")
            await pilot.pause(0.3)
            assert abs(snap(app).table_state.angles_deg[2] - (start - 10.0)) < 1e-3
            log = events_text(app)
            assert "jog inner +1 deg" in log and "jog inner -1 deg" in log and log.count("jog inner -10 deg") == 1
            assert "jog: inner by 10 deg" in app.query_one("#table-panel").plain
            # the e-stop from the open rate dialog while a frame turns: servos off at once
            app.session.set_rate(0, 20.0).join(5)
            await wait_until(pilot, lambda: abs(snap(app).table_state.axes[0].rate_dps - 20.0) < 1e-6, "outer turning")
            await press(pilot, "v")
            await dialog_open(pilot, "RateScreen", "#stop")
            await press(pilot, "f12")
            await wait_until(pilot, lambda: len(app.screen_stack) == 1, "the dialog to close")
            await wait_until(pilot, lambda: not any(a.enabled for a in snap(app).table_state.axes), "servos off")
            assert_disabled(controller, at_rest=False)
            assert "EMERGENCY STOP" in events_text(app)
            await wait_until(pilot, lambda: abs(snap(app).table_state.axes[0].rate_dps) < 1e-9, "outer at rest")
        assert_disabled(controller, at_rest=True)
    run(body)


def test_check_rate_command_refuses_travel_limited_axes():
    from bench.tui.session import check_rate_command
    from drivers.errors import TurntableLimitError
    from drivers.turntable import AxisLimits, TurntableLimits

    limits = TurntableLimits((AxisLimits(), AxisLimits(-90.0, 90.0, 50.0), AxisLimits(max_rate_dps=20.0)))
    check_rate_command(limits, 0, -100.0)
    check_rate_command(limits, 2, 20.0)
    for frame, rate, words in ((0, 100.5, "exceeds"), (2, -21.0, "exceeds"), (0, float("nan"), "exceeds"),
                               (1, 5.0, "travel limits")):
        with pytest.raises(TurntableLimitError, match=words):
            check_rate_command(limits, frame, rate)


def test_snapshot_running_light_theme(tmp_path, snap_compare):
    async def before(pilot):
        _feed_running(pilot.app)
        pilot.app.buffer.note("warning", "a warning line")
        pilot.app.buffer.note("fault", "a fault line")
        pilot.app.refresh_panels()
        await pilot.pause(0.2)
    app = make_app(tmp_path, auto_connect=False, refresh_hz=10.0, theme="textual-light")
    assert snap_compare(app, terminal_size=SIZE, run_before=before)


# -- replay: a recorded run, no hardware ------------------------------------------------------------

@pytest.fixture(scope="module")
def recorded_log(tmp_path_factory):
    """A short simulated run recorded with `bench run` (1 s dwells): its log and result JSON."""
    from run_helpers import cli

    out = tmp_path_factory.mktemp("tui-replay")
    config = out / "bench.toml"
    config.write_text(config_text(dwell_s=1.0, positions="traditional-12", rotations="traditional-3s6r"))
    rc, _, err = cli(["run", "--config", str(config), "--out", str(out), "--quiet"])
    assert rc == 0, err
    log_path = next(out.glob("*.mcap"))
    return log_path, next(out.glob("*.result.json"))


def test_replay_shows_the_recorded_run_and_its_result(recorded_log):
    import json

    from bench.logread import read_log

    log_path, result_path = recorded_log
    recorded = read_log(str(log_path))
    expected = json.loads(result_path.read_text())["coefficients"]

    async def body():
        from bench.tui import create_app

        app = create_app(replay=log_path, speed=None, refresh_hz=20.0)
        async with app.run_test(size=SIZE) as pilot:
            await wait_until(pilot, lambda: snap(app).result is not None, "the replay to end with its result")
            await pilot.pause(0.2)
            s = snap(app)
            assert s.run_state is RunState.DONE and set(s.step_states) == {STEP_DONE}
            assert s.event_count >= len(recorded.events)
            plan = app.query_one("#plan-panel").plain
            assert "run done" in plan and "100.0%" in plan and f"{len(app.steps)} done" in plan, plan
            log = events_text(app)
            shown = [e for e in recorded.events if e.kind != "step_started"]
            for e in (shown[0], shown[len(shown) // 2], shown[-1]):
                assert f"{e.kind}: {e.message}" in log
            assert "result attached to the log" in log
            table = app.query_one("#table-panel").plain
            last = recorded.table_states.angles_deg[-1]
            assert f"outer  {last[0]:.4f}" in table and "link: replay" in table, table
            assert app.query_one("#left-tabs").active == "results-tab"
            results = app.query_one("#results-panel").plain
            for name, entry in expected.items():
                assert f"{name} {entry['value']:.8g}" in results
            for key in ("c", "g", "v", "s", "e", "right_square_bracket", "h", "a"):
                await press(pilot, key)
            assert len(app.screen_stack) == 1
            await wait_until(pilot, lambda: events_text(app).count("refused: replay mode: no hardware") == 8,
                             "eight refusals")
            await press(pilot, "f12")
            await wait_until(pilot, lambda: "replay mode, no hardware" in events_text(app), "the e-stop note")
            await press(pilot, "q")
            await wait_until(pilot, lambda: not app.is_running, "the app to exit")
    run(body)


def test_replay_pause_and_resume_the_playback(recorded_log):
    async def body():
        from bench.tui import create_app

        app = create_app(replay=recorded_log[0], speed=1.0, refresh_hz=20.0)
        async with app.run_test(size=SIZE) as pilot:
            await wait_until(pilot, lambda: snap(app).event_count >= 4, "the playback under way")
            await press(pilot, "p")
            await wait_until(pilot, lambda: app.session.paused, "the playback paused")
            await pilot.pause(0.1)
            count = snap(app).event_count
            await pilot.pause(0.4)
            assert snap(app).event_count == count and app.session.playing
            await press(pilot, "r")
            await wait_until(pilot, lambda: snap(app).event_count > count + 1, "the playback to go on")
            await press(pilot, "q")                          # quits at once; the playback thread stops
            await wait_until(pilot, lambda: not app.is_running, "the app to exit")
        assert not app.session.playing and app.session.stats.stopped
    run(body)


def test_replay_result_is_solved_when_not_attached(recorded_log, tmp_path):
    import dataclasses
    import json

    from bench.tui.replay_session import log_result, open_log

    log_path, result_path = recorded_log
    opened = open_log(log_path)
    assert opened.simulated and len(opened.steps) > 10 and not opened.notes
    bare = dataclasses.replace(opened, log=dataclasses.replace(opened.log, attachments={}))
    result, text = log_result(bare)
    assert "solved from the log" in text
    expected = json.loads(result_path.read_text())["coefficients"]
    assert {k: c.value for k, c in result.coefficients.items()} == {k: v["value"] for k, v in expected.items()}
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not a log")
    result, text = log_result(dataclasses.replace(bare, path=junk))
    assert result is None and text.startswith("no result in this log")
