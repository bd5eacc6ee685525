"""What a walk keeps of the messages it gathers (`Keep.add`): held in their chunk, left in the file to be read
again, only counted, or copied out up to a per-topic limit. The walk (`bench.log.mcap.walk`) decides where the
messages are; this decides what of them outlives the walk."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from bench.log.mcap.channel import ChannelData
from bench.log.mcap.chunks import ChunkSlice
from bench.log.mcap.parts import InChunk, Joined, MessageCut, gather
from bench.log.mcap.records import ChunkHeader


@dataclass(frozen=True)
class Keep:
    """A walk's choices about messages. Without a `source` every part is lazy (the chunk stays in memory while
    it lives); with one, nothing keeps a decompressed chunk: `defer_topics`' messages become `ChunkSlice`s
    (read again through `source(offset, length)`), a topic outside `topics` (None: all) is only counted, the
    others are copied out (at most `limits[topic]` messages, the rest counted). `cut`: what is done to a kept
    message too long to be held as it is."""

    source: Callable[[int, int], bytes] | None = None
    defer_topics: frozenset[str] = frozenset()
    topics: frozenset[str] | None = None
    limits: Mapping[str, int] = field(default_factory=dict)
    cut: MessageCut | None = None

    def add(self, d: ChannelData, channel_id: int, topic: str | None, chunk: tuple[int, ChunkHeader] | None,
            data: bytes, starts: np.ndarray, lengths: np.ndarray, times: np.ndarray) -> None:
        """Channel `channel_id`'s messages (`topic`, None when its channel record is unknown) in `data`, the
        chunk at `(offset, header)` = `chunk` being gathered (None: outside chunks), into `d`."""
        if (self.cut is not None and topic in self.cut.topics and len(lengths)
                and int(lengths.max()) > self.cut.max_bytes):
            data, starts, lengths = self.cut.apply(data, starts, lengths)
        if self.source is None or chunk is None or topic is None:
            d.add(InChunk(data, starts), lengths, times)
            return
        if topic in self.defer_topics:
            pos, header = chunk
            d.add(ChunkSlice(pos, header.start_ns, header.end_ns, header.compression, None, header.size, header.crc,
                             channel_id, times, starts, header.data_span, self.source, lengths), lengths, times)
            return
        if self.topics is not None and topic not in self.topics:
            d.not_kept += len(lengths)
            return
        limit = self.limits.get(topic)
        if limit is not None:
            room = max(0, limit - len(d))
            if room < len(lengths):
                d.over_limit += len(lengths) - room
                starts, lengths, times = starts[:room], lengths[:room], times[:room]
            if not len(lengths):
                return
        d.add(Joined(gather(data, starts, lengths)), lengths, times)
