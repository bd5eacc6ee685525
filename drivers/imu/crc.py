"""CRC-8/SAE-J1850 as the IMU frames use it: over the arbitration id, then the data bytes.

Parameters (the catalogue's CRC-8/SAE-J1850): width 8, poly 0x1D, init 0xFF, not
reflected, xorout 0xFF; check value (CRC of b"123456789") 0x4B. The bytes covered are
the arbitration id, big-endian (2 bytes for an 11-bit id, 4 for a 29-bit id), followed
by every data byte except the CRC's own byte, in order. Including the id means a frame
that arrives on the wrong id fails its CRC.

Two evaluation strategies, checked against each other in the tests:
- `crc8` / `crc8_columns`: the textbook table-driven loop (bytewise, or bytewise across
  the columns of a frame array for the bulk decoder);
- `LinearCrc`: the CRC of a fixed-length message is affine in its bits, so it is the
  CRC of the id with zero data XOR one table lookup per 16-bit chunk of the data; the
  live path uses this (4 lookups per classic frame instead of 9 loop turns), and so does
  the bulk decoder, on a uint16 view of the frame array (`LinearCrc.tables_np`).
"""

from __future__ import annotations

import functools

import numpy as np

POLY = 0x1D
INIT = 0xFF
XOROUT = 0xFF
CHECK = 0x4B


def _make_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


TABLE = _make_table()
TABLE_NP = np.array(TABLE, dtype=np.uint8)


def crc8(data: bytes, state: int = INIT) -> int:
    """CRC-8/SAE-J1850 of `data` (`state` lets a caller continue from a prefix's raw state)."""
    table = TABLE
    for b in data:
        state = table[state ^ b]
    return state ^ XOROUT


def crc8_raw(data: bytes, state: int = INIT) -> int:
    """The register after `data`, before the final XOR (to continue with more bytes)."""
    table = TABLE
    for b in data:
        state = table[state ^ b]
    return state


def id_bytes(arbitration_id: int, is_extended_id: bool) -> bytes:
    """The id as the CRC covers it: 2 bytes big-endian (11-bit) or 4 bytes (29-bit)."""
    return arbitration_id.to_bytes(4 if is_extended_id else 2, "big")


def frame_crc(arbitration_id: int, is_extended_id: bool, data: bytes, crc_byte: int) -> int:
    """The CRC a frame must carry in byte `crc_byte` (that byte itself is not covered)."""
    return crc8(id_bytes(arbitration_id, is_extended_id) + bytes(data[:crc_byte]) + bytes(data[crc_byte + 1:]))


def crc8_columns(start: np.ndarray | int, columns: np.ndarray) -> np.ndarray:
    """Bytewise CRC across many frames at once.

    `start`: the raw register per frame (uint8 array or scalar) after the id bytes;
    `columns`: (n, k) uint8, the covered data bytes of each frame in order. Returns the
    (n,) uint8 CRCs after the final XOR.
    """
    n = columns.shape[0]
    state = np.full(n, start, dtype=np.uint8) if np.isscalar(start) else np.asarray(start, dtype=np.uint8).copy()
    for j in range(columns.shape[1]):
        state = TABLE_NP[state ^ columns[:, j]]
    return state ^ np.uint8(XOROUT)


@functools.lru_cache(maxsize=None)
def linear_crc(length: int, crc_byte: int) -> "LinearCrc":
    """The (shared, immutable) `LinearCrc` tables of one frame shape."""
    return LinearCrc(length, crc_byte)


class LinearCrc:
    """Chunk tables for frames of `length` bytes whose CRC sits in byte `crc_byte`.

    `check(v, id_state)`: `v` is the frame's data as a little-endian int; returns the CRC
    the frame must carry. `id_state` is `id_constant(...)` for the frame's id.
    """

    def __init__(self, length: int, crc_byte: int):
        if not 0 <= crc_byte < length:
            raise ValueError(f"CRC byte {crc_byte} outside a {length}-byte frame")
        self.length, self.crc_byte = length, crc_byte
        chunk_bits = 16 if length <= 8 else 8
        n_values = 1 << chunk_bits
        values = np.arange(n_values, dtype=np.int64)
        keep = [j for j in range(length) if j != crc_byte]
        zero_crc = crc8(bytes(length - 1))
        chunks: list[tuple[int, int, list[int]]] = []   # (first bit, index mask, CRC table)
        for first_bit in range(0, 8 * length, chunk_bits):
            data = np.zeros((n_values, length), dtype=np.uint8)
            for b in range(chunk_bits // 8):
                j = first_bit // 8 + b
                if j < length:
                    data[:, j] = (values >> (8 * b)) & 0xFF
            # A chunk that holds only the CRC byte contributes nothing: skip it.
            if all(first_bit // 8 + b == crc_byte or first_bit // 8 + b >= length for b in range(chunk_bits // 8)):
                continue
            table = crc8_columns(INIT, data[:, keep]) ^ np.uint8(zero_crc)
            chunks.append((first_bit, n_values - 1, table.tolist()))
        self.chunks = tuple(chunks)
        self._zero_crc = zero_crc
        self._keep = keep

    @functools.cached_property
    def tables_np(self) -> tuple[tuple[int, np.ndarray], ...]:
        """The chunk tables as (first bit, uint8 array) for whole-array lookups (the bulk decoder)."""
        return tuple((shift, np.array(table, dtype=np.uint8)) for shift, _, table in self.chunks)

    @property
    def chunk_bits(self) -> int:
        """Width of one table's index: 16 bits for frames of up to 8 bytes, else 8."""
        return 16 if self.length <= 8 else 8

    def id_constant(self, arbitration_id: int, is_extended_id: bool) -> int:
        """CRC of the id followed by zero data bytes (the affine part of every frame's CRC)."""
        return crc8(id_bytes(arbitration_id, is_extended_id) + bytes(self.length - 1))

    def compute(self, v: int, id_constant: int) -> int:
        crc = id_constant
        for shift, mask, table in self.chunks:
            crc ^= table[(v >> shift) & mask]
        return crc
