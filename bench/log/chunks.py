"""MCAP record framing and chunk decoding for the damage-tolerant walk (`bench.log.walk`).

Constants of the MCAP record layout, chunk decompression with CRC checks, the
plausibility checks used to resynchronise after damage, the vectorised framing of a
chunk by its message index, and `Prefetch`, which decompresses and frames chunks on
worker threads ahead of the walk (zstd, zlib and numpy release the GIL). Everything
here is pure: the walk decides what to do with what it returns.
"""

from __future__ import annotations

import os
import struct
import zlib
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from io import BytesIO
from types import ModuleType

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.records import Channel

from bench.errors import BenchError

zstandard: ModuleType | None   # None when it is not installed
try:
    import zstandard
except ImportError:    # pragma: no cover - mcap depends on it
    zstandard = None
try:
    # lz4 ships no type information (no stubs, no py.typed), and pyproject's list of such packages lacks it
    import lz4.frame as lz4_frame  # type: ignore[import-untyped]
except ImportError:    # pragma: no cover - mcap depends on it
    lz4_frame = None

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX = 1, 2, 3, 4, 5, 6, 7
OP_CHUNK_INDEX, OP_ATTACHMENT, OP_ATTACHMENT_INDEX, OP_STATISTICS, OP_METADATA = 8, 9, 10, 11, 12
OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = 13, 14, 15
OP_NAMES = {1: "header", 2: "footer", 3: "schema", 4: "channel", 5: "message", 6: "chunk", 7: "message index",
            8: "chunk index", 9: "attachment", 10: "attachment index", 11: "statistics", 12: "metadata",
            13: "metadata index", 14: "summary offset", 15: "data end"}

RECORD_HEAD = struct.Struct("<BQ")
MESSAGE_HEAD = struct.Struct("<BQHIQ")     # opcode, length, channel id, sequence, log time
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length
_U64 = struct.Struct("<Q")
MESSAGE_DATA_OFFSET = 9 + 22                   # record header + message header

#: (start, end, uncompressed size, crc, compression, data start, data length) of a chunk record
ChunkFields = tuple[int, int, int, int, str, int, int]


class WalkError(BenchError):
    """The file cannot be read as MCAP at all (the caller turns this into its own error)."""


def body_stream(buf, start: int, end: int) -> ReadDataStream:
    return ReadDataStream(BytesIO(bytes(buf[start:end])))


def _decompress(compression: str, payload, size: int) -> bytes:
    if compression == "":
        return bytes(payload)
    if compression == "zstd":
        if zstandard is None:
            raise WalkError("zstd chunks need the zstandard package")
        return zstandard.ZstdDecompressor().decompress(payload, max_output_size=size)
    if compression == "lz4":
        if lz4_frame is None:
            raise WalkError("lz4 chunks need the lz4 package")
        return lz4_frame.decompress(payload)
    raise ValueError(f"unknown compression {compression!r}")


def inflate_chunk(compression: str, payload, size: int, crc: int):
    """Decompress one chunk and compute its CRC (when it has one and the size is right), in a worker
    thread: (data, computed crc or None, exception or None)."""
    try:
        data = _decompress(compression, payload, size)
    except Exception as exc:
        return None, None, exc
    return data, (zlib.crc32(data) if crc != 0 and len(data) == size else None), None


def _inflate_and_frame(compression: str, payload, size: int, crc: int, buf, index: list[tuple[int, int]]):
    """`inflate_chunk`, then `index_chunk` on a good chunk with the message index records that follow it."""
    data, computed, exc = inflate_chunk(compression, payload, size, crc)
    framed = None
    if exc is None and len(data) == size and (crc == 0 or computed == crc):
        framed = index_chunk(buf, data, index)
    return data, computed, exc, framed


@dataclass
class DeferredChunk:
    """A chunk holding messages of one deferred channel only, kept compressed until they are asked
    for (`inflate`). Its message index gave the offsets and log times; nothing is checked yet."""

    offset: int                 # byte offset of the chunk record in the file
    start_ns: int
    end_ns: int
    compression: str
    payload: bytes              # the compressed data (a copy: the file's mapping is closed after the walk)
    size: int                   # uncompressed size
    crc: int
    channel: int
    log_times: np.ndarray       # uint64, per message, file order
    offsets: np.ndarray         # uint64, record offsets in the uncompressed data, increasing

    @property
    def lengths(self) -> np.ndarray:
        """Payload lengths implied by the offsets (the records tile the chunk; checked by `inflate`)."""
        ends = np.append(self.offsets[1:], self.size).astype(np.int64)
        return ends - self.offsets.astype(np.int64) - MESSAGE_DATA_OFFSET

    def inflate(self):
        """(chunk data, payload starts) when the chunk decompresses, passes its CRC and is framed
        exactly by its index; else a reason string."""
        data, computed, exc = inflate_chunk(self.compression, self.payload, self.size, self.crc)
        if exc is not None:
            return f"{self.compression} data cannot be decompressed ({exc})"
        if len(data) != self.size:
            return f"decompressed to {len(data)} bytes, header says {self.size}"
        if self.crc != 0 and computed != self.crc:
            return "CRC mismatch"
        framed = _frame_by_entries(data, [(self.channel, self.log_times, self.offsets)])
        if framed is False or framed[0] != 0:
            return "malformed chunk content (its message index does not frame it)"
        return data, framed[1][0][1]


def _deferrable(buf, fields: tuple, index: list[tuple[int, int]], deferred_channels: set[int]):
    """(channel, log times, offsets) when the chunk holds messages of one deferred channel and
    nothing else, as far as its message index says; else None."""
    if not index or not deferred_channels:
        return None
    entries = _index_entries(buf, index)
    if entries is False or len(entries) != 1 or entries[0][0] not in deferred_channels:
        return None
    ch, t, o = entries[0]
    usize = fields[2]
    if not len(o) or int(o[0]) != 0 or int(o[-1]) > usize - MESSAGE_DATA_OFFSET:
        return None
    if len(o) > 1 and not (np.diff(o.astype(np.int64)) >= MESSAGE_DATA_OFFSET).all():
        return None
    return ch, t, o


class Prefetch:
    """Decompresses and CRC-checks the chunks ahead of the walk on worker threads (zstd and zlib
    release the GIL, so this uses every core). Chunks are found by following the record framing
    from the start; where that framing breaks the walk resyncs on its own and decompresses inline.

    Chunks that hold only messages of a channel whose topic is in `defer_topics` (by their message
    index) are not decompressed at all: `deferred[offset]` says what they hold."""

    AHEAD_PER_WORKER = 3
    MIN_CHUNKS = 3   # fewer: not worth the threads

    def __init__(self, buf, workers: int | None = None, defer_topics: frozenset[str] = frozenset()):
        self.buf = buf
        self.topics: dict[int, str] = {}
        self.chunks = self._scan(buf)
        self.index = {c[0]: k for k, c in enumerate(self.chunks)}
        deferred_channels = {ch for ch, topic in self.topics.items() if topic in defer_topics}
        self.deferred: dict[int, tuple] = {}
        for pos, fields, index in self.chunks if deferred_channels else ():
            found = _deferrable(buf, fields, index, deferred_channels)
            if found is not None:
                self.deferred[pos] = found
        self.futures: dict[int, Future] = {}
        self.submitted = 0
        workers = workers or min(4, os.cpu_count() or 1)
        self.pool = (ThreadPoolExecutor(workers, thread_name_prefix="mcap-inflate")
                     if len(self.chunks) >= self.MIN_CHUNKS and workers > 1 else None)
        self.ahead = workers * self.AHEAD_PER_WORKER

    def _scan(self, buf) -> list[tuple[int, ChunkFields, list[tuple[int, int]]]]:
        """(offset, `chunk_fields`, the message index records right after it) of every chunk; the
        channel topics of the channel records outside chunks into `self.topics`."""
        size, pos = len(buf), 8
        found: list[tuple[int, ChunkFields, list[tuple[int, int]]]] = []
        # the index records of the last chunk, while only such records follow it
        current: list[tuple[int, int]] | None = None
        while pos + 9 <= size:
            op, length = RECORD_HEAD.unpack_from(buf, pos)
            end = pos + 9 + length
            if op not in OP_NAMES or end > size or op == OP_FOOTER:
                break
            if op == OP_CHUNK:
                f = chunk_fields(buf, pos + 9, length)
                if f is None:
                    break
                current = []
                found.append((pos, f, current))
            elif op == OP_MESSAGE_INDEX:
                if current is not None:
                    current.append((pos + 9, end))
            else:
                current = None
                if op == OP_CHANNEL:
                    try:
                        c = Channel.read(body_stream(buf, pos + 9, end))
                        self.topics.setdefault(c.id, c.topic)
                    except Exception:   # the walk reports a damaged record; here it only defers nothing
                        pass
            pos = end
        return found

    def take(self, pos: int, fields: tuple):
        """(data, computed crc, exception, (message index records, their framing)) of the chunk at `pos`,
        None if it was not prefetched."""
        k = self.index.get(pos)
        if self.pool is None or k is None or self.chunks[k][1] != fields:
            return None
        while self.submitted < min(len(self.chunks), k + 1 + self.ahead):
            cpos, (_, _, usize, crc, compression, dstart, dlen), index = self.chunks[self.submitted][:3]
            if cpos in self.deferred:
                self.submitted += 1
                continue
            self.futures[cpos] = self.pool.submit(_inflate_and_frame, compression,
                                                  memoryview(self.buf)[dstart:dstart + dlen], usize, crc, self.buf,
                                                  index)
            self.submitted += 1
        future = self.futures.pop(pos, None)
        if future is None:
            return None
        data, computed, exc, framed = future.result()
        return data, computed, exc, (self.chunks[k][2], framed)

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.futures.clear()


def chunk_fields(buf, body: int, length: int) -> ChunkFields | None:
    """(start, end, usize, crc, compression, data_start, data_len) of a chunk body, or None if inconsistent."""
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
    return start, end, usize, crc, compression, body + 40 + clen, dlen


def _plausible_chunk_at(buf, pos: int, size: int) -> bool:
    if pos + 9 > size or buf[pos] != OP_CHUNK:
        return False
    (length,) = _U64.unpack_from(buf, pos + 1)
    if pos + 9 + length > size:
        return False
    f = chunk_fields(buf, pos + 9, length)
    return f is not None and f[4] in ("", "zstd", "lz4")


def plausible_record_at(buf, pos: int, size: int) -> bool:
    if pos == size:
        return True
    if pos + 9 > size:
        return False
    return buf[pos] in OP_NAMES   # a length past the end is a truncation, told apart by the main loop


def resync(buf, pos: int, size: int) -> int:
    """The offset of the next plausible chunk record after `pos`, or `size`."""
    p = pos + 1
    while True:
        p = buf.find(b"\x06", p)
        if p < 0:
            return size
        if _plausible_chunk_at(buf, p, size):
            return p
        p += 1


def index_chunk(buf, data: bytes, index: list[tuple[int, int]]):
    """Vectorised framing of a chunk by its message index records (`(body, end)` offsets in `buf`):
    (offset of the first message, [(channel, payload starts, lengths, log times)] by channel id), or
    False unless the index provably frames every message of the chunk: its records tile the chunk from
    the first message to the end. Pure (worker threads run it)."""
    entries = _index_entries(buf, index)
    return False if entries is False else _frame_by_entries(data, entries)


def _index_entries(buf, index: list[tuple[int, int]]):
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


def _frame_by_entries(data: bytes, per_channel: list):
    """`index_chunk` for index entries already read (`_index_entries`)."""
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
