"""Issue 27, item 6: IMU samples lost on the link fail the quality check only where a dwell or turn the solve uses
lost them (the failure names the step); samples lost outside every window (moves, settles) are reported with
their count, and an [acceptance] `max_lost_samples` counts every lost sample.

One real run is recorded on the simulator; its copies lose the CAN frames of chosen samples (picked by their
counters, cut by the frames' receive times), and `bench solve` re-solves them: the very extraction and quality
check `bench run` uses on its own log (tests/e2e/test_run.py drops frames on a live run).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bench.log.events import finished_observation_steps
from bench.log.format import HEADER_SIZE, LENGTH_OFFSET, TOPIC_CAN
from bench.log.reader import read_log
from bench.log.run_info import layout_and_config_from_log
from tests.helpers.mcap_surgery import rewrite
from tests.helpers.run import cli, config_text, load_json, only_file

LOST = 6        # samples each damaged copy loses


def _recording(log_path: Path) -> SimpleNamespace:
    """A recorded log with its decoded sample counters and receive times and its dwell and turn windows."""
    log = read_log(str(log_path))
    setup = layout_and_config_from_log(log)
    samples, stats = log.imu_samples(setup.layout, setup.rate_hz)
    assert stats.lost_samples == 0
    windows = {unit: (f.step_kind, f.window.first, f.window.last)
               for unit, (_, f) in finished_observation_steps(log.events).items()}
    return SimpleNamespace(log=log_path, counter=samples.counter.copy(), receive_time_s=samples.receive_time_s.copy(),
                           windows=windows, layout=setup.layout, rate_hz=setup.rate_hz)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lost")
    config = folder / "bench.toml"
    config.write_text(config_text(), encoding="utf-8")
    rc, _, stderr = cli(["run", "--config", str(config), "--out", str(folder / "out"), "--quiet", "--no-db"])
    assert rc == 0, stderr
    return _recording(only_file(folder / "out", "*.mcap"))


def _between_windows(recorded) -> int:
    """The first counter of `LOST` samples between two windows (the table moving to the next position)."""
    spans = sorted((first, last) for _, first, last in recorded.windows.values())
    gap_first, gap_last = next((a[1] + 1, b[0] - 1) for a, b in zip(spans, spans[1:]) if b[0] - a[1] > 3 * LOST)
    return (gap_first + gap_last) // 2 - LOST // 2


def _without_samples(recorded, first_counter: int, dst: Path, acceptance: str = "") -> Path:
    """A copy of the recorded log without the CAN frames of samples first_counter .. first_counter + LOST - 1 (the
    frames received after the sample before them completed, up to the last one's completing frame), and with
    `acceptance` added to its recorded configuration."""
    at = int(np.searchsorted(recorded.counter, first_counter))
    assert recorded.counter[at] == first_counter and recorded.counter[at + LOST - 1] == first_counter + LOST - 1
    after_s, until_s = recorded.receive_time_s[at - 1], recorded.receive_time_s[at + LOST - 1]

    def message(topic: str, data: bytes) -> bytes:
        if topic != TOPIC_CAN:
            return data
        kept, pos = [], 0
        while pos < len(data):
            end = pos + HEADER_SIZE + data[pos + LENGTH_OFFSET]
            (t,) = struct.unpack_from("<d", data, pos)
            if not after_s < t <= until_s:
                kept.append(data[pos:end])
            pos = end
        return b"".join(kept)

    def metadata(name: str, record: dict) -> dict:
        if name == "config" and acceptance:
            record["toml"] += "\n" + acceptance
        return record

    return rewrite(recorded.log, dst, message=message, metadata=metadata)


def _solve(log: Path, out: Path) -> tuple[int, str, str, dict, str]:
    rc, stdout, stderr = cli(["solve", str(log), "--out", str(out), "--no-html", "--no-db"])
    result = load_json(only_file(out, "*.solved.result.json"))
    return rc, stdout, stderr, result, only_file(out, "*.solved.report.md").read_text(encoding="utf-8")


def _note(n: int) -> str:
    return f"{n} IMU samples lost outside every dwell and turn window"


def test_samples_lost_while_the_table_moves_are_reported_not_failed(recorded, tmp_path):
    first = _between_windows(recorded)
    damaged = _without_samples(recorded, first, tmp_path / "moved.mcap")
    _, stats = read_log(str(damaged)).imu_samples(recorded.layout, recorded.rate_hz)
    assert stats.lost_samples == LOST
    rc, stdout, stderr, result, report = _solve(damaged, tmp_path / "out")
    assert rc == 0, stderr              # before: exit 4, "quality check failed: IMU link lost samples: ..."
    assert result["run"]["quality_failures"] == []
    assert result["run"]["lost_samples"] == {"total": LOST, "in_windows": {}, "outside_windows": LOST}
    assert result["verdict"]["verdict"] == "not checked"
    assert f"note: {_note(LOST)}" in stdout
    assert f"Note: {_note(LOST)}" in report


def test_samples_lost_inside_a_dwell_fail_the_quality_check_naming_the_dwell(recorded, tmp_path):
    unit = "P07"
    kind, first, last = recorded.windows[unit]
    assert kind == "dwell"
    damaged = _without_samples(recorded, (first + last) // 2, tmp_path / "dwell.mcap")
    rc, stdout, stderr, result, report = _solve(damaged, tmp_path / "out")
    assert rc == 4, stderr
    expected = f"{unit} dwell: {LOST} of {last - first + 1} samples lost in its window"
    assert "quality check failed" in stderr and expected in stderr
    assert [f for f in result["run"]["quality_failures"] if "lost" in f] == [
        f"{damaged}: {expected}; mean over the {last - first + 1 - LOST} received"]
    assert result["run"]["lost_samples"] == {"total": LOST, "in_windows": {unit: LOST}, "outside_windows": 0}
    assert "note:" not in stdout and expected in report
    # a solve of the turns alone does not use the dwell's window: its loss is reported, not failed
    rc, stdout, stderr = cli(["solve", str(damaged), "--positions", "none", "--out", str(tmp_path / "turns"),
                              "--no-html", "--no-db"])
    assert rc == 0, stderr
    assert f"note: {_note(LOST)} the solve uses" in stdout
    turns = load_json(only_file(tmp_path / "turns", "*.result.json"))
    assert turns["run"]["lost_samples"] == {"total": LOST, "in_windows": {}, "outside_windows": LOST}
    assert turns["run"]["quality_failures"] == []


def test_samples_lost_inside_a_turn_leave_it_out_naming_the_turn(recorded, tmp_path):
    unit = "R03"
    kind, first, last = recorded.windows[unit]
    assert kind == "turn"
    damaged = _without_samples(recorded, (first + last) // 2, tmp_path / "turn.mcap")
    rc, _, stderr, result, _ = _solve(damaged, tmp_path / "out")
    assert rc == 4, stderr
    assert f"{unit} turn: {LOST} of {last - first + 1} samples lost in its window: its integral is incomplete; " \
           "left out" in stderr
    assert unit in result["run"]["left_out"]
    assert result["run"]["lost_samples"]["in_windows"] == {unit: LOST}


def test_max_lost_samples_counts_every_lost_sample_as_an_acceptance_check(recorded, tmp_path):
    first = _between_windows(recorded)
    strict = _without_samples(recorded, first, tmp_path / "strict.mcap", "[acceptance]\nmax_lost_samples = 0\n")
    rc, stdout, stderr, result, _ = _solve(strict, tmp_path / "strict")
    assert rc == 4, stderr
    assert f"acceptance limit: lost samples {LOST} > 0 samples" in stderr and "quality check failed" not in stderr
    assert [c["name"] for c in result["verdict"]["checks"] if not c["passed"]] == ["lost samples"]
    assert f"note: {_note(LOST)}" in stdout
    # a limit the loss keeps: PASS, the loss still reported
    loose = _without_samples(recorded, first, tmp_path / "loose.mcap", f"[acceptance]\nmax_lost_samples = {LOST}\n")
    rc, stdout, stderr, result, _ = _solve(loose, tmp_path / "loose")
    assert rc == 0, stderr
    assert result["verdict"]["verdict"] == "pass" and f"note: {_note(LOST)}" in stdout


def test_a_limit_judges_a_dwells_lost_samples_in_place_of_the_quality_check(recorded, tmp_path):
    """With `max_lost_samples` set, a dwell's lost samples are judged by it (the dwell's mean is over the samples
    received); the report still names the dwell."""
    kind, first, last = recorded.windows["P07"]
    damaged = _without_samples(recorded, (first + last) // 2, tmp_path / "dwell.mcap",
                               f"[acceptance]\nmax_lost_samples = {LOST}\n")
    rc, _, stderr, result, report = _solve(damaged, tmp_path / "out")
    assert rc == 0, stderr
    assert result["verdict"]["verdict"] == "pass"
    assert "P07 dwell: 6 of 150 samples lost in its window; mean over the 144 received (judged by its" in report
    assert json.dumps(result["run"]["lost_samples"]) == json.dumps(
        {"total": LOST, "in_windows": {"P07": LOST}, "outside_windows": 0})


def test_a_window_reaching_past_the_decoded_samples_counts_only_the_gaps_between_them():
    """A log cut inside a window lost the samples after the cut to the damage, not on the link: only the counter
    gaps between the first and last sample decoded count as lost (the extraction still says the dwell is short)."""
    from bench.solve.extract import missing_in_window

    counter = np.array([10, 11, 12, 15, 16, 20], dtype=np.int64)       # 13, 14, 17, 18, 19 missing
    window = slice(*np.searchsorted(counter, [12, 16 + 1]))
    assert missing_in_window(counter, window, 12, 16) == 2
    assert missing_in_window(counter, slice(*np.searchsorted(counter, [15, 30 + 1])), 15, 30) == 3   # 17..19
    assert missing_in_window(counter, slice(0, 0), 30, 40) == 0                                         # all past
    assert missing_in_window(np.zeros(0, np.int64), slice(0, 0), 0, 5) == 0


def test_a_thermal_run_fails_on_a_dwell_of_any_temperature_that_lost_samples_and_notes_a_soaks(thermal_run_log,
                                                                                               tmp_path):
    """A thermal log re-solved (its headline result is the block nearest the reference, here T2): samples lost in a
    dwell of T1 fail it, naming the dwell; samples lost while the chamber soaks are only reported. The session's
    thermal log is only read: its damaged copies are written to `tmp_path`."""
    folder = tmp_path
    thermal = _recording(thermal_run_log)
    attached = read_log(str(thermal.log)).attachments[thermal.log.name.removesuffix(".mcap") + ".result.json"]
    assert json.loads(attached[1])["run"]["thermal"]["this_block"] == 2
    kind, first, last = thermal.windows["T1-P07"]
    damaged = _without_samples(thermal, (first + last) // 2, folder / "dwell.mcap")
    rc, stdout, stderr, result, _ = _solve(damaged, folder / "dwell")
    assert rc == 4, stderr
    assert f"T1-P07 dwell: {LOST} of {last - first + 1} samples lost in its window" in stderr
    assert result["run"]["lost_samples"] == {"total": LOST, "in_windows": {"T1-P07": LOST}, "outside_windows": 0}
    soak_first = max(last for unit, (_, _, last) in thermal.windows.items() if unit.startswith("T1-")) + 100
    soaked = _without_samples(thermal, soak_first, folder / "soak.mcap")
    rc, stdout, stderr, result, _ = _solve(soaked, folder / "soak")
    assert rc == 0, stderr
    assert result["run"]["lost_samples"] == {"total": LOST, "in_windows": {}, "outside_windows": LOST}
    assert f"note: {_note(LOST)}" in stdout
