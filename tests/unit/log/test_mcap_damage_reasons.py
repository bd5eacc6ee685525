"""The damage lines a reader of a run log sees name the reason a chunk was refused, word for word (issue 28,
item 5: the MCAP reader was restructured with its lines unchanged; tests/fuzz/reader_fingerprints.py compares
two code trees over hundreds of damaged logs, this pins the reasons of the refusals one by one).

Each case spoils chunks of the small log of tests/test_log_fuzz.py (zstd, lz4, uncompressed): chunks declaring
more than a chunk may hold (refused in a row: told as one line), a size their data does not inflate to, a
decompression bomb declaring 4 KiB, a CRC that does not match (a deferred `/imu/samples` chunk: found when the
samples are read, or at once with `defer_samples=False`)."""

from __future__ import annotations

import re

import pytest

from bench.log.reader import read_log
from tests.helpers import mcap_surgery as ms
from tests.unit.log.test_log_fuzz import base_log

COMPRESSIONS = ("zstd", "lz4", "none")
MSG = ms.message_record(1, ms.can_frames(40))


def _spoiled(tmp_path, compression: str, chunk: bytes) -> tuple[str, list[int]]:
    """The log with its chunks 1 to 3 replaced by `chunk`: (path, their offsets)."""
    data = base_log(compression)
    for pos in reversed(ms.chunks(data)[1:4]):
        data = ms.replace_chunk(data, pos, chunk)
    path = tmp_path / f"{compression}.mcap"
    path.write_bytes(data)
    return str(path), ms.chunks(data)[1:4]


@pytest.mark.parametrize("compression", COMPRESSIONS)
def test_chunks_over_the_cap_in_a_row_are_one_line(tmp_path, compression):
    path, (first, _, last) = _spoiled(tmp_path, compression, ms.chunk_record(MSG * 10, "", 1 << 40))
    damage = read_log(path).scan().damage
    assert damage[0] == (f"3 chunks at bytes {first}..{last} (log time 0.000..0.000 s), each: declares {1 << 40} "
                         "bytes uncompressed, more than a chunk may hold (268435456 bytes); not decompressed; their "
                         "messages lost (count unknown)")


@pytest.mark.parametrize("compression", COMPRESSIONS)
def test_a_chunk_that_inflates_to_another_size_says_both(tmp_path, compression):
    path, offsets = _spoiled(tmp_path, compression, ms.chunk_record(MSG * 10, "", 100))
    damage = read_log(path).scan().damage
    assert damage[:3] == [f"chunk at byte {pos} (log time 0.000..0.000 s): decompressed to {len(MSG) * 10} bytes, "
                          "header says 100; its messages lost (count unknown)" for pos in offsets]


@pytest.mark.parametrize("compression", COMPRESSIONS)
def test_a_bomb_is_not_inflated_past_what_it_declares(tmp_path, compression):
    bomb = ms.chunk_record(ms.zstd_bomb(MSG, 64 << 20, content_size=False), "zstd", 4096)
    path, offsets = _spoiled(tmp_path, compression, bomb)
    damage = read_log(path).scan().damage
    assert damage[:3] == [f"chunk at byte {pos} (log time 0.000..0.000 s): inflates to more than the 4096 bytes its "
                          "header says; not decompressed further; its messages lost (count unknown)"
                          for pos in offsets]


@pytest.mark.parametrize("compression", ("zstd", "lz4"))
def test_a_deferred_chunk_failing_its_crc_is_named_when_read_and_at_once(tmp_path, compression):
    data = base_log(compression)
    log_path = tmp_path / "crc.mcap"
    for pos in ms.chunks(data):
        fields = ms.chunk_fields(data, pos)
        spoiled = bytearray(data)
        spoiled[fields["usize_at"] + 8] ^= 0xFF   # the CRC's first byte
        log_path.write_bytes(bytes(spoiled))
        deferred = read_log(log_path)
        if deferred.damage_found:   # a chunk the walk decompressed: found at once
            continue
        records = deferred.read_imu_records()   # the deferred /imu/samples chunks are read now
        damage = deferred.scan().damage   # and the /can/raw ones
        if "/imu/samples" not in damage[0]:
            continue
        assert len(damage) == 1 and re.fullmatch(
            rf"chunk at byte {pos} \(log time \d+\.\d{{3}}\.\.\d+\.\d{{3}} s\): CRC mismatch; its messages lost "
            r"\(10 on /imu/samples\)", damage[0]), damage
        assert len(records) == 50
        assert read_log(log_path, defer_samples=False).damage_found == damage
        return
    raise AssertionError("no deferred /imu/samples chunk in the log")
