"""A run of several IMUs (issue 31): a unit's frames and samples on its own topics, read back as a single IMU's;
the reference unit's counter windows turned into another unit's by the samples' receive times."""

from __future__ import annotations

import numpy as np

from bench.finish.units import remapped_events
from bench.log.events import CounterWindow, StepFinished, Transition
from bench.log.reader import read_log
from bench.log.recorder import McapRecorder
from drivers.imu import ImuSampleBlock, default_layout
from tests.unit.log.test_recorder import make_messages

DWELL = {"kind": "dwell", "unit": "P01", "index": 1, "angles_deg": [0.0, 0.0, 0.0], "dwell_s": 1.0}


def block(first: int, times: np.ndarray, counter: np.ndarray | None = None) -> ImuSampleBlock:
    n = len(times)
    counter = np.arange(first, first + n) if counter is None else counter
    return ImuSampleBlock(counter, times, np.zeros((n, 3)), np.zeros((n, 3)), np.full(n, np.nan),
                          np.zeros(n, np.int64), 200.0)


def test_a_units_window_is_its_samples_received_within_the_reference_window():
    times = np.arange(1, 401) / 200.0
    reference, unit = block(10, times), block(5000, times + 0.001)          # another counter, 1 ms later
    events = [Transition(0.0, "run started", state="running", previous="idle"),
              StepFinished(2.0, "P01 done", 1, "P01", step=DWELL, window=CounterWindow(60, 259, 200))]
    out = remapped_events(events, reference, unit, 200.0)
    assert out[0] is events[0]
    assert out[1].window == CounterWindow(5050, 5249, 200) and out[1].step == DWELL
    lost = np.s_[100:110]                                               # ten samples lost inside the window
    gap = block(0, np.delete(times, lost) + 0.001, np.delete(np.arange(5000, 5400), lost))
    window = remapped_events(events, reference, gap, 200.0)[1].window
    assert window.first == 5050 and window.last - window.first + 1 - window.samples == 10
    silent = remapped_events(events, reference, block(0, times[:20]), 200.0)[1].window
    assert silent.samples == 0                                          # nothing there: the extraction says so


def test_a_units_frames_and_samples_are_on_its_topics_and_read_back_as_a_single_imus(tmp_path):
    path = tmp_path / "units.mcap"
    mine, my_block = make_messages(30, start=0)
    theirs, their_block = make_messages(40, start=100)
    with McapRecorder(path, units=["U-2"]) as recorder:
        recorder.on_can_frames(mine)
        recorder.on_imu(my_block)
        recorder.on_unit_can_frames("U-2", theirs)
        recorder.on_unit_imu("U-2", their_block)
    log, unit = read_log(path), read_log(path, unit="U-2")
    assert log.message_counts["/imu/U-2/can/raw"] == 1 and log.message_counts["/imu/U-2/samples"] == 40
    for read, expected in ((log, my_block), (unit, their_block)):
        samples, stats = read.imu_samples(default_layout(), 200.0)
        np.testing.assert_array_equal(samples.counter, expected.counter)
        np.testing.assert_array_equal(samples.gyro_counts, expected.gyro_counts)
        assert read.scan().complete and len(read.read_imu_records().counter) == len(expected)
