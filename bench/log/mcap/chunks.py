"""Chunk decoding within limits, for the damage-tolerant walk (`bench.log.mcap.walk`).

Chunk decompression with CRC checks (`inflate_checked`; a chunk that fails raises `ChunkRefused`, its
message the damage reason), the budgets of what a log's chunks may inflate to, the chunks kept
compressed until asked for (`DeferredChunk`, `ChunkSlice`), and `Prefetch`, which decompresses and
frames chunks on worker threads ahead of the walk (zstd, zlib and numpy release the GIL). The record
layout is `bench.log.mcap.records`. Everything here is pure: the walk decides what to do with what
it returns.

Limits (a log from outside is hostile): a chunk may declare at most `MAX_CHUNK_BYTES`
uncompressed, and it must inflate to exactly what it declares, whatever its compression
(zstd, lz4 or none): at most that many bytes are ever produced, a size that does not
match is damage of that chunk (`ChunkRefused`), and a chunk declaring more than the limit
is not decompressed at all. A zstd or lz4 frame that states its own content size is
checked against the chunk header before anything is allocated; one that does not is
decompressed in steps, never past the declared size. All the chunks of one log together
inflate to at most `inflate_budget(file size)` (`MAX_INFLATE_RATIO` times the file plus
`INFLATE_ALLOWANCE`, at most `MAX_LOG_INFLATED`): recorded logs inflate 3 to 7 times, a
decompression bomb thousands of times.
"""

from __future__ import annotations

import zlib
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from types import ModuleType
from typing import Callable, NamedTuple

import numpy as np
from mcap.records import Channel

from bench.log.mcap.parts import NOT_INFLATED, InChunk, Part
from bench.log.mcap.records import (
    MESSAGE_DATA_OFFSET,
    OP_CHANNEL,
    OP_CHUNK,
    OP_FOOTER,
    OP_MESSAGE_INDEX,
    OP_NAMES,
    RECORD_HEAD,
    ChunkHeader,
    ChunkRefused,
    PageDropper,
    WalkError,
    body_stream,
    drop_pages,
    frame_by_entries,
    index_chunk,
    index_entries,
    read_chunk_header,
)
from bench.log.threads import reader_threads

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

class ScannedChunk(NamedTuple):
    """A chunk found by the scan ahead of the walk, with the message index records right after it."""

    offset: int                      # of the chunk record
    header: ChunkHeader
    index_records: list[tuple[int, int]]   # (body, end) offsets of its message index records

#: The most a chunk may declare (and inflate to) uncompressed. The recorder closes its chunks at
#: 4 MiB (`McapRecorder(chunk_size=...)`); a chunk declaring more is damage, never decompressed.
MAX_CHUNK_BYTES = 256 << 20
#: What the chunks of one log may inflate to in all: `MAX_INFLATE_RATIO` times the file's size plus
#: `INFLATE_ALLOWANCE`, and never more than `MAX_LOG_INFLATED` (see `inflate_budget`). Chunks past
#: the budget (in file order, each counted at its declared size) are damage, never decompressed.
MAX_INFLATE_RATIO = 16
INFLATE_ALLOWANCE = 256 << 20
MAX_LOG_INFLATED = 1 << 30
#: What a log's streamed chunks (the raw CAN frames, read one chunk at a time and let go: memory does not
#: grow with them) may inflate to in all, on top: `INFLATE_ALLOWANCE` plus `STREAMED_INFLATE_RATIO` times
#: the file's size, at most `MAX_STREAMED_INFLATED`. It bounds time, not memory: a recorded log's frames
#: inflate about 4 times (a 1 h, 1 kHz static log: 555 MB of frames in a 142 MB file), a bomb thousands.
STREAMED_INFLATE_RATIO = 6
MAX_STREAMED_INFLATED = 64 << 30
#: Records a log may hold outside chunks (a recorded log holds a few per chunk); the walk reads no further.
MAX_RECORDS = 1_000_000
#: Decompressed chunks the prefetch may hold ahead of the walk, in bytes (at least one chunk).
PREFETCH_BYTES = 64 << 20
_FIRST_STEP, _MAX_STEP = 1 << 20, 64 << 20   # output steps of a frame that does not state its size


def inflate_budget(file_size: int) -> int:
    """The total uncompressed size the chunks of a log of `file_size` bytes may declare (see above)."""
    return min(MAX_LOG_INFLATED, INFLATE_ALLOWANCE + MAX_INFLATE_RATIO * file_size)


def streamed_budget(file_size: int) -> "InflateBudget":
    """What the streamed chunks of a log of `file_size` bytes may declare in all (see above)."""
    return InflateBudget(min(MAX_STREAMED_INFLATED, INFLATE_ALLOWANCE + STREAMED_INFLATE_RATIO * file_size),
                         cap=MAX_STREAMED_INFLATED, ratio=STREAMED_INFLATE_RATIO)


@dataclass
class InflateBudget:
    """What the chunks of one log may still inflate to: each chunk is counted at its declared size when
    it is decompressed (a deferred chunk when it is first needed), in that order."""

    total: int
    used: int = 0
    cap: int = MAX_LOG_INFLATED   # what `total` is capped at, and the ratio to the file size (said in the refusal)
    ratio: int = MAX_INFLATE_RATIO

    def take(self, size: int) -> None:
        """Count a chunk of `size` bytes; `ChunkRefused` (the reason: `over_limits`) if it may not be decompressed."""
        reason = over_limits(size, self.used, self.total, self.cap, self.ratio)
        if reason is not None:
            raise ChunkRefused(reason)
        self.used += size

    def fits(self, size: int) -> bool:
        """`take`, saying whether the chunk fits instead of why not."""
        try:
            self.take(size)
        except ChunkRefused:
            return False
        return True


def _bounded(read, size: int, stated: bool) -> bytes:
    """What `read(n)` gives until it gives nothing, at most `size + 1` bytes: in one step when the frame
    `stated` its size (already checked equal to `size`), else in growing steps (nothing is allocated
    for output that does not come)."""
    parts, total = [], 0
    step = size + 1 if stated else min(size + 1, _FIRST_STEP)
    while total <= size:
        piece = read(min(step, size + 1 - total))
        if not piece:
            break
        parts.append(piece)
        total += len(piece)
        step = min(2 * step, _MAX_STEP)
    if total > size:
        raise ChunkRefused(f"inflates to more than the {size} bytes its header says; not decompressed further")
    return parts[0] if len(parts) == 1 else b"".join(parts)


def _zstd(payload, size: int) -> bytes:
    if zstandard is None:
        raise WalkError("zstd chunks need the zstandard package")
    stated = zstandard.frame_content_size(payload)   # -1: not stated; ZstdError: not a zstd frame
    if stated >= 0 and stated != size:
        raise ChunkRefused(f"its zstd frame says {stated} bytes, its header {size}; not decompressed")
    if stated >= 0:   # zstd itself checks the output against the stated size
        return zstandard.ZstdDecompressor().decompress(payload)
    return _bounded(zstandard.ZstdDecompressor().stream_reader(payload).read, size, False)


def _lz4(payload, size: int) -> bytes:
    if lz4_frame is None:
        raise WalkError("lz4 chunks need the lz4 package")
    stated = lz4_frame.get_frame_info(payload)["content_size"]   # 0: not stated; RuntimeError: not lz4
    if stated and stated != size:
        raise ChunkRefused(f"its lz4 frame says {stated} bytes, its header {size}; not decompressed")
    d = lz4_frame.LZ4FrameDecompressor()
    pending = [payload]

    def read(n: int) -> bytes:
        return b"" if d.eof else d.decompress(pending.pop() if pending else b"", max_length=n)

    data = _bounded(read, size, bool(stated))
    if not d.eof:
        raise ValueError("the lz4 frame is cut short")
    return data


def _decompress(compression: str, payload, size: int) -> bytes:
    """The chunk's data, exactly `size` bytes (ChunkRefused, or the library's error, otherwise)."""
    if size > MAX_CHUNK_BYTES:
        raise ChunkRefused(f"declares {size} bytes uncompressed, more than a chunk may hold "
                           f"({MAX_CHUNK_BYTES} bytes); not decompressed")
    if compression == "":
        data = payload
    elif compression == "zstd":
        data = _zstd(payload, size)
    elif compression == "lz4":
        data = _lz4(payload, size)
    else:
        raise ValueError(f"unknown compression {compression!r}")
    if len(data) != size:
        raise ChunkRefused(f"decompressed to {len(data)} bytes, header says {size}")
    return bytes(data) if compression == "" else data


def over_limits(size: int, used: int, budget: int, cap: int = MAX_LOG_INFLATED,
                ratio: int = MAX_INFLATE_RATIO) -> str | None:
    """Why a chunk declaring `size` bytes is not decompressed when the chunks before it declared `used`
    of the log's `budget` (`inflate_budget`); None if it may be."""
    if size > MAX_CHUNK_BYTES:
        return (f"declares {size} bytes uncompressed, more than a chunk may hold ({MAX_CHUNK_BYTES} bytes); "
                "not decompressed")
    if used + size > budget:
        return (f"declares {size} bytes uncompressed, past what this log's chunks may inflate to in all "
                f"({budget} bytes: {ratio} times the file's size plus {INFLATE_ALLOWANCE} bytes, "
                f"at most {cap}); not decompressed")
    return None


def inflate_checked(compression: str, payload, size: int, crc: int) -> bytes:
    """One chunk's data, exactly `size` bytes, when it decompresses and passes its CRC (when it has one);
    `ChunkRefused` with the damage reason otherwise (`WalkError` when a compression library is missing).
    Pure: worker threads run it."""
    try:
        data = _decompress(compression, payload, size)
    except (ChunkRefused, WalkError):
        raise
    except Exception as exc:
        raise ChunkRefused(f"{compression or 'uncompressed'} data cannot be decompressed ({exc})") from exc
    if crc != 0 and zlib.crc32(data) != crc:
        raise ChunkRefused("CRC mismatch")
    return data


def _inflate_and_frame(header: ChunkHeader, payload, buf, index: list[tuple[int, int]]):
    """`inflate_checked`, then `index_chunk` with the message index records that follow the chunk:
    (data, framing)."""
    data = inflate_checked(header.compression, payload, header.size, header.crc)
    return data, index_chunk(buf, data, index)


@dataclass
class DeferredChunk:
    """A chunk holding messages of one deferred channel only, kept compressed until they are asked
    for (`inflate`). Its message index gave the offsets and log times; nothing is checked yet.
    A `Part` (`bench.log.mcap.parts`): `inflated()` gives its payloads, the other methods need that first."""

    compressed = True

    offset: int                 # byte offset of the chunk record in the file
    start_ns: int
    end_ns: int
    compression: str
    payload: bytes | None       # the compressed data (a copy: the file's mapping is closed after the walk),
                                # or None: read from `source` at `span` when inflated (nothing held meanwhile)
    size: int                   # uncompressed size
    crc: int
    channel: int
    log_times: np.ndarray       # uint64, per message, file order
    offsets: np.ndarray         # uint64, record offsets in the uncompressed data, increasing
    span: tuple[int, int] = (0, 0)                                 # (file offset, length) of the compressed data
    source: Callable[[int, int], bytes] | None = field(default=None, repr=False)

    def read_again(self) -> bytes:
        """The compressed data read from `source` again (`ChunkRefused` if it cannot be)."""
        if self.source is None:
            raise ChunkRefused("chunk data not available")
        try:
            payload = self.source(*self.span)
        except OSError as err:
            raise ChunkRefused(f"cannot read the chunk's data again: {err.strerror or err}") from err
        if len(payload) != self.span[1]:
            raise ChunkRefused("the file is shorter than when it was walked")
        return payload

    @property
    def lengths(self) -> np.ndarray:
        """Payload lengths implied by the offsets (the records tile the chunk; checked by `inflate`)."""
        ends = np.append(self.offsets[1:], self.size).astype(np.int64)
        return ends - self.offsets.astype(np.int64) - MESSAGE_DATA_OFFSET

    def _inflate_checked(self, payload: bytes) -> bytes:
        """`inflate_checked` of the chunk's compressed `payload` (a missing compression library, which stops
        the walk, is this chunk's damage here)."""
        try:
            return inflate_checked(self.compression, payload, self.size, self.crc)
        except WalkError as exc:
            raise ChunkRefused(f"{self.compression or 'uncompressed'} data cannot be decompressed ({exc})") from exc

    def inflate(self) -> tuple[bytes, np.ndarray]:
        """(chunk data, payload starts) when the chunk decompresses, passes its CRC and is framed
        exactly by its index; `ChunkRefused` with the reason otherwise."""
        data = self._inflate_checked(self.payload if self.payload is not None else self.read_again())
        framed = frame_by_entries(data, [(self.channel, self.log_times, self.offsets)])
        if framed is False or framed[0] != 0:
            raise ChunkRefused("malformed chunk content (its message index does not frame it)")
        return data, framed[1][0][1]


    def inflated(self) -> InChunk:
        return InChunk(*self.inflate())

    def declared_bytes(self, lengths: np.ndarray) -> int:
        return self.size

    def located(self, lengths: np.ndarray) -> tuple[bytes, np.ndarray]:
        raise RuntimeError(NOT_INFLATED)

    def joined(self, lengths: np.ndarray) -> bytes:
        raise RuntimeError(NOT_INFLATED)

    def head(self, count: int, lengths: np.ndarray) -> Part:
        raise RuntimeError(NOT_INFLATED)

    def byte_at(self, offset: int, lengths: np.ndarray) -> int:
        raise RuntimeError(NOT_INFLATED)


def inflated_or_refusal(part: Part) -> Part | ChunkRefused:
    """`part.inflated()`, or its refusal (for a pool's map: the answers of every part, in order)."""
    try:
        return part.inflated()
    except ChunkRefused as refused:
        return refused


@dataclass
class ChunkSlice(DeferredChunk):
    """One channel's messages in a chunk the walk decompressed and let go (a chunk shared with other
    channels): `inflate` reads the chunk from the file again, decompresses and checks it, and gives its
    payloads where the walk found them (`offsets` holds the payload starts here)."""

    payload_lengths: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def lengths(self) -> np.ndarray:
        return self.payload_lengths

    def inflate(self) -> tuple[bytes, np.ndarray]:
        """(chunk data, payload starts); `ChunkRefused` with the reason the chunk cannot be used again."""
        return self._inflate_checked(self.read_again()), self.offsets


def _deferrable(buf, header: ChunkHeader, index: list[tuple[int, int]], deferred_channels: set[int]):
    """(channel, log times, offsets) when the chunk holds messages of one deferred channel and
    nothing else, as far as its message index says; else None."""
    if not index or not deferred_channels:
        return None
    entries = index_entries(buf, index)
    if entries is False or len(entries) != 1 or entries[0][0] not in deferred_channels:
        return None
    ch, t, o = entries[0]
    if not len(o) or int(o[0]) != 0 or int(o[-1]) > header.size - MESSAGE_DATA_OFFSET:
        return None
    if len(o) > 1 and not (np.diff(o.astype(np.int64)) >= MESSAGE_DATA_OFFSET).all():
        return None
    return ch, t, o


# bytes of a memory-mapped file the chunk scan leaves mapped behind it (1 GB of 15 kB chunks, each with
# its message indexes, touched every page: 1 GB of the file counted as the reader's memory)
SCAN_DROP_BYTES = 64 << 20


class Prefetch:
    """Decompresses and CRC-checks the chunks ahead of the walk on worker threads (zstd and zlib
    release the GIL, so this uses every core). Chunks are found by following the record framing
    from the start; where that framing breaks the walk resyncs on its own and decompresses inline.

    Chunks that hold only messages of a channel whose topic is in `defer_topics` (by their message
    index) are not decompressed at all: `deferred[offset]` says what they hold."""

    AHEAD_PER_WORKER = 3
    MIN_CHUNKS = 3   # fewer: not worth the threads

    def __init__(self, buf, workers: int | None = None, defer_topics: frozenset[str] = frozenset(),
                 budget: int | None = None, lazy: bool = False):
        self.buf = buf
        self.topics: dict[int, str] = {}
        self.chunks = self._scan(buf)
        self.index = {c.offset: k for k, c in enumerate(self.chunks)}
        deferred_channels = {ch for ch, topic in self.topics.items() if topic in defer_topics}
        # offset -> (channel, log times, offsets); None for a deferrable chunk past what the log may stream
        # (`lazy`: counted at its declared size in file order, as the walk counts it): its index is not kept
        # (a 1 GB file of 250 honest 256 MiB chunks held 1 GB of index entries here)
        self.deferred: dict[int, tuple | None] = {}
        stream_room = streamed_budget(len(buf))
        behind = PageDropper(buf, SCAN_DROP_BYTES)
        for pos, header, index in self.chunks if deferred_channels else ():
            found = _deferrable(buf, header, index, deferred_channels) if header.size <= MAX_CHUNK_BYTES else None
            if index:   # the index records were read: let their pages go (a file of 4 MB indexes is all index)
                drop_pages(buf, index[0][0], index[-1][1])
                behind.passed(index[-1][1])
            if found is not None:
                self.deferred[pos] = found if not lazy or stream_room.fits(header.size) else None
        behind.passed(len(buf), last=True)
        # the chunks within the limits, counted in file order as the walk counts them (a deferred one at its
        # compressed size: it is kept so; nothing when `lazy`: it is read again from the file when needed)
        room = InflateBudget(inflate_budget(len(buf)) if budget is None else budget)
        self.allowed = {pos for pos, header, _ in self.chunks
                        if room.fits((0 if lazy else header.data_length) if pos in self.deferred else header.size)}
        self.futures: dict[int, Future] = {}
        self.in_flight = 0   # declared bytes of the chunks submitted and not taken yet
        self.submitted = 0
        workers = workers or reader_threads()
        self.pool = (ThreadPoolExecutor(workers, thread_name_prefix="mcap-inflate")
                     if len(self.chunks) >= self.MIN_CHUNKS and workers > 1 else None)
        self.ahead = workers * self.AHEAD_PER_WORKER

    def _scan(self, buf) -> list[ScannedChunk]:
        """Every chunk with its header and the message index records right after it; the channel topics
        of the channel records outside chunks into `self.topics`."""
        size, pos = len(buf), 8
        # the pages scanned go as the scan passes them: small chunks are all headers
        behind = PageDropper(buf, SCAN_DROP_BYTES)
        found: list[ScannedChunk] = []
        # the index records of the last chunk, while only such records follow it
        current: list[tuple[int, int]] | None = None
        records = 0
        while pos + 9 <= size and records < MAX_RECORDS:
            records += 1
            op, length = RECORD_HEAD.unpack_from(buf, pos)
            end = pos + 9 + length
            if op not in OP_NAMES or end > size or op == OP_FOOTER:
                break
            if op == OP_CHUNK:
                header = read_chunk_header(buf, pos + 9, length)
                if header is None:
                    break
                current = []
                found.append(ScannedChunk(pos, header, current))
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
            behind.passed(pos)
        behind.passed(pos, last=True)
        return found

    def scanned(self, pos: int, header: ChunkHeader) -> ScannedChunk | None:
        """The chunk the scan found at `pos`, if it found this one there."""
        k = self.index.get(pos)
        return self.chunks[k] if k is not None and self.chunks[k].header == header else None

    def take(self, pos: int, header: ChunkHeader):
        """(data, (message index records, their framing)) of the chunk at `pos`, None if it was not
        prefetched; `ChunkRefused` if it failed (as `inflate_checked`)."""
        k = self.index.get(pos)
        if self.pool is None or k is None or self.chunks[k].header != header:
            return None
        while self.submitted < min(len(self.chunks), k + 1 + self.ahead):
            ahead = self.chunks[self.submitted]
            if ahead.offset in self.deferred or ahead.offset not in self.allowed:
                self.submitted += 1
                continue
            if self.futures and self.in_flight + ahead.header.size > PREFETCH_BYTES:
                break   # enough decompressed data ahead already
            start, length = ahead.header.data_span
            self.futures[ahead.offset] = self.pool.submit(_inflate_and_frame, ahead.header,
                                                          memoryview(self.buf)[start:start + length], self.buf,
                                                          ahead.index_records)
            self.in_flight += ahead.header.size
            self.submitted += 1
        future = self.futures.pop(pos, None)
        if future is None:
            return None
        self.in_flight -= self.chunks[k].header.size
        data, framed = future.result()
        return data, (self.chunks[k].index_records, framed)

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.futures.clear()
