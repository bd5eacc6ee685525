"""A log from outside is hostile (issue 13, item 6): bounded memory, bounded time.

Decompression bombs are refused as damage of their chunk, quickly and without allocating
what they declare: a chunk must inflate to exactly its declared uncompressed size
(zstd, lz4 or none), declare at most `MAX_CHUNK_BYTES`, and all chunks together at most
the log's inflate budget. The crafted files are a real log with one chunk replaced
(`tests/helpers/mcap_surgery.py`).
"""

from __future__ import annotations

import tracemalloc
import zlib
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

import bench.log.chunks as chunks_module
from bench.log.chunks import MAX_CHUNK_BYTES, MAX_RECORDS
from bench.log.format import TOPIC_CAN
from bench.log.reader import read_log
from bench.log.walk import walk
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
    top_records,
    zstd_bomb,
)
from tests.helpers.run import cli, config_text

GiB = 1 << 30


@pytest.fixture(scope="module")
def run_log(tmp_path_factory) -> Path:
    """A real simulated run's log (the short test plan with 1 s dwells)."""
    folder = tmp_path_factory.mktemp("limits")
    config = folder / "bench.toml"
    config.write_text(config_text(dwell_s=1.0), encoding="utf-8")
    rc, _, stderr = cli(["run", "--config", str(config), "--out", str(folder / "run"), "--quiet"])
    assert rc == 0, stderr
    return next((folder / "run").glob("*.mcap"))


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
    found = [d for d in log.damage if d.startswith(f"chunk at byte {pos}")]
    assert len(found) == 1, log.damage
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
        assert 0 < len(good.can_ids) - len(log.can_ids) < len(good.can_ids) // 4, name


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


def test_the_chunks_of_one_log_inflate_to_a_bounded_total(can_chunk, monkeypatch):
    # Four chunks of 1 MiB each, declared honestly and framed by their index, in a log whose budget
    # (made small here, so the test stays small) leaves room for two of them: the others are refused.
    buf, _, can = can_chunk
    msg = message_record(can, can_frames(40))
    n = (1 << 20) // len(msg)
    honest = chunk_record(zstd_bomb(msg, n * len(msg)), "zstd", n * len(msg))
    index = message_index(can, [(1_000_000_000, k * len(msg)) for k in range(n)])
    data = buf
    for p in reversed(chunks(buf)[-4:]):
        data = replace_chunk(data, p, honest + index)
    used = walk(data).budget.used
    monkeypatch.setattr(chunks_module, "MAX_LOG_INFLATED", used - 2 * n * len(msg) + n * len(msg) // 2)
    w = walk(data)
    refused = [d for d in w.damage if "past what this log's chunks may inflate to in all" in d.reason]
    assert len(refused) == 2 and all(f"({w.budget.total} bytes:" in d.reason for d in refused)
    assert w.budget.used <= w.budget.total < w.budget.used + n * len(msg)
    assert all(d.lost == {TOPIC_CAN: n} for d in refused)   # their index still counts what was lost


def test_deferred_sample_chunks_count_against_the_budget_kept_and_inflated(run_log, monkeypatch):
    # /imu/samples chunks are kept compressed (counted at that size) and inflated only when asked for
    # (counted then at their own): with no room left for that, they are refused when asked for.
    used = walk(run_log.read_bytes(), frozenset({"/imu/samples"})).budget.used
    monkeypatch.setattr(chunks_module, "MAX_LOG_INFLATED", used)
    log = read_log(run_log)
    assert log.complete and log.unchecked_chunks and len(log.can_ids)
    assert len(log.imu_records) == 0 and log.unchecked_chunks == 0
    refused = [d for d in log.damage if "past what this log's chunks may inflate to in all" in d]
    assert refused and all("on /imu/samples" in d for d in refused)
    monkeypatch.setattr(chunks_module, "MAX_LOG_INFLATED", used - 1)
    log = read_log(run_log)   # one byte less: a chunk is refused as the walk reaches it
    assert len(log.can_ids) and any("past what" in d for d in log.damage)


def test_a_chunk_walked_record_by_record_is_not_walked_in_python_per_message(can_chunk, tmp_path):
    # 4 MiB of one repeated message and no message index (the walk's fallback): gathered at one stride
    buf, pos, can = can_chunk
    msg = message_record(can, can_frames(1, t=12345.5))
    n = (4 << 20) // len(msg)
    content = msg * n
    path = _crafted(tmp_path, replace_chunk(buf, pos, chunk_record(zstd_bomb(msg, len(content)), "zstd",
                                                                   len(content), zlib.crc32(content))))
    log = read_log(path)
    assert not [d for d in log.damage if d.startswith(f"chunk at byte {pos}")], log.damage
    assert int(np.count_nonzero(log.can_timestamp_s == 12345.5)) == n


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
    assert any(d.startswith(f"byte {pos}: chunk record with an impossible length; bytes {pos}..") for d in log.damage)
    assert len(log.can_ids) > 0


def test_records_outside_chunks_are_counted_and_the_walk_stops_at_the_limit(can_chunk, tmp_path, monkeypatch):
    buf, _, _ = can_chunk
    import bench.log.walk as walk_module
    monkeypatch.setattr(walk_module, "MAX_RECORDS", 50)
    log = read_log(_crafted(tmp_path, buf))
    assert any("more than 50 records outside chunks" in d for d in log.damage), log.damage
    assert MAX_RECORDS >= 100 * len(top_records(buf))   # a recorded log is far from the real limit


def test_honest_chunks_still_read_exactly_as_before(can_chunk, tmp_path):
    # the same chunk rewritten honestly in each compression reads back frame for frame
    buf, pos, _ = can_chunk
    f = chunk_fields(buf, pos)
    content = inflate(f["compression"], f["data"])
    expected = read_log(_crafted(tmp_path, buf, "orig.mcap"))
    for compression, data in (("", content), ("zstd", zstd_bomb(content, len(content))),
                              ("lz4", lz4_bomb(content, len(content))),
                              ("zstd", zstd_bomb(content, len(content), content_size=False)),
                              ("lz4", lz4_bomb(content, len(content), content_size=False))):
        chunk = chunk_record(data, compression, len(content), zlib.crc32(content), f["start"], f["end"])
        log = read_log(_crafted(tmp_path, replace_chunk(buf, pos, chunk, drop_index=False)))
        assert not [d for d in log.damage if "chunk" in d], (compression, log.damage)
        np.testing.assert_array_equal(log.can_data, expected.can_data)
