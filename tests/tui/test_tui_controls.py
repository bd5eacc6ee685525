"""TUI manual controls against the simulator: connect/enable/disable keys, theme, rate mode, stop and jog."""

from __future__ import annotations

import pytest

from tests.helpers.run import assert_disabled
from tests.helpers.tui import SIZE, connected, dialog_open, events_text, make_app, press, run, snap, wait_until


@pytest.mark.slow
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
            # the event-log panel is redrawn at 20 Hz: it may show the event a refresh later
            await wait_until(pilot, lambda: "disconnected" in events_text(app), "the event log")
            assert app.theme == "textual-dark"
            await press(pilot, "t")
            assert app.theme == "textual-light" and not app.current_theme.dark
            await press(pilot, "t")
            assert app.theme == "textual-dark"
    run(body)


@pytest.mark.slow
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
            # the event-log panel is redrawn at 20 Hz: it may show the event a refresh later
            await wait_until(pilot, lambda: "inner turning at -15 deg/s" in events_text(app), "the event log")
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
            # the event-log panel is redrawn at 20 Hz: it may show the event a refresh later
            await wait_until(pilot, lambda: "EMERGENCY STOP" in events_text(app), "the event log")
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
