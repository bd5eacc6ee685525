"""`bench apply`'s outputs keep the run log's time convention (issue 33, item 3): `time_s` is the run clock
(the log time of the run log's `/imu/samples` message), `imu_time_s` is counter / rate."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from mcap.reader import make_reader

from bench.calibration.apply import TOPIC_COMPENSATED
from bench.log.format import TOPIC_SAMPLES
from tests.helpers.run import cli


def _topics(path) -> dict[str, list[tuple[int, dict]]]:
    """Every JSON message of an MCAP file by topic, with its log time in ns."""
    topics: dict[str, list[tuple[int, dict]]] = {}
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f, validate_crcs=True).iter_messages(log_time_order=False):
            if channel.message_encoding == "json":
                topics.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
    return topics


@pytest.fixture(scope="module")
def run_log_samples(short_run) -> dict[int, dict]:
    """The run log's own `/imu/samples` messages by counter."""
    return {m["counter"]: m for _t, m in _topics(short_run.log)[TOPIC_SAMPLES]}


def test_the_mcap_has_the_run_logs_time_s_and_imu_time_s(short_run, run_log_samples, tmp_path):
    out = tmp_path / "applied.mcap"
    rc, _, stderr = cli(["apply", str(short_run.result), str(short_run.log), "--out", str(out), "--quiet"])
    assert rc == 0, stderr
    topics = _topics(out)
    for topic in (TOPIC_SAMPLES, TOPIC_COMPENSATED):
        messages = topics[topic]
        assert len(messages) >= len(run_log_samples) > 1000
        for log_time_ns, m in messages:
            assert m["time_s"] == pytest.approx(log_time_ns / 1e9, abs=1e-9)
            theirs = run_log_samples.get(m["counter"])
            if theirs is not None:
                assert (m["time_s"], m["imu_time_s"]) == (theirs["time_s"], theirs["imu_time_s"]), topic
    first = topics[TOPIC_SAMPLES][0][1]
    assert first["time_s"] != first["imu_time_s"]     # two different clocks (the issue: 0.0 against 0.005)


def test_the_csv_has_the_run_logs_time_s_and_imu_time_s(short_run, run_log_samples, tmp_path):
    out = tmp_path / "applied.csv"
    rc, _, stderr = cli(["apply", str(short_run.result), str(short_run.log), "--out", str(out), "--quiet"])
    assert rc == 0, stderr
    with open(out, encoding="utf-8", newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0][:3] == ["counter", "time_s", "imu_time_s"]
    data = np.array(rows[1:], dtype=float)
    matched = 0
    for counter, time_s, imu_time_s in data[:, :3]:
        theirs = run_log_samples.get(int(counter))
        if theirs is not None:
            assert (time_s, imu_time_s) == (theirs["time_s"], theirs["imu_time_s"])
            matched += 1
    assert matched == len(run_log_samples)
