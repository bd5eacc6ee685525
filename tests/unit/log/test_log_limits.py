"""A log from outside is hostile (issue 13, items 6 and 7): bounded memory, bounded time, one line.

Decompression bombs are refused as damage of their chunk, quickly and without allocating
what they declare: a chunk must inflate to exactly its declared uncompressed size
(zstd, lz4 or none), declare at most `MAX_CHUNK_BYTES`, and all chunks together at most
the log's inflate budget. Crafted content (a CAN record claiming 255 data bytes, an event
whose step is a string, table angles of 1e308, a DBC padded to megabytes) becomes damage
or a left-out step with a reason, never a traceback. The crafted files are a real log with
one chunk replaced (`tests/helpers/mcap_surgery.py`) or rewritten through `mcap.writer`.
"""

from __future__ import annotations

import json
import tracemalloc
import zlib
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

import bench.log.mcap.chunks as chunks_module
from bench.log.format import TOPIC_CAN, TOPIC_EVENTS
from bench.log.mcap.chunks import MAX_CHUNK_BYTES, MAX_RECORDS
from bench.log.mcap.walk import MAX_ATTACHMENT_BYTES, MAX_DBC_BYTES, walk
from bench.log.reader import read_log
from tests.helpers.mcap_surgery import (
    can_frames,
    chunk_fields,
    chunk_record,
    chunks,
    inflate,
    lz4_bomb,
    message_index,
    message_record,
    replace_chunk,
    rewrite,
    top_records,
    zstd_bomb,
)
from tests.helpers.run import cli

GiB = 1 << 30


@pytest.fixture(scope="module")
def run_log(cli_run_log) -> Path:
    """A real simulated run's log (the session's `bench run` of the short test plan with 1 s dwells)."""
    return cli_run_log


@pytest.fixture(scope="module")
def can_chunk(run_log):
    """(log bytes, offset of a chunk in the middle holding /can/raw, the /can/raw channel id)."""
    buf = run_log.read_bytes()
    with open(run_log, "rb") as f:
        summary = make_reader(f).get_summary()
    can = next(cid for cid, c in summary.channels.items() if c.topic == TOPIC_CAN)
    holding = [i.chunk_start_offset for i in summary.chunk_indexes if can in i.message_index_offsets]
    return buf, holding[len(holding) // 2], can


def _crafted(tmp_path: Path, data: bytes, name: str = "crafted.mcap") -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path


def _chunk_damage(log, pos: int) -> str:
    found = [d for d in log.scan().damage if d.startswith(f"chunk at byte {pos}")]
    assert len(found) == 1, log.scan().damage
    return found[0]


def _peak_while(fn):
    """(fn(), the peak of traced Python allocations while it ran)."""
    tracemalloc.start()
    try:
        result = fn()
        return result, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


# -- item 6: decompression bombs ---------------------------------------------------------------

def _bomb_cases(can: int):
    msg = message_record(can, can_frames(40))
    block = zstd_bomb(msg, 64 << 20)              # 64 MiB of messages in ~10 KB, the size stated in the frame
    unstated = zstd_bomb(msg, 64 << 20, content_size=False)
    return {
        # declares more than a chunk may hold: not even looked at
        "declared 4 GiB": (chunk_record(block, "zstd", 4 * GiB), "more than a chunk may hold"),
        "declared 2^64-1": (chunk_record(block, "zstd", (1 << 64) - 1), "more than a chunk may hold"),
        "none, declared 2^40": (chunk_record(msg, "", 1 << 40), "more than a chunk may hold"),
        # the zstd frame states a size other than the chunk header's: refused before decompressing
        "zstd lies": (chunk_record(block, "zstd", 4096), "its zstd frame says 67108"),
        # the frame states no size: decompressed in steps, never past the declared size
        "zstd unstated": (chunk_record(unstated, "zstd", 4096), "inflates to more than the 4096 bytes"),
        "zstd unstated, short": (chunk_record(zstd_bomb(msg, 3 * len(msg), content_size=False), "zstd", 64 << 20),
                                 f"decompressed to {3 * len(msg)} bytes, header says {64 << 20}"),
        "lz4 lies": (chunk_record(lz4_bomb(msg, 64 << 20), "lz4", 4096), "its lz4 frame says 67108"),
        "lz4 unstated": (chunk_record(lz4_bomb(msg, 64 << 20, content_size=False), "lz4", 4096),
                         "inflates to more than the 4096 bytes"),
        "none, declared less": (chunk_record(msg * 10, "", 100),
                                f"decompressed to {10 * len(msg)} bytes, header says 100"),
    }


@pytest.mark.slow
def test_decompression_bombs_are_refused_as_damage_of_their_chunk_without_allocating_them(can_chunk, tmp_path):
    buf, pos, can = can_chunk
    good = read_log(_crafted(tmp_path, buf, "good.mcap"))
    for name, (chunk, reason) in _bomb_cases(can).items():
        path = _crafted(tmp_path, replace_chunk(buf, pos, chunk))
        log, peak = _peak_while(lambda p=path: read_log(p, defer_samples=False))
        text = _chunk_damage(log, pos)
        assert reason in text and "messages lost" in text, (name, text)
        assert peak < 32 << 20, (name, peak)   # nothing near what the chunk declares or inflates to
        # everything else is still read: only the replaced chunk's frames are missing
        good_frames = len(good.read_can_frames().ids)
        assert 0 < good_frames - len(log.read_can_frames().ids) < good_frames // 4, name


def test_a_chunk_over_the_cap_is_refused_even_when_its_index_frames_it(can_chunk, tmp_path):
    buf, pos, can = can_chunk
    msg = message_record(can, can_frames(40))
    n = MAX_CHUNK_BYTES // len(msg) + 1
    index = message_index(can, [(1_000_000_000, k * len(msg)) for k in range(n)])
    path = _crafted(tmp_path, replace_chunk(buf, pos, chunk_record(zstd_bomb(msg, n * len(msg)), "zstd",
                                                                   n * len(msg)) + index))
    log, peak = _peak_while(lambda: read_log(path))
    text = _chunk_damage(log, pos)
    assert f"declares {n * len(msg)} bytes uncompressed, more than a chunk may hold ({MAX_CHUNK_BYTES} bytes)" in text
    assert f"{n} on {TOPIC_CAN}" in text     # its message index still counts what was lost
    assert peak < 3 * len(index)             # the index itself is read; the chunk is not


def _four_honest_chunks(can_chunk) -> tuple[bytes, int, int]:
    """The log with its last four chunks replaced by honest 1 MiB ones, each framed by its message index:
    (log bytes, messages per chunk, bytes per chunk inflated)."""
    buf, _, can = can_chunk
    msg = message_record(can, can_frames(40))
    n = (1 << 20) // len(msg)
    honest = chunk_record(zstd_bomb(msg, n * len(msg)), "zstd", n * len(msg))
    index = message_index(can, [(1_000_000_000, k * len(msg)) for k in range(n)])
    data = buf
    for p in reversed(chunks(buf)[-4:]):
        data = replace_chunk(data, p, honest + index)
    return data, n, n * len(msg)


def test_the_chunks_of_one_log_inflate_to_a_bounded_total(can_chunk, monkeypatch):
    # Four chunks of 1 MiB each, declared honestly and framed by their index, in a log whose budget
    # (made small here, so the test stays small) leaves room for two of them: the others are refused.
    data, n, size = _four_honest_chunks(can_chunk)
    used = walk(data).budget.used
    monkeypatch.setattr(chunks_module, "MAX_LOG_INFLATED", used - 2 * size + size // 2)
    w = walk(data)
    refused = [d for d in w.damage if "past what this log's chunks may inflate to in all" in d.reason]
    # the two refused chunks follow each other: told as one damage line (a file of a million bomb chunks held
    # a million lines, 1 GB of memory)
    assert len(refused) == 1 and f"({w.budget.total} bytes:" in refused[0].reason and refused[0].chunks == 2
    assert refused[0].describe().startswith(f"2 chunks at bytes {refused[0].offset}..{refused[0].last_offset} ")
    assert w.budget.used <= w.budget.total < w.budget.used + size
    assert refused[0].lost == {TOPIC_CAN: 2 * n}   # their index still counts what was lost


def test_deferred_sample_chunks_count_against_the_budget_kept_and_inflated(run_log, monkeypatch):
    # /imu/samples chunks are left in the file (counted at nothing: read_log walks with a source to read
    # them again) and inflated only when asked for (counted then at their own size): with no room left for
    # that, they are refused when asked for. (/can/raw chunks are streamed: a budget of their own.)
    used = walk(run_log.read_bytes(), frozenset({"/imu/samples", TOPIC_CAN}), source=lambda o, n: b"").budget.used
    monkeypatch.setattr(chunks_module, "MAX_LOG_INFLATED", used)
    log = read_log(run_log)
    assert log.scan().complete and log.unchecked_chunks and len(log.read_can_frames().ids)
    assert len(log.read_imu_records()) == 0 and log.unchecked_chunks == 0
    refused = [d for d in log.scan().damage if "past what this log's chunks may inflate to in all" in d]
    assert refused and all("on /imu/samples" in d for d in refused)
    monkeypatch.setattr(chunks_module, "MAX_LOG_INFLATED", used - 1)
    log = read_log(run_log)   # one byte less: a chunk is refused as the walk reaches it
    assert len(log.read_can_frames().ids) and any("past what" in d for d in log.scan().damage)


def test_a_chunk_walked_record_by_record_is_not_walked_in_python_per_message(can_chunk, tmp_path):
    # 4 MiB of one repeated message and no message index (the walk's fallback): gathered at one stride
    buf, pos, can = can_chunk
    msg = message_record(can, can_frames(1, t=12345.5))
    n = (4 << 20) // len(msg)
    content = msg * n
    path = _crafted(tmp_path, replace_chunk(buf, pos, chunk_record(zstd_bomb(msg, len(content)), "zstd",
                                                                   len(content), zlib.crc32(content))))
    log = read_log(path)
    assert not [d for d in log.scan().damage if d.startswith(f"chunk at byte {pos}")], log.scan().damage
    assert int(np.count_nonzero(log.read_can_timestamps_s() == 12345.5)) == n


def test_records_inside_a_chunk_other_than_schemas_channels_and_messages_make_it_damage(can_chunk, tmp_path):
    buf, pos, can = can_chunk
    content = message_record(can, can_frames(2)) + bytes(9) * 1000   # then records of opcode 0
    path = _crafted(tmp_path, replace_chunk(buf, pos, chunk_record(content, "", len(content))))
    log = read_log(path)
    assert "malformed chunk content: opcode 0x0 record at offset" in _chunk_damage(log, pos)


def test_a_file_of_chunk_opcodes_resyncs_in_bounded_time(can_chunk, tmp_path):
    # 8 MiB of 0x06 bytes where a chunk was: every byte looks like the start of a chunk record
    buf, pos, _ = can_chunk
    path = _crafted(tmp_path, replace_chunk(buf, pos, b"\x06" * (8 << 20)))
    log = read_log(path)
    assert any(d.startswith(f"byte {pos}: chunk record with an impossible length; bytes {pos}..")
               for d in log.scan().damage)
    assert len(log.read_can_frames().ids) > 0


def test_records_outside_chunks_are_counted_and_the_walk_stops_at_the_limit(can_chunk, tmp_path, monkeypatch):
    buf, _, _ = can_chunk
    import bench.log.mcap.walk as walk_module
    monkeypatch.setattr(walk_module, "MAX_RECORDS", 50)
    log = read_log(_crafted(tmp_path, buf))
    assert any("more than 50 records outside chunks" in d for d in log.scan().damage), log.scan().damage
    assert MAX_RECORDS >= 100 * len(top_records(buf))   # a recorded log is far from the real limit


# -- item 7: crafted content, never a traceback ------------------------------------------------

_EVENT_CHANGES = {   # unit -> how its step_finished event is spoiled, and the reason the solve gives
    "P01": (lambda d: d["data"].update(step="dwell"), "its step record is not an object"),
    "P02": (lambda d: d["data"].update(step=["dwell"]), "its step record is not an object"),
    "P03": (lambda d: d["data"].update(counter_first="x"), "its IMU counter window is not two integers"),
    "P04": (lambda d: d["data"]["step"].pop("angles_deg"), "its angles_deg are not three finite numbers"),
    "P05": (lambda d: d.update(step_unit=["P05"]), None),   # the event itself is unreadable: log damage
    "R01": (lambda d: d["data"]["step"].update(frame="sideways"), "its frame or direction is not one the bench knows"),
    "R02": (lambda d: d["data"]["step"].update(revolutions="two"), "its revolutions are not a positive integer"),
}


@pytest.fixture(scope="module")
def crafted_content(run_log, tmp_path_factory):
    """The run log with item 7's crafted content: the first /can/raw message holds a record claiming 255
    data bytes; the step_finished events of the units in `_EVENT_CHANGES` are spoiled; every table state's
    angles are +-1e308; the DBC attachment is padded with a 2 MiB comment."""
    spoiled_can = []

    def message(topic, data):
        if topic == TOPIC_CAN and not spoiled_can:
            spoiled_can.append(len(data) // 22)
            return can_frames(3) + can_frames(1, length=255) + can_frames(2)
        if topic == "/table/state":
            d = json.loads(data)
            d["angles_deg"] = [1e308, -1e308, d["angles_deg"][2]]
            return json.dumps(d).encode()
        if topic == TOPIC_EVENTS:
            d = json.loads(data)
            change = _EVENT_CHANGES.get(d.get("step_unit"))
            if change and d["kind"] == "step_finished" and d["data"]["step"]["kind"] in ("dwell", "turn"):
                change[0](d)
                return json.dumps(d).encode()
        return data

    def attachment(name, data):
        return data + b'\nCM_ "' + b"x" * (2 << 20) + b'";\n' if name.endswith(".dbc") else data

    path = rewrite(run_log, tmp_path_factory.mktemp("crafted") / "crafted.mcap", message, attachment)
    return path, spoiled_can[0]


def test_crafted_content_is_read_as_damage_with_bounded_memory(run_log, crafted_content):
    path, frames_replaced = crafted_content
    log, peak = _peak_while(lambda: read_log(path))
    assert peak < 64 << 20     # the 255-byte claim allocates nothing per claim, the DBC is not kept
    good = read_log(run_log)
    frames = log.read_can_frames()
    assert len(frames.ids) == len(good.read_can_frames().ids) - frames_replaced and int(frames.lengths.max()) <= 64
    assert not any(name.endswith(".dbc") for name in log.attachments)
    for text in (f"1 malformed {TOPIC_CAN} messages skipped", f"1 malformed {TOPIC_EVENTS} messages skipped",
                 f"attachment 'sim_imu.dbc' holds {len(good.attachments['sim_imu.dbc'][1]) + (2 << 20) + 9} bytes, "
                 f"more than {MAX_DBC_BYTES} bytes"):
        assert any(text in d for d in log.scan().damage), (text, log.scan().damage)
    assert np.abs(log.read_table_states().angles_deg[:, :2]).max() == 1e308
    block, stats = log.imu_samples()
    assert len(block.counter)


@pytest.mark.slow
def test_crafted_content_solves_with_steps_left_out_and_a_report_without_the_bad_plot(crafted_content, tmp_path):
    path, _ = crafted_content
    rc, _, stderr = cli(["solve", str(path), "--out", str(tmp_path)])
    assert rc == 4 and "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1, stderr
    report = next(tmp_path.glob("*.report.md")).read_text(encoding="utf-8")
    for unit, (_, reason) in _EVENT_CHANGES.items():
        if reason is not None:
            assert f"{unit}: its step_finished event is malformed ({reason}" in report, unit
    assert "P05: left out" in report and f"1 malformed {TOPIC_EVENTS} messages skipped" in report
    assert f"1 malformed {TOPIC_CAN} messages skipped" in report and "sim_imu.dbc" in report
    html = next(tmp_path.glob("*.report.html")).read_text(encoding="utf-8")
    assert "The figure of the table angles is not drawn: the table angles reach 1e+308" in html
    assert html.count("<svg") >= 3   # the other figures are there
    rc, _, stderr = cli(["replay", str(path), "--quiet"])   # replay notes each damage on a line of its own
    assert rc == 0 and "Traceback" not in stderr and "malformed" in stderr, stderr


def test_a_message_of_records_all_claiming_255_bytes_is_malformed_not_an_error(run_log, tmp_path):
    def edit(topic, data):
        return can_frames(50, length=255) if topic == TOPIC_CAN else data

    log = read_log(rewrite(run_log, tmp_path / "all255.mcap", message=edit))
    assert len(log.read_can_frames().ids) == 0
    assert any(f"malformed {TOPIC_CAN} messages skipped" in d for d in log.scan().damage)
    block, stats = log.imu_samples()
    assert len(block.counter) == 0


def test_attachments_over_their_limit_are_skipped_without_reading_them(run_log, tmp_path):
    big = b"#" * (MAX_ATTACHMENT_BYTES + 1)
    path = rewrite(run_log, tmp_path / "big.mcap", attachment=lambda name, data: big if name == "bench.toml" else data)
    log, peak = _peak_while(lambda: read_log(path))
    assert "bench.toml" not in log.attachments and "sim_imu.dbc" in log.attachments
    assert any(f"attachment 'bench.toml' holds {len(big)} bytes" in d for d in log.scan().damage)
    assert peak < MAX_ATTACHMENT_BYTES   # reading it would copy it at least twice


def test_honest_chunks_still_read_exactly_as_before(can_chunk, tmp_path):
    # the same chunk rewritten honestly in each compression reads back frame for frame
    buf, pos, _ = can_chunk
    f = chunk_fields(buf, pos)
    content = inflate(f["compression"], f["data"])
    expected = read_log(_crafted(tmp_path, buf, "orig.mcap")).read_can_frames().data
    for compression, data in (("", content), ("zstd", zstd_bomb(content, len(content))),
                              ("lz4", lz4_bomb(content, len(content))),
                              ("zstd", zstd_bomb(content, len(content), content_size=False)),
                              ("lz4", lz4_bomb(content, len(content), content_size=False))):
        chunk = chunk_record(data, compression, len(content), zlib.crc32(content), f["start"], f["end"])
        log = read_log(_crafted(tmp_path, replace_chunk(buf, pos, chunk, drop_index=False)))
        assert not [d for d in log.scan().damage if "chunk" in d], (compression, log.scan().damage)
        np.testing.assert_array_equal(log.read_can_frames().data, expected)


def test_a_turn_window_holding_many_or_repeated_table_states_is_integrated_in_bounded_time():
    # A log from outside may hold any number of table states inside a turn's window, in any order: they
    # are taken in time order, once per time, a block of pieces at a time (the same integral).
    from bench.log.events import TurnRecord
    from bench.model.earth import Site
    from bench.model.motion import Piece
    from bench.model.observations import turn_earth_integral
    from bench.model.units import DEG
    from bench.solve.extract import _turn_earth_integral

    site, n = Site(latitude_deg=30.0), 3000
    step = TurnRecord((0.0, 90.0, 0.0), (360.0, 90.0, 0.0), "outer", "ccw", 1)
    t = np.linspace(0.0, 36.0, n)
    angles = np.zeros((n, 3))
    angles[:, 0] = 10.0 * t
    angles[:, 1] = 90.0
    theta = (angles[:, 0] - 360.0) * DEG
    pieces = [Piece(float(t[i]), float(theta[i]), float((theta[i + 1] - theta[i]) / (t[i + 1] - t[i])), 0.0)
              for i in range(n - 1)] + [Piece(float(t[-1]), float(theta[-1]), 0.0, 0.0)]
    one_call = turn_earth_integral(site, step.start_deg, 0, pieces, 0.0, 36.0)
    blocked = _turn_earth_integral(site, step, 36.0, -1.0, 37.0, t, angles, None)
    np.testing.assert_allclose(blocked, one_call, rtol=1e-12, atol=1e-18)   # its at-rest terms cancel here
    repeated = _turn_earth_integral(site, step, 36.0, -1.0, 37.0, np.concatenate([t] * 20),
                                    np.concatenate([angles] * 20), None)
    np.testing.assert_array_equal(repeated, blocked)


# -- item 6: the raw CAN frames are streamed, never held -----------------------------------------

def test_the_can_frames_are_decoded_chunk_by_chunk_and_never_held(run_log, monkeypatch):
    """1 GiB of a log's frames made the reader hold 2-3.8 GB (every frame as arrays); now each chunk is read
    from the file, decoded and let go, and the samples are those of decoding every frame at once."""
    from bench.log.mcap.chunks import DeferredChunk
    from bench.log.run_info import layout_and_config_from_log
    from drivers.imu import decode_frames
    from drivers.imu.stream import StreamDecoder

    fed: list[int] = []
    feed = StreamDecoder.feed

    def counting(self, ids, *args, **kwargs):
        fed.append(len(ids))
        return feed(self, ids, *args, **kwargs)

    monkeypatch.setattr(StreamDecoder, "feed", counting)
    log = read_log(run_log)
    setup = layout_and_config_from_log(log)
    block, stats = log.imu_samples(setup.layout, setup.rate_hz)
    parts = log._can.parts
    assert len(parts) > 10 and all(isinstance(p, DeferredChunk) and p.payload is None for p in parts)
    assert len(fed) == len(parts) and max(fed) < sum(fed) // 5       # piece by piece
    assert not [k for k, v in vars(log).items() if isinstance(v, np.ndarray)]   # nothing of the frames kept
    t, ids, data, lengths, flags = log.read_can_frames()
    assert sum(fed) == len(ids) == log.scan().can_frame_count
    whole, whole_stats = decode_frames(ids, data, lengths, t, layout=setup.layout, rate_hz=setup.rate_hz)
    assert whole_stats == stats and np.array_equal(whole.counter, block.counter)
    assert np.array_equal(whole.gyro_counts, block.gyro_counts) and np.array_equal(whole.receive_time_s,
                                                                                  block.receive_time_s)


def test_a_log_larger_than_what_may_be_held_is_still_read_whole(run_log, monkeypatch):
    """The 1 GiB budget of what the reader holds cut an 8 h 1 kHz static log at about 1.9 h (issue 17): the
    streamed frames have a budget of their own (time, not memory), so a log past the first is read whole."""
    good = read_log(run_log)
    n_frames, n_samples = good.scan().can_frame_count, len(good.imu_samples(*_setup(good))[0])
    can_bytes = sum(p.size for p in good._can.parts)
    held = walk(run_log.read_bytes(), frozenset({"/imu/samples", TOPIC_CAN}), source=lambda o, n: b"").budget.used
    assert can_bytes > held > 0
    monkeypatch.setattr(chunks_module, "MAX_LOG_INFLATED", held)   # room for what is held, not the frames
    log = read_log(run_log)
    assert log.scan().complete, log.scan().damage
    assert log.scan().can_frame_count == n_frames and len(log.imu_samples(*_setup(log))[0]) == n_samples


def test_the_streamed_frames_have_a_budget_of_their_own(run_log, monkeypatch):
    good = read_log(run_log)
    sizes = [p.size for p in good._can.parts]
    monkeypatch.setattr(chunks_module, "MAX_STREAMED_INFLATED", sum(sizes) // 2)
    log = read_log(run_log)
    # the chunks left in the file (frames and samples) are counted as the walk meets them: the later ones are
    # refused, their index not kept
    refused = [d for d in log.scan().damage if "past what this log's chunks may inflate to in all" in d]
    assert refused and all(f"at most {sum(sizes) // 2})" in d for d in refused)
    assert any(f"on {TOPIC_CAN}" in d for d in refused)
    assert 0 < log.scan().can_frame_count < good.scan().can_frame_count
    lost = sum(d.lost.get(TOPIC_CAN, 0) for d in log.scan().lost)
    assert lost == good.message_counts[TOPIC_CAN] - sum(len(p.offsets) for p in log._can.parts if p is not None)


def _setup(log):
    from bench.log.run_info import layout_and_config_from_log
    setup = layout_and_config_from_log(log)
    return setup.layout, setup.rate_hz


def test_chunks_left_in_the_file_past_what_may_stream_keep_no_index(can_chunk, tmp_path, monkeypatch):
    """A 1 GB file of 250 honest 256 MiB chunks, each with a 4 MB message index, held 1 GB of index entries
    before the walk began (2.2 GB peak): a chunk left in the file past what the log may stream keeps none."""
    from bench.log.mcap.chunks import Prefetch
    data, n, size = _four_honest_chunks(can_chunk)
    honest_at = chunks(data)[-4:]
    topics = frozenset({TOPIC_CAN, "/imu/samples"})   # what read_log leaves in the file
    everything = Prefetch(data, defer_topics=topics, lazy=True)
    sizes = {pos: fields[2] for pos, fields, _ in everything.chunks if pos in everything.deferred}
    assert set(honest_at) <= set(sizes) and None not in everything.deferred.values()
    # room for everything but the last two and a half honest chunks: the first honest one fits, the others not
    monkeypatch.setattr(chunks_module, "MAX_STREAMED_INFLATED", sum(sizes.values()) - 5 * size // 2)
    lazy = Prefetch(data, defer_topics=topics, lazy=True)
    refused = {pos for pos, entries in lazy.deferred.items() if entries is None}
    assert refused == set(honest_at[1:])
    log = read_log(_crafted(tmp_path, data))
    damage = [d for d in log.scan().lost if "past what this log's chunks may inflate to in all" in d.reason]
    assert sum(d.chunks for d in damage) == len(refused)
    assert sum(d.lost.get(TOPIC_CAN, 0) for d in damage) >= 2 * n   # their index still counts what was lost


def test_a_metadata_read_keeps_no_messages(run_log):
    """The records database read a whole log (states, events) to catalogue it, after the solve had read it:
    a hostile 1 GB log then peaked at 1.75 GB in `bench solve`. `messages=False` keeps the records only."""
    full, full_peak = _peak_while(lambda: read_log(run_log))
    meta, meta_peak = _peak_while(lambda: read_log(run_log, messages=False))
    assert meta.metadata == full.metadata and meta.attachments.keys() == full.attachments.keys()
    assert meta.message_counts == full.message_counts          # still counted
    assert not meta.events and len(meta.read_table_states()) == 0 and full.events and len(full.read_table_states())
    assert meta_peak < full_peak


def _mapped_kib(path: Path) -> int:
    """KiB of `path`'s memory mapping resident in this process (Linux: /proc/self/smaps)."""
    lines = Path("/proc/self/smaps").read_text().splitlines()
    for k, line in enumerate(lines):
        if line.endswith(str(path)):
            return next(int(x.split()[1]) for x in lines[k + 1:] if x.startswith("Rss:"))
    raise AssertionError(f"{path} is not mapped")


@pytest.mark.skipif(not Path("/proc/self/smaps").exists(), reason="needs Linux /proc/self/smaps")
def test_the_chunk_scan_lets_the_pages_it_passed_go(run_log, monkeypatch):
    """A 1 GB log of 15 kB chunks: the scan for chunks touched every page (each chunk's header and message
    indexes), so `bench solve` counted the whole file as its memory (1.3 GB to read its metadata alone)."""
    import mmap

    monkeypatch.setattr(chunks_module, "SCAN_DROP_BYTES", 8192)
    with open(run_log, "rb") as f:
        buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    try:
        buf.madvise(mmap.MADV_WILLNEED)
        touched = sum(buf[k] for k in range(0, len(buf), mmap.PAGESIZE))   # every page resident: the worst case
        assert touched >= 0 and _mapped_kib(run_log) > len(buf) // 2048
        prefetch = chunks_module.Prefetch(buf, defer_topics=frozenset({TOPIC_CAN}), lazy=True)
        prefetch.close()
        assert len(prefetch.chunks) > 10
        assert _mapped_kib(run_log) <= 64, "the scanned pages are still mapped"
    finally:
        buf.close()
