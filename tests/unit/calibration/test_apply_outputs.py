"""`bench apply`'s outputs keep the run log's time convention (issue 33, item 3): `time_s` is the run clock
(the log time of the run log's `/imu/samples` message), `imu_time_s` is counter / rate; they are formatted a
block of samples at a time and hold every value exactly, with a bar on a terminal (item 6)."""

from __future__ import annotations

import csv
import json
import sys

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


# -- issue 33, item 6: the writing formatted a block at a time, its progress on a terminal ----------------------

def _samples(n: int = 53, seed: int = 3):
    """Samples with every kind of value: large and tiny, negative, a temperature missing (NaN) in some rows."""
    from bench.calibration.apply import CompensatedSamples
    from drivers.imu import ImuSampleBlock

    rng = np.random.default_rng(seed)
    temperature = rng.normal(25.0, 3.0, n)
    temperature[::5] = np.nan
    block = ImuSampleBlock(counter=np.arange(n, dtype=np.int64) + 2**40, receive_time_s=0.005 + np.arange(n) / 200,
                           gyro_counts=rng.normal(0, 1e4, (n, 3)) * 10.0 ** rng.integers(-9, 9, (n, 3)),
                           acc_counts=rng.normal(0, 1e6, (n, 3)), temperature_c=temperature,
                           status=rng.integers(0, 2**16, n), rate_hz=200.0)
    return CompensatedSamples(block, rng.normal(0, 1, (n, 3)) / 3.0, rng.normal(0, 9.8, (n, 3)), "deg/s", "g")


def _strict_json(data: bytes) -> dict:
    def refuse(constant):
        raise AssertionError(f"not JSON: {constant}")
    return json.loads(data, parse_constant=refuse)


@pytest.mark.parametrize("block_samples", [7, 10_000])
def test_the_mcap_bodies_hold_every_value_exactly(tmp_path, monkeypatch, block_samples):
    from bench.calibration import apply
    from bench.calibration.compensation import compensation_of
    from bench.model.imu import default_sim_imu
    from bench.model.result import CalibrationResult, coefficient_table

    monkeypatch.setattr(apply, "BLOCK_SAMPLES", block_samples)
    samples = _samples()
    samples.raw.gyro_counts[12, 1] = np.nan          # a value JSON cannot hold, outside the nullable fields
    values = default_sim_imu().to_canonical()
    compensation = compensation_of(CalibrationResult(coefficient_table(values, {k: 1e-6 for k in values})))
    done: list[tuple[int, int]] = []
    apply.write_mcap(samples, tmp_path / "a.mcap", compensation=compensation, source_log="x.mcap",
                     progress=lambda d, t: done.append((d, t)))
    raw, compensated = [], []
    with open(tmp_path / "a.mcap", "rb") as f:
        for _schema, channel, message in make_reader(f, validate_crcs=True).iter_messages(log_time_order=False):
            topic = raw if channel.topic == TOPIC_SAMPLES else compensated
            topic.append((message.log_time, _strict_json(message.data)))
    block, n = samples.raw, len(samples)
    assert len(raw) == len(compensated) == n and done[-1] == (n, n) and len(done) == -(-n // block_samples)
    for k, ((log_time, r), (_t, c)) in enumerate(zip(raw, compensated)):
        assert log_time == round(block.receive_time_s[k] * 1e9)
        assert r["counter"] == c["counter"] == block.counter[k] and r["status"] == block.status[k]
        assert r["time_s"] == c["time_s"] == block.receive_time_s[k] and r["imu_time_s"] == block.time_s[k]
        gyro = [None if not np.isfinite(x) else x for x in block.gyro_counts[k]]
        assert r["gyro_counts"] == gyro and r["acc_counts"] == block.acc_counts[k].tolist()
        assert r["acc_rate"] == (block.acc_counts[k] * 200.0).tolist()
        temperature = block.temperature_c[k]
        assert r["temperature_c"] == (None if np.isnan(temperature) else temperature)
        assert c["angular_rate"] == samples.angular_rate[k].tolist()
        assert c["specific_force"] == samples.specific_force[k].tolist()
        assert (c["rate_unit"], c["force_unit"]) == ("deg/s", "g")


def test_the_csv_holds_every_value_exactly(tmp_path, monkeypatch):
    from bench.calibration import apply

    monkeypatch.setattr(apply, "BLOCK_SAMPLES", 7)
    samples = _samples()
    apply.write_csv(samples, tmp_path / "a.csv")
    with open(tmp_path / "a.csv", encoding="utf-8", newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["counter", "time_s", "imu_time_s", "rate_x_dps", "rate_y_dps", "rate_z_dps", "force_x_g",
                       "force_y_g", "force_z_g"]
    assert [int(r[0]) for r in rows[1:]] == samples.counter.tolist()
    data = np.array(rows[1:], dtype=float)
    assert np.array_equal(data[:, 1], samples.time_s) and np.array_equal(data[:, 2], samples.imu_time_s)
    assert np.array_equal(data[:, 3:6], samples.angular_rate) and np.array_equal(data[:, 6:9], samples.specific_force)


def test_bench_apply_shows_a_bar_on_a_terminal_only(short_run, tmp_path, monkeypatch, capsys):
    from bench.cli.main import main

    argv = ["apply", str(short_run.result), str(short_run.log), "--out"]
    assert main([*argv, str(tmp_path / "a.csv"), "--quiet"]) == 0
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert main([*argv, str(tmp_path / "b.csv")]) == 0
    err = capsys.readouterr().err
    assert "] 100/100 100%" in err and err.startswith("\r[") and err.endswith("\x1b[K"), repr(err[-200:])


# -- issue 33, item 6: formatted in C (orjson) and written in bulk, the values of the per-sample path -------------

def _per_sample_outputs(result_path, log_path) -> tuple[list[list[float]], list[tuple[str, int, dict]]]:
    """What `bench apply` wrote before it was vectorised (22d4fe1), a sample at a time: the compensation as
    `(y - b) @ C.T`, each CSV row through `%.17g`, each message a JSON document, both topics sample by sample."""
    from bench.calibration.apply import log_samples
    from bench.calibration.compensation import FORCE_UNITS, RATE_UNITS, compensation_of, load_result
    from bench.log.reader import read_log

    compensation = compensation_of(load_result(str(result_path)))
    block = log_samples(read_log(str(log_path)))
    gyros, accs = block.gyro_counts * block.rate_hz, block.acc_counts * block.rate_hz
    rates = ((gyros - compensation.gyro.bias_counts) @ compensation.gyro.matrix.T) * RATE_UNITS["deg/s"]
    forces = ((accs - compensation.acc.bias_counts) @ compensation.acc.matrix.T) * FORCE_UNITS["g"]
    rows, messages = [], []
    for k in range(len(block)):
        gyro, acc, rate, force = gyros[k], accs[k], rates[k], forces[k]
        time_s, imu_time_s, counter = float(block.receive_time_s[k]), float(block.time_s[k]), int(block.counter[k])
        rows.append([float(x) for x in ("%d," % counter + ",".join(
            "%.17g" % x for x in [time_s, imu_time_s, *rate, *force])).split(",")])
        log_time = int(np.rint(time_s * 1e9)) if time_s > 0 else 0
        temperature = float(block.temperature_c[k])
        messages.append((TOPIC_SAMPLES, log_time, {
            "counter": counter, "time_s": time_s, "imu_time_s": imu_time_s,
            "gyro_counts": block.gyro_counts[k].tolist(), "acc_counts": block.acc_counts[k].tolist(),
            "gyro_rate": gyro.tolist(), "acc_rate": acc.tolist(),
            "temperature_c": temperature if np.isfinite(temperature) else None, "status": int(block.status[k])}))
        messages.append((TOPIC_COMPENSATED, log_time, {
            "counter": counter, "time_s": time_s, "imu_time_s": imu_time_s, "angular_rate": rate.tolist(),
            "specific_force": force.tolist(), "rate_unit": "deg/s", "force_unit": "g"}))
    return rows, messages


def test_the_outputs_hold_the_values_the_per_sample_path_wrote(short_run, tmp_path):
    """Value for value (every number read back as the same float, every log time, the messages' order) what
    the per-sample path wrote; the text may differ (orjson prints 1e-5 where %.17g printed 1.0000000000000001e-05)."""
    rows, messages = _per_sample_outputs(short_run.result, short_run.log)
    assert len(rows) > 1000
    argv = ["apply", str(short_run.result), str(short_run.log), "--quiet", "--out"]
    assert cli([*argv, str(tmp_path / "a.csv")])[0] == 0
    assert cli([*argv, str(tmp_path / "a.mcap")])[0] == 0
    with open(tmp_path / "a.csv", encoding="utf-8", newline="") as f:
        written_rows = [[float(x) for x in row] for row in list(csv.reader(f))[1:]]
    assert written_rows == rows
    written = []
    with open(tmp_path / "a.mcap", "rb") as f:
        for _schema, channel, message in make_reader(f, validate_crcs=True).iter_messages(log_time_order=False):
            written.append((channel.topic, message.log_time, _strict_json(message.data)))
    assert written == messages


def test_the_applied_mcap_is_in_log_time_order(short_run, tmp_path):
    """Issue 33, item 4: the raw and the compensated message of a sample follow each other, so no message of the
    applied file is older than one before it (what `mcap doctor` checks: with MCAP_CLI it must say nothing)."""
    import os
    import subprocess

    from tests.helpers.mcap_order import log_time_order

    out = tmp_path / "a.mcap"
    assert cli(["apply", str(short_run.result), str(short_run.log), "--out", str(out), "--quiet"])[0] == 0
    own, behind = log_time_order(out)
    assert set(own) == {TOPIC_SAMPLES, TOPIC_COMPENSATED}
    assert not any(own.values()) and not any(behind.values()), (own, behind)
    if os.environ.get("MCAP_CLI"):
        proc = subprocess.run([os.environ["MCAP_CLI"], "doctor", str(out)], capture_output=True, text=True,
                              timeout=120)
        assert proc.returncode == 0 and not (proc.stdout + proc.stderr).strip(), proc.stdout + proc.stderr


# -- issue 33, item 6: the records laid out in bulk (bench.log.json_records) are the per-message path's -----------

def _messages_of(path) -> list[tuple]:
    """Every message of an MCAP file in file order, with everything that says what it is and when."""
    with open(path, "rb") as f:
        return [(schema.name, schema.encoding, schema.data, channel.topic, channel.message_encoding,
                 message.log_time, message.publish_time, message.sequence, message.data)
                for schema, channel, message in make_reader(f, validate_crcs=True).iter_messages(log_time_order=False)]


def _write_mcap_per_message(samples, path) -> None:
    """The straightforward path: a JSON document per message (orjson of its dict), `Writer.add_message` each,
    the raw then the compensated message of a sample."""
    import orjson
    from mcap.writer import CompressionType, Writer

    from bench.calibration.apply import COMPENSATED_SCHEMA, COMPENSATED_SCHEMA_BODY
    from bench.log.format import SCHEMAS

    block = samples.raw
    with open(path, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start()
        raw = writer.register_channel(TOPIC_SAMPLES, "json", writer.register_schema(
            "turntable_bench.ImuSample", "jsonschema", json.dumps(SCHEMAS["turntable_bench.ImuSample"]).encode()))
        compensated = writer.register_channel(TOPIC_COMPENSATED, "json", writer.register_schema(
            COMPENSATED_SCHEMA, "jsonschema", json.dumps(COMPENSATED_SCHEMA_BODY).encode()))
        for k in range(len(samples)):
            time_s = float(block.receive_time_s[k])
            log_time = round(time_s * 1e9) if time_s > 0.0 else 0
            times = {"counter": int(block.counter[k]), "time_s": time_s, "imu_time_s": float(block.time_s[k])}
            writer.add_message(raw, log_time, orjson.dumps({
                **times, "gyro_counts": block.gyro_counts[k].tolist(), "acc_counts": block.acc_counts[k].tolist(),
                "gyro_rate": (block.gyro_counts[k] * block.rate_hz).tolist(),
                "acc_rate": (block.acc_counts[k] * block.rate_hz).tolist(),
                "temperature_c": float(block.temperature_c[k]), "status": int(block.status[k])}), log_time)
            writer.add_message(compensated, log_time, orjson.dumps({
                **times, "angular_rate": samples.angular_rate[k].tolist(),
                "specific_force": samples.specific_force[k].tolist(), "rate_unit": samples.rate_unit,
                "force_unit": samples.force_unit}), log_time)
        writer.finish()


def _samples_of_every_kind(n: int = 400):
    """`_samples` with whole counts (printed as integers) in some rows, -0.0, values past 1e16, a status word and a
    temperature constant over some blocks only, a receive time of 0 (log time 0)."""
    samples = _samples(n, seed=11)
    block = samples.raw
    block.gyro_counts[: n // 2] = np.rint(block.gyro_counts[: n // 2] * 1e-3)
    block.acc_counts[n // 4:] = np.rint(block.acc_counts[n // 4:])
    block.acc_counts[n // 3, 0] = -0.0
    block.acc_counts[n // 3 + 1, 1] = 3e16
    block.status[: n // 3] = 5
    block.temperature_c[40:80] = 24.5
    block.receive_time_s[0] = 0.0
    samples.angular_rate[100:140] = [0.25, -0.0, 1e-7]
    return samples


@pytest.mark.parametrize("block_samples, record_rows", [(7, 3), (10_000, 2_000), (100, 64)])
def test_the_bulk_records_are_the_per_message_paths(tmp_path, monkeypatch, block_samples, record_rows):
    """Every message (topic, schema, encoding, log and publish time, sequence, bytes) and their order, whatever
    the blocks: a value, a time or an order that differs fails."""
    from bench.calibration import apply
    from bench.calibration.compensation import compensation_of
    from bench.model.imu import default_sim_imu
    from bench.model.result import CalibrationResult, coefficient_table

    monkeypatch.setattr(apply, "BLOCK_SAMPLES", block_samples)
    monkeypatch.setattr(apply, "RECORD_ROWS", record_rows)
    samples = _samples_of_every_kind()
    values = default_sim_imu().to_canonical()
    compensation = compensation_of(CalibrationResult(coefficient_table(values, {k: 1e-6 for k in values})))
    apply.write_mcap(samples, tmp_path / "bulk.mcap", compensation=compensation, source_log="x.mcap")
    _write_mcap_per_message(samples, tmp_path / "per-message.mcap")
    bulk, per_message = _messages_of(tmp_path / "bulk.mcap"), _messages_of(tmp_path / "per-message.mcap")
    assert len(bulk) == 2 * len(samples)
    assert bulk == per_message


def test_bench_apply_of_a_log_writes_the_per_message_paths_records(short_run, tmp_path):
    from bench.calibration.apply import apply_to_log
    from bench.calibration.compensation import compensation_of, load_result

    out = tmp_path / "applied.mcap"
    assert cli(["apply", str(short_run.result), str(short_run.log), "--out", str(out), "--quiet"])[0] == 0
    samples, _log = apply_to_log(compensation_of(load_result(str(short_run.result))), str(short_run.log),
                                 rate_unit="deg/s", force_unit="g")
    _write_mcap_per_message(samples, tmp_path / "per-message.mcap")
    written = _messages_of(out)
    assert len(written) > 2000 and written == _messages_of(tmp_path / "per-message.mcap")
