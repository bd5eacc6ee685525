"""`bench replay`: a log played back delivers what the live run delivered to its listeners.

One short simulated run (tests/helpers/run.py's plan, ~4 s) is captured live by a
listener; its log is then replayed into another one and the two are compared item by
item. Pacing runs on a ManualClock, so `--speed` tests take no wall time.
"""

from __future__ import annotations

import dataclasses
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from bench.config.load import parse_config
from bench.log.events import RunListener, StepFinished
from bench.log.reader import read_log
from bench.log.replay import replay
from bench.log.run_info import layout_and_config_from_log, steps_from_log
from bench.plan.steps import step_from_dict, step_to_dict
from bench.run.devices import SIMULATOR
from bench.run.runner import BenchRun, compile_from_config
from drivers.clock import ManualClock
from drivers.imu import DEFAULT_DBC, DEFAULT_PACKED_DBC, ImuSampleBlock, default_packed_layout
from tests.helpers.run import REPO, Trigger, api_run, cli, config_text, start_cli, step_index, stop_process
from tests.helpers.shared import share


class Capture(RunListener):
    """Everything a listener is given, in order; `clock` stamps each event's delivery."""

    def __init__(self, clock=None):
        self.clock = clock
        self.order: list[tuple[str, object]] = []
        self.events, self.states, self.blocks, self.frames = [], [], [], []
        self.event_clock: list[float] = []
        self.closed = 0

    def on_event(self, event):
        self.events.append(event)
        self.order.append(("event", event))
        if self.clock is not None:
            self.event_clock.append(self.clock.now())

    def on_table_state(self, state):
        self.states.append(state)
        self.order.append(("state", state))

    def on_imu(self, block):
        self.blocks.append(block)
        self.order.append(("imu", block))

    def on_can_frames(self, frames):
        self.frames.extend(frames)
        self.order.append(("frames", frames))

    def close(self):
        self.closed += 1

    def samples(self) -> ImuSampleBlock:
        return ImuSampleBlock.concatenate(self.blocks, rate_hz=1.0)


@dataclasses.dataclass
class Recorded:
    log_path: Path
    live: Capture
    plan: object
    config: object


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Recorded:
    """A run of the short test plan (1 s dwells) with what its listener received live: its own run (the session's
    logs were recorded without this listener; the shortest plan gives fewer samples and steps than the checks ask
    for), read only by the tests."""
    out = tmp_path_factory.mktemp("replay")
    config = parse_config(config_text(dwell_s=1.0), source=str(out / "bench.toml"), base_dir=out)
    plan = compile_from_config(config)
    live = Capture()
    with BenchRun(config, plan, devices=SIMULATOR, out_dir=out, listeners=[live]) as run:
        run.open()
        run.run()
        outcome = run.finish()
    assert outcome.error is None, outcome.error
    share(out)
    return Recorded(outcome.log_path, live, plan, config)


@pytest.fixture(scope="module")
def log(recorded):
    return read_log(recorded.log_path)


@pytest.fixture(scope="module")
def replayed(log):
    capture = Capture()
    stats = replay(log, [capture])
    return capture, stats


class EventClock(RunListener):
    """Only events and the clock time of each delivery (no CAN frames asked for: none are built)."""

    def __init__(self, clock=None, stop_after: int | None = None, stop: threading.Event | None = None):
        self.clock, self.stop_after, self.stop = clock, stop_after, stop
        self.events, self.event_clock = [], []
        self.closed = 0

    def on_event(self, event):
        self.events.append(event)
        if self.clock is not None:
            self.event_clock.append(self.clock.now())
        if self.stop_after is not None and len(self.events) == self.stop_after:
            self.stop.set()

    def close(self):
        self.closed += 1


def frame_tuple(m) -> tuple:
    return (m.timestamp, m.arbitration_id, m.is_extended_id, m.is_fd, m.bitrate_switch, m.error_state_indicator,
            m.is_remote_frame, m.is_error_frame, m.dlc, bytes(m.data))


# -- same content as live ------------------------------------------------------------------

def test_replay_delivers_the_live_event_sequence(recorded, replayed):
    capture, stats = replayed
    live = recorded.live.events
    assert len(live) > 100 and stats.events == len(live)
    assert [(e.kind, e.message, e.step_index, e.time_s, e.to_dict()["data"]) for e in capture.events] == \
           [(e.kind, e.message, e.step_index, e.time_s, e.to_dict()["data"]) for e in live]
    assert capture.events == live     # state and step_unit too
    assert capture.closed == 1


def test_replay_delivers_the_live_samples(recorded, replayed):
    capture, stats = replayed
    live, again = recorded.live.samples(), capture.samples()
    assert len(live) > 10_000
    assert stats.samples == len(again) == len(live)
    np.testing.assert_array_equal(again.counter, live.counter)
    np.testing.assert_array_equal(again.gyro_counts, live.gyro_counts)
    np.testing.assert_array_equal(again.acc_counts, live.acc_counts)
    np.testing.assert_array_equal(again.temperature_c, live.temperature_c)
    np.testing.assert_array_equal(again.status, live.status)
    np.testing.assert_array_equal(again.receive_time_s, live.receive_time_s)
    assert {b.rate_hz for b in capture.blocks} == {recorded.config.imu.rate_hz}
    assert stats.imu_stats.lost_samples == 0 and stats.imu_stats.frame_faults == 0


def test_blocks_hold_at_most_a_tenth_of_a_second(replayed):
    capture, _ = replayed
    spans = [b.receive_time_s[-1] - b.receive_time_s[0] for b in capture.blocks]
    assert max(spans) <= 0.1 + 1e-9
    assert all(len(b) for b in capture.blocks)


def test_replay_delivers_the_live_can_frames(recorded, replayed):
    capture, stats = replayed
    live = recorded.live.frames
    assert len(live) > 50_000 and stats.frames == len(capture.frames) == len(live)
    assert [frame_tuple(m) for m in capture.frames] == [frame_tuple(m) for m in live]


def test_replay_delivers_the_live_table_states(recorded, replayed):
    capture, stats = replayed
    assert len(recorded.live.states) > 100
    assert stats.table_states == len(capture.states)
    assert capture.states == recorded.live.states


def test_samples_of_a_finished_step_arrive_before_its_event(replayed):
    capture, _ = replayed
    newest = -1
    checked = 0
    for kind, item in capture.order:
        if kind == "imu":
            newest = int(item.counter[-1])
        elif kind == "event" and isinstance(item, StepFinished) and item.window is not None:
            assert newest >= item.window.last, item
            checked += 1
    assert checked > 20


def test_frames_arrive_before_the_samples_they_complete(replayed):
    capture, _ = replayed
    newest_frame = -np.inf
    for kind, item in capture.order:
        if kind == "frames":
            newest_frame = max(newest_frame, max(m.timestamp for m in item))
        elif kind == "imu":
            assert item.receive_time_s.max() <= newest_frame


# -- pacing and stopping --------------------------------------------------------------------

def test_speed_paces_log_time_on_the_injected_clock(log):
    clock = ManualClock(100.0)
    capture = EventClock(clock)
    stats = replay(log, [capture], speed=10.0, clock=clock)
    t0 = stats.log_start_s
    assert stats.log_duration_s > 100.0
    assert clock.now() - 100.0 == pytest.approx(stats.log_duration_s / 10.0, abs=1e-6)
    assert stats.wall_s == pytest.approx(stats.log_duration_s / 10.0, abs=1e-6)
    lag = [wall - 100.0 - (e.time_s - t0) / 10.0 for wall, e in zip(capture.event_clock, capture.events)]
    assert max(abs(x) for x in lag) < 1e-6


def test_as_fast_as_possible_never_sleeps(log):
    clock = ManualClock(5.0)
    replay(log, [EventClock()], clock=clock)
    assert clock.now() == 5.0


def test_stop_ends_the_replay_early_and_closes_the_listeners(log):
    stop = threading.Event()
    capture = EventClock(stop_after=10, stop=stop)
    stats = replay(log, [capture], speed=1000.0, clock=ManualClock(), stop=stop)
    assert stats.stopped and stats.events == 10 and capture.closed == 1
    # the summary says how far it got, not the log's whole length as if it had played it all
    tenth = log.events[9].time_s - stats.log_start_s
    assert stats.log_reached_s == pytest.approx(tenth, abs=0.1) and stats.log_reached_s < stats.log_duration_s
    assert (f"stopped early at log time {stats.log_reached_s:.1f} s of {stats.log_duration_s:.1f} s in "
            in stats.summary())


def test_the_summary_says_when_the_recorded_run_ended_early(tmp_path):
    """A log of an aborted run replays to its end, and the summary says the run itself failed."""
    text = config_text(dwell_s=1.0)
    plan = compile_from_config(parse_config(text, source=str(tmp_path / "bench.toml"), base_dir=tmp_path))
    trigger = Trigger(step_index(plan, "dwell", 1), lambda run: run.abort("operator abort"))
    with api_run(text, tmp_path, trigger) as (run, outcome):
        assert outcome.state.value == "failed"
    stats = replay(read_log(outcome.log_path), [Capture()])
    assert not stats.stopped and stats.run_state == "failed"
    assert f"log time {stats.log_duration_s:.1f} s (the recorded run ended early: failed) in " in stats.summary()


def test_a_listener_error_propagates_after_every_listener_is_closed(log):
    class Broken(RunListener):
        def on_table_state(self, state):
            raise RuntimeError("listener broke")

    other = EventClock()
    with pytest.raises(RuntimeError, match="listener broke"):
        replay(log, [other, Broken()])
    assert other.closed == 1


@pytest.mark.parametrize("speed", [0, -1.0, float("nan"), float("inf")])
def test_bad_speed_is_refused(log, speed):
    with pytest.raises(ValueError, match="speed"):
        replay(log, [], speed=speed)


# -- the setup recorded in the log ------------------------------------------------------------

def test_steps_and_setup_come_back_from_the_log(recorded, log):
    assert steps_from_log(log) == tuple(recorded.plan.steps)
    setup = layout_and_config_from_log(log)
    assert setup.config is not None and setup.notes == ()
    assert setup.layout == recorded.config.imu.layout
    assert setup.rate_hz == recorded.config.imu.rate_hz and setup.site == recorded.config.site.site
    with pytest.raises(ValueError, match="unknown step kind"):
        step_from_dict({**step_to_dict(recorded.plan.steps[0]), "kind": "jump"})


def _with_config(log, toml: str, attachments: dict | None = None):
    """A copy of `log` whose recorded configuration (and attachments) are replaced."""
    return dataclasses.replace(log, metadata={**log.metadata, "config": {"toml": toml, "path": "<test>"}},
                               attachments=log.attachments if attachments is None else attachments)


def test_a_dbc_missing_here_is_taken_from_the_log(recorded, log):
    text = config_text().replace('[imu]\n', '[imu]\ndbc = "/nonexistent/turntable-bench/custom_imu.dbc"\n')
    dbc = DEFAULT_DBC.read_bytes()
    log = _with_config(log, text, {**log.attachments, "custom_imu.dbc": ("text/plain", dbc)})
    setup = layout_and_config_from_log(log)
    assert setup.config is not None, setup.notes
    assert "custom_imu.dbc" in " ".join(setup.notes)
    assert setup.config.imu.dbc == Path("/nonexistent/turntable-bench/custom_imu.dbc")
    assert setup.config.source_text == text
    assert setup.layout.dbc_text == dbc.decode()
    assert len(log.imu_samples(setup.layout, setup.rate_hz)[0]) == len(recorded.live.samples())


def test_without_a_usable_config_the_layout_comes_from_the_attachment(recorded, log):
    text = config_text().replace('[table]\n', '[table]\nregister_map = "/nonexistent/map.toml"\n')
    log = _with_config(log, text)
    setup = layout_and_config_from_log(log)
    assert setup.config is None and "configuration not rebuilt" in setup.notes[0]
    assert setup.layout.messages == recorded.config.imu.layout.messages
    assert setup.rate_hz == recorded.config.imu.rate_hz and setup.site == recorded.config.site.site
    # ...and replay still decodes every sample
    stats = replay(log, [])
    assert stats.samples == len(recorded.live.samples())


def test_without_a_usable_config_a_recorded_shipped_layout_name_picks_its_mapping(log):
    # a log of a packed-layout run whose configuration cannot be rebuilt here: `layout = "packed"` in the
    # recorded [imu] chooses the packed mapping for the attached DBC (it used to fall back to the classic one)
    text = config_text().replace('[table]\n', '[table]\nregister_map = "/nonexistent/map.toml"\n')
    text = text.replace("rate_hz =", 'layout = "packed"\nrate_hz =', 1)
    log = _with_config(log, text, {"sim_imu_packed.dbc": ("text/plain", DEFAULT_PACKED_DBC.read_bytes())})
    log = dataclasses.replace(log, metadata={**log.metadata, "imu": {**log.metadata["imu"],
                                                                       "dbc": "sim_imu_packed.dbc"}})
    setup = layout_and_config_from_log(log)
    assert setup.config is None and setup.layout.messages == default_packed_layout().messages


def test_the_attached_dbc_wins_over_a_changed_file_here(recorded, log):
    name = recorded.config.imu.dbc.name
    changed = log.attachments[name][1].decode().replace("(0.00390625,0)", "(0.0078125,0)", 1)
    assert changed != log.attachments[name][1].decode()
    log = dataclasses.replace(log, attachments={**log.attachments, name: ("text/plain", changed.encode())})
    setup = layout_and_config_from_log(log)
    assert "differs from the file on this machine" in " ".join(setup.notes)
    assert setup.layout.scale != recorded.config.imu.layout.scale


def test_no_decodable_layout_replays_events_and_says_why(recorded, log):
    log = dataclasses.replace(log, metadata={k: v for k, v in log.metadata.items() if k not in ("config", "imu")},
                              attachments={})
    capture = EventClock()
    stats = replay(log, [capture])
    assert stats.samples == 0 and stats.events == len(recorded.live.events)
    assert stats.frames == len(recorded.live.frames)
    assert "IMU samples not replayed" in stats.notes[0]


# -- the command line --------------------------------------------------------------------------

def test_cli_replays_and_prints_the_summary(recorded, replayed):
    live, stats = recorded.live, replayed[1]
    rc, out, err = cli(["replay", str(recorded.log_path), "--quiet"])
    assert rc == 0, err
    assert (f"replayed {len(live.events)} events, {len(live.states)} table states, "
            f"{len(live.samples())} IMU samples, {len(live.frames)} CAN frames") in out
    assert f"log time {stats.log_duration_s:.1f} s in " in out
    assert err == ""


def test_cli_progress_and_speed(recorded):
    rc, out, err = cli(["replay", str(recorded.log_path), "--speed", "2000"])
    assert rc == 0, err
    assert "P01 (unit 1 of" in err and "transition: run complete" in err
    assert out.count("\n") == 1 and out.startswith("replayed ")


def test_cli_not_mcap_is_one_line_exit_2(tmp_path):
    bad = tmp_path / "notes.mcap"
    bad.write_text("this is not a log\n")
    rc, out, err = cli(["replay", str(bad)])
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and "notes.mcap" in err and "not an MCAP file" in err
    rc, _, err = cli(["replay", str(tmp_path / "missing.mcap")])
    assert rc == 2 and "missing.mcap" in err and err.count("\n") == 1


def test_cli_refuses_a_bad_speed(recorded, capsys):
    with pytest.raises(SystemExit) as exc:
        cli(["replay", str(recorded.log_path), "--speed", "0"])
    assert exc.value.code == 2


def test_cli_damaged_log_replays_what_is_readable(recorded, tmp_path):
    data = recorded.log_path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    rc, out, err = cli(["replay", str(cut), "--quiet"])
    assert rc == 0, err
    assert "damaged log:" in err
    capture = Capture()
    stats = replay(read_log(cut), [capture])
    live = recorded.live.events
    assert 0 < stats.events < len(live) and capture.events == live[:stats.events]
    assert f"replayed {stats.events} events" in out


@pytest.mark.slow
def test_cli_ctrl_c_stops_a_paced_replay_with_the_summary(recorded):
    proc = start_cli("replay", str(recorded.log_path), "--speed", "1")
    try:
        first = proc.stderr.readline()       # printed once the Ctrl-C handler is in place
        assert recorded.log_path.name in first, first
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    finally:
        stop_process(proc)
    assert proc.returncode == 130, err
    assert out.startswith("replayed ") and "stopped early" in out


@pytest.mark.slow
@pytest.mark.parametrize("signum, ignored", [(signal.SIGINT, True), (signal.SIGTERM, False), (signal.SIGHUP, False)])
def test_cli_a_stop_signal_stops_a_paced_replay_even_with_sigint_ignored(recorded, signum, ignored):
    # A shell starts `bench replay LOG &` in a script with SIGINT ignored: SIGINT must still stop it;
    # SIGTERM and SIGHUP stop it the same way (exit 130, the summary printed).
    proc = subprocess.Popen([sys.executable, "-m", "bench.cli", "replay", str(recorded.log_path), "--speed", "1"],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=(lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if ignored else None)
    try:
        first = proc.stderr.readline()       # printed once the stop handler is in place
        assert recorded.log_path.name in first, first
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=20)
    finally:
        stop_process(proc)
    assert proc.returncode == 130, err
    assert out.startswith("replayed ") and "stopped early" in out


def test_cli_reads_the_frames_once_with_or_without_quiet(recorded, monkeypatch):
    """Without --quiet the log's summary came first and read every frame chunk once more (a 1 GB log: a
    whole extra pass) before the replay read them again."""
    from bench.log.mcap.chunks import DeferredChunk

    inflated = [0]
    inflate = DeferredChunk.inflate

    def counting(self, *args, **kwargs):
        inflated[0] += 1
        return inflate(self, *args, **kwargs)

    monkeypatch.setattr(DeferredChunk, "inflate", counting)
    reads, said = {}, {}
    for quiet in (False, True):
        inflated[0] = 0
        rc, out, err = cli(["replay", str(recorded.log_path), *(["--quiet"] if quiet else [])])
        assert rc == 0, err
        reads[quiet], said[quiet] = inflated[0], err
    assert reads[False] == reads[True] > 0
    # issue 33: the count before the replay is of recorded batches (it read "1853 CAN frames" for 149,457)
    assert "batches of CAN frames recorded" in said[False] and recorded.log_path.name in said[False].splitlines()[0]
    # and the summary names the same batches: it gave the replay's own deliveries (23,796) as "recorded" (986)
    before = int(re.search(r"(\d+) batches of CAN frames recorded", said[False]).group(1))
    assert f"CAN frames ({before} recorded batches)" in out


@pytest.mark.slow
def test_a_thermal_runs_chamber_states_are_read_and_replayed_in_log_time_order(thermal_run_log):
    """A thermal run's `/chamber/state` messages come back as `ChamberState`s (every one recorded) and are
    replayed to `on_chamber_state` in log-time order among the table states (they were not read at all)."""
    from bench.log.events import RunListener
    from bench.log.format import TOPIC_CHAMBER
    from bench.log.reader import read_log
    from bench.log.replay import replay

    log = read_log(str(thermal_run_log))
    states = log.chamber_states
    assert len(states) == log.message_counts[TOPIC_CHAMBER] >= 10 and log.scan().complete
    assert [round(s.setpoint_c) for s in states] == sorted(round(s.setpoint_c) for s in states)
    assert {round(s.setpoint_c) for s in states} == {24, 26} and all(s.running and not s.alarm for s in states)

    class Order(RunListener):
        def __init__(self) -> None:
            self.seen: list[tuple[str, float]] = []

        def on_table_state(self, state) -> None:
            self.seen.append(("table", state.time_s))

        def on_chamber_state(self, state) -> None:
            self.seen.append(("chamber", state.time_s))

    order = Order()
    stats = replay(log, [order])
    assert [t for kind, t in order.seen if kind == "chamber"] == [s.time_s for s in states]
    times = [t for _, t in order.seen]
    assert times == sorted(times) and stats.chamber_states == len(states)
    assert f"{len(states)} chamber states" in stats.summary()


def test_malformed_chamber_states_are_counted_not_read():
    from bench.log.json_topics import MAX_ALARM_TEXT, chamber_state_row

    good = {"time_s": 5.0, "temperature_c": 23.5, "setpoint_c": 24.0, "ramp_c_per_min": None, "running": True,
            "alarms": 4, "alarm_text": "x" * 2000}
    state = chamber_state_row(good)
    assert state is not None and state.ramp_c_per_min is None and state.describe_alarms().startswith("door open")
    assert len(state.alarm_text) == MAX_ALARM_TEXT
    assert np.isnan(chamber_state_row({**good, "temperature_c": None}).temperature_c)    # a null reading: NaN
    for bad in ({**good, "time_s": None}, {**good, "time_s": "5"}, {**good, "setpoint_c": [1]},
                {**good, "running": 1}, {**good, "alarms": -1}, {**good, "alarms": 1 << 40}, {**good, "alarms": 1.5},
                {**good, "alarm_text": 7}, {**good, "ramp_c_per_min": "fast"}, {**good, "time_s": float("inf")}):
        assert chamber_state_row(bad) is None, bad


@pytest.mark.slow
def test_chamber_states_past_the_readers_limit_are_said_not_read(thermal_run_log, monkeypatch):
    from bench.log import reader
    from bench.log.format import TOPIC_CHAMBER

    monkeypatch.setattr(reader, "MAX_CHAMBER_STATES", 10)
    log = reader.read_log(str(thermal_run_log))
    recorded = log.message_counts[TOPIC_CHAMBER]
    assert len(log.chamber_states) == 10 < recorded and not log.scan().complete
    assert log.scan().damage == [f"byte 0: {recorded - 10} {TOPIC_CHAMBER} messages past the first 10 not read"]


def test_the_summary_counts_frames_and_batches_and_its_time_includes_the_read():
    """Issue 33: stdout said "in 0.19 s" where the progress said "0:00:02 wall": the replay's time left out the
    reading and decoding of the log, which is most of it when played as fast as possible."""
    from bench.log.replay import ReplayStats

    stats = ReplayStats(frames=149_457, recorded_batches=1_853, frame_batches=24_000, wall_s=2.0, read_s=1.81)
    line = stats.summary()
    assert "149457 CAN frames (1853 recorded batches)" in line
    assert "in 2.00 s (1.81 s of it reading and decoding the log)" in line


def test_the_replay_time_counts_from_the_start_of_the_read(log, monkeypatch):
    """The injected clock moves while the log is read: that time is in `wall_s` and in `read_s`."""
    from bench.log import replay as replay_module

    clock = ManualClock(100.0)
    decode = replay_module._decode

    def slow_decode(*args, **kwargs):
        clock.advance(3.0)
        return decode(*args, **kwargs)

    monkeypatch.setattr(replay_module, "_decode", slow_decode)
    stats = replay(log, [], clock=clock)
    assert stats.read_s == pytest.approx(3.0) and stats.wall_s == pytest.approx(3.0)
