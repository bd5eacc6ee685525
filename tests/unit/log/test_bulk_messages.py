"""`add_messages` writes the file `Writer.add_message` writes, byte for byte, whatever the chunk cuts."""

from __future__ import annotations

import io

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from bench.log import bulk_messages
from bench.log.bulk_messages import add_messages


def _messages(n: int, seed: int) -> list[tuple[int, bytes]]:
    import random

    rng = random.Random(seed)
    # times not in order (a block's receive times can step back), bodies of many sizes
    return [(rng.randrange(0, 10**12), bytes(rng.randrange(256) for _ in range(rng.randrange(0, 300))))
            for _ in range(n)]


def _write(batches: list[list[tuple[int, bytes]]], bulk: bool, chunk_size: int) -> bytes:
    out = io.BytesIO()
    writer = Writer(out, chunk_size=chunk_size, compression=CompressionType.NONE)
    writer.start()
    schema = writer.register_schema("s", "jsonschema", b"{}")
    channels = [writer.register_channel(f"/t{k}", "json", schema) for k in range(2)]
    for k, batch in enumerate(batches):
        channel = channels[k % 2]
        if bulk:
            add_messages(writer, channel, batch)
        else:
            for t, body in batch:
                writer.add_message(channel, t, body, t)
        if k % 3 == 2:
            writer.flush()
    writer.finish()
    return out.getvalue()


@pytest.mark.parametrize("chunk_size", [1, 500, 4096, 1 << 20])
def test_bulk_writes_the_same_bytes(chunk_size):
    batches = [_messages(n, seed) for seed, n in enumerate([0, 1, 7, 40, 3, 120, 1])]
    bulk = _write(batches, True, chunk_size)
    assert bulk == _write(batches, False, chunk_size)
    read = [(m.log_time, m.data) for _, _, m in make_reader(io.BytesIO(bulk)).iter_messages(log_time_order=False)]
    assert read == [m for batch in batches for m in batch]


def test_a_writer_kept_differently_gets_messages_one_by_one(monkeypatch):
    monkeypatch.setattr(bulk_messages, "_state", lambda writer: None)
    batches = [_messages(30, 1), _messages(5, 2)]
    assert _write(batches, True, 700) == _write(batches, False, 700)


@pytest.mark.parametrize("chunk_size", [1, 700, 1 << 20])
def test_interleaved_channels_write_the_same_bytes(chunk_size):
    """Messages of two channels in one call (`bench apply`'s raw and compensated samples, one after the other)."""
    import numpy as np

    from bench.log.bulk_messages import add_message_arrays

    messages = _messages(90, 5)
    files = []
    for bulk in (True, False):
        out = io.BytesIO()
        writer = Writer(out, chunk_size=chunk_size, compression=CompressionType.NONE)
        writer.start()
        schema = writer.register_schema("s", "jsonschema", b"{}")
        ids = [writer.register_channel(f"/t{k}", "json", schema) for k in range(3)]
        # the third channel first appears mid-way: its message index comes after the others' in that chunk
        channels = np.array([ids[2] if 40 <= k < 45 else ids[k % 2] for k in range(len(messages))])
        if bulk:
            add_message_arrays(writer, channels, np.array([t for t, _ in messages], np.uint64),
                               [body for _, body in messages])
        else:
            for channel, (t, body) in zip(channels.tolist(), messages):
                writer.add_message(channel, t, body, t)
        writer.finish()
        files.append(out.getvalue())
    assert files[0] == files[1]


def test_bulk_and_single_messages_mixed_on_one_channel_write_the_same_bytes():
    """Entries added in bulk stay arrays until written; one `add_message` in between keeps its place."""
    batches = [_messages(20, 7), _messages(3, 8), _messages(15, 9), _messages(2, 10)]
    files = []
    for mixed in (True, False):
        out = io.BytesIO()
        writer = Writer(out, chunk_size=1 << 20, compression=CompressionType.NONE)
        writer.start()
        channel = writer.register_channel("/t", "json", writer.register_schema("s", "jsonschema", b"{}"))
        for k, batch in enumerate(batches):
            if mixed and k % 2 == 0:
                add_messages(writer, channel, batch)
            else:
                for t, body in batch:
                    writer.add_message(channel, t, body, t)
        writer.finish()
        files.append(out.getvalue())
    assert files[0] == files[1]
