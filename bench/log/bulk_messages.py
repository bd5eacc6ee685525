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
from bisect import bisect_right
from collections.abc import Sequence
from itertools import accumulate

import numpy as np
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.writer import Writer

#: a Message record's head: opcode, record length, channel id, sequence, log time, publish time
_HEAD = struct.Struct("<BQHIQQ")
_HEAD_DTYPE = np.dtype([("opcode", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
                        ("log_time", "<u8"), ("publish_time", "<u8")])


class _PackedMessageIndex(MessageIndex):
    """A message index that writes its (log time, offset) entries with one pack (the same bytes)."""

    def write(self, stream) -> None:
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(self.records) * 16)
        flat = [x for entry in self.records for x in entry]
        stream.write(struct.pack(f"<{len(flat)}Q", *flat))
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


def _records(channel_id: int, times: list[int], bodies: list[bytes], sizes: list[int]) -> bytes:
    """The Message records of `bodies` (sizes: each record's, head included): the heads laid out as one array,
    then each head and its body joined in turn (one join; a byte mask over the records cost five times more)."""
    n = len(bodies)
    heads = np.zeros(n, _HEAD_DTYPE)
    size = np.array(sizes, np.int64)
    heads["opcode"], heads["length"], heads["channel"] = int(Opcode.MESSAGE), size - 9, channel_id
    heads["log_time"] = heads["publish_time"] = np.array(times, np.uint64)
    packed, step = heads.tobytes(), _HEAD.size
    parts: list[bytes] = [b""] * (2 * n)
    parts[0::2] = [packed[at:at + step] for at in range(0, n * step, step)]
    parts[1::2] = bodies
    return b"".join(parts)


def add_messages(writer: Writer, channel_id: int, messages: Sequence[tuple[int, bytes]]) -> None:
    """`writer.add_message(channel_id, t, body, t)` for each (t, body) of `messages`, in order."""
    state = _state(writer)
    if state is None:
        for t, body in messages:
            writer.add_message(channel_id, t, body, t)
        return
    builder, stats, chunk_size, finalize = state
    sizes = [_HEAD.size + len(body) for _, body in messages]
    at, n = 0, len(messages)
    while at < n:
        # the messages up to the first that takes the chunk past `chunk_size` (the writer closes it after that one):
        # ends[j] is the chunk's size before message at + j, the first end beyond `chunk_size` follows the last one
        ends = list(accumulate(sizes[at:], initial=builder.record_writer.count))
        stop = at + min(bisect_right(ends, chunk_size, 1), n - at)
        offsets = ends[:stop - at]
        part = messages[at:stop]
        times = [t for t, _ in part]
        lo, hi = min(times), max(times)
        if builder.num_messages == 0:
            builder.message_start_time = lo
        else:
            builder.message_start_time = min(builder.message_start_time, lo)
        builder.message_end_time = max(builder.message_end_time, hi)
        index = builder.message_indices.get(channel_id)
        if not index:
            index = builder.message_indices[channel_id] = _PackedMessageIndex(channel_id=channel_id, records=[])
        index.records.extend(zip(times, offsets))
        builder.num_messages += len(part)
        builder.record_writer.write(_records(channel_id, times, [body for _, body in part], sizes[at:stop]))
        stats.message_start_time = lo if stats.message_count == 0 else min(stats.message_start_time, lo)
        stats.message_end_time = max(stats.message_end_time, hi)
        stats.channel_message_counts[channel_id] += len(part)
        stats.message_count += len(part)
        at = stop
        if builder.record_writer.count > chunk_size:
            finalize()


__all__ = ["add_messages"]
