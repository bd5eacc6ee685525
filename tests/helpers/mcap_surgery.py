"""Byte surgery on MCAP logs, for the tests (and tests/fuzz/hostile_logs.py) that treat a log as hostile.

Built on the record layout in `bench.log.chunks` (opcode u8 | length u64 | body; a chunk
body is start u64 | end u64 | uncompressed size u64 | crc u32 | compression string |
data length u64 | data): find the top-level records, build chunk, message and message
index records, put a crafted chunk in place of a real one, and compress a repeated block
to any size without holding the output (`zstd_bomb`, `lz4_bomb`); copy a log through
`mcap.writer` with its messages and attachments edited (`rewrite`).
"""

from __future__ import annotations

import struct

import lz4.frame
import zstandard
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from bench.log.chunks import OP_CHUNK, OP_FOOTER, OP_MESSAGE, OP_MESSAGE_INDEX, RECORD_HEAD
from bench.log.format import CAN_RECORD


def top_records(buf: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, body length) of every top-level record, up to the footer or the first that overruns."""
    pos, out = 8, []
    while pos + 9 <= len(buf):
        op, length = RECORD_HEAD.unpack_from(buf, pos)
        out.append((pos, op, length))
        if op == OP_FOOTER or pos + 9 + length > len(buf):
            break
        pos += 9 + length
    return out


def chunks(buf: bytes) -> list[int]:
    """Offsets of the chunk records."""
    return [pos for pos, op, _ in top_records(buf) if op == OP_CHUNK]


def chunk_fields(buf: bytes, pos: int) -> dict:
    """The fields of the chunk record at `pos`, and where the uncompressed size and data length sit."""
    body = pos + 9
    start, end, usize, crc, clen = struct.unpack_from("<QQQII", buf, body)
    compression = buf[body + 32:body + 32 + clen].decode()
    (dlen,) = struct.unpack_from("<Q", buf, body + 32 + clen)
    return {"start": start, "end": end, "usize": usize, "crc": crc, "compression": compression,
            "data": buf[body + 40 + clen:body + 40 + clen + dlen], "usize_at": body + 16, "dlen_at": body + 32 + clen}


def inflate(compression: str, data: bytes) -> bytes:
    """A chunk's data decompressed with the libraries themselves (for honest rewrites)."""
    if compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(data)
    if compression == "lz4":
        return lz4.frame.decompress(data)
    return data


def chunk_record(data: bytes, compression: str, usize: int, crc: int = 0, start: int = 0, end: int = 0) -> bytes:
    """A chunk record holding `data` (already compressed) and declaring `usize` bytes uncompressed."""
    c = compression.encode()
    body = struct.pack("<QQQII", start, end, usize, crc, len(c)) + c + struct.pack("<Q", len(data)) + data
    return RECORD_HEAD.pack(OP_CHUNK, len(body)) + body


def message_record(channel: int, payload: bytes, log_time: int = 1_000_000_000, sequence: int = 0) -> bytes:
    head = struct.pack("<HIQQ", channel, sequence, log_time, log_time)
    return RECORD_HEAD.pack(OP_MESSAGE, 22 + len(payload)) + head + payload


def message_index(channel: int, entries: list[tuple[int, int]]) -> bytes:
    """A message index record: (log time, offset in the chunk's data) per message."""
    body = struct.pack("<HI", channel, 16 * len(entries)) + b"".join(struct.pack("<QQ", t, o) for t, o in entries)
    return RECORD_HEAD.pack(OP_MESSAGE_INDEX, len(body)) + body


def replace_chunk(buf: bytes, pos: int, new: bytes, *, drop_index: bool = True) -> bytes:
    """`buf` with the chunk record at `pos` replaced by `new` (and the message index records after it
    dropped, unless `drop_index` is False)."""
    _, length = RECORD_HEAD.unpack_from(buf, pos)
    end = pos + 9 + length
    while drop_index and end + 9 <= len(buf) and buf[end] == OP_MESSAGE_INDEX:
        end += 9 + RECORD_HEAD.unpack_from(buf, end)[1]
    return buf[:pos] + new + buf[end:]


def can_frames(n: int = 1, length: int = 8, can_id: int = 0x100, t: float = 1.0) -> bytes:
    """`n` raw CAN records (`can-frames-v1`) of `length` zero data bytes each (the length byte as given)."""
    return (CAN_RECORD.pack(t, can_id, 0, length) + bytes(length)) * n


def _repeat(block: bytes, total: int):
    big = block * max(1, (1 << 20) // len(block))
    left = total
    while left > 0:
        piece = big[:left] if left < len(big) else big
        yield piece
        left -= len(piece)


def zstd_bomb(block: bytes, total: int, *, content_size: bool = True) -> bytes:
    """One zstd frame of `block` repeated to `total` bytes (stating `total` in its header unless told not)."""
    cobj = zstandard.ZstdCompressor(level=3, write_content_size=content_size).compressobj(
        size=total if content_size else -1)
    return b"".join([cobj.compress(piece) for piece in _repeat(block, total)] + [cobj.flush()])


def lz4_bomb(block: bytes, total: int, *, content_size: bool = True) -> bytes:
    """One lz4 frame of `block` repeated to `total` bytes."""
    comp = lz4.frame.LZ4FrameCompressor()
    out = [comp.begin(source_size=total if content_size else 0)]   # 0: the frame states no size
    out += [comp.compress(piece) for piece in _repeat(block, total)]
    return b"".join(out + [comp.flush()])


def rewrite(src, dst, message=None, attachment=None):
    """A copy of log `src` at `dst` through `mcap.writer`, each message's data through
    `message(topic, data) -> data` and each attachment's through `attachment(name, data) -> data`."""
    with open(src, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        messages = list(reader.iter_messages(log_time_order=False))
        attachments = list(reader.iter_attachments())
        metadata = list(reader.iter_metadata())
    with open(dst, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="", library="tests/helpers/mcap_surgery.py")
        schemas = {s.id: w.register_schema(s.name, s.encoding, s.data) for s in summary.schemas.values()}
        channels = {c.id: w.register_channel(c.topic, c.message_encoding, schemas.get(c.schema_id, 0), c.metadata)
                    for c in summary.channels.values()}
        for _, channel, m in messages:
            data = m.data if message is None else message(channel.topic, m.data)
            w.add_message(channels[channel.id], m.log_time, data, m.publish_time, m.sequence)
        for a in attachments:
            data = a.data if attachment is None else attachment(a.name, a.data)
            w.add_attachment(a.log_time, a.create_time, a.name, a.media_type, data)
        for m in metadata:
            w.add_metadata(m.name, m.metadata)
        w.finish()
    return dst
