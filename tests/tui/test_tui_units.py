"""The TUI with several IMUs (issue 31 item 6): each unit's live state, the selected unit's means, per-unit results
and verdicts, a unit silenced mid-run shown as dropped with its reason; the replay of such a run shows the units
too; a single IMU's screen is as it was."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.config.load import parse_config
from bench.log.events import RunListener, StepStarted
from bench.tui.budget_panel import NO_UNIT_BUDGET
from tests.e2e.test_several_imus import several_config
from tests.helpers.tui import SIZE, connected, make_app, press, run, snap, start_plan, wait_until

#: three units on two faces and two buses (two sharing bus-a with an id offset); B1 is silenced mid-run
UNITS = (("A1", "bus-a", 0, '"z-up"'), ("A2", "bus-a", 16, '"x-up"'), ("B1", "bus-b", 0, '"y-down"'))
#: the step whose start silences B1 (of the 48 of traditional-12 + traditional-3s6r)
SILENCE_AT = 20
#: a bound on the waits for a whole run (not a time it should take: the waits end as soon as the state is there)
RUN_BOUND_S = 400.0


def _config(tmp_path: Path):
    text = several_config(UNITS, black_box_arcsec=0.0) + '[run]\non_unit_failure = "continue"\n'
    return parse_config(text, source=str(tmp_path / "several.toml"), base_dir=tmp_path)


def _silence_b1(world) -> None:
    world.units[1].drop_frames(10 ** 9)          # the world's units: A2, B1 (A1 is the world's own IMU)


def _units(app) -> str:
    return app.query_one("#units-panel").plain


def _footer_keys(app) -> set[str]:
    return {b.action for _, b, enabled, _ in app.active_bindings.values() if b.show and enabled}


@pytest.mark.slow
@pytest.mark.timeout(3 * RUN_BOUND_S)
def test_live_units_their_state_a_silenced_unit_dropped_and_per_unit_results(tmp_path):
    async def body():
        app = make_app(tmp_path, config=_config(tmp_path))
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            # every unit receives while the table is idle (the idle monitor polls each one)
            await wait_until(pilot, lambda: all(u.imu.samples > 0 for u in snap(app).units), "samples of every unit")
            app.refresh_panels()
            units = _units(app).splitlines()
            assert [line.split()[-5:-3] for line in units[::2]] == [["A1", "z-up"], ["A2", "x-up"],
                                                                      ["B1", "y-down"]], units
            assert units[0].startswith("> A1") and set(units[1::2]) == {"    receiving"}, units
            assert "next_unit" in _footer_keys(app)
            imu = app.query_one("#imu-panel")
            assert imu.plain.startswith("IMU A1 z-up (1/3): 1 s means"), imu.plain
            await press(pilot, "u")
            await wait_until(pilot, lambda: imu.plain.startswith("IMU A2 x-up (2/3)"), "the IMU panel on A2")
            assert _units(app).splitlines()[2].startswith("> A2"), _units(app)
            # A2's x is up on the fixture: at rest its x accelerometer reads about 1 g, A1's z does
            a2 = snap(app).units[1].imu
            assert a2.acc_cps is not None and abs(a2.acc_cps[0]) > 5 * max(abs(a2.acc_cps[1]), abs(a2.acc_cps[2]))

            await start_plan(pilot)
            # B1 falls silent once the run reached step SILENCE_AT (the run's state, not a time)
            await wait_until(pilot, lambda: (snap(app).current_step or 0) >= SILENCE_AT, f"step {SILENCE_AT + 1}",
                             timeout_s=RUN_BOUND_S)
            _silence_b1(app.session.run.world)
            await wait_until(pilot, lambda: snap(app).units[2].dropped, "B1 dropped", timeout_s=RUN_BOUND_S)
            app.refresh_panels()
            b1 = _units(app).splitlines()[5]
            assert b1.strip().startswith("dropped: silent: no sample for "), _units(app)
            assert snap(app).units[0].dropped == "" and snap(app).units[1].dropped == ""
            await wait_until(pilot, lambda: snap(app).unit_outcomes, "every unit's outcome", timeout_s=RUN_BOUND_S)
            outcomes = {o.serial: o for o in snap(app).unit_outcomes}
            # after the run the idle monitor polls the units again (their frames no longer go to the closed log)
            after = snap(app).units[1].imu.samples
            await wait_until(pilot, lambda: snap(app).units[1].imu.samples > after, "A2's samples after the run")
            assert outcomes["A1"].result is not None and outcomes["A2"].result is not None
            assert outcomes["B1"].result is None and outcomes["B1"].text.startswith("dropped from the run at ")
            results = app.query_one("#results-panel")
            await wait_until(pilot, lambda: "unit A2 (x-up) (2/3)" in results.plain, "A2's result shown")
            assert app.query_one("#left-tabs").active == "results-tab"
            assert results.result is outcomes["A2"].result
            summary = next(line for line in results.plain.splitlines() if line.startswith("units: "))
            assert summary.startswith(f"units: A1 {outcomes['A1'].verdict_word} | A2 "), summary
            assert "| B1 no result (dropped from the run at " in summary and "silent: no sample for" in summary
            budget = app.query_one("#budget-panel")
            assert budget.result is outcomes["A2"].result and budget.plain.startswith("unit A2 (x-up) (2/3)\nunits: ")
            await press(pilot, "u")
            await wait_until(pilot, lambda: "unit B1 (y-down) (3/3): no result: dropped" in results.plain,
                             "B1's account")
            assert results.result is None and budget.result is None
            assert budget.plain.startswith("unit B1 (y-down) (3/3)\nunits: A1 ")
            assert budget.plain.splitlines()[2] == NO_UNIT_BUDGET
            assert imu.plain.startswith("IMU B1 y-down (3/3)") and "dropped: silent" in imu.plain.splitlines()[1]
    run(body)


@pytest.fixture(scope="module")
def silenced_log(tmp_path_factory) -> Path:
    """A simulated run of the three units, B1 silenced when step `SILENCE_AT` starts (its own folder and records)."""
    from bench.run.devices import SIMULATOR
    from bench.run.runner import BenchRun, compile_from_config

    folder = tmp_path_factory.mktemp("silenced")
    config = _config(folder)

    class Silence(RunListener):
        def on_event(self, event) -> None:
            if isinstance(event, StepStarted) and event.step_index == SILENCE_AT:
                _silence_b1(bench_run.world)

    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("BENCH_DB", str(folder / "records.sqlite"))
        bench_run = BenchRun(config, compile_from_config(config), devices=SIMULATOR, out_dir=folder)
        bench_run.extra_listeners.append(Silence())
        with bench_run:
            bench_run.open()
            bench_run.run()
            outcome = bench_run.finish()
    assert outcome.units["B1"].result is None and outcome.units["A2"].result is not None
    return bench_run.log_path


@pytest.mark.slow
def test_replay_of_several_units_shows_each_unit_its_drop_and_its_result(silenced_log):
    async def body():
        from bench.tui import create_app

        app = create_app(replay=silenced_log, speed=None, refresh_hz=20.0)
        async with app.run_test(size=SIZE) as pilot:
            await wait_until(pilot, lambda: snap(app).unit_outcomes and snap(app).result is not None,
                             "the replay to end with every unit's result")
            app.refresh_panels()
            s = snap(app)
            assert [(u.serial, u.face) for u in s.units] == [("A1", "z-up"), ("A2", "x-up"), ("B1", "y-down")]
            assert s.units[1].imu.samples > 0 and s.units[2].imu.samples > 0
            assert s.units[1].imu.samples > 2 * s.units[2].imu.samples    # B1 fell silent before half the run
            assert s.units[2].dropped.startswith("silent: no sample for ") and not s.units[1].dropped
            lines = _units(app).splitlines()
            assert lines[5].strip().startswith("dropped: silent: no sample for "), lines
            outcomes = {o.serial: o for o in s.unit_outcomes}
            assert outcomes["A2"].text.startswith("result attached to the log (")
            assert outcomes["B1"].result is None and outcomes["B1"].text.startswith("dropped from the run at ")
            results = app.query_one("#results-panel")
            assert "unit A1 (z-up) (1/3)" in results.plain and results.result is outcomes["A1"].result
            assert "| B1 no result (dropped from the run at " in results.plain
            await press(pilot, "u")
            await wait_until(pilot, lambda: "unit A2 (x-up) (2/3)" in results.plain, "A2's result")
            assert results.result is outcomes["A2"].result
            assert app.query_one("#imu-panel").plain.startswith("IMU A2 x-up (2/3)")
    run(body)


def test_a_single_imu_screen_has_no_units(tmp_path):
    """One [imu]: no units panel, no unit key in the footer or the help, the IMU panel's title as ever."""
    async def body():
        from bench.tui.app import HELP_KEYS, UNIT_HELP
        from bench.tui.panels import IMU_TITLE

        app = make_app(tmp_path, auto_connect=False)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause(0.2)
            assert not app.query("#units-panel") and snap(app).units == ()
            assert "next_unit" not in _footer_keys(app)
            assert app.query_one("#imu-panel").plain.startswith(IMU_TITLE)
            await press(pilot, "question_mark")
            await wait_until(pilot, lambda: type(app.screen).__name__ == "HelpScreen", "the help")
            assert app.screen.keys == HELP_KEYS and UNIT_HELP not in app.screen.keys
    run(body)


def test_the_help_lists_the_unit_key_with_several_units(tmp_path):
    async def body():
        from bench.tui.app import UNIT_HELP

        app = make_app(tmp_path, config=_config(tmp_path), auto_connect=False)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause(0.2)
            assert app.query("#units-panel") and "next_unit" in _footer_keys(app)
            assert [line.split() for line in _units(app).splitlines()] == [
                [">", "A1", "z-up", "0", "lost", "0"], ["waiting:", "no", "sample", "yet"],
                ["A2", "x-up", "0", "lost", "0"], ["waiting:", "no", "sample", "yet"],
                ["B1", "y-down", "0", "lost", "0"], ["waiting:", "no", "sample", "yet"]]
            await press(pilot, "question_mark")
            await wait_until(pilot, lambda: type(app.screen).__name__ == "HelpScreen", "the help")
            keys = [key for key, _ in app.screen.keys]
            assert UNIT_HELP in app.screen.keys and keys.index("u") == keys.index("t") - 1
            await pilot.pause(0.2)
            dialog = app.screen.query_one("Vertical")       # all of it fits 100x30, the note's last line too
            assert app.screen.region.contains_region(dialog.region)
            assert dialog.virtual_size.height <= dialog.scrollable_content_region.height
    run(body)


def test_the_buffer_keeps_each_unit_its_state_waiting_receiving_stale_dropped():
    """Without a run: the states come from the samples' age on the session's clock and the run's drop warning."""
    import numpy as np

    from bench.log.events import UNIT_DROPPED, RunWarning
    from bench.tui.buffer import STALE_AFTER_S, UiBuffer
    from drivers.imu import ImuSampleBlock

    now = [100.0]
    buffer = UiBuffer((), clock=lambda: now[0])
    buffer.set_units([("A1", "z-up"), ("A2", "x-up"), ("B1", "y-down")])
    assert [u.state for u in buffer.snapshot().units] == ["waiting: no sample yet"] * 3

    def block(n: int) -> ImuSampleBlock:
        k = np.arange(n)
        return ImuSampleBlock(k, k / 200.0, np.ones((n, 3)), np.ones((n, 3)), np.full(n, 25.0), np.zeros(n, np.int64),
                              200.0)

    buffer.on_imu(block(10))
    buffer.on_unit_imu("A2", block(20))
    buffer.on_unit_imu("B1", block(30))
    buffer.on_unit_imu("C9", block(5))                  # not a unit of this run: ignored
    units = buffer.snapshot().units
    assert [(u.serial, u.imu.samples, u.state) for u in units] == [
        ("A1", 10, "receiving"), ("A2", 20, "receiving"), ("B1", 30, "receiving")]
    assert units[0].imu.samples == buffer.snapshot().imu.samples      # the reference unit is the IMU panel's IMU
    now[0] += STALE_AFTER_S + 1.0
    buffer.on_unit_imu("A2", block(20))
    buffer.on_event(RunWarning(812.0, "unit B1 dropped from the run: silent: no sample for 2.1 s", 7, "P05",
                               details={UNIT_DROPPED: "B1", "reason": "silent: no sample for 2.1 s"}))
    states = [u.state for u in buffer.snapshot().units]
    assert states == ["stale: no sample for 4 s", "receiving", "dropped: silent: no sample for 2.1 s"]
    buffer.begin_run(())                                 # a new run: nobody dropped yet
    assert buffer.snapshot().units[2].state == "stale: no sample for 4 s"
