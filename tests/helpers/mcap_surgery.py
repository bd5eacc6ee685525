"""Byte surgery on MCAP logs, for the tests (and fuzz/hostile_logs.py) that treat a log as hostile.

Built on the record layout in `bench.log.mcap.records` (opcode u8 | length u64 | body; a chunk
body is start u64 | end u64 | uncompressed size u64 | crc u32 | compression string |
data length u64 | data): find the top-level records, build chunk, message and message
index records, put a crafted chunk in place of a real one, and compress a repeated block
to any size without holding the output (`zstd_bomb`, `lz4_bomb`); copy a log through
`mcap.writer` with its messages and attachments edited (`rewrite`); and the random
mutations of the fuzzing (`mutate`).
"""

from __future__ import annotations

import json
import struct
import zlib

import lz4.frame
import zstandard
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from bench.log.format import CAN_RECORD, HEADER_SIZE, LENGTH_OFFSET
from bench.log.mcap.records import OP_CHUNK, OP_FOOTER, OP_MESSAGE, OP_MESSAGE_INDEX, RECORD_HEAD


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


def rewrite(src, dst, message=None, attachment=None, metadata=None):
    """A copy of log `src` at `dst` through `mcap.writer`, each message's data through
    `message(topic, data) -> data`, each attachment's through `attachment(name, data) -> data` and each
    metadata record's through `metadata(name, dict) -> dict`."""
    with open(src, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        messages = list(reader.iter_messages(log_time_order=False))
        attachments = list(reader.iter_attachments())
        records = list(reader.iter_metadata())
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
        for m in records:
            w.add_metadata(m.name, m.metadata if metadata is None else metadata(m.name, dict(m.metadata)))
        w.finish()
    return dst


# -- mutations (the suite's fuzz test, tests/unit/log/test_log_fuzz.py, and fuzz/hostile_logs.py) ---------

#: Forged values for lengths and sizes: small, around the limits, and the largest a field holds.
FORGED = (0, 1, 7, 21, 255, 1 << 16, 1 << 31, 1 << 32, 1 << 40, (1 << 63) - 1, (1 << 64) - 1)
KINDS = ("truncate", "flip", "record length", "chunk usize", "chunk data length", "chunk compression length",
         "index entry", "can length", "message content")


def _pick(items: list, where: float):
    return items[min(int(where * len(items)), len(items) - 1)]


def _forge_can_length(data: bytes, where: float, value: int) -> bytes:
    """A CAN record's length byte forged inside a chunk holding /can/raw; the chunk rewritten honestly."""
    positions = [pos for pos, op, _ in top_records(data) if op == OP_CHUNK]
    if not positions:
        return data
    pos = _pick(positions, where)
    f = chunk_fields(data, pos)
    try:
        content = bytearray(inflate(f["compression"], f["data"]))
    except Exception:   # the chunk is already damaged by an earlier mutation
        return data
    q, candidates = 0, []
    while q + 31 <= len(content):
        op, length = struct.unpack_from("<BQ", content, q)
        if op == OP_MESSAGE and length >= 22 + HEADER_SIZE:
            candidates.append(q + 9 + 22 + LENGTH_OFFSET)   # the first record's length byte of this message
        q += 9 + length
    if not candidates:
        return data
    content[_pick(candidates, where)] = value
    content = bytes(content)
    packed = {"zstd": lambda b: zstd_bomb(b, len(b)), "lz4": lambda b: lz4_bomb(b, len(b))}.get(f["compression"])
    if packed is None:
        packed = bytes
    chunk = chunk_record(packed(content), f["compression"], len(content), zlib.crc32(content), f["start"], f["end"])
    return replace_chunk(data, pos, chunk, drop_index=False)


_ODD_VALUES = (10 ** 400, "x", [[1, 2, 3]], None, {}, [1e308, -1e308, 1e308], -1, 1 << 64, [], True)


def _forged_payload(payload: bytes, value: int) -> bytes:
    """A message's payload with well-framed but hostile content: for a /can/raw batch, its first record
    claims `value` data bytes (and has them); for a JSON message, each field gets an odd value, or the
    whole message becomes deeply nested arrays or an array."""
    if not payload.startswith(b"{"):
        if len(payload) < HEADER_SIZE:
            return payload
        first = HEADER_SIZE + payload[LENGTH_OFFSET]
        return payload[:LENGTH_OFFSET] + bytes([value]) + bytes(value) + payload[first:]
    if value % 7 == 0:
        return b'{"time_s": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"
    if value % 7 == 1:
        return b"[]"
    try:
        d = json.loads(payload)
    except ValueError:
        return payload
    return json.dumps({k: _ODD_VALUES[(value + i) % len(_ODD_VALUES)] for i, k in enumerate(d)}).encode()


def _forge_message(data: bytes, where: float, value: int) -> bytes:
    """One message inside a chunk replaced by `_forged_payload`; the chunk rewritten honestly (its message
    index, now wrong, kept: the walk falls back to the records)."""
    positions = [pos for pos, op, _ in top_records(data) if op == OP_CHUNK]
    pos = _pick(positions, where)
    f = chunk_fields(data, pos)
    content = inflate(f["compression"], f["data"])
    q, records = 0, []
    while q + 9 <= len(content):
        op, length = struct.unpack_from("<BQ", content, q)
        records.append(content[q:q + 9 + length])
        q += 9 + length
    messages = [k for k, r in enumerate(records) if r[0] == OP_MESSAGE and len(r) >= 31]
    if not messages:
        return data
    k = _pick(messages, (where * 7919) % 1)
    head, payload = records[k][9:31], records[k][31:]
    new = _forged_payload(payload, value)
    records[k] = struct.pack("<BQ", OP_MESSAGE, 22 + len(new)) + head + new
    content = b"".join(records)
    packed = {"zstd": lambda b: zstd_bomb(b, len(b)), "lz4": lambda b: lz4_bomb(b, len(b))}.get(f["compression"], bytes)
    chunk = chunk_record(packed(content), f["compression"], len(content), zlib.crc32(content), f["start"], f["end"])
    return replace_chunk(data, pos, chunk, drop_index=False)


def mutate(data: bytes, kind: str, where: float, value: int, flips: list[tuple[float, int]]) -> bytes:
    """`data` with one mutation of `kind` (one of `KINDS`): `where` in [0, 1) picks the place, `value` the
    forged value, `flips` the (place, xor) of byte flips. Unchanged where an earlier mutation left nothing
    this one can apply to."""
    try:
        return _mutate(data, kind, where, value, flips)
    except (struct.error, UnicodeDecodeError, IndexError, ValueError, ZeroDivisionError):
        return data


def _mutate(data: bytes, kind: str, where: float, value: int, flips: list[tuple[float, int]]) -> bytes:
    buf = bytearray(data)
    records = top_records(data)
    if kind == "truncate":
        return data[:int(where * len(data))]
    if kind == "flip":
        for at, xor in flips:
            buf[min(int(at * len(buf)), len(buf) - 1)] ^= xor
        return bytes(buf)
    if kind == "record length":
        pos = _pick(records, where)[0]
        struct.pack_into("<Q", buf, pos + 1, value)
        return bytes(buf)
    if kind in ("chunk usize", "chunk data length", "chunk compression length"):
        positions = [pos for pos, op, _ in records if op == OP_CHUNK]
        if not positions:
            return data
        f = chunk_fields(data, _pick(positions, where))
        if kind == "chunk usize":
            struct.pack_into("<Q", buf, f["usize_at"], value)
        elif kind == "chunk data length":
            struct.pack_into("<Q", buf, f["dlen_at"], value)
        else:
            struct.pack_into("<I", buf, f["usize_at"] + 12, value & 0xFFFFFFFF)
        return bytes(buf)
    if kind == "index entry":
        indexes = [(pos, length) for pos, op, length in records if op == OP_MESSAGE_INDEX and length >= 22]
        if not indexes:
            return data
        pos, length = _pick(indexes, where)
        entry = min(int(where * 1000) % ((length - 6) // 16), (length - 6) // 16 - 1)
        struct.pack_into("<Q", buf, pos + 9 + 6 + 16 * entry + 8 * (value & 1), value)
        return bytes(buf)
    if kind == "message content":
        return _forge_message(data, where, value & 0xFF)
    return _forge_can_length(data, where, value & 0xFF)


KINDS = ("truncate", "flip", "record length", "chunk usize", "chunk data length", "chunk compression length",
         "index entry", "can length", "message content")
