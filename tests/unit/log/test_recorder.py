"""The MCAP recorder and the tolerant log reader: round trip, library compatibility, damage."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from bench.log.events import make_event
from bench.log.format import CAN_ENCODING, CHANNELS, FLAG_ERROR, FLAG_FD, FLAG_REMOTE
from bench.log.reader import LogError, read_log
from bench.log.recorder import McapRecorder, RecorderError, frame_quaternions
from bench.model.kinematics import rot_y, rot_z
from drivers.imu import ImuEncoder, decode_frames, default_layout
from drivers.turntable.base import AxisMode, AxisState, AxisStatus, TableState

LAYOUT = default_layout()
RATE_HZ = 1000.0
SAMPLES_PER_BATCH = 20


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def state_at(t: float, k: int) -> TableState:
    status = AxisStatus.ENABLED | (AxisStatus.IN_POSITION if k % 2 else AxisStatus.MOVING)
    axes = tuple(AxisState(10.0 * k + 30.0 * j - 45.0, 0.5 * j, AxisMode.POSITION if j else AxisMode.RATE, status)
                 for j in range(3))
    return TableState(t, axes, "" if k % 3 else f"note {k}")


@dataclass
class Run:
    """What a test run recorded, to compare the log against."""

    messages: list          # every can.Message in order
    block: object           # ImuSampleBlock of every sample
    events: list
    states: list
    batch_frames: list      # frames per on_can_frames call
    recorder: McapRecorder


def make_messages(n_samples: int, start: int = 0, t0: float = 0.0):
    rng = np.random.default_rng(start + 1)
    frames = ImuEncoder(LAYOUT).encode(np.arange(start, start + n_samples), rng.normal(0, 3000, (n_samples, 3)),
                                       rng.normal(0, 40, (n_samples, 3)))
    times = t0 + (frames.sample + 1) / RATE_HZ + np.arange(len(frames)) * 1e-6
    msgs = [can.Message(timestamp=float(times[i]), arbitration_id=int(frames.ids[i]), is_extended_id=False,
                        data=frames.data[i, :frames.lengths[i]].tobytes()) for i in range(len(frames))]
    block, stats = decode_frames(frames.ids, frames.data, frames.lengths, times, layout=LAYOUT, rate_hz=RATE_HZ)
    assert stats.samples == n_samples
    return msgs, block


def record(path, n_batches=12, clock=None, extras=False, **kwargs) -> Run:
    """A small realistic run: metadata, attachments, events, table states, samples and frames.

    With a fake clock, each batch advances it past the chunk interval, so every batch ends
    in its own chunk. `extras` adds extended-id, FD, remote and error frames (mixed lengths).
    """
    metadata = {"run": {"run_id": "r-1", "operator": "ana", "software_version": "0.1.0", "mode": "sim"},
                "config": {"toml": "[imu]\nrate_hz = 1000\n"}}
    rec = McapRecorder(path, metadata=metadata, clock=clock or FakeClock(), **kwargs)
    run = Run([], None, [], [], [], rec)
    blocks = []
    ev = make_event(0.0, "transition", "start", state="running", data={"from": "idle"})
    rec.on_event(ev)
    run.events.append(ev)
    for b in range(n_batches):
        msgs, block = make_messages(SAMPLES_PER_BATCH, start=b * SAMPLES_PER_BATCH, t0=b * SAMPLES_PER_BATCH / RATE_HZ)
        if extras and b % 3 == 1:
            t = msgs[-1].timestamp
            msgs += [can.Message(timestamp=t, arbitration_id=0x1ABCDEF0, is_extended_id=True, data=b"\x01\x02\x03"),
                     can.Message(timestamp=t, arbitration_id=0x123, is_extended_id=False, is_fd=True,
                                 bitrate_switch=True, data=bytes(range(48))),
                     can.Message(timestamp=t, arbitration_id=0x321, is_extended_id=False, is_remote_frame=True,
                                 dlc=0),
                     can.Message(timestamp=t, arbitration_id=0, is_extended_id=False, is_error_frame=True,
                                 data=b"")]
        rec.on_can_frames(msgs)
        rec.on_imu(block)
        st_ = state_at(block.receive_time_s[-1], b)
        rec.on_table_state(st_)
        run.messages += msgs
        run.batch_frames.append(len(msgs))
        run.states.append(st_)
        blocks.append(block)
        if b == n_batches // 2:
            for kind in ("step_started", "warning", "fault"):
                e = make_event(float(st_.time_s), kind, f"{kind} at batch {b}", step_index=b, step_unit="P03",
                          data={"step": {"kind": "dwell", "dwell_s": 60.0}, "n": np.int64(3)})
                rec.on_event(e)
                run.events.append(e)
        if clock is not None:
            clock.t += 1.5
    rec.add_attachment("plan.toml", "application/toml", b"[[positions]]\nouter = 0\n", log_time_s=0.0)
    rec.add_attachment("imu.dbc", "text/plain", LAYOUT.dbc_text.encode() if hasattr(LAYOUT, "dbc_text") else b"dbc")
    rec.add_metadata("result", {"rms": 1.5, "ok": True})
    from drivers.imu import ImuSampleBlock
    run.block = ImuSampleBlock.concatenate(blocks)
    return run


@pytest.fixture
def closed_log(tmp_path):
    path = tmp_path / "run.mcap"
    run = record(path, clock=FakeClock())
    run.recorder.close()
    return path, run


def chunk_layout(path):
    """(start offset, end offset, CAN frames inside) of every chunk, from the library's reader."""
    with open(path, "rb") as f:
        indexes = make_reader(f).get_summary().chunk_indexes
    from mcap.records import Chunk
    from mcap.stream_reader import breakup_chunk
    out = []
    with open(path, "rb") as f:
        chunks = [r for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(chunks) == len(indexes)
    for idx, chunk in zip(indexes, chunks):
        frames = 0
        for r in breakup_chunk(chunk):
            if getattr(r, "channel_id", None) == 6 and hasattr(r, "log_time"):
                frames += _count_frames(r.data)
        out.append((idx.chunk_start_offset, idx.chunk_start_offset + idx.chunk_length, frames, idx))
    return out


def _count_frames(payload: bytes) -> int:
    n, pos = 0, 0
    while pos < len(payload):
        pos += 14 + payload[pos + 13]
        n += 1
    return n


def assert_frames_equal(log, msgs):
    frames = log.read_can_frames()
    assert len(frames.ids) == len(msgs)
    assert np.array_equal(frames.timestamp_s, log.read_can_timestamps_s())
    for i, m in enumerate(msgs):
        n = int(frames.lengths[i])
        assert bytes(frames.data[i, :n]) == bytes(m.data)
        assert not frames.data[i, n:].any()
        assert int(frames.ids[i]) == m.arbitration_id | ((1 << 31) if m.is_extended_id else 0)
        assert frames.timestamp_s[i] == m.timestamp


# -- round trip ----------------------------------------------------------------------------

def test_round_trip_is_lossless(closed_log):
    path, run = closed_log
    log = read_log(path)
    assert log.scan().complete and log.scan().damage == [] and log.summary_present
    assert_frames_equal(log, run.messages)
    frames = log.read_can_frames()
    assert frames.data.shape[1] == 8 and not frames.flags.any()
    block, stats = log.imu_samples(LAYOUT, RATE_HZ)
    assert stats.samples == len(run.block) and stats.lost_samples == 0 and stats.frame_faults == 0
    np.testing.assert_array_equal(block.counter, run.block.counter)
    np.testing.assert_array_equal(block.gyro_counts, run.block.gyro_counts)
    np.testing.assert_array_equal(block.acc_counts, run.block.acc_counts)
    np.testing.assert_array_equal(block.receive_time_s, run.block.receive_time_s)
    rec = log.read_imu_records()
    np.testing.assert_array_equal(rec.counter, run.block.counter)
    np.testing.assert_array_equal(rec.gyro_counts, run.block.gyro_counts)
    np.testing.assert_array_equal(rec.acc_counts, run.block.acc_counts)
    np.testing.assert_array_equal(rec.temperature_c, run.block.temperature_c)
    np.testing.assert_array_equal(rec.status, run.block.status)
    np.testing.assert_allclose(rec.receive_time_s, run.block.receive_time_s, atol=1e-9)
    np.testing.assert_allclose(rec.imu_time_s, run.block.counter / RATE_HZ)
    assert [e.to_dict() for e in log.events] == [json.loads(json.dumps(e.to_dict(), default=int)) for e in run.events]
    assert log.metadata["run"]["operator"] == "ana" and log.metadata["config"]["toml"].startswith("[imu]")
    assert log.metadata["result"] == {"rms": "1.5", "ok": "true"}
    assert log.attachments["plan.toml"] == ("application/toml", b"[[positions]]\nouter = 0\n")
    assert "imu.dbc" in log.attachments
    ts = log.read_table_states()
    assert len(ts) == len(run.states)
    np.testing.assert_array_equal(ts.time_s, [s.time_s for s in run.states])
    np.testing.assert_array_equal(ts.angles_deg, [s.angles_deg for s in run.states])
    np.testing.assert_array_equal(ts.rates_dps, [s.rates_dps for s in run.states])
    np.testing.assert_array_equal(ts.status, [[int(a.status) for a in s.axes] for s in run.states])
    assert ts.modes[0] == ("rate", "position", "position") and ts.fault_text == [s.fault_text for s in run.states]
    assert run.recorder.frames_written == len(run.messages) and run.recorder.samples_written == len(run.block)
    assert log.message_counts["/tf"] == 3 * len(run.states) and log.message_counts["/log"] == len(run.events)


def test_mixed_frames_round_trip_with_flags(tmp_path):
    path = tmp_path / "mixed.mcap"
    run = record(path, n_batches=6, extras=True)
    run.recorder.close()
    log = read_log(path)
    assert log.scan().complete
    assert_frames_equal(log, run.messages)
    frames = log.read_can_frames()
    assert frames.data.shape[1] == 64
    ext = np.flatnonzero(frames.ids == (0x1ABCDEF0 | 1 << 31))
    assert len(ext) == 2
    assert set(frames.flags[frames.ids == 0x123]) == {FLAG_FD | 0x02}
    assert set(frames.flags[frames.ids == 0x321]) == {FLAG_REMOTE}
    assert set(frames.flags[frames.ids == 0]) == {FLAG_ERROR}
    block, stats = log.imu_samples(LAYOUT, RATE_HZ)
    # the extended-id and FD frames are unknown to the layout; remote and error frames are not decoded
    assert stats.samples == len(run.block) and stats.unknown_id == 4 and log.scan().non_data_frames == 4


def test_decimated_sample_topic_keeps_every_raw_frame(tmp_path):
    path = tmp_path / "dec.mcap"
    run = record(path, n_batches=5, imu_samples_topic_decimation=4)
    run.recorder.close()
    log = read_log(path)
    assert_frames_equal(log, run.messages)
    np.testing.assert_array_equal(log.read_imu_records().counter, run.block.counter[run.block.counter % 4 == 0])
    assert len(log.imu_samples(LAYOUT, RATE_HZ)[0]) == len(run.block)


# -- what other tools see ------------------------------------------------------------------

def test_mcap_library_reads_everything_with_crc_validation(closed_log):
    path, run = closed_log
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        seen = [(schema.name, schema.encoding, channel.topic, channel.message_encoding, msg)
                for schema, channel, msg in reader.iter_messages()]
        summary = reader.get_summary()
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        attachments = {a.name: a.media_type for a in reader.iter_attachments()}
    assert len(seen) == run.recorder.messages_written == summary.statistics.message_count
    topics = {(t, s, se, me) for s, se, t, me, _ in seen}
    assert topics == {(t, s, se, me) for t, (s, se, me) in CHANNELS.items()}
    assert summary.statistics.chunk_count >= 12     # one per batch: the fake clock passes the interval each time
    assert set(metadata) == {"run", "config", "result"} and metadata["run"]["run_id"] == "r-1"
    assert attachments == {"plan.toml": "application/toml", "imu.dbc": "text/plain"}
    with open(path, "rb") as f:   # the stream reader validates chunk CRCs and the data-section CRC
        records = list(StreamReader(f, validate_crcs=True).records)
    assert sum(type(r).__name__ == "Message" for r in records) == len(seen)


def test_json_channels_are_strict_json_with_the_documented_fields(closed_log):
    path, run = closed_log

    def strict(text):
        return json.loads(text, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))

    with open(path, "rb") as f:
        reader = make_reader(f)
        by_topic: dict[str, list] = {}
        for schema, channel, msg in reader.iter_messages():
            if channel.message_encoding == "json":
                strict(schema.data)
                by_topic.setdefault(channel.topic, []).append((msg.log_time, strict(msg.data)))
            else:
                assert channel.message_encoding == CAN_ENCODING and b"uint32" in schema.data
    log_time, sample = by_topic["/imu/samples"][0]
    assert set(sample) == {"counter", "time_s", "imu_time_s", "gyro_counts", "acc_counts", "gyro_rate", "acc_rate",
                           "temperature_c", "status"}
    # one time base: time_s is the message's log time on the run clock; the IMU's own clock is imu_time_s
    assert sample["time_s"] == pytest.approx(log_time / 1e9, abs=1e-9)
    assert sample["imu_time_s"] == pytest.approx(sample["counter"] / RATE_HZ)
    np.testing.assert_allclose(sample["gyro_rate"], np.array(sample["gyro_counts"]) * RATE_HZ)
    levels = {m["message"]: m["level"] for _, m in by_topic["/log"]}
    assert levels["[P03] fault at batch 6"] == 4 and levels["[P03] warning at batch 6"] == 3 and levels["start"] == 2
    log_time, state = by_topic["/table/state"][0]
    assert log_time == round(state["time_s"] * 1e9) and state["estop"] is False
    tfs = by_topic["/tf"][:3]
    assert [(m["parent_frame_id"], m["child_frame_id"]) for _, m in tfs] == [("world", "outer"), ("outer", "middle"),
                                                                            ("middle", "inner")]
    assert tfs[0][1]["timestamp"]["sec"] * 10**9 + tfs[0][1]["timestamp"]["nsec"] == tfs[0][0]


def _quat_matrix(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_frame_transforms_are_the_transposed_design_matrices():
    angles = (30.0, -70.0, 200.0)
    q_outer, q_middle, q_inner = frame_quaternions(angles)
    rad = np.radians(angles)
    np.testing.assert_allclose(_quat_matrix(q_outer), rot_z(rad[0]).T, atol=1e-15)
    np.testing.assert_allclose(_quat_matrix(q_middle), rot_y(rad[1]).T, atol=1e-15)
    np.testing.assert_allclose(_quat_matrix(q_inner), rot_z(rad[2]).T, atol=1e-15)


def test_non_finite_values_become_null(tmp_path):
    path = tmp_path / "nan.mcap"
    with McapRecorder(path) as rec:
        axes = tuple(AxisState(math.nan, 0.0, AxisMode.OFF, AxisStatus(0)) for _ in range(3))
        rec.on_table_state(TableState(1.0, axes))
        rec.on_event(make_event(2.0, "info", "odd value", data={"x": math.inf}))
        msgs, block = make_messages(3)
        block.temperature_c[:] = np.nan
        block.gyro_counts[1, 2] = np.nan
        rec.on_imu(block)
    with open(path, "rb") as f:
        for _, channel, msg in make_reader(f).iter_messages():
            json.loads(msg.data, parse_constant=lambda c, channel=channel: pytest.fail(f"{channel.topic}: {c}"))
    log = read_log(path)
    assert np.isnan(log.read_table_states().angles_deg).all() and log.events[0].to_dict()["data"] == {"x": None}
    records = log.read_imu_records()
    assert np.isnan(records.temperature_c).all() and np.isnan(records.gyro_counts[1, 2])


# -- chunking and crashes ------------------------------------------------------------------

def test_chunk_closes_after_the_interval_so_an_unclosed_file_is_readable(tmp_path):
    path = tmp_path / "live.mcap"
    clock = FakeClock()
    rec = McapRecorder(path, clock=clock, chunk_interval_s=1.0)
    start_size = path.stat().st_size
    msgs, block = make_messages(50)
    for k in range(0, len(msgs), 35):
        rec.on_can_frames(msgs[k:k + 35])
        clock.t += 0.1     # 10 batches: 0.9 s < the interval
    assert path.stat().st_size == start_size        # still in the open chunk
    clock.t = 1.0
    rec.on_imu(block)
    grown = path.stat().st_size
    assert grown > start_size
    log = read_log(path)          # the recorder is still open: no summary yet
    assert not log.summary_present and not log.scan().complete and "not closed" in log.scan().damage[0]
    assert_frames_equal(log, msgs)
    np.testing.assert_array_equal(log.read_imu_records().counter, block.counter)
    rec.on_can_frames(msgs[:7])   # into a new chunk, not yet closed
    assert path.stat().st_size == grown
    rec.close()
    rec.close()                   # idempotent
    assert len(read_log(path).read_can_frames().ids) == len(msgs) + 7
    with pytest.raises(RecorderError, match="closed"):
        rec.on_can_frames(msgs[:1])


def _run_clock_recording(path, chunk_run_interval_s):
    """Table states every 0.5 s of run time for 10 s, then three CAN batches 7 s of run time
    apart, with a wall clock that never advances (a fast machine records it in no time)."""
    rec = McapRecorder(path, clock=FakeClock(), chunk_run_interval_s=chunk_run_interval_s)
    for k in range(20):
        rec.on_table_state(state_at(0.5 * k, k))
    msgs, _ = make_messages(3)
    for b in range(3):
        rec.on_can_frames([can.Message(timestamp=12.0 + 7.0 * b + 1e-3 * j, arbitration_id=m.arbitration_id,
                                       is_extended_id=False, data=m.data) for j, m in enumerate(msgs)])
    rec.close()
    return chunk_layout(path), len(msgs)


def test_chunks_close_by_run_clock_time_whatever_the_wall_clock_does(tmp_path):
    """Every multiple of `chunk_run_interval_s` on the run clock (the messages' log times)
    starts a new chunk, so a simulated run is chunked the same on any machine."""
    chunks, n_frames = _run_clock_recording(tmp_path / "run-clock.mcap", 2.0)
    spans = [(c[3].message_start_time / 1e9, c[3].message_end_time / 1e9) for c in chunks]
    # the states: 4 per 2 s chunk; the CAN batches, each more than the interval after the last: one chunk each
    assert spans[:5] == [(2.0 * k, 2.0 * k + 1.5) for k in range(5)]
    assert spans[5:] == [pytest.approx((t, t)) for t in (12.02, 19.02, 26.02)]
    assert [c[2] for c in chunks] == [0] * 5 + [n_frames] * 3
    assert len(chunks) == 8
    # without the run-clock rule the frozen wall clock never closes a chunk: one for the states and one for
    # all the frames (written in chunks of their own)
    chunks, _ = _run_clock_recording(tmp_path / "wall-only.mcap", None)
    assert [c[2] for c in chunks] == [0, 3 * n_frames]


@pytest.fixture(scope="module")
def chunked_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("chunked") / "run.mcap"
    run = record(path, clock=FakeClock())
    run.recorder.close()
    return path, run, chunk_layout(path), path.read_bytes()


def test_truncated_files_read_up_to_the_last_complete_chunk(chunked_log, tmp_path):
    path, run, chunks, data = chunked_log
    cut_points = [chunks[0][0] + 20, (chunks[2][0] + chunks[2][1]) // 2, chunks[5][1] - 1, chunks[7][1],
                  chunks[-1][1] + 30]
    for cut in cut_points:
        cut_path = tmp_path / f"cut{cut}.mcap"
        cut_path.write_bytes(data[:cut])
        log = read_log(cut_path)
        complete = [c for c in chunks if c[1] <= cut]
        n = sum(c[2] for c in complete)
        assert_frames_equal(log, run.messages[:n])
        assert not log.scan().complete and not log.summary_present
        assert any("not closed" in d for d in log.scan().damage)
        inside = [c for c in chunks if c[0] < cut < c[1]]
        if inside:
            idx = inside[0][3]
            text = f"log time {idx.message_start_time / 1e9:.3f}..{idx.message_end_time / 1e9:.3f} s"
            text = text if cut - inside[0][0] >= 25 else ""   # the chunk header holds the time range
            assert any(d.startswith(f"truncated after byte {cut}: the last chunk (at byte {inside[0][0]})")
                       and text in d and "messages lost" in d for d in log.scan().damage), log.scan().damage


def test_a_file_cut_inside_the_header_is_an_error(chunked_log, tmp_path):
    path, run, chunks, data = chunked_log
    for cut in (4, 8, 12):
        p = tmp_path / f"h{cut}.mcap"
        p.write_bytes(data[:cut])
        with pytest.raises(LogError) as err:
            read_log(p)
        assert str(p) in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("compression", ["zstd", "none"])
def test_a_corrupt_chunk_is_skipped_and_reading_resumes_after_it(tmp_path, compression):
    path = tmp_path / f"{compression}.mcap"
    run = record(path, clock=FakeClock(), compression=compression)
    run.recorder.close()
    chunks = chunk_layout(path)
    data = bytearray(path.read_bytes())
    bad = [k for k, c in enumerate(chunks) if c[2]][3]   # the fourth chunk holding CAN frames
    start, end, frames, idx = chunks[bad]
    data[(start + end) // 2] ^= 0x5A
    path.write_bytes(bytes(data))
    for defer in (True, False):
        log = read_log(path, defer_samples=defer)
        before = sum(c[2] for c in chunks[:bad])
        assert_frames_equal(log, run.messages[:before] + run.messages[before + frames:])
        assert log.summary_present and not log.scan().complete
        chunk_damage = [d for d in log.scan().damage if d.startswith(f"chunk at byte {start}")]
        assert len(chunk_damage) == 1, log.scan().damage
        text = chunk_damage[0]
        assert f"log time {idx.message_start_time / 1e9:.3f}..{idx.message_end_time / 1e9:.3f} s" in text
        # the frames have chunks of their own: only they are lost with it
        assert "messages lost" in text and "on /can/raw" in text and "on /table/state" not in text
        if compression == "none":
            assert "CRC mismatch" in text
        assert len(log.scan().damage) == 1     # the message index accounts for every lost message
        assert log.scan().lost[0].lost == {"/can/raw": 1}
        assert len(log.read_imu_records()) == len(run.batch_frames) * SAMPLES_PER_BATCH
        assert log.scan().damage == [text]


@pytest.mark.parametrize("compression", ["zstd", "none"])
def test_imu_samples_have_chunks_of_their_own_checked_when_first_read(tmp_path, compression):
    path = tmp_path / f"{compression}.mcap"
    run = record(path, clock=FakeClock(), compression=compression)
    run.recorder.close()
    chunks = chunk_layout(path)
    samples_only = [c for c in chunks if not c[2] and c[3].message_index_offsets.keys() == {2}]
    assert len(samples_only) >= len(run.batch_frames) - 1
    start, end, _, idx = samples_only[2]
    data = bytearray(path.read_bytes())
    data[(start + end) // 2] ^= 0x5A
    path.write_bytes(bytes(data))

    log = read_log(path)   # the samples chunks are left compressed: the damage is not seen yet
    assert_frames_equal(log, run.messages)
    assert log.scan().complete and log.unchecked_chunks == len(samples_only)
    assert f"{len(samples_only)} /imu/samples chunks" in log.summary()
    records = log.read_imu_records()   # now they are read: one chunk is lost, and said so
    assert log.unchecked_chunks == 0 and not log.scan().complete and len(log.scan().damage) == 1
    assert log.scan().damage[0].startswith(f"chunk at byte {start}")
    assert f"{SAMPLES_PER_BATCH} on /imu/samples" in log.scan().damage[0]
    if compression == "none":
        assert "CRC mismatch" in log.scan().damage[0]
    assert len(records) == len(run.batch_frames) * SAMPLES_PER_BATCH - SAMPLES_PER_BATCH

    eager = read_log(path, defer_samples=False)   # the same damage, found at once
    assert eager.unchecked_chunks == 0 and eager.scan().damage == log.scan().damage
    assert len(eager.read_imu_records()) == len(records)


def test_a_corrupt_record_header_resyncs_at_the_next_chunk(chunked_log, tmp_path):
    path, run, chunks, data = chunked_log
    data = bytearray(data)
    start, end, frames, _ = chunks[4]
    data[start] = 0xEE        # the chunk's opcode
    p = tmp_path / "op.mcap"
    p.write_bytes(bytes(data))
    log = read_log(p)
    before = sum(c[2] for c in chunks[:4])
    assert_frames_equal(log, run.messages[:before] + run.messages[before + frames:])
    damage = log.scan().damage
    assert any(f"byte {start}: unreadable record" in d and "next chunk" in d for d in damage), damage
    assert any("summary counts" in d for d in log.scan().damage)


def test_good_chunks_are_gathered_through_their_message_index(chunked_log, monkeypatch):
    import bench.log.mcap.walk as mw
    walked = []
    original = mw._Walker.chunk_records

    def spy(self, data, messages=True):
        walked.append(messages)
        return original(self, data, messages)

    monkeypatch.setattr(mw._Walker, "chunk_records", spy)
    path, run, chunks, _ = chunked_log
    log = read_log(path)
    assert log.scan().complete and log.chunks == len(chunks)
    assert True not in walked     # only the first chunk's schema/channel prefix is walked record by record


def test_a_wrong_message_index_falls_back_to_the_record_walk(chunked_log, tmp_path):
    path, run, chunks, data = chunked_log
    data = bytearray(data)
    index_at = chunks[2][1]            # the message index records follow their chunk
    assert data[index_at] == 0x07
    data[index_at + 9 + 6 + 8] ^= 0x01  # the first entry's offset: the index no longer frames the chunk
    p = tmp_path / "index.mcap"
    p.write_bytes(bytes(data))
    log = read_log(p)
    assert log.scan().complete, log.scan().damage
    assert_frames_equal(log, run.messages)
    np.testing.assert_array_equal(log.read_imu_records().counter, run.block.counter)


def test_not_mcap_and_empty_files_give_one_line_errors(tmp_path):
    cases = {"text.mcap": b"hello, this is not a log\n" * 10, "empty.mcap": b"",
             "magic_only.mcap": b"\x89MCAP0\r\n"}
    for name, content in cases.items():
        p = tmp_path / name
        p.write_bytes(content)
        with pytest.raises(LogError) as err:
            read_log(p)
        msg = str(err.value)
        assert msg.startswith(str(p)) and "\n" not in msg
    with pytest.raises(LogError, match="empty file"):
        read_log(tmp_path / "empty.mcap")
    with pytest.raises(LogError, match="not an MCAP file"):
        read_log(tmp_path / "text.mcap")
    with pytest.raises(LogError, match="cannot read"):
        read_log(tmp_path / "missing.mcap")


def test_recorder_rejects_bad_arguments(tmp_path):
    with pytest.raises(RecorderError, match="decimation"):
        McapRecorder(tmp_path / "a.mcap", imu_samples_topic_decimation=0)
    with pytest.raises(RecorderError, match="compression"):
        McapRecorder(tmp_path / "b.mcap", compression="brotli")
    for interval in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(RecorderError, match="chunk_run_interval_s"):
            McapRecorder(tmp_path / "b.mcap", chunk_run_interval_s=interval)
    with pytest.raises(RecorderError, match="cannot create"):
        McapRecorder(tmp_path / "no" / "such" / "dir.mcap")
    with pytest.raises(RecorderError, match="key"):
        McapRecorder(tmp_path / "c.mcap", metadata={"run": {"x": ["not", "a", "string"]}})
    with McapRecorder(tmp_path / "d.mcap") as rec:
        with pytest.raises(RecorderError, match="bytes"):
            rec.add_attachment("x", "text/plain", "text, not bytes")
        with pytest.raises(RecorderError, match="encode"):
            rec.on_can_frames([object()])


# -- random damage -------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("small") / "small.mcap"
    run = record(path, n_batches=4, clock=FakeClock(), compression="none")
    run.recorder.close()
    return path.read_bytes(), len(run.messages)


@pytest.mark.slow
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(flips=st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(1, 255)), min_size=1, max_size=4),
       cut=st.one_of(st.none(), st.floats(0, 1)))
def test_random_damage_never_crashes_the_reader(small_log, tmp_path, flips, cut):
    data, n_frames = small_log
    data = bytearray(data)
    for where, xor in flips:
        data[int(where * len(data))] ^= xor
    if cut is not None:
        data = data[:int(cut * len(data))]
    p = tmp_path / "fuzz.mcap"
    p.write_bytes(bytes(data))
    try:
        log = read_log(p)
    except LogError as exc:
        assert "\n" not in str(exc)
        return
    assert len(log.read_can_frames().ids) <= n_frames + 50
    assert all(isinstance(d, str) for d in log.scan().damage)
    log.imu_samples(LAYOUT, RATE_HZ)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=st.binary(max_size=400))
def test_random_bytes_after_the_magic_are_an_error_or_damage(tmp_path, body):
    p = tmp_path / "rand.mcap"
    p.write_bytes(b"\x89MCAP0\r\n" + body)
    try:
        log = read_log(p)
    except LogError:
        return
    assert not log.scan().complete


def test_malformed_messages_found_on_first_use_are_counted_in_damage_and_lost(tmp_path):
    # The derived topics are parsed when first used; what cannot be parsed is skipped, the rest
    # kept, and the skipped messages are named in `damage` and counted per topic in `lost`.
    from mcap.writer import Writer

    from bench.log.format import TOPIC_SAMPLES, TOPIC_STATE

    good_sample = {"counter": 7, "time_s": 0.07, "gyro_counts": [1, 2, 3], "acc_counts": [4, 5, 6],
                   "temperature_c": None, "status": 0}
    good_state = {"time_s": 1.0, "angles_deg": [0, 90, 0], "rates_dps": [0, 0, 0], "modes": ["position"] * 3,
                  "status": [5, 5, 5], "estop": False, "fault_text": ""}
    path = tmp_path / "malformed.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        for topic, good in ((TOPIC_SAMPLES, good_sample), (TOPIC_STATE, good_state)):
            schema = writer.register_schema(name=topic, encoding="jsonschema", data=b"{}")
            channel = writer.register_channel(topic=topic, message_encoding="json", schema_id=schema)
            for k, payload in enumerate((b"not json", json.dumps(good).encode(), b'{"counter": [1, 2]}')):
                writer.add_message(channel, log_time=k + 1, data=payload, publish_time=k + 1)
        writer.finish()
    log = read_log(path)
    records = log.read_imu_records()
    assert len(records) == 1 and records.counter.tolist() == [7]
    assert log.read_imu_records() is records   # parsed once, kept (its damage counted once)
    assert len(log.read_table_states().time_s) == 1
    assert {topic: n for d in log.scan().lost for topic, n in d.lost.items()} == {TOPIC_SAMPLES: 2, TOPIC_STATE: 2}
    assert len(log.scan().damage) == len(log.scan().lost) == 2 and not log.scan().complete
