"""`bench noise LOG` streams: the frames decoded chunk by chunk straight into the Allan phase (issue 17).

The streamed analysis is held to the whole-log one (`static_record`: every sample decoded first), bit for
bit on a log without gaps and to 1e-9 with counter gaps (where the mean taken off differs).
"""

from __future__ import annotations

import numpy as np
import pytest

import bench.noise.from_log as from_log
from bench.log.reader import RunLog, read_log
from bench.log.run_info import layout_and_config_from_log
from bench.noise.from_log import analyse_log, static_record
from bench.noise.result import analyse_blocks
from drivers.imu import ImuSampleBlock
from tests.helpers.static_log import write_static_log

RATE_HZ = 1000.0


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("static-logs")
    # 40 s: 8 recorder chunks (one every 5 s of run clock), each a piece of the stream
    whole = write_static_log(folder / "whole.mcap", 40.0, RATE_HZ)
    gaps = write_static_log(folder / "gaps.mcap", 40.0, RATE_HZ, drop=((8000, 8300), (31000, 31007)))
    return whole, gaps


def _whole_log_curves(path, block_samples):
    record = static_record(path)
    channels = analyse_blocks(record.blocks(block_samples), record.rate_hz, capacity=len(record))
    return record, {c.name: c.curve.adev for c in channels}


@pytest.fixture
def small_batches(monkeypatch):
    # many hand-overs and accumulator blocks in a small log, as in a long one
    monkeypatch.setattr(from_log, "BLOCK_SAMPLES", 4096)
    monkeypatch.setattr(from_log, "_HAND_OVER_SAMPLES", 1500)
    monkeypatch.setattr(from_log, "_IN_FLIGHT", 1)
    return 4096


def test_the_streamed_analysis_is_the_whole_log_one_bit_for_bit(logs, small_batches):
    record, expected = _whole_log_curves(logs[0], small_batches)
    result, run_id = analyse_log(logs[0])
    assert result.n_samples == len(record) == 40_000 and run_id == "whole"
    for name, adev in expected.items():
        np.testing.assert_array_equal(np.asarray(result.channels[name]["adev"]), adev)
    assert result.source == record.source and result.notes == list(record.notes)


def test_counter_gaps_analyse_the_longest_stretch_as_the_whole_log_does(logs, small_batches):
    record, expected = _whole_log_curves(logs[1], small_batches)
    result, _ = analyse_log(logs[1])
    assert result.n_samples == len(record) == 31000 - 8300
    assert any("307 of its 40000 samples missing; the longest gap-free stretch, 22700 samples" in n
               for n in result.notes)
    assert result.notes == list(record.notes)
    for name, adev in expected.items():
        np.testing.assert_allclose(np.asarray(result.channels[name]["adev"]), adev, rtol=1e-9, atol=0)


def test_bench_noise_never_decodes_the_whole_log_at_once(logs, monkeypatch):
    def whole(*args, **kwargs):
        raise AssertionError("the whole log decoded at once")

    monkeypatch.setattr(RunLog, "imu_samples", whole)
    monkeypatch.setattr(RunLog, "imu_samples_visiting", whole)
    result, _ = analyse_log(logs[0])
    assert result.n_samples == 40_000


def test_the_sample_blocks_of_a_log_joined_are_its_decoded_samples(logs):
    log = read_log(str(logs[1]))
    setup = layout_and_config_from_log(log)
    blocks = list(log.imu_sample_blocks(setup.layout, setup.rate_hz))
    assert len(blocks) >= 8 and log._decoded == []          # a piece at a time, nothing kept
    joined = ImuSampleBlock.concatenate(blocks)
    whole, stats = read_log(str(logs[1])).imu_samples(setup.layout, setup.rate_hz)
    for field in ("counter", "receive_time_s", "gyro_counts", "acc_counts", "status"):
        np.testing.assert_array_equal(getattr(joined, field), getattr(whole, field))
    assert stats.counter_gaps == 307
