"""A damage-tolerant walk over the records of an MCAP file (what `bench.log.reader` builds on).

The `mcap` library's readers stop at the first damaged record (a CRC mismatch ends the
stream reader's generator; the seeking reader needs the summary). A run log cut off by a
crash, or with one bad chunk, must still give everything else, so this walks the record
framing itself (MCAP spec: magic, then records `opcode u8 | length u64 | body`; a Chunk
body is `start u64 | end u64 | uncompressed size u64 | uncompressed crc32 u32 |
compression string | data length u64 | data`, its data again records). Record bodies
other than messages are parsed with the library's own record classes.

Messages are gathered per channel and per chunk (`bench.log.mcap.channel.ChannelData`: a part per
chunk, `bench.log.mcap.parts`, with their lengths and log times); damage is collected as `Damage`
entries with byte offsets and log-time ranges (`bench.log.mcap.damage`).

Speed: chunks are decompressed, CRC-checked and framed by their message index on worker
threads ahead of the walk (`bench.log.mcap.chunks.Prefetch`; zstd, zlib and numpy release
the GIL), while the walk itself stays sequential and decides everything exactly as it
would inline. The record layout and chunk decoding live in `bench.log.mcap.chunks`.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from mcap.records import Attachment, Channel, Footer, Header, Metadata, Schema, Statistics

from bench.log.mcap.channel import ChannelData
from bench.log.mcap.chunks import (
    MAX_RECORDS,
    DeferredChunk,
    InflateBudget,
    Prefetch,
    inflate_budget,
    inflate_checked,
    streamed_budget,
)
from bench.log.mcap.damage import Damage
from bench.log.mcap.keep import Keep
from bench.log.mcap.parts import Joined, MessageCut
from bench.log.mcap.records import (
    MAGIC,
    MESSAGE_DATA_OFFSET,
    MESSAGE_HEAD,
    OP_ATTACHMENT,
    OP_CHANNEL,
    OP_CHUNK,
    OP_FOOTER,
    OP_HEADER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_METADATA,
    OP_NAMES,
    OP_SCHEMA,
    OP_STATISTICS,
    RECORD_HEAD,
    ChunkHeader,
    ChunkRefused,
    PageDropper,
    WalkError,
    attachment_head,
    body_stream,
    chunk_content,
    index_chunk,
    plausible_record_at,
    read_chunk_header,
    resync,
)

_DROP_BEHIND = 64 << 20   # bytes of a mapped file the walk leaves mapped behind it


@dataclass
class Walk:
    """Everything found in a file."""

    header: Header | None = None
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    data: dict[int, ChannelData] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, tuple[str, bytes]] = field(default_factory=dict)
    attachment_offsets: dict[str, int] = field(default_factory=dict)   # name -> byte offset of its record
    statistics: Statistics | None = None
    footer: Footer | None = None
    chunks: int = 0
    damage: list[Damage] = field(default_factory=list)
    size: int = 0
    budget: InflateBudget = field(default_factory=lambda: InflateBudget(0))   # what the chunks may inflate to
    stream_budget: InflateBudget = field(default_factory=lambda: InflateBudget(0))   # deferred ones read again

    def topic(self, channel_id: int) -> str:
        ch = self.channels.get(channel_id)
        return ch.topic if ch is not None else f"<channel {channel_id}>"


#: The most a record other than a chunk, its message index or an attachment may hold (a recorded log's
#: largest, a metadata record with the configuration, holds a few KB).
MAX_RECORD_BYTES = 16 << 20
_CAPPED = frozenset({OP_HEADER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_METADATA, OP_STATISTICS})
#: The most an attachment may hold (configuration, schedules, the result) and a DBC file (by its name).
MAX_ATTACHMENT_BYTES = 16 << 20
MAX_DBC_BYTES = 1 << 20


def attachment_limit(name: str) -> int:
    """How many bytes the attachment `name` may hold: `MAX_DBC_BYTES` for a DBC file (`*.dbc`)."""
    return MAX_DBC_BYTES if name.lower().endswith(".dbc") else MAX_ATTACHMENT_BYTES


class _OverLimits(ChunkRefused):
    """A chunk refused by the limits (told with the refused chunks right before it, see `_Walker.refuse`)."""


def _within_limits(budget: InflateBudget, size: int) -> None:
    """`budget.take(size)`, its refusal an `_OverLimits`."""
    try:
        budget.take(size)
    except ChunkRefused as exc:
        raise _OverLimits(str(exc)) from exc


@dataclass
class _PendingChunk:
    """A good chunk waiting for the message index records after it (its data, or still compressed)."""

    offset: int
    header: ChunkHeader
    data: bytes | DeferredChunk
    index: list[tuple[int, int]] = field(default_factory=list)   # (body, end) of the index records seen
    framed: tuple | None = None   # (message index records, `index_chunk` answer), from a worker


class _Walker:
    def __init__(self, buf: bytes, defer_topics: frozenset[str] = frozenset(),
                 source: Callable[[int, int], bytes] | None = None, keep_topics: frozenset[str] | None = None,
                 keep_limits: dict[str, int] | None = None, cut: MessageCut | None = None):
        self.buf = buf
        self.defer_topics = defer_topics
        self.source = source
        self.keep = Keep(source, defer_topics, keep_topics, keep_limits or {}, cut)
        self.current: tuple[int, ChunkHeader] | None = None   # (offset, header) of the chunk being gathered
        self.w = Walk(size=len(buf), budget=InflateBudget(inflate_budget(len(buf))),
                      stream_budget=streamed_budget(len(buf)))
        self.lost_chunk: Damage | None = None   # message index records after a lost chunk count its messages
        self.last_refused: Damage | None = None   # the refusal the next refused chunk joins, if nothing came between
        self.pending: _PendingChunk | None = None   # a good chunk waiting for its message index records
        self.prefetch: Prefetch | None = None
        self.loose: dict[int, tuple[list, list, list]] = {}   # messages outside chunks not yet in their channel
        self.pages = PageDropper(buf, _DROP_BEHIND, keep=_DROP_BEHIND // 2)

    def channel_data(self, channel_id: int) -> ChannelData:
        d = self.w.data.get(channel_id)
        if d is None:
            d = self.w.data[channel_id] = ChannelData()
        return d

    def run(self) -> Walk:
        self.prefetch = Prefetch(self.buf, defer_topics=self.defer_topics, budget=self.w.budget.total,
                                 lazy=self.source is not None)
        try:
            return self._run()
        finally:
            self.prefetch.close()

    def _run(self) -> Walk:
        buf, w = self.buf, self.w
        size = len(buf)
        if size == 0:
            raise WalkError("empty file")
        if size < 8 or buf[:8] != MAGIC:
            raise WalkError("not an MCAP file (no MCAP magic at the start)")
        pos = 8
        if size < 17 or buf[8] != OP_HEADER or not plausible_record_at(buf, 8, size):
            raise WalkError("not a readable MCAP file (no header record after the magic)")
        records = 0
        while pos < size:
            if size - pos < 9:
                w.damage.append(Damage("truncated", size, f"a record header at byte {pos} is incomplete"))
                break
            records += 1
            if records > MAX_RECORDS:
                w.damage.append(Damage("corrupt", pos, f"more than {MAX_RECORDS} records outside chunks (a recorded "
                                                       f"log holds a few per chunk): bytes {pos}..{size} not read"))
                break
            op, length = RECORD_HEAD.unpack_from(buf, pos)
            body, end = pos + 9, pos + 9 + length
            if op != OP_MESSAGE_INDEX or end > size:
                self.finish_chunk()
            if op not in OP_NAMES:
                nxt = resync(buf, pos, size, self.passed)
                w.damage.append(Damage("corrupt", pos, f"unreadable record (opcode {op:#x}); bytes {pos}..{nxt} "
                                                       f"skipped" + (" to the next chunk" if nxt < size else "")))
                pos = nxt
                continue
            if end > size:
                nxt = resync(buf, pos, size, self.passed)
                if nxt == size:   # nothing readable follows: the file was cut off here
                    self.truncated(op, pos, body, length)
                    break
                w.damage.append(Damage("corrupt", pos, f"{OP_NAMES[op]} record with an impossible length; bytes "
                                                       f"{pos}..{nxt} skipped to the next chunk"))
                pos = nxt
                continue
            if op == OP_FOOTER:
                self.footer(pos, body, end)
                if buf[end:end + 8] != MAGIC:
                    w.damage.append(Damage("truncated", end, "the closing magic after the footer is missing"))
                pos = end + 8
                break
            if op == OP_CHUNK:
                if not self.chunk(pos, body, length):
                    nxt = end if plausible_record_at(buf, end, size) else resync(buf, pos, size, self.passed)
                    pos = nxt
                    continue
            else:
                try:
                    self.record(op, pos, body, end)
                except Exception as exc:   # a damaged record body: skip it, say so
                    w.damage.append(Damage("corrupt", pos, f"{OP_NAMES[op]} record unreadable ({exc}); skipped"))
            if not plausible_record_at(buf, end, size):
                nxt = resync(buf, end, size, self.passed)
                w.damage.append(Damage("corrupt", end, f"unreadable record after byte {end}; bytes {end}..{nxt} "
                                                       f"skipped" + (" to the next chunk" if nxt < size else "")))
                end = nxt
            pos = end
            self.passed(pos)
        self.finish_chunk()
        self.flush_loose()
        if w.footer is None:
            w.damage.append(Damage("no_summary", size, "no summary or footer: the recording was not closed "
                                                       "(stopped or crashed); anything not yet in a closed chunk "
                                                       "was never written"))
        elif pos < size:
            w.damage.append(Damage("corrupt", pos, f"{size - pos} unexpected bytes after the closing magic"))
        return w

    def footer(self, pos: int, body: int, end: int) -> None:
        w, buf = self.w, self.buf
        try:
            w.footer = footer = Footer.read(body_stream(buf, body, end))
        except Exception as exc:
            w.damage.append(Damage("corrupt", pos, f"footer record unreadable ({exc})"))
            return
        if footer.summary_crc != 0 and footer.summary_start <= pos:
            start = footer.summary_start or pos   # no summary section: the CRC covers the footer fields only
            if zlib.crc32(buf[start:pos + 25]) != footer.summary_crc:
                w.statistics = None   # the counts cannot be trusted
                w.damage.append(Damage("corrupt", start, "the summary section fails its CRC check; ignored"))

    def truncated(self, op: int, pos: int, body: int, length: int) -> None:
        buf, size = self.buf, len(self.buf)
        if op == OP_CHUNK:
            start, end = struct.unpack_from("<QQ", buf, body) if size - body >= 16 else (1, 0)
            known = start <= end
            self.w.damage.append(Damage("truncated", size, f"the last chunk (at byte {pos}) is incomplete, its "
                                        f"messages lost", start if known else None, end if known else None))
        else:
            self.w.damage.append(Damage("truncated", size, f"the last {OP_NAMES[op]} record (at byte {pos}) is "
                                        f"incomplete ({size - body} of {length} bytes)"))

    def passed(self, pos: int) -> None:
        """The walk (or a resync) has read up to `pos`: the pages well behind it go (a file read once does not
        count whole towards the process' memory)."""
        self.pages.passed(pos)

    def flush_loose(self) -> None:
        """The messages read outside chunks since the last chunk, into their channels (one part each)."""
        for ch, (payloads, lengths, times) in self.loose.items():
            self.channel_data(ch).add(Joined(b"".join(payloads)), lengths, times)
        self.loose = {}

    def record(self, op: int, pos: int, body: int, end: int) -> None:
        w, buf = self.w, self.buf
        if op in _CAPPED and end - body > MAX_RECORD_BYTES:
            w.damage.append(Damage("corrupt", pos, f"{OP_NAMES[op]} record of {end - body} bytes, more than "
                                                   f"{MAX_RECORD_BYTES} bytes such a record may hold; skipped"))
            self.lost_chunk = None
            return
        if op == OP_HEADER:
            w.header = Header.read(body_stream(buf, body, end))
        elif op == OP_SCHEMA:
            s = Schema.read(body_stream(buf, body, end))
            w.schemas.setdefault(s.id, s)
        elif op == OP_CHANNEL:
            c = Channel.read(body_stream(buf, body, end))
            w.channels.setdefault(c.id, c)
        elif op == OP_MESSAGE:   # a message outside any chunk (unchunked files): gathered per channel
            _, _, ch, _, log_time = MESSAGE_HEAD.unpack_from(buf, pos)
            start = pos + MESSAGE_DATA_OFFSET
            loose = self.loose.get(ch)
            if loose is None:
                loose = self.loose[ch] = ([], [], [])
            loose[0].append(bytes(buf[start:end]))
            loose[1].append(end - start)
            loose[2].append(log_time)
        elif op == OP_MESSAGE_INDEX:
            if self.pending is not None:
                self.pending.index.append((body, end))
            elif self.lost_chunk is not None and end - body >= 6:
                ch, n = struct.unpack_from("<HI", buf, body)
                lost = self.lost_chunk.lost   # (refused chunks told as one add up)
                lost[w.topic(ch)] = lost.get(w.topic(ch), 0) + n // 16
        elif op == OP_METADATA:
            m = Metadata.read(body_stream(buf, body, end))
            w.metadata[m.name] = m.metadata
        elif op == OP_ATTACHMENT:
            head = attachment_head(buf, body, end)
            if head is not None and head[1] > attachment_limit(head[0]):
                name, n = head
                w.damage.append(Damage("attachment", pos, f"attachment {name[:64]!r} holds {n} bytes, more than "
                                                          f"{attachment_limit(name)} bytes (the limit for its kind); "
                                                          "dropped"))
            else:
                a = Attachment.read(body_stream(buf, body, end))
                (crc,) = struct.unpack_from("<I", buf, end - 4)
                if crc != 0 and zlib.crc32(buf[body:end - 4]) != crc:
                    w.damage.append(Damage("attachment", pos, f"attachment {a.name[:64]!r} fails its CRC check; "
                                                              "dropped"))
                else:
                    w.attachments[a.name] = (a.media_type, a.data)
                    w.attachment_offsets[a.name] = pos
        elif op == OP_STATISTICS:
            w.statistics = Statistics.read(body_stream(buf, body, end))
        if op != OP_MESSAGE_INDEX and op != OP_CHUNK:
            self.lost_chunk = None

    def refuse(self, pos: int, reason: str, start: int, end: int, joinable: Damage | None) -> None:
        """A chunk refused by the limits: damage, told with the refused chunks right before it when they were
        refused for the same reason (a file of a million bomb chunks is one line, not a million)."""
        w = self.w
        last = w.damage[-1] if w.damage else None
        if last is not None and last is joinable and last.reason == reason:
            last.chunks += 1
            last.last_offset = pos
            last.start_ns = min(last.start_ns, start) if last.start_ns is not None else None
            last.end_ns = max(last.end_ns, end) if last.end_ns is not None else None
            self.lost_chunk = self.last_refused = last
            return
        w.damage.append(Damage("chunk", pos, reason, start, end, last_offset=pos))
        self.lost_chunk = self.last_refused = w.damage[-1]

    def chunk(self, pos: int, body: int, length: int) -> bool:
        """Read one chunk record; False when its framing is broken (the caller re-syncs)."""
        w = self.w
        self.lost_chunk = None
        joinable, self.last_refused = self.last_refused, None
        header = read_chunk_header(self.buf, body, length)
        if header is None:
            w.damage.append(Damage("chunk", pos, "chunk header inconsistent"))
            self.lost_chunk = w.damage[-1]
            return False
        self.flush_loose()
        try:
            self.pending = self._checked_chunk(pos, header)
        except _OverLimits as refused:
            self.refuse(pos, str(refused), header.start_ns, header.end_ns, joinable)
        except ChunkRefused as failed:
            w.damage.append(Damage("chunk", pos, str(failed), header.start_ns, header.end_ns))
            self.lost_chunk = w.damage[-1]
        return True

    def _checked_chunk(self, pos: int, header: ChunkHeader) -> _PendingChunk:
        """The chunk at `pos`, decompressed and checked (or kept compressed, deferred), waiting for the message
        index records after it; `_OverLimits` if the limits refuse it, `ChunkRefused` if it fails."""
        w, prefetch = self.w, self.prefetch
        scanned = prefetch is not None and prefetch.scanned(pos, header) is not None
        deferred = prefetch.deferred.get(pos) if prefetch is not None and scanned else None
        if prefetch is not None and scanned and deferred is None and pos in prefetch.deferred \
                and self.source is not None:
            # left in the file, past what the log may stream (the prefetch kept no index for it)
            _within_limits(w.stream_budget, header.size)
            raise _OverLimits("past what this log's chunks may stream")
        if deferred is not None:
            # kept compressed: counted against the budget at that size now, at its own when it is inflated
            # (`ChannelData.inflate_deferred`); with a `source`, nothing is kept (it is read again when needed)
            # but its index is: counted at its own size against what the log may stream, so a file of a
            # million small bomb chunks keeps the index of a few
            if self.source is not None:
                _within_limits(w.stream_budget, header.size)
            else:
                _within_limits(w.budget, header.data_length)
            ch, t, o = deferred
            start, length = header.data_span
            payload = None if self.source is not None else bytes(self.buf[start:start + length])
            return _PendingChunk(pos, header, DeferredChunk(pos, header.start_ns, header.end_ns, header.compression,
                                                            payload, header.size, header.crc, ch, t, o,
                                                            header.data_span, self.source))
        _within_limits(w.budget, header.size)
        done = prefetch.take(pos, header) if prefetch is not None else None
        if done is not None:
            data, framed = done
            return _PendingChunk(pos, header, data, framed=framed)
        start, length = header.data_span
        data = inflate_checked(header.compression, memoryview(self.buf)[start:start + length], header.size, header.crc)
        return _PendingChunk(pos, header, data)

    def finish_chunk(self) -> None:
        """Gather the pending chunk's records: by its message index when that checks out, else record by record."""
        pending, self.pending = self.pending, None
        if pending is None:
            return
        try:
            self._finish_chunk(pending)
        finally:
            self.current = None

    def _finish_chunk(self, pending: _PendingChunk) -> None:
        data, index = pending.data, pending.index
        if isinstance(data, DeferredChunk):
            chunk = data
            assert self.prefetch is not None   # only the prefetch's scan defers chunks
            if index == self.prefetch.chunks[self.prefetch.index[pending.offset]].index_records:
                self.channel_data(chunk.channel).add(chunk, chunk.lengths, chunk.log_times)
                self.w.chunks += 1
                return
            # the walk found other index records after it than the scan did: check it now, inline
            try:
                self.w.budget.take(chunk.size)
                data, _ = chunk.inflate()
            except ChunkRefused as failed:
                self.w.damage.append(Damage("chunk", pending.offset, str(failed), chunk.start_ns, chunk.end_ns,
                                            {self.w.topic(chunk.channel): len(chunk.offsets)}))
                return
        self.current = (pending.offset, pending.header)
        framed = None
        if pending.framed is not None and pending.framed[0] == index:   # the worker framed it with these records
            framed = pending.framed[1]
        if self.chunk_by_index(data, index, framed):
            self.w.chunks += 1
            return
        reason = self.chunk_records(data)
        if reason is None:
            self.w.chunks += 1
            return
        header = pending.header
        self.w.damage.append(Damage("chunk", pending.offset, reason, header.start_ns, header.end_ns))

    def chunk_by_index(self, data: bytes, index: list[tuple[int, int]], framed=None) -> bool:
        """Gathering with the chunk's message index (`framed`: `index_chunk`'s answer when a worker
        already has it); False (nothing kept) unless the index provably frames every record."""
        framed = index_chunk(self.buf, data, index) if framed is None else framed
        if framed is False:
            return False
        first, per_channel = framed
        if first:   # schema and channel records ahead of the messages (the first chunk)
            if self.chunk_records(data[:first], messages=False) is not None:
                return False
        for ch, starts, lengths, t in per_channel:
            self.add_part(ch, data, starts, lengths, t)
        return True

    def chunk_records(self, data: bytes, messages: bool = True) -> str | None:
        """Gather the chunk's records; a reason string if its content is malformed (nothing kept then),
        or (with `messages` False) if it holds a message. A chunk holds schema, channel and message
        records only (MCAP spec). The framing is followed record by record, except where the messages
        provably follow at one stride (checked at once); the messages' fields are read vectorised and
        kept as lazy parts, like the message index gives them."""
        try:
            o, others = chunk_content(data, messages)
        except ChunkRefused as malformed:
            return str(malformed)
        for op, q, end in others:
            try:
                if op == OP_SCHEMA:
                    schema = Schema.read(body_stream(data, q + 9, end))
                    self.w.schemas.setdefault(schema.id, schema)
                else:
                    c = Channel.read(body_stream(data, q + 9, end))
                    self.w.channels.setdefault(c.id, c)
            except Exception as exc:
                return f"malformed {OP_NAMES[op]} record in the chunk ({exc})"
        if not len(o):
            return None
        size = len(data)
        lengths = np.ndarray((size - 8,), "<u8", data, 1, (1,))[o].astype(np.int64) - 22
        channels = np.ndarray((size - 10,), "<u2", data, 9, (1,))[o]
        times = np.ndarray((size - 22,), "<u8", data, 15, (1,))[o]
        for ch in np.unique(channels).tolist():
            mine = channels == ch
            self.add_part(ch, data, o[mine] + MESSAGE_DATA_OFFSET, lengths[mine], times[mine])
        return None

    def add_part(self, ch: int, data: bytes, starts: np.ndarray, lengths: np.ndarray, times: np.ndarray) -> None:
        """One channel's messages in the chunk being gathered (or outside chunks), kept as `self.keep` says."""
        topic = self.w.channels[ch].topic if ch in self.w.channels else None
        self.keep.add(self.channel_data(ch), ch, topic, self.current, data, starts, lengths, times)

def walk(buf: bytes, defer_topics: frozenset[str] = frozenset(),
         source: Callable[[int, int], bytes] | None = None, keep_topics: frozenset[str] | None = None,
         keep_limits: dict[str, int] | None = None, cut: MessageCut | None = None) -> Walk:
    """Walk an MCAP file held in memory; raises `WalkError` if it is not MCAP at all.

    Chunks holding nothing but messages of `defer_topics` are not decompressed: their channel
    data holds them as `DeferredChunk` parts (see `ChannelData.inflate_deferred`), with their
    compressed data copied, or read again through `source(offset, length)` when given (nothing held).
    With a `source`, no decompressed chunk outlives its gathering: see `bench.log.mcap.keep.Keep` (`keep_topics`:
    the topics whose messages are kept, None for all; `keep_limits`: the most messages kept per topic; `cut`: what
    is done to a kept message too long to be held as it is)."""
    return _Walker(buf, frozenset(defer_topics), source, keep_topics, keep_limits, cut).run()
