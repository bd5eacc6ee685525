"""The MCAP record layout (MCAP spec: magic, then records `opcode u8 | length u64 | body`; a chunk body is
`start u64 | end u64 | uncompressed size u64 | uncompressed crc32 u32 | compression string | data length u64 |
data`, its data again records), and what reads it without trusting it: chunk headers, the plausibility checks
and the resync after damage, the vectorised framing of a chunk by its message index, and letting the pages of a
mapped file go once read. Pure: the walk (`bench.log.mcap.walk`) decides what to do with what it returns.
"""

from __future__ import annotations

import mmap
import struct
from array import array
from io import BytesIO
from typing import NamedTuple

import numpy as np
from mcap.data_stream import ReadDataStream

from bench.errors import BenchError

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX = 1, 2, 3, 4, 5, 6, 7
OP_CHUNK_INDEX, OP_ATTACHMENT, OP_ATTACHMENT_INDEX, OP_STATISTICS, OP_METADATA = 8, 9, 10, 11, 12
OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = 13, 14, 15
OP_NAMES = {1: "header", 2: "footer", 3: "schema", 4: "channel", 5: "message", 6: "chunk", 7: "message index",
            8: "chunk index", 9: "attachment", 10: "attachment index", 11: "statistics", 12: "metadata",
            13: "metadata index", 14: "summary offset", 15: "data end"}

#: Schema and channel records a chunk may hold (a recorded log has six channels).
MAX_DEFINITIONS = 4096
RECORD_HEAD = struct.Struct("<BQ")
MESSAGE_HEAD = struct.Struct("<BQHIQ")     # opcode, length, channel id, sequence, log time
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length
_U64 = struct.Struct("<Q")
MESSAGE_DATA_OFFSET = 9 + 22                   # record header + message header


class ChunkHeader(NamedTuple):
    """A chunk record's fields ahead of its data (MCAP spec), and where its data lies in the file."""

    start_ns: int       # log time of its first and last message
    end_ns: int
    size: int           # uncompressed, as declared
    crc: int            # of the uncompressed data; 0: none
    compression: str    # "", "zstd" or "lz4" (anything else is damage when decompressed)
    data_start: int     # byte offset of the compressed data in the file
    data_length: int

    @property
    def data_span(self) -> tuple[int, int]:
        """(file offset, length) of the compressed data."""
        return self.data_start, self.data_length


class ChunkRefused(Exception):
    """A chunk not decompressed, or not kept: its size, its data, its CRC or its framing; the message is the
    reason, as the damage line tells it."""


class WalkError(BenchError):
    """The file cannot be read as MCAP at all (the caller turns this into its own error)."""


def body_stream(buf, start: int, end: int) -> ReadDataStream:
    return ReadDataStream(BytesIO(bytes(buf[start:end])))


def drop_pages(buf, start: int, end: int) -> None:
    """Unmap the whole pages of a memory-mapped file between `start` and `end` (read again from the page cache
    if needed): what was read once does not count towards the process' memory."""
    if not isinstance(buf, mmap.mmap) or not hasattr(mmap, "MADV_DONTNEED"):
        return
    first = -(-start // mmap.PAGESIZE) * mmap.PAGESIZE
    last = end - end % mmap.PAGESIZE
    if last > first:
        buf.madvise(mmap.MADV_DONTNEED, first, last - first)


class PageDropper:
    """Lets the pages of a mapped file go as a pass over it moves on: every `every` bytes, up to `keep` bytes
    behind where the pass is (the walk may look back a little; the chunk scan does not)."""

    def __init__(self, buf, every: int, keep: int = 0):
        self.buf, self.every, self.keep = buf, every, keep
        self.dropped = 0   # the pages before this offset went

    def passed(self, pos: int, last: bool = False) -> None:
        """The pass has read up to `pos` (`last`: and is done: every page goes)."""
        if last or pos - self.dropped > self.every:
            stop = len(self.buf) if last else pos - self.keep
            drop_pages(self.buf, self.dropped, stop)
            stop = pos - self.keep   # the page `stop` is in goes next time
            self.dropped = max(self.dropped, stop - stop % mmap.PAGESIZE)


def read_chunk_header(buf, body: int, length: int) -> ChunkHeader | None:
    """The header of the chunk record whose body is at `body`, or None if it is inconsistent."""
    if length < 40:
        return None
    start, end, usize, crc, clen = _CHUNK_HEAD.unpack_from(buf, body)
    if clen > 16 or 40 + clen > length:
        return None
    try:
        compression = bytes(buf[body + 32:body + 32 + clen]).decode("ascii")
    except UnicodeDecodeError:
        return None
    (dlen,) = _U64.unpack_from(buf, body + 32 + clen)
    if 40 + clen + dlen != length or start > end:
        return None
    return ChunkHeader(start, end, usize, crc, compression, body + 40 + clen, dlen)


def _plausible_chunk_at(buf, pos: int, size: int) -> bool:
    if pos + 9 > size or buf[pos] != OP_CHUNK:
        return False
    (length,) = _U64.unpack_from(buf, pos + 1)
    if pos + 9 + length > size:
        return False
    header = read_chunk_header(buf, pos + 9, length)
    return header is not None and header.compression in ("", "zstd", "lz4")


def plausible_record_at(buf, pos: int, size: int) -> bool:
    if pos == size:
        return True
    if pos + 9 > size:
        return False
    return buf[pos] in OP_NAMES   # a length past the end is a truncation, told apart by the main loop


_RESYNC_TRIES, _RESYNC_WINDOW = 64, 1 << 22


def _chunk_candidates(buf, start: int, stop: int, size: int) -> np.ndarray:
    """Offsets in [start, stop) of a chunk opcode followed by a length that fits the file (vectorised)."""
    if size < 9 + 40:
        return np.zeros(0, np.int64)
    u8 = np.frombuffer(buf, np.uint8, count=stop - start, offset=start)
    cand = np.flatnonzero(u8 == OP_CHUNK).astype(np.int64) + start
    cand = cand[cand + 9 + 40 <= size]
    if not len(cand):
        return cand
    lengths = np.ndarray((size - 8,), "<u8", buf, 1, (1,))[cand]
    return cand[(lengths >= 40) & (lengths <= (size - 9 - cand).astype(np.uint64))]


def resync(buf, pos: int, size: int, passed=None) -> int:
    """The offset of the next plausible chunk record after `pos`, or `size`: the next few chunk opcodes
    one by one, then windows of the file screened at once (a file of chunk opcodes takes no longer);
    `passed(offset)` is told after each window (the walk unmaps what it has left behind)."""
    p = pos + 1
    for _ in range(_RESYNC_TRIES):
        p = buf.find(b"\x06", p)
        if p < 0:
            return size
        if _plausible_chunk_at(buf, p, size):
            return p
        p += 1
    while p < size:
        stop = min(size, p + _RESYNC_WINDOW)
        for c in _chunk_candidates(buf, p, stop, size).tolist():
            if _plausible_chunk_at(buf, c, size):
                return c
        p = stop
        if passed is not None:
            passed(p)
    return size


def index_chunk(buf, data: bytes, index: list[tuple[int, int]]):
    """Vectorised framing of a chunk by its message index records (`(body, end)` offsets in `buf`):
    (offset of the first message, [(channel, payload starts, lengths, log times)] by channel id), or
    False unless the index provably frames every message of the chunk: its records tile the chunk from
    the first message to the end. Pure (worker threads run it)."""
    entries = index_entries(buf, index)
    return False if entries is False else frame_by_entries(data, entries)


def index_entries(buf, index: list[tuple[int, int]]):
    """[(channel, log times, offsets)] by channel id from a chunk's message index records (copies,
    in file order), or False if they are malformed."""
    if not index:
        return False
    by_channel: dict[int, list] = {}
    for body, end in index:
        ch, n = struct.unpack_from("<HI", buf, body)
        if n % 16 or body + 6 + n > end:
            return False
        entries = np.frombuffer(buf, "<u8", count=n // 8, offset=body + 6).reshape(-1, 2)
        by_channel.setdefault(ch, []).append(entries)
    per_channel = []
    for ch in sorted(by_channel):
        parts = by_channel[ch]
        entries = parts[0] if len(parts) == 1 else np.concatenate(parts)
        t, o = entries[:, 0], entries[:, 1]
        if len(o) > 1 and not (o[1:] > o[:-1]).all():   # kept in file order, as the tiling check sorts
            order = np.argsort(o, kind="stable")
            t, o = t[order], o[order]
        per_channel.append((ch, t.copy(), o.copy()))   # copies: nothing may keep the file's buffer alive
    return per_channel


def frame_by_entries(data: bytes, per_channel: list):
    """`index_chunk` for index entries already read (`index_entries`)."""
    size = len(data)
    if size < 31:
        return False
    o_all = np.concatenate([o for _, _, o in per_channel])
    if not len(o_all) or int(o_all.max()) > size - 31:
        return False
    o_all = o_all.astype(np.int64)
    # Every record's header fields, read in place: views of the chunk at every byte offset.
    u8 = np.frombuffer(data, np.uint8)
    length = np.ndarray((size - 8,), "<u8", data, 1, (1,))[o_all].astype(np.int64)
    rec_ch = np.ndarray((size - 10,), "<u2", data, 9, (1,))[o_all]
    rec_t = np.ndarray((size - 22,), "<u8", data, 15, (1,))[o_all]
    chans = np.concatenate([np.full(len(o), ch, np.uint16) for ch, _, o in per_channel])
    times = np.concatenate([t for _, t, _ in per_channel])
    if not ((u8[o_all] == OP_MESSAGE).all() and (length >= 22).all() and (rec_ch == chans).all()
            and (rec_t == times).all()):
        return False
    order = np.argsort(o_all, kind="stable")
    o, ends = o_all[order], (o_all + 9 + length)[order]
    if not ((o[1:] == ends[:-1]).all() and ends[-1] == size):
        return False
    out, k = [], 0
    for ch, t, offsets in per_channel:
        m = len(offsets)
        out.append((ch, o_all[k:k + m] + MESSAGE_DATA_OFFSET, length[k:k + m] - 22, t))
        k += m
    return int(o[0]), out


def attachment_head(buf, body: int, end: int) -> tuple[str, int] | None:
    """(name, data length) of an attachment record, read without its data; None if malformed."""
    q = body + 16                                    # log time, create time
    if q + 4 > end:
        return None
    (n,) = struct.unpack_from("<I", buf, q)
    if q + 4 + n + 4 > end:
        return None
    name = bytes(buf[q + 4:q + 4 + n]).decode("utf-8", "replace")
    q += 4 + n
    (m,) = struct.unpack_from("<I", buf, q)
    q += 4 + m
    if q + 8 > end:
        return None
    return name, struct.unpack_from("<Q", buf, q)[0]


def chunk_content(data: bytes, messages: bool = True) -> tuple[np.ndarray, list[tuple[int, int, int]]]:
    """(offsets of the message records, (opcode, offset, end) of the schema and channel records) of a chunk's
    data; `ChunkRefused` with the reason if its content is malformed, or (with `messages` False) if it holds a
    message. A chunk holds schema, channel and message records only (MCAP spec). The framing is followed
    record by record, except where the messages provably follow at one stride (checked at once)."""
    unpack_rec = RECORD_HEAD.unpack_from
    size = len(data)
    starts = array("q")
    strided = np.zeros(0, np.int64)   # the messages found at one stride, to the end of the chunk
    others: list[tuple[int, int, int]] = []
    q = 0
    while q < size:
        if q + 9 > size:
            raise ChunkRefused(f"malformed chunk content at offset {q}")
        op, ln = unpack_rec(data, q)
        end = q + 9 + ln
        if end > size:
            raise ChunkRefused(f"malformed chunk content: record at offset {q} overruns the chunk")
        if op == OP_MESSAGE:
            if ln < 22 or not messages:
                raise ChunkRefused(f"malformed message at chunk offset {q}")
            if not starts and (size - q) % (9 + ln) == 0 and _one_stride(data, q, 9 + ln):
                strided = np.arange(q, size, 9 + ln, dtype=np.int64)
                break
            starts.append(q)
        elif op in (OP_SCHEMA, OP_CHANNEL):
            if len(others) >= MAX_DEFINITIONS:
                raise ChunkRefused(f"malformed chunk content: more than {MAX_DEFINITIONS} schema and channel "
                                   "records")
            others.append((op, q, end))
        else:
            what = OP_NAMES.get(op, f"opcode {op:#x}")
            raise ChunkRefused(f"malformed chunk content: {what} record at offset {q}")
        q = end
    return (np.frombuffer(starts, np.int64) if starts else strided), others


def _one_stride(data: bytes, q: int, stride: int) -> bool:
    """Whether every record from `q` to the end of `data` is a message of length `stride` (vectorised)."""
    n = (len(data) - q) // stride
    ops = np.ndarray((n,), np.uint8, data, q, (stride,))
    lengths = np.ndarray((n,), "<u8", data, q + 1, (stride,))
    return bool((ops == OP_MESSAGE).all() and (lengths == stride - 9).all())
