"""Terminal progress of a run (bench/cli/progress.py): live bar, plain lines, quiet (issue 19)."""

from __future__ import annotations

import dataclasses
import io

from bench.cli.progress import ERASE_TO_END, CountProgress, ProgressPrinter
from bench.log.events import Event, make_event
from bench.plan.steps import DwellStep, MoveStep, SettleStep, TurnStep, step_to_dict

STEPS = (MoveStep(index=0, unit="P01", target_deg=(0.0, 90.0, 90.0), rate_dps=60.0, estimated_s=2.0),
         SettleStep(index=1, unit="P01", duration_s=1.0, estimated_s=1.0),
         DwellStep(index=2, unit="P01", schedule="test", schedule_index=0, angles_deg=(0.0, 90.0, 90.0),
                   target_deg=(0.0, 90.0, 90.0), dwell_s=2.0, estimated_s=2.0),
         MoveStep(index=3, unit="P02", target_deg=(0.0, 0.0, 0.0), rate_dps=60.0, estimated_s=2.0),
         DwellStep(index=4, unit="P02", schedule="test", schedule_index=1, angles_deg=(0.0, 0.0, 0.0),
                   target_deg=(0.0, 0.0, 0.0), dwell_s=2.0, estimated_s=1.0),
         TurnStep(index=5, unit="R01", schedule="test", schedule_index=0, start_deg=(0.0, 0.0, 0.0),
                  target_deg=(0.0, 0.0, 0.0), frame="inner", direction="ccw", revolutions=1, rate_dps=90.0,
                  accel_dps2=90.0, rest_s=0.5, estimated_s=2.0))      # 10 s in all


class WallClock:
    """A wall clock the test sets."""

    def __init__(self):
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


def _step_events(index: int, start_s: float) -> list[Event]:
    step = STEPS[index]
    data = {"step": step_to_dict(step)}
    return [make_event(start_s, "step_started", f"{step.unit} {step.kind}", None, index, step.unit, data),
            make_event(start_s + step.estimated_s, "step_finished", f"{step.unit} {step.kind} done", None, index,
                  step.unit, data)]


def _whole_run() -> list[Event]:
    events, t = [make_event(0.0, "transition", "run started", "running")], 0.0
    for index, step in enumerate(STEPS):
        events += _step_events(index, t)
        t += step.estimated_s
    return events + [make_event(t, "transition", "run done", "done")]


def _feed(printer: ProgressPrinter, events: list[Event]) -> None:
    for event in events:
        printer.on_event(event)
    printer.close()


def test_plain_mode_prints_one_line_per_unit_and_a_summary():
    out, wall = io.StringIO(), WallClock()
    printer = ProgressPrinter(STEPS, out, live=False, simulated=True, wall_clock=wall)
    wall.now_s += 3.0
    _feed(printer, _whole_run())
    assert out.getvalue().splitlines() == [
        "[0:00:00] transition: run started",
        "[0:00:00] P01 (unit 1 of 3, 0% done)",
        "[0:00:05] P02 (unit 2 of 3, 50% done)",
        "[0:00:08] R01 (unit 3 of 3, 80% done)",
        "[0:00:10] transition: run done",
        "6 of 6 steps done in 0:00:10 simulated, 0:00:03 wall",
    ]


def test_live_bar_erases_what_it_drew_before_and_gives_the_wall_eta_under_the_simulator():
    out, wall = io.StringIO(), WallClock()
    printer = ProgressPrinter(STEPS, out, live=True, simulated=True, wall_clock=wall)
    events = _whole_run()
    for event in events[:8]:          # P01 and P02's move: 7 s of 10 done
        printer.on_event(event)
    wall.now_s += 14.0                # 14 s of wall time for 70 %: 6 s to go
    printer.on_event(events[8])
    draws = out.getvalue().split("\r")[1:]
    assert draws and all(draw.split("\n")[0].endswith(ERASE_TO_END) for draw in draws)
    assert "ETA sim 0:00:03, wall ~0:00:06" in draws[-1]


def test_after_the_run_starts_ending_the_bar_is_not_drawn_again():
    """After Ctrl-C the bar came back after every line the abort printed."""
    out = io.StringIO()
    printer = ProgressPrinter(STEPS, out, live=True)
    events = _whole_run()[:4] + [
        make_event(3.1, "transition", "interrupted (SIGINT)", "aborting"),
        make_event(3.2, "info", "table stopped and servos off", None),
        make_event(3.3, "transition", "run ended early; table stopped", "failed")]
    for event in events:
        printer.on_event(event)
    printer.close()
    text = out.getvalue()
    after = text[text.index("transition: interrupted"):]
    assert "\r[" in text[:text.index("transition: interrupted")] and "\r[" not in after
    assert after.splitlines()[1:] == ["[0:00:03] info: table stopped and servos off",
                                      "[0:00:03] transition: run ended early; table stopped",
                                      "1 of 6 steps done in 0:00:03"]


def test_quiet_prints_faults_only():
    out = io.StringIO()
    events = _whole_run()[:3] + [make_event(2.0, "fault", "TurntableTimeout: no reply", None, 1, "P01",
                                       {"error": "TurntableTimeout"})]
    _feed(ProgressPrinter(STEPS, out, quiet=True, live=False), events)
    assert out.getvalue() == "FAULT: TurntableTimeout: no reply\n"


def test_skipped_units_of_a_resumed_run_are_one_line_each():
    out = io.StringIO()
    skipped = [make_event(0.0, "step_skipped", f"{s.unit} {s.kind}", None, s.index, s.unit, {}) for s in STEPS[:5]]
    _feed(ProgressPrinter(STEPS, out, live=False), skipped)
    assert out.getvalue().splitlines() == ["skipped P01 (complete in an earlier log)",
                                           "skipped P02 (complete in an earlier log)",
                                           "0 of 6 steps done, 5 skipped in 0:00:00"]


def test_close_on_a_stream_whose_reader_went_away_does_not_raise():
    class Gone(io.StringIO):
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

    printer = ProgressPrinter(STEPS, Gone(), live=False)
    printer._first_time_s = 0.0       # something to summarise
    printer.close()


def test_times_are_from_the_runs_start_not_the_machines_uptime():
    """A hardware run's clock is the monotonic clock: its lines said [0:53:50] for the first step."""
    out = io.StringIO()
    shifted = [dataclasses.replace(e, time_s=e.time_s + 3230.0) for e in _whole_run()]
    _feed(ProgressPrinter(STEPS, out, live=False), shifted)
    lines = out.getvalue().splitlines()
    assert lines[:2] == ["[0:00:00] transition: run started", "[0:00:00] P01 (unit 1 of 3, 0% done)"]
    assert lines[-1] == "6 of 6 steps done in 0:00:10"


class _Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_count_progress_lines_carry_the_count_and_the_eta():
    """`bench solve --archive`'s progress: one line per log with its count, share and ETA (the mean time per
    log so far times the logs left); a failed log goes to stderr, also when quiet; no bar off a terminal."""
    out, err, clock = io.StringIO(), io.StringIO(), _Clock()
    progress = CountProgress(4, out, err, live=False, clock=clock)
    clock.now += 10.0
    progress.item("a.result.json")
    clock.now += 30.0
    progress.item("FAILED b.mcap: not an MCAP file", problem=True)
    progress.note("bench solve: warning: c.mcap: not recorded (disk full)")
    clock.now += 20.0
    progress.item("c.result.json")
    progress.item("d.result.json")
    progress.close()
    assert out.getvalue().splitlines() == ["[1/4 25%, ETA 0:00:30] a.result.json",
                                           "[3/4 75%, ETA 0:00:20] c.result.json",
                                           "[4/4 100%] d.result.json"]
    assert err.getvalue().splitlines() == ["[2/4 50%, ETA 0:00:40] FAILED b.mcap: not an MCAP file",
                                           "bench solve: warning: c.mcap: not recorded (disk full)"]
    quiet_out, quiet_err = io.StringIO(), io.StringIO()
    quiet = CountProgress(2, quiet_out, quiet_err, quiet=True, clock=clock)
    quiet.item("a.result.json")
    quiet.item("FAILED b.mcap: cut", problem=True)
    assert quiet_out.getvalue() == "" and quiet_err.getvalue() == "[2/2 100%] FAILED b.mcap: cut\n"


def test_count_progress_on_a_terminal_redraws_a_bar_below_the_lines():
    out, clock = io.StringIO(), _Clock()
    progress = CountProgress(2, out, out, live=True, bar_width=4, clock=clock)
    clock.now += 5.0
    progress.item("a.result.json")
    progress.close()
    # the bar from the start (a cluster starting), erased before each line and redrawn after it, gone at the end
    assert out.getvalue() == (f"\r[----] 0/2 0%{ERASE_TO_END}" + f"\r{ERASE_TO_END}"
                              + "[1/2 50%, ETA 0:00:05] a.result.json\n"
                              + f"\r[##--] 1/2 50%, ETA 0:00:05{ERASE_TO_END}" + f"\r{ERASE_TO_END}")


def test_advance_to_redraws_the_bar_without_a_line_per_part():
    """Work counted in parts (the schedule search's percent): the bar grows, never shrinks, and no item lines."""
    clock = iter(range(100)).__next__
    out = io.StringIO()
    progress = CountProgress(100, out, out, live=True, bar_width=4, clock=clock)
    progress.advance_to(50)
    progress.advance_to(40)                    # never backwards
    progress.advance_to(150)                   # capped at the total
    progress.close()
    text = out.getvalue()
    assert "[##--] 50/100 50%" in text and "40/100" not in text and "[####] 100/100 100%" in text
    assert "\n" not in text and text.endswith("\r" + ERASE_TO_END)
    plain = io.StringIO()
    CountProgress(100, plain, plain, live=False).advance_to(50)
    assert plain.getvalue() == ""
