"""What a new user tripped over in the TUI (issue 33, items 8-10): stale IMU values while paused, event times
that went back, a progress bar that dropped on abort, no word on `bench run --resume`, cut texts, solid
sparklines, a jargon legend, tabs with no keys, a Start dialog that did not say what Enter does.

The session's clocks are injected (`FakeClock`): no assertion depends on real time. Pilot tests drive the real
app (100x30); the live ones run the short simulated plan of tests/helpers/run.py with bounded waits.
"""

from __future__ import annotations

import math
import shlex
import subprocess
import sys
import time

import numpy as np
import pytest

from bench.log.events import RunState, make_event
from bench.model.result import CalibrationResult, coefficient_table
from bench.run.runner import compile_from_config
from bench.tui.buffer import STALE_AFTER_S, StepState, UiBuffer, progress
from bench.tui.panels import TRACE_LEVELS, log_time, trace_levels
from drivers.imu import ImuSampleBlock
from tests.helpers.run import REPO, config_text
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
    wait_ended,
    wait_until,
)

#: a fixed wall-clock time for the event log's lines outside a run (2026-11-27 10:00:00 UTC)
WALL_S = 1_795_773_600.0


class FakeClock:
    """A clock that stands still until the test moves it."""

    def __init__(self, now: float = 0.0):
        self.now = now

    def __call__(self) -> float:
        return self.now


def _block(counter0: int, values_cps, n: int = 50, rate_hz: float = 50.0) -> ImuSampleBlock:
    """`n` samples whose six rates (counts/s) are `values_cps` (one value each, or an (n, 6) array)."""
    rates = np.broadcast_to(np.asarray(values_cps, dtype=float), (n, 6))
    counter = np.arange(counter0, counter0 + n, dtype=np.int64)
    return ImuSampleBlock(counter, counter / rate_hz, rates[:, :3] / rate_hz, rates[:, 3:] / rate_hz,
                          np.full(n, 25.0), np.zeros(n, np.int64), rate_hz)


def _local(wall_s: float) -> str:
    return time.strftime("%H:%M:%S", time.localtime(wall_s))


# -- item 8: stale IMU values -------------------------------------------------------------------------

def test_imu_values_turn_stale_when_no_sample_came_on_the_session_clock():
    """While paused the panel kept the last move's values for more than 10 s and said nothing."""
    clock = FakeClock(100.0)
    buf = UiBuffer(clock=clock)
    assert buf.snapshot().imu.age_s is None and not buf.snapshot().imu.stale      # no sample yet: nothing old
    buf.on_imu(_block(0, (1.0,) * 6))
    clock.now += STALE_AFTER_S - 0.01
    imu = buf.snapshot().imu
    assert imu.age_s == pytest.approx(STALE_AFTER_S - 0.01) and not imu.stale
    clock.now += 0.01
    assert buf.snapshot().imu.stale
    buf.on_imu(_block(50, (1.0,) * 6))
    assert buf.snapshot().imu.age_s == 0.0 and not buf.snapshot().imu.stale


@pytest.mark.slow
def test_imu_panel_dims_stale_values_and_says_how_old_they_are(tmp_path):
    clock = FakeClock(0.0)

    async def body():
        app = make_app(tmp_path, auto_connect=False, refresh_hz=1.0, clock=clock)
        async with app.run_test(size=SIZE) as pilot:
            feed_running(app)
            app.refresh_panels()
            await pilot.pause(0.1)
            panel = app.query_one("#imu-panel")
            fresh = panel.plain.splitlines()
            assert "stale" not in panel.plain and not panel.has_class("-stale")
            clock.now += 12.0
            app.refresh_panels()
            await pilot.pause(0.1)
            lines = panel.plain.splitlines()
            assert lines[1] == "stale: no sample for 12 s" and panel.has_class("-stale"), panel.plain
            assert lines[2:] == fresh[2:]                   # the values stay, marked as old
            app.buffer.on_imu(_block(1000, (18000.0, 0.0, 0.0, 0.0, 0.0, 40000.0)))
            app.refresh_panels()
            await pilot.pause(0.1)
            assert "stale" not in panel.plain and not panel.has_class("-stale")
    run(body)


@pytest.mark.slow
def test_a_paused_run_shows_its_imu_values_as_stale(tmp_path):
    """The live case: a paused run reads no IMU; once the session's clock moved on, the panel says so."""
    clock = FakeClock(0.0)

    async def body():
        app = make_app(tmp_path, clock=clock)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            await start_plan(pilot)
            await wait_until(pilot, lambda: snap(app).step_states.count(StepState.DONE) >= 1, "a step done")
            await press(pilot, "p")
            await wait_until(pilot, lambda: snap(app).run_state is RunState.PAUSED, "the pause")

            def stale() -> bool:                # the session's clock goes on; a last block may come after the pause
                clock.now += 1.0
                return "stale: no sample for" in app.query_one("#imu-panel").plain
            await wait_until(pilot, stale, "the stale mark")
            samples = snap(app).imu.samples
            await pilot.pause(0.3)
            assert snap(app).imu.samples == samples and snap(app).imu.stale     # nothing comes while paused
            await press(pilot, "r")
            await wait_until(pilot, lambda: "stale" not in app.query_one("#imu-panel").plain, "fresh values")
    run(body)


# -- item 9: event times, progress on abort, the resume command --------------------------------------

def test_event_times_never_go_back_and_lines_outside_a_run_carry_the_local_time():
    """`[0:00:25] info: log ...` came before `[0:00:00] transition: run started`: the session's lines were timed
    from the session's first line, and the origin moved to the run's start when it came."""
    wall = FakeClock(WALL_S)
    buf = UiBuffer(wall_clock=wall)
    buf.note("info", "connected (scpi, simulator)")
    wall.now += 25.0
    buf.note("info", "log out/run.mcap")
    wall.now += 1.0
    buf.on_event(make_event(25.0, "transition", "run started: 3 steps", state="running", data={"from": "idle"}))
    buf.on_event(make_event(40.0, "transition", "paused", state="paused", data={"from": "running"}))
    buf.on_event(make_event(55.0, "transition", "resumed", state="running", data={"from": "paused"}))
    buf.on_event(make_event(86.0, "step_finished", "P01 dwell done", step_index=0, step_unit="P01"))
    buf.on_event(make_event(85.5, "info", "an event stamped before the last one"))
    buf.note("warning", "abort requested")                  # a note: the latest time seen on the run's clock
    buf.on_event(make_event(90.0, "transition", "run ended early", state="failed", data={"from": "aborting"}))
    wall.now += 100.0
    buf.note("info", "aborted; table stopped")
    buf.on_event(make_event(0.0, "transition", "run started: 3 steps", state="running", data={"from": "idle"}))
    buf.on_event(make_event(3.0, "step_finished", "P01 move done", step_index=0, step_unit="P01"))
    lines, count = buf.lines_since(0)
    shown = [f"[{log_time(line)}] {line.event.kind}: {line.event.message}" for line in lines]
    assert count == len(shown) == 12
    assert shown == [f"[{_local(WALL_S)}] info: connected (scpi, simulator)",
                     f"[{_local(WALL_S + 25.0)}] info: log out/run.mcap",
                     "[+0:00:00] transition: run started: 3 steps",
                     "[+0:00:15] transition: paused",
                     "[+0:00:30] transition: resumed",
                     "[+0:01:01] step_finished: P01 dwell done",
                     "[+0:01:01] info: an event stamped before the last one",
                     "[+0:01:01] warning: abort requested",
                     "[+0:01:05] transition: run ended early",
                     f"[{_local(WALL_S + 126.0)}] info: aborted; table stopped",
                     "[+0:00:00] transition: run started: 3 steps",      # a new run (a new simulated world)
                     "[+0:00:03] step_finished: P01 move done"]
    runs = [line.run_elapsed_s for line in lines if line.run_elapsed_s is not None]
    assert runs[:7] == sorted(runs[:7]) and runs[7:] == sorted(runs[7:])


def test_the_progress_never_goes_back_when_a_run_is_aborted(tmp_path):
    """33.8 % before the abort, 32.0 % after: the step under way lost its part done."""
    steps = compile_from_config(make_config(tmp_path)).steps
    buf = UiBuffer(steps)
    dwell = next(s for s in steps if s.kind == "dwell")
    buf.on_event(make_event(0.0, "transition", "run started", state="running", data={"from": "idle"}))
    for s in steps[:dwell.index]:
        buf.on_event(make_event(0.0, "step_started", "", step_index=s.index, step_unit=s.unit))
        buf.on_event(make_event(0.0, "step_finished", "", step_index=s.index, step_unit=s.unit))
    buf.on_event(make_event(10.0, "step_started", "", step_index=dwell.index, step_unit=dwell.unit))
    buf.on_event(make_event(10.0 + dwell.estimated_s / 2, "transition", "aborted by the operator", state="aborting",
                       data={"from": "running"}))
    before = progress(buf.snapshot(), steps).fraction
    buf.on_event(make_event(10.0 + dwell.estimated_s / 2 + 0.5, "transition", "run ended early", state="failed",
                       data={"from": "aborting"}))
    after = progress(buf.snapshot(), steps).fraction
    assert buf.snapshot().run_state_text == "aborted"
    assert after >= before > 0, (before, after)
    done = sum(s.estimated_s for s in steps[:dwell.index])
    assert after == pytest.approx((done + dwell.estimated_s / 2 + 0.5) / sum(s.estimated_s for s in steps))


@pytest.mark.slow
def test_an_aborted_run_says_how_to_continue_it_and_the_command_works(tmp_path, capsys):
    """After an abort neither the event log nor the quit line named `bench run --resume LOG`."""
    from bench.cli.common import ExitCode
    from bench.cli.tui import exit_status
    from bench.config.load import load_config

    config_path = tmp_path / "bench.toml"
    config_path.write_text(config_text(), encoding="utf-8")
    out = tmp_path / "out"

    async def body():
        app = make_app(tmp_path, config=load_config(config_path), out_dir=out)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            await start_plan(pilot)
            await wait_until(pilot, lambda: snap(app).step_states.count(StepState.DONE) >= 4, "a unit done")
            await press(pilot, "a")
            await dialog_open(pilot, "ConfirmScreen", "#yes")
            await press(pilot, "y")
            await wait_ended(pilot)
            log = app.session.last_end.log_path
            command = f"bench run --config {config_path} --resume {log} --out {out}"
            assert app.session.last_end.resume == command
            await wait_until(pilot, lambda: f"info: continue this run with: {command}" in events_text(app),
                             "the resume command in the event log")
            assert snap(app).outcome_text.endswith(f"; continue with: {command}")
            await press(pilot, "2")             # the Results tab said "no result yet" after an abort
            await wait_until(pilot, lambda: command in app.query_one("#results-panel").plain, "the Results tab")
        return app

    holder = []

    async def keep():
        holder.append(await body())
    run(keep)
    capsys.readouterr()
    assert exit_status(holder[0]) == ExitCode.FAULT
    line = capsys.readouterr().err.strip()
    log = holder[0].session.last_end.log_path
    assert line.endswith(f"Log: {log} (continue with: bench run --config {config_path} --resume {log} --out {out})")
    # the command as printed, checked by `bench run` itself (--dry-run: nothing moves)
    args = shlex.split(holder[0].session.last_end.resume)
    assert args[:2] == ["bench", "run"]
    done = subprocess.run([sys.executable, "-m", "bench.cli", *args[1:], "--dry-run"], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "units complete in earlier logs would be skipped: P01" in done.stdout, done.stdout


def test_the_resume_command_names_the_built_in_simulator_and_a_log_outside_the_output_folder(tmp_path):
    from bench.config.load import default_sim_config
    from bench.tui.session import resume_command

    config = default_sim_config()
    log = tmp_path / "my runs" / "r.mcap"
    assert resume_command(config, True, log) == f"bench run --sim --resume '{log}' --out '{log.parent}'"
    inside = config.output.folder / "r.mcap"
    assert resume_command(config, True, inside) == f"bench run --sim --resume {inside}"


# -- item 10: texts that fit, panels that line up, sparklines, legend, keys, the Start dialog ----------

@pytest.mark.slow
def test_the_results_status_wraps_instead_of_cutting_the_file_name(tmp_path):
    """`result attached to the log (....result.jso`: the status line was cut at the panel's edge."""
    async def body():
        app = make_app(tmp_path, auto_connect=False, refresh_hz=10.0)
        async with app.run_test(size=SIZE) as pilot:
            feed_running(app)
            feed_result(app)
            name = "20261127T115715Z-50ef0b.result.json"
            app.buffer.set_outcome(snap(app).result, f"result attached to the log ({name})")
            app.refresh_panels()
            await pilot.pause(0.2)
            status = app.query_one("#results-status")
            assert status.region.right <= app.query_one("#left-tabs").region.right
            shown = " ".join("".join(seg.text for seg in strip).strip()
                             for strip in status.render_lines(status.content_region.reset_offset))
            assert f"({name})" in shown, shown
    run(body)


@pytest.mark.slow
def test_budget_table_fits_two_long_parts_at_100_columns(tmp_path):
    """The Budget tab cut `bias instab. 19%` to `bias instab. 1`: two parts of 16 characters did not fit."""
    from tests.tui.test_tui_layout import _fits

    async def body():
        app = make_app(tmp_path, auto_connect=False, refresh_hz=10.0)
        async with app.run_test(size=SIZE) as pilot:
            truth = app.session.config.sim.imu.to_canonical()
            budgets = {name: {"bias instability": 3e-7, "unexplained scatter": 0.8e-7, "noise": 0.4e-7}
                       for name in truth}
            sigmas = {name: math.sqrt(sum(v * v for v in b.values())) for name, b in budgets.items()}
            app.buffer.set_outcome(CalibrationResult(coefficient_table(truth, sigmas, budgets, 2.0)), "done")
            app.refresh_panels()
            await pilot.press("3")
            await pilot.pause(0.2)
            table = app.query_one("#budget-table")
            assert _fits(table), (table.virtual_size, table.scrollable_content_region)
            assert "Kg_x 3.13e-07 6.26e-07 bias inst. 92% scatter 7%" in app.query_one("#budget-panel").plain
            assert "bias instab. (B) 3e-07 (92%)" in app.query_one("#budget-panel").detail   # the full name below
    run(body)


def test_a_near_constant_channel_draws_flat_and_a_move_draws_full_height():
    """Textual's Sparkline drew a near-constant channel's noise as a solid bar (every cell at the top)."""
    rng = np.random.default_rng(1)
    assert trace_levels([5.0] * 120, 12) == [3] * 12                       # constant: flat, mid-height
    noisy = 40000.0 + rng.normal(0.0, 30.0, 120)                          # 1 g and its noise
    levels = trace_levels(noisy, 12)
    assert max(levels) - min(levels) <= 2 and 2 <= min(levels) and max(levels) <= 5, levels
    counts = rng.choice([0.0, 200.0], size=120, p=[0.25, 0.75])           # whole counts at 200 Hz, at rest
    levels = trace_levels(counts, 12, floor=200.0)
    assert max(levels) - min(levels) <= 3 and 7 not in levels, levels
    step = np.r_[np.zeros(60), np.full(60, 720000.0)] + rng.normal(0.0, 30.0, 120)   # a move to 20 deg/s
    levels = trace_levels(step, 12)
    assert levels[:6] == [0] * 6 and levels[6:] == [7] * 6
    assert trace_levels([], 12) == [] and trace_levels([1.0, 2.0, 3.0], 6) == [0, 0, 3, 3, 7, 7]   # stretched


def test_the_imu_panel_says_what_its_values_are_in_plain_words(tmp_path):
    async def body():
        app = make_app(tmp_path, auto_connect=False, refresh_hz=10.0)
        async with app.run_test(size=SIZE) as pilot:
            feed_running(app)
            n = 120
            app.buffer.on_imu(_block(100, np.c_[np.full((n, 5), 1000.0), 40000.0 + np.arange(n) % 2], n=n))
            app.refresh_panels()
            await pilot.pause(0.2)
            panel = app.query_one("#imu-panel")
            assert panel.border_title == "IMU: means over 1 s"
            assert panel.plain.splitlines()[-1] == "deg/s deg/h g (the simulator's scale)"
            assert "sim truth" not in panel.plain
            az = app.query_one("#spark-az")
            assert az.plain and set(az.plain) <= set(TRACE_LEVELS[2:6]) and TRACE_LEVELS[-1] not in az.plain
    run(body)


@pytest.mark.slow
def test_number_keys_show_the_tabs_and_the_footer_and_help_say_so(tmp_path):
    """The Results and Budget tabs were reachable only with Shift-Tab and arrows, and nothing said so."""
    from textual.widgets._footer import FooterKey

    from bench.tui.app import HELP_KEYS

    async def body():
        app = make_app(tmp_path, auto_connect=False, refresh_hz=10.0)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause(0.2)
            tabs = app.query_one("#left-tabs")
            for key, tab in (("3", "budget-tab"), ("2", "results-tab"), ("1", "plan-tab")):
                await pilot.press(key)
                await pilot.pause(0.05)
                assert tabs.active == tab
            # the footer draws its keys on a later refresh: wait for them
            keys = await wait_until(pilot, lambda: {(k.key_display, k.description) for k in app.query(FooterKey)},
                                    "the footer's keys")
            assert ("1-3", "tabs") in keys, keys
            footer = app.query_one("Footer")
            assert all(k.region.right <= footer.region.right for k in app.query(FooterKey))   # all on screen
            assert ("1-3", "show the Plan (1), Results (2) or Budget (3) tab") in HELP_KEYS
    run(body)


@pytest.mark.slow
def test_the_start_dialog_says_what_enter_does(tmp_path):
    """In the Start dialog Enter means Cancel (the focused button): safe, and now said on the dialog."""
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            await press(pilot, "s")
            dialog = await dialog_open(pilot, "ConfirmScreen", "#confirm-keys")
            keys = dialog.query_one("#confirm-keys")
            assert str(keys.render()) == "y: Start   n or Esc: Cancel   Enter: the highlighted button (Cancel)"
            dialog.query_one("#yes").focus()
            await pilot.pause(0.05)
            assert str(keys.render()).endswith("(Start)")
            dialog.query_one("#no").focus()
            await pilot.pause(0.05)
            await press(pilot, "enter")
            await wait_until(pilot, lambda: len(app.screen_stack) == 1, "the dialog to close")
            assert not app.session.running
    run(body)
