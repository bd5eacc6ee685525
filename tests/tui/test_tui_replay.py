"""TUI replay mode: a recorded run and its result shown with no hardware."""

from __future__ import annotations

import pytest

from bench.log.events import RunState
from bench.tui.buffer import StepState
from tests.helpers.tui import SIZE, events_text, press, run, snap, wait_until


@pytest.fixture(scope="module")
def recorded_log(short_run):
    """A short simulated run (the session's: 1 s dwells): its log and result JSON."""
    return short_run.log, short_run.result


@pytest.mark.slow
def test_replay_shows_the_recorded_run_and_its_result(recorded_log):
    import json

    from bench.log.reader import read_log

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
            assert s.run_state is RunState.DONE and set(s.step_states) == {StepState.DONE}
            assert s.event_count >= len(recorded.events)
            plan = app.query_one("#plan-panel").plain
            assert "run done" in plan and "100.0%" in plan and f"{len(app.steps)} done" in plan, plan
            log = events_text(app)
            shown = [e for e in recorded.events if e.kind != "step_started"]
            for e in (shown[0], shown[len(shown) // 2], shown[-1]):
                assert f"{e.kind}: {e.message}" in log
            assert "result attached to the log" in log
            table = app.query_one("#table-panel").plain
            last = recorded.read_table_states().angles_deg[-1]
            assert f"outer  {last[0]:.4f}" in table and "link: replay" in table, table
            assert app.query_one("#left-tabs").active == "results-tab"
            results = app.query_one("#results-panel").plain
            # the verdict first (issue 16): the recorded run has no [acceptance] limits and passed its quality checks:
            # nothing was checked, and the TUI says so as the reports do (issue 27)
            assert results.splitlines()[0].startswith("VERDICT NOT CHECKED (no check ran"), results
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_replay_table_panel_is_as_tall_as_the_imu_panel(recorded_log):
    """The replay's table panel has no jog line: it was one line shorter than the IMU panel (issue 33, item 10);
    its link line named the log the header already names, and wrapped at 100 columns once played."""
    async def body():
        from bench.tui import create_app
        from bench.tui.app import TOP_PANEL_HEIGHT

        app = create_app(replay=recorded_log[0], speed=1.0, refresh_hz=20.0)
        async with app.run_test(size=SIZE) as pilot:
            await wait_until(pilot, lambda: snap(app).table_state is not None and snap(app).imu.samples > 0,
                             "the playback under way")
            await pilot.pause(0.2)
            heights = [app.query_one(name).outer_size.height for name in ("#table-panel", "#imu-panel")]
            assert heights == [TOP_PANEL_HEIGHT] * 2, heights
            table = app.query_one("#table-panel").plain.splitlines()
            assert table[-2:] == ["link: replay (1x)", "replay, no hardware: p / r pause and resume it"], table
            await press(pilot, "q")
            await wait_until(pilot, lambda: not app.is_running, "the app to exit")
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


@pytest.mark.slow
def test_replay_footer_shows_only_the_playback_keys(recorded_log):
    """The footer listed E-STOP, start, abort, go to, rate and halt in replay mode too (issue 19); they
    are hidden there, and pressed anyway they still say why nothing happens."""
    async def body():
        from textual.widgets import Footer

        from bench.tui import create_app

        app = create_app(replay=recorded_log[0], speed=1.0, refresh_hz=20.0)
        async with app.run_test(size=SIZE) as pilot:
            await wait_until(pilot, lambda: snap(app).event_count >= 1, "the playback under way")
            shown = {b.action for _, b, enabled, _ in app.active_bindings.values() if b.show}
            assert shown == {"pause", "resume", "show_tab('plan-tab')", "help", "quit_app"}, shown   # (1-3 tabs)
            footer = app.query_one(Footer)

            def footer_keys() -> str:
                return " ".join(str(k.render()) for k in footer.query("FooterKey"))
            # the footer draws its keys on a later refresh: wait for them, not for a fixed time (a 0.2 s
            # pause found none once on a loaded machine)
            await wait_until(pilot, lambda: "quit" in footer_keys(), "the footer's keys")
            keys = footer_keys()
            for hidden in ("E-STOP", "start", "abort", "go to", "rate", "halt"):
                assert hidden not in keys, keys
            assert "pause" in keys and "quit" in keys
            await press(pilot, "s")
            await wait_until(pilot, lambda: "refused: replay mode: no hardware" in events_text(app), "the refusal")
            await press(pilot, "q")
            await wait_until(pilot, lambda: not app.is_running, "the app to exit")
    run(body)


@pytest.mark.slow
def test_live_footer_keeps_the_hardware_keys(tmp_path):
    async def body():
        from tests.helpers.tui import make_app

        app = make_app(tmp_path, auto_connect=False)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause(0.2)
            shown = {b.action for _, b, enabled, _ in app.active_bindings.values() if b.show}
            assert {"estop", "start", "abort", "goto", "rate", "halt", "pause", "quit_app"} <= shown, shown
    run(body)


@pytest.mark.slow
def test_replay_of_a_thermal_run_shows_the_chamber(thermal_run_log):
    """The Chamber panel of a thermal run's replay shows the recorded chamber states (it said "no reading yet"):
    at the end, the last one polled, at the second temperature's setpoint."""
    from bench.log.reader import read_log

    last = read_log(str(thermal_run_log)).chamber_states[-1]

    async def body():
        from bench.tui import create_app

        app = create_app(replay=thermal_run_log, speed=None, refresh_hz=20.0)
        async with app.run_test(size=SIZE) as pilot:
            await wait_until(pilot, lambda: snap(app).result is not None, "the replay to end with its result")
            await pilot.pause(0.2)
            panel = app.query_one("#chamber-panel").plain
            assert f"air {last.temperature_c:.1f}  set 26.0 degC" in panel and last.setpoint_c == 26.0, panel
            assert "no reading yet" not in panel and snap(app).chamber_state == last
            await press(pilot, "q")
            await wait_until(pilot, lambda: not app.is_running, "the app to exit")
    run(body)
