"""Many messages of one channel into an `mcap.writer.Writer` at once: the bytes `add_message` writes, a
few operations per message instead of a dozen calls.

A run's log holds one `/imu/samples` message per sample (hundreds of thousands): through
`Writer.add_message` each costs a record object, a statistics update, a message-index entry and
six buffer writes, more than the rest of the recorder's work per sample. `add_messages` writes
the same records, indexes, chunk boundaries and statistics into the writer's own chunk builder;
the file is byte for byte the one the message-by-message calls write (a test holds the two
equal). It reaches into the writer's private state, so it checks for that state first and falls
back to `add_message` per message on an mcap release that keeps it differently.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.writer import Writer

#: a Message record's head: opcode, record length, channel id, sequence, log time, publish time
_HEAD = struct.Struct("<BQHIQQ")
_HEAD_DTYPE = np.dtype([("opcode", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
                        ("log_time", "<u8"), ("publish_time", "<u8")])


class _PackedMessageIndex(MessageIndex):
    """A message index whose (log time, offset) entries added in bulk stay arrays until it is written (one copy,
    the same bytes); `records` turns them into the list `MessageIndex` keeps when something reads it (the
    writer's own `add_message` appending to it), so that the entries keep their order."""

    _records: list[tuple[int, int]]
    _blocks: list[np.ndarray]

    @property
    def records(self) -> list[tuple[int, int]]:
        blocks = self.__dict__.setdefault("_blocks", [])
        if blocks:
            self._records.extend(map(tuple, np.concatenate(blocks).tolist()))
            blocks.clear()
        return self._records

    @records.setter
    def records(self, value: list[tuple[int, int]]) -> None:
        self._records, self._blocks = list(value), []

    def add_block(self, times: np.ndarray, offsets: np.ndarray) -> None:
        """Entries of many messages at once (their log times and offsets, in order)."""
        self._blocks.append(np.column_stack([times.astype(np.uint64), offsets.astype(np.uint64)]))

    def write(self, stream) -> None:
        parts = ([np.array(self._records, np.uint64).reshape(-1, 2)] if self._records else []) + self._blocks
        data = np.concatenate(parts).astype("<u8").tobytes() if parts else b""
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(data))
        stream.write(data)
        stream.finish_record()


def _state(writer: Writer):
    """(chunk builder, statistics, chunk size) of `writer`, or None when this mcap keeps them differently."""
    builder = getattr(writer, "_Writer__chunk_builder", None)
    stats = getattr(writer, "_Writer__statistics", None)
    size = getattr(writer, "_Writer__chunk_size", None)
    finalize = getattr(writer, "_Writer__finalize_chunk", None)
    if builder is None or stats is None or not isinstance(size, int) or finalize is None:
        return None
    if not all(hasattr(builder, name) for name in ("record_writer", "message_indices", "message_start_time",
                                                   "message_end_time", "num_messages")):
        return None
    if not all(hasattr(stats, name) for name in ("message_count", "message_start_time", "message_end_time",
                                                 "channel_message_counts")):
        return None
    return builder, stats, size, finalize


def _records(channels: int | np.ndarray, times: np.ndarray, bodies: Sequence[bytes], sizes: np.ndarray) -> bytes:
    """The Message records of `bodies` (sizes: each record's, head included), heads laid out as one array and
    joined with the bodies (no Python step per byte)."""
    n = len(bodies)
    packed, width = message_heads(channels, times, sizes).tobytes(), _HEAD.size
    # each head then its body, in one join over a list filled by slice assignment (the cheapest layout measured)
    parts: list[bytes] = [b""] * (2 * n)
    parts[0::2] = [packed[k:k + width] for k in range(0, n * width, width)]
    parts[1::2] = bodies
    return b"".join(parts)


def _index_parts(channels: int | np.ndarray, times: np.ndarray,
                 offsets: np.ndarray) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """(channel, its messages' log times, their offsets) for each channel of a part, in the order the channels
    first appear (the order `add_message` creates the message indexes in)."""
    if isinstance(channels, int):
        return [(channels, times, offsets)]
    ids, first = np.unique(channels, return_index=True)
    return [(int(channel), times[mask], offsets[mask])
            for channel in ids[np.argsort(first)] for mask in [channels == channel]]


def add_messages(writer: Writer, channel_id: int | np.ndarray, messages: Sequence[tuple[int, bytes]]) -> None:
    """`writer.add_message(channel_id, t, body, t)` for each (t, body) of `messages`, in order; `channel_id` is
    one channel's, or an array of each message's (messages of several channels interleaved)."""
    add_message_arrays(writer, channel_id, np.array([t for t, _ in messages], np.uint64),
                       [body for _, body in messages])


def add_message_arrays(writer: Writer, channel_id: int | np.ndarray, log_times_ns: np.ndarray,
                       bodies: Sequence[bytes]) -> None:
    """`add_messages` with the log times (ns) as an array and the bodies as a list beside it."""
    n = len(bodies)
    times = np.asarray(log_times_ns, np.uint64)
    if _state(writer) is None:
        ids = [channel_id] * n if isinstance(channel_id, int) else np.asarray(channel_id).tolist()
        for channel, t, body in zip(ids, times.tolist(), bodies):
            writer.add_message(channel, t, body, t)
        return
    sizes = np.fromiter(map(len, bodies), np.int64, n) + _HEAD.size
    channels = channel_id if isinstance(channel_id, int) else np.asarray(channel_id, np.int64)
    add_records(writer, channels, times, sizes, _records(channels, times, bodies, sizes))


def message_heads(channels: int | np.ndarray, log_times_ns: np.ndarray, record_sizes: np.ndarray) -> np.ndarray:
    """The heads (`_HEAD_DTYPE`: opcode to publish time, 31 bytes) of Message records of `record_sizes` bytes
    each (head included), sequence 0, published at their log time."""
    heads = np.zeros(len(record_sizes), _HEAD_DTYPE)
    heads["opcode"], heads["length"], heads["channel"] = int(Opcode.MESSAGE), np.asarray(record_sizes) - 9, channels
    heads["log_time"] = heads["publish_time"] = log_times_ns
    return heads


def add_records(writer: Writer, channel_id: int | np.ndarray, log_times_ns: np.ndarray, record_sizes: np.ndarray,
                records: bytes) -> None:
    """Message records already laid out back to back (`records`: each a head of `message_heads` then its body;
    `record_sizes`: each one's bytes), of `channel_id` (one, or each record's) at `log_times_ns`: the chunks,
    message indexes and statistics `writer.add_message` of each would make, the same bytes."""
    n = len(record_sizes)
    channels = None if isinstance(channel_id, int) else np.asarray(channel_id, np.int64)
    times = np.asarray(log_times_ns, np.uint64)
    sizes = np.asarray(record_sizes, np.int64)
    ends = np.cumsum(sizes)           # of each record, counted from the first
    if int(ends[-1] if n else 0) != len(records):
        raise ValueError(f"{len(records)} bytes of records where their sizes add up to {int(ends[-1]) if n else 0}")
    state = _state(writer)
    if state is None:
        ids = [channel_id] * n if channels is None else channels.tolist()
        for channel, t, end, size in zip(ids, times.tolist(), ends.tolist(), sizes.tolist()):
            writer.add_message(channel, t, records[end - size + _HEAD.size:end], t)
        return
    builder, stats, chunk_size, finalize = state
    view = memoryview(records)
    at = 0
    while at < n:
        # the messages up to the first that takes the chunk past `chunk_size` (the writer closes it after that one)
        before = int(ends[at - 1]) if at else 0
        start = builder.record_writer.count - before    # where ends[at - 1] lands
        stop = min(n, at + 1 + int(np.searchsorted(ends[at:], chunk_size - start, side="right")))
        offsets = ends[at:stop] - sizes[at:stop] + start
        part_times = times[at:stop]
        lo, hi = int(part_times.min()), int(part_times.max())
        if builder.num_messages == 0:
            builder.message_start_time = lo
        else:
            builder.message_start_time = min(builder.message_start_time, lo)
        builder.message_end_time = max(builder.message_end_time, hi)
        part_channels = channel_id if channels is None else channels[at:stop]
        for channel, channel_times, channel_offsets in _index_parts(part_channels, part_times, offsets):
            index = builder.message_indices.get(channel)
            if not index:
                index = builder.message_indices[channel] = _PackedMessageIndex(channel_id=channel, records=[])
            if isinstance(index, _PackedMessageIndex):
                index.add_block(channel_times, channel_offsets)
            else:       # an index the writer's own add_message began in this chunk
                index.records.extend(zip(channel_times.tolist(), channel_offsets.tolist()))
            stats.channel_message_counts[channel] += len(channel_times)
        builder.num_messages += stop - at
        builder.record_writer.write(view[before:int(ends[stop - 1])])
        stats.message_start_time = lo if stats.message_count == 0 else min(stats.message_start_time, lo)
        stats.message_end_time = max(stats.message_end_time, hi)
        stats.message_count += stop - at
        at = stop
        if builder.record_writer.count > chunk_size:
            finalize()


__all__ = ["add_message_arrays", "add_messages", "add_records", "message_heads"]
