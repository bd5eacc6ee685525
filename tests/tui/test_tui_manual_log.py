"""The log of manual moves in `bench tui` (issue 19): the first manual move starts a log; no move, no file.

A session that only moved the table by hand left no record at all. Now the first go to, rate or
jog opens `<run-id>-manual.mcap` (a run log's layout without a plan), a plan closes it and writes
its own, and a log that cannot be written warns without holding up the table or the controls.
The logs replay (`bench replay`, `bench tui --replay`) and `bench solve` refuses them in one line.
Every wait is bounded; no timing is asserted.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

import bench.log.recorder as recorder_module
from bench.cli.tui import exit_status
from bench.log.events import Note
from bench.log.reader import read_log
from bench.log.recorder import McapRecorder
from bench.log.run_info import NO_PLAN_IN_MANUAL_LOG
from bench.tui.manual_log import ManualLog
from drivers.clock import ManualClock
from drivers.imu import ImuSampleBlock
from drivers.turntable import AxisMode, AxisState, AxisStatus, TableState
from tests.helpers.disk import FillingDisk
from tests.helpers.run import assert_disabled, assert_mcap_readable, cli, read_all_messages
from tests.helpers.tui import (
    SIZE,
    connected,
    dialog_open,
    events_text,
    make_app,
    press,
    run,
    snap,
    submit,
    wait_until,
)

#: where layout matters (the warning's line in the Events panel): the two terminal widths the TUI is checked at
SIZES = [(100, 30), (140, 40)]


def _at(app, frame: int, angle_deg: float) -> bool:
    state = snap(app).table_state
    return state is not None and abs(state.angles_deg[frame] - angle_deg) < 1e-3 and state.axes[frame].in_position


def _manual_logs(folder):
    return sorted(folder.glob("*-manual.mcap"))


@pytest.fixture(scope="module")
def manual_session(tmp_path_factory):
    """A session that went to (5, 0, 0) deg with the go-to dialog and jogged the inner frame +1 deg, then quit:
    (its folder, the app after it ended)."""
    out = tmp_path_factory.mktemp("tui-manual")
    holder = []

    async def body():
        app = make_app(out)
        holder.append(app)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            assert list(out.iterdir()) == []
            await press(pilot, "g")
            dialog = await dialog_open(pilot, "GotoScreen", "#goto-inner")
            dialog.query_one("#goto-outer").value = "5"
            await submit(pilot, dialog)
            await wait_until(pilot, lambda: _at(app, 0, 5.0), "the go to (5, 0, 0) deg")
            assert len(_manual_logs(out)) == 1
            await wait_until(pilot, lambda: "log of manual moves" in events_text(app), "the log's name in the events")
            for _ in range(2):
                await press(pilot, "j")                          # outer -> middle -> inner
            await press(pilot, "right_square_bracket")
            await wait_until(pilot, lambda: _at(app, 2, 1.0), "the jog of inner to +1 deg")
            await pilot.pause(0.3)                               # a few more monitor polls: the table at rest
    run(body)
    return out, holder[0]


def test_a_manual_move_starts_a_log_with_the_move_in_it(manual_session):
    out, app = manual_session
    logs = list(out.iterdir())
    assert len(logs) == 1 and logs[0].name.endswith("-manual.mcap"), logs
    path = logs[0]
    assert app.session.manual_logs == [path]
    assert_mcap_readable(path)                     # closed properly: summary, statistics, CRCs
    counts, _, metadata, attachments = read_all_messages(path)
    # the layout of a run's log, without a plan record
    assert metadata["run"]["kind"] == "manual" and metadata["run"]["mode"] == "simulator"
    assert path.name == metadata["run"]["run_id"] + ".mcap"
    assert "plan" not in metadata and {"config", "site", "imu"} <= set(metadata)
    assert metadata["imu"]["dbc"] in attachments
    assert counts["/table/state"] > 5 and counts["/events"] >= 4 and counts["/can/raw"] > 0
    assert counts["/imu/samples"] > 0
    log = read_log(str(path))
    assert log.scan().complete and not log.scan().damage
    commands = [e.details for e in log.events if isinstance(e, Note) and "command" in e.details]
    assert [c["command"] for c in commands] == ["go_to", "jog"]
    assert commands[0]["angles_deg"] == [5.0, 0.0, 0.0] and commands[1]["frame"] == "inner"
    assert commands[1]["step_deg"] == 1.0
    messages = [e.message for e in log.events]
    assert messages[0].startswith("log of manual moves ") and "go to 5, 0, 0 deg" in messages[0]
    assert messages[-1] == "manual log closed: the session ended"
    assert "table stopped, servos off" in messages
    # the move itself: the table states go from zero to the targets, and end stopped with the servos off
    states = log.read_table_states()
    assert list(states.angles_deg[0]) == [0.0, 0.0, 0.0]
    assert any(abs(a[0] - 5.0) < 1e-3 and abs(a[2]) < 1e-3 for a in states.angles_deg)
    assert abs(states.angles_deg[-1][0] - 5.0) < 1e-3 and abs(states.angles_deg[-1][2] - 1.0) < 1e-3
    assert list(states.modes[-1]) == ["off", "off", "off"]
    # IMU data from the first move on, on the run clock like the states
    can_t = log.read_can_timestamps_s()
    assert can_t[0] >= states.time_s[0] - 0.5 and can_t[-1] <= states.time_s[-1] + 0.5


def test_quitting_names_the_log_of_manual_moves(manual_session, capsys):
    out, app = manual_session
    capsys.readouterr()
    assert exit_status(app) == 0
    assert capsys.readouterr().out.strip() == f"bench tui: manual moves logged to {_manual_logs(out)[0]}"


def test_bench_replay_plays_a_log_of_manual_moves(manual_session):
    out, _ = manual_session
    path = _manual_logs(out)[0]
    rc, stdout, stderr = cli(["replay", str(path)])
    assert rc == 0, stderr
    assert f"bench replay: {path}: a log of manual moves (bench tui), no plan; progress without step names" in stderr
    assert "damaged" not in stderr
    assert "moving to 5, 0, 0 deg" in stderr and "jog inner +1 deg" in stderr
    summary = stdout.strip().splitlines()[-1]
    counts, _, _, _ = read_all_messages(path)
    assert summary.startswith(f"replayed {counts['/events']} events, {counts['/table/state']} table states, ")
    assert " 0 IMU samples" not in summary and " 0 CAN frames" not in summary


def test_bench_solve_says_there_is_no_calibration_plan(manual_session, tmp_path):
    out, _ = manual_session
    path = _manual_logs(out)[0]
    rc, stdout, stderr = cli(["solve", str(path), "--out", str(tmp_path)])
    assert rc == 2 and stdout == ""
    assert stderr.strip() == f"bench solve: {path}: {NO_PLAN_IN_MANUAL_LOG}, so there is nothing to solve"
    assert stderr.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_tui_replay_shows_the_manual_moves(manual_session):
    out, _ = manual_session
    path = _manual_logs(out)[0]

    async def body():
        from bench.tui import create_app

        app = create_app(replay=path, speed=None, refresh_hz=20.0)
        async with app.run_test(size=SIZE) as pilot:
            await wait_until(pilot, lambda: snap(app).outcome_text, "the end of the playback")
            assert snap(app).outcome_text == f"no result: {NO_PLAN_IN_MANUAL_LOG}, so there is nothing to solve"
            assert snap(app).result is None and app.session.stats.table_states > 5
            assert app.session.stats.samples > 0
            assert abs(snap(app).table_state.angles_deg[0] - 5.0) < 1e-3
            await wait_until(pilot, lambda: "jog inner +1 deg" in events_text(app), "the recorded jog in the events")
            text = events_text(app)
            assert "moving to 5, 0, 0 deg" in text and "no plan record" not in text and "damaged" not in text
    run(body)


@pytest.mark.slow
def test_no_move_no_file(tmp_path):
    """Servos on, halt, servos off, disconnect and connect again: nothing moved, nothing written."""
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            await press(pilot, "e")
            await wait_until(pilot, lambda: all(a.enabled for a in snap(app).table_state.axes), "servos on")
            await press(pilot, "h")
            await wait_until(pilot, lambda: "stop: every axis" in events_text(app), "the halt")
            await press(pilot, "x")
            await wait_until(pilot, lambda: not any(a.enabled for a in snap(app).table_state.axes), "servos off")
            await press(pilot, "d")
            await wait_until(pilot, lambda: app.session.run is None, "the disconnect")
            await press(pilot, "c")
            await connected(pilot)
        return app

    holder = []

    async def keep():
        holder.append(await body())
    run(keep)
    assert list(tmp_path.iterdir()) == []
    assert holder[0].session.manual_logs == []


@pytest.mark.slow
def test_a_log_that_cannot_be_opened_warns_once_and_the_moves_go_ahead(tmp_path):
    """The output folder gone since the connect (a file in its place, which stops root too): the operator is
    told once, the table moves anyway, and it is stopped on quit."""
    import shutil

    out = tmp_path / "out"

    async def body():
        app = make_app(tmp_path, out_dir=out)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)
            controller = app.session.run.world.controller
            shutil.rmtree(out)
            out.write_text("not a folder\n", encoding="utf-8")
            app.session.go_to((3.0, 0.0, 0.0)).join(10)
            await wait_until(pilot, lambda: _at(app, 0, 3.0), "the move")
            await wait_until(pilot, lambda: "manual moves are not logged: output folder" in events_text(app),
                             "the warning")
            app.session.go_to((0.0, 0.0, 0.0)).join(10)
            await wait_until(pilot, lambda: _at(app, 0, 0.0), "the move back")
            app.session.set_rate(0, 20.0).join(10)
            await wait_until(pilot, lambda: abs(snap(app).table_state.axes[0].rate_dps - 20.0) < 1e-6,
                             "outer turning")
            assert events_text(app).count("manual moves are not logged") == 1
        return controller

    holder = []

    async def keep():
        holder.append(await body())
    run(keep)
    assert_disabled(holder[0], at_rest=False)
    assert out.read_text(encoding="utf-8") == "not a folder\n"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


@pytest.mark.slow
@pytest.mark.parametrize("size", SIZES, ids=[f"{w}x{h}" for w, h in SIZES])
def test_a_full_disk_warns_the_controls_still_work_and_quit_stops_the_table(tmp_path, monkeypatch, capsys, size):
    monkeypatch.setattr(FillingDisk, "full", False)
    monkeypatch.setattr(recorder_module, "open", FillingDisk.open, raising=False)

    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=size) as pilot:
            await connected(pilot)
            controller = app.session.run.world.controller
            app.session.go_to((2.0, 0.0, 0.0)).join(10)
            await wait_until(pilot, lambda: _at(app, 0, 2.0), "the move")
            path = app.session.manual_logs[0]
            FillingDisk.full = True
            warning = f"manual log {path.name} failed: log disk full: cannot write MCAP log {path}: No space left"
            await wait_until(pilot, lambda: warning in " ".join(events_text(app).split()), "the warning")
            # it is in the Events panel as drawn, at this width
            shown = " ".join(app.query_one("#event-log").plain_lines[-20:])
            assert "manual moves are no longer recorded" in " ".join(shown.split())
            # the controls: a jog and rate mode still work (the jog keys move the outer frame)
            await press(pilot, "right_square_bracket")
            await wait_until(pilot, lambda: _at(app, 0, 3.0), "the jog to 3 deg")
            app.session.set_rate(0, -20.0).join(10)
            await wait_until(pilot, lambda: abs(snap(app).table_state.axes[0].rate_dps + 20.0) < 1e-6,
                             "outer turning")
            assert events_text(app).count("manual moves are no longer recorded") == 1
        return app, controller

    holder = []

    async def keep():
        holder.append(await body())
    run(keep)
    app, controller = holder[0]
    assert_disabled(controller, at_rest=False)          # quit stopped the table while it turned: servos off
    assert app.session.run is None
    path = app.session.manual_logs[0]
    capsys.readouterr()
    assert exit_status(app) == 0
    assert capsys.readouterr().out.strip() == (f"bench tui: manual moves logged to {path} (cut short: log disk full: "
                                               f"cannot write MCAP log {path}: No space left on device)")
    # what reached the disk is kept: a log cut short at the failure, readable like a crashed run's
    log = read_log(str(app.session.manual_logs[0]))
    assert not log.scan().complete and log.metadata["run"]["kind"] == "manual"


def test_bench_run_will_not_resume_a_log_of_manual_moves(manual_session, tmp_path):
    out, _ = manual_session
    path = _manual_logs(out)[0]
    rc, _, stderr = cli(["run", "--sim", "--resume", str(path), "--out", str(tmp_path / "out"), "--quiet"])
    assert rc == 2
    assert stderr.strip() == f"bench run: {path}: {NO_PLAN_IN_MANUAL_LOG}, so there is nothing to resume"
    assert not (tmp_path / "out").exists() or list((tmp_path / "out").iterdir()) == []


# -- ManualLog on its own: a slow disk drops records and says so; a failing one is contained ------------------

class _SlowRecorder(McapRecorder):
    """A recorder whose first table state waits until released (a disk that stalls)."""

    def __init__(self, path):
        super().__init__(path)
        self.entered, self.release = threading.Event(), threading.Event()

    def on_table_state(self, state):
        if not self.entered.is_set():
            self.entered.set()
            assert self.release.wait(30.0), "never released"
        super().on_table_state(state)


def _state(t: float) -> TableState:
    return TableState(t, tuple(AxisState(0.0, 0.0, AxisMode.OFF, AxisStatus(0)) for _ in range(3)))


def test_a_stalled_disk_drops_records_without_blocking_and_says_how_many(tmp_path):
    warnings: list[str] = []
    recorder = _SlowRecorder(tmp_path / "m.mcap")
    manual = ManualLog(recorder, ManualClock(), warnings.append, max_pending=3)
    manual.on_table_state(_state(0.0))
    assert recorder.entered.wait(30.0)              # the writer is stuck in the first write
    for k in range(1, 11):                          # 3 fit in the queue, 7 are dropped: none of these calls waits
        manual.on_table_state(_state(float(k)))
    assert manual.dropped == 7
    assert warnings == ["manual log m.mcap: the disk does not keep up; records are being dropped"]
    recorder.release.set()
    assert manual.close("test over")
    log = read_log(str(tmp_path / "m.mcap"))
    assert log.scan().complete and list(log.read_table_states().time_s) == [0.0, 1.0, 2.0, 3.0]
    assert [e.message for e in log.events] == ["7 records were dropped: the disk did not keep up",
                                               "manual log closed: test over"]


class _BrokenRecorder(McapRecorder):
    def on_imu(self, block):
        raise OSError(28, "No space left on device")


def test_a_failing_write_is_contained_warned_once_and_the_file_closed(tmp_path):
    warnings: list[str] = []
    manual = ManualLog(_BrokenRecorder(tmp_path / "b.mcap"), ManualClock(), warnings.append)
    manual.on_table_state(_state(0.0))
    block = ImuSampleBlock(np.arange(3), np.arange(3) / 10.0, np.zeros((3, 3)), np.zeros((3, 3)), np.full(3, 20.0),
                           np.zeros(3, np.int64), 10.0)
    for _ in range(3):
        manual.on_imu(block)                        # never raises here: the writer thread meets the error
    manual.event("info", "after the failure")
    assert manual.close("test over")
    assert manual.failure == "OSError: [Errno 28] No space left on device"
    assert warnings == [f"manual log b.mcap failed: {manual.failure}; manual moves are no longer recorded "
                        "(the table and the controls are not affected)"]
    assert manual.closed and manual.recorder.closed
    assert read_log(str(tmp_path / "b.mcap")).events == []      # nothing after the failure
