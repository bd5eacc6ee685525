"""The sequencer's state machine against the simulated world (real SCPI driver, virtual CAN bus)."""

from __future__ import annotations

import pytest

from bench.log.events import RunListener, RunState, Transition
from bench.model.earth import Site
from bench.model.imu import NoiseModel, default_sim_imu
from bench.plan.steps import DwellStep, MoveStep, SettleStep, TurnStep
from bench.run.sequencer import RunAborted, Sequencer, SequencerError, SequencerOptions
from bench.sim.world import SimWorld
from drivers.errors import ImuTimeout
from drivers.imu.receiver import ImuReceiver
from drivers.turntable import open_turntable

STEPS = (MoveStep(index=0, unit="P01", target_deg=(0.0, 90.0, 90.0), rate_dps=60.0, estimated_s=2.0),
         SettleStep(index=1, unit="P01", duration_s=1.0, estimated_s=1.0),
         DwellStep(index=2, unit="P01", schedule="test", schedule_index=0, angles_deg=(0.0, 90.0, 90.0),
                   target_deg=(0.0, 90.0, 90.0), dwell_s=2.0, estimated_s=2.0),
         MoveStep(index=3, unit="P02", target_deg=(0.0, 0.0, 0.0), rate_dps=60.0, estimated_s=2.0),
         DwellStep(index=4, unit="P02", schedule="test", schedule_index=1, angles_deg=(0.0, 0.0, 0.0),
                   target_deg=(0.0, 0.0, 0.0), dwell_s=2.0, estimated_s=2.0),
         TurnStep(index=5, unit="R01", schedule="test", schedule_index=0, start_deg=(0.0, 0.0, 0.0),
                  target_deg=(0.0, 0.0, 0.0), frame="inner", direction="ccw", revolutions=1, rate_dps=90.0,
                  accel_dps2=90.0, rest_s=0.5, estimated_s=6.0))
OPTIONS = SequencerOptions(move_poll_s=0.1, imu_poll_s=0.25, state_period_s=0.5)


class Recorder(RunListener):
    """Keeps what a run produced; `hooks[(kind, index)]` runs when that event arrives."""

    def __init__(self):
        self.events, self.samples, self.states, self.frames, self.hooks = [], 0, [], 0, {}

    def on_event(self, event):
        self.events.append(event)
        hook = self.hooks.get((event.kind, event.step_index))
        if hook:
            hook()

    def on_imu(self, block):
        self.samples += len(block)

    def on_table_state(self, state):
        self.states.append(state)

    def on_can_frames(self, frames):
        self.frames += len(frames)

    def kinds(self):
        return [(e.kind, e.state if isinstance(e, Transition) else e.step_unit) for e in self.events]


@pytest.fixture
def bench():
    with SimWorld(Site(30.27), default_sim_imu(), NoiseModel.off(), imu_rate_hz=50.0) as world:
        table = open_turntable(world.table_url, "scpi", clock=world.clock, timeout_s=1.0)
        table.connect()
        receiver = ImuReceiver(world.receiver_bus(), rate_hz=50.0)
        table.enable()
        yield world, table, world.imu_source(receiver)
        table.close()
        receiver.close()


def _sequencer(bench, listener, steps=STEPS, **kwargs):
    world, table, imu = bench
    return Sequencer(steps, table, imu, world.clock, [listener], OPTIONS, **kwargs)


def test_a_run_goes_idle_running_done_with_every_step_boundary_as_an_event(bench):
    listener = Recorder()
    seq = _sequencer(bench, listener)
    assert seq.state is RunState.IDLE
    assert seq.run() is RunState.DONE and seq.error is None
    transitions = [e.state for e in listener.events if e.kind == "transition"]
    assert transitions == ["running", "done"]
    started = [e.step_index for e in listener.events if e.kind == "step_started"]
    finished = [e.step_index for e in listener.events if e.kind == "step_finished"]
    assert started == finished == list(range(len(STEPS)))
    dwell = next(e for e in listener.events if e.kind == "step_finished" and e.step_index == 2)
    assert dwell.window.last - dwell.window.first + 1 == dwell.window.samples == 100  # 2 s at 50 Hz
    turn = seq.windows["R01"]
    assert turn.samples >= 50 * (4.0 + 1.0)             # rest, 360 deg at 90 deg/s, rest
    assert listener.frames == 7 * listener.samples > 0     # every frame reached the listeners
    world = bench[0]
    assert world.controller.state().angles_deg == pytest.approx((0.0, 0.0, -360.0))
    # Event times are simulated: the whole plan took more simulated than real time.
    assert listener.events[-1].time_s > 15.0


def test_pause_takes_effect_at_a_step_boundary_and_resume_continues(bench):
    listener = Recorder()
    seq = _sequencer(bench, listener)
    paused_at = []

    def pause_then_resume():
        seq.pause()
        def on_transition():
            if seq.state is RunState.PAUSED:
                paused_at.append(listener.events[-1].time_s)
                seq.resume()

        listener.hooks[("transition", None)] = on_transition

    listener.hooks[("step_started", 2)] = pause_then_resume   # asked mid-dwell
    assert seq.run() is RunState.DONE
    transitions = [e.state for e in listener.events if e.kind == "transition"]
    assert transitions == ["running", "paused", "running", "done"]
    # The pause came after the dwell finished, not inside it.
    order = listener.kinds()
    assert order.index(("step_finished", "P01")) < order.index(("transition", "paused"))
    assert len(paused_at) == 1


def test_abort_stops_the_table_switches_servos_off_and_fails(bench):
    listener = Recorder()
    seq = _sequencer(bench, listener)
    listener.hooks[("step_started", 5)] = lambda: seq.abort("operator abort")
    assert seq.run() is RunState.FAILED
    assert isinstance(seq.error, RunAborted)
    transitions = [e.state for e in listener.events if e.kind == "transition"]
    assert transitions == ["running", "aborting", "failed"]
    state = bench[0].controller.state()
    assert all(not axis.enabled and axis.rate_dps == 0.0 for axis in state.axes)
    assert not listener.states[-1].axes[0].enabled          # the last published state shows it


def test_abort_while_paused_ends_the_run(bench):
    listener = Recorder()
    seq = _sequencer(bench, listener)
    listener.hooks[("step_started", 1)] = seq.pause
    listener.hooks[("transition", None)] = (
        lambda: seq.abort("abort while paused") if seq.state is RunState.PAUSED else None
    )
    assert seq.run() is RunState.FAILED
    assert [e.state for e in listener.events if e.kind == "transition"] == ["running", "paused", "aborting", "failed"]


def test_completed_units_are_skipped(bench):
    listener = Recorder()
    seq = _sequencer(bench, listener, completed_units={"P01"})
    assert seq.run() is RunState.DONE
    skipped = [e.step_index for e in listener.events if e.kind == "step_skipped"]
    assert skipped == [0, 1, 2]


def test_silent_imu_while_recording_is_a_fault_and_a_safe_stop(bench):
    world, table, imu = bench

    class Silent:                     # the receiver with the bus unplugged: polls return nothing
        stats, on_frames = imu.stats, None

        def poll(self):
            return imu._receiver.decoder.take_block()

    listener = Recorder()
    seq = Sequencer(STEPS, table, Silent(), world.clock, [listener], OPTIONS)
    assert seq.run() is RunState.FAILED
    assert isinstance(seq.error, ImuTimeout)
    fault = next(e for e in listener.events if e.kind == "fault")
    assert fault.error == "ImuTimeout" and fault.step_unit == "P01"
    assert all(not a.enabled for a in world.controller.state().axes)


class Raising(RunListener):
    """Raises from `method` from its `after + 1`-th call on, as a progress printer does on a closed pipe."""

    def __init__(self, method: str, after: int):
        self.method, self.after, self.calls, self.raised = method, after, 0, 0

    def _call(self, method: str) -> None:
        if method == self.method:
            self.calls += 1
            if self.calls > self.after:
                self.raised += 1
                raise BrokenPipeError(32, "Broken pipe")

    def on_event(self, event):
        self._call("on_event")

    def on_imu(self, block):
        self._call("on_imu")


class TableAtFault(RunListener):
    """The simulated controller's state when the fault event arrives."""

    def __init__(self, controller):
        self.controller, self.state = controller, None

    def on_event(self, event):
        if event.kind == "fault" and self.state is None:
            self.state = self.controller.state()


@pytest.mark.parametrize("method", ["on_event", "on_imu"])
def test_a_listener_that_raises_ends_the_run_with_the_table_stopped_and_the_others_told(bench, method):
    world, table, imu = bench
    before, failing, after, at_fault = Recorder(), Raising(method, after=5), Recorder(), TableAtFault(world.controller)
    seq = Sequencer(STEPS, table, imu, world.clock, [before, failing, after, at_fault], OPTIONS)
    assert seq.run() is RunState.FAILED
    assert type(seq.error).__name__ == "ListenerError"
    assert str(seq.error) == "Raising failed: BrokenPipeError: [Errno 32] Broken pipe"
    assert failing.raised == 1                         # set aside at its first error: nothing more to it
    assert [(listener, type(exc)) for listener, exc in seq.listener_errors] == [(failing, BrokenPipeError)]
    assert all(not axis.enabled and axis.rate_dps == 0.0 for axis in world.controller.state().axes)
    # the table was stopped before any listener heard of the failure
    assert at_fault.state is not None and all(not axis.enabled for axis in at_fault.state.axes)
    for listener in (before, after):                   # the others got everything, in order
        assert [e.state for e in listener.events if e.kind == "transition"] == ["running", "aborting", "failed"]
        faults = [e for e in listener.events if e.kind == "fault"]
        assert len(faults) == 1 and "Raising failed: BrokenPipeError" in faults[0].message
        kinds = [e.kind for e in listener.events]
        assert kinds.index("fault") < kinds.index("info") < len(kinds) - 1
        assert any(e.kind == "info" and "servos off" in e.message for e in listener.events)
        assert not listener.states[-1].axes[0].enabled
    assert before.kinds() == after.kinds() and before.samples == after.samples > 0


def test_listener_errors_while_the_table_stops_are_reported_once_each(bench):
    world, table, imu = bench
    first, second, other = Raising("on_event", after=3), Raising("on_event", after=4), Recorder()
    seq = Sequencer(STEPS, table, imu, world.clock, [first, second, other], OPTIONS)
    assert seq.run() is RunState.FAILED
    assert [listener for listener, _ in seq.listener_errors] == [first, second]
    assert first.raised == second.raised == 1
    faults = [e for e in other.events if e.kind == "fault"]
    warnings = [e for e in other.events if e.kind == "warning" and "Raising failed" in e.message]
    assert len(faults) == 1 and len(warnings) == 1
    assert all(not axis.enabled for axis in world.controller.state().axes)


def test_illegal_transitions_are_refused(bench):
    seq = _sequencer(bench, Recorder())
    with pytest.raises(SequencerError, match="illegal transition idle -> done"):
        seq._transition(RunState.DONE, "no")


@pytest.mark.slow
@pytest.mark.parametrize("dialect", ["mn", "modbus", "acutrol"])
def test_a_whole_run_works_in_the_other_dialects(tmp_path, dialect):
    """`bench run` on the simulator served in $MN (TCP), Modbus TCP and ACL (TCP): same plan, same precision."""
    from tests.helpers.run import cli, config_text, load_json, only_file

    config = tmp_path / "bench.toml"
    config.write_text(config_text(dialect=dialect, positions="traditional-12", rotations="traditional-3s6r"),
                      encoding="utf-8")
    code, _, stderr = cli(["run", "--config", str(config), "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 0, stderr
    result = load_json(only_file(tmp_path / "out", "*.result.json"))
    truth = result["sim_truth"]["coefficients"]
    for name in ("Kg_x", "Kg_y", "Kg_z", "Ka_x", "Ka_y", "Ka_z"):
        assert result["coefficients"][name]["value"] == pytest.approx(truth[name]["value"], rel=1e-7), name


def test_a_rest_polls_the_state_on_time_when_the_imu_is_drained_less_often(bench):
    """The simulator drains the IMU every 2 s but polls the table every 1 s: the clock stops at every state poll."""
    world, table, imu = bench
    listener = Recorder()
    dwell = DwellStep(index=0, unit="P01", schedule="test", schedule_index=0, angles_deg=(0.0, 0.0, 0.0),
                      target_deg=(0.0, 0.0, 0.0), dwell_s=6.0, estimated_s=6.0)
    options = SequencerOptions(move_poll_s=0.1, imu_poll_s=2.0, state_period_s=0.5)
    seq = Sequencer([dwell], table, imu, world.clock, [listener], options)
    drains = []
    poll = imu.poll

    def counted_poll(*args, **kwargs):
        drains.append(world.clock.now())
        return poll(*args, **kwargs)

    imu.poll = counted_poll
    assert seq.run() is RunState.DONE
    times = [s.time_s for s in listener.states]
    assert len(times) >= 12 and max(b - a for a, b in zip(times, times[1:])) <= 0.5 + 1e-9
    # drains: before the window, every 2 s, at its end and after the run (not at every 0.5 s step)
    assert len(drains) <= 6 and listener.samples == 6 * 50
