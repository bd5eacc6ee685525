"""A batch of raw CAN frames as arrays: what a poll of the IMU receiver hands on, in one piece.

A `CanFrameBatch` holds n frames as columns (receive times, ids with the extended-id flag, data bytes,
lengths, flags) so that the decoder, the time-base mapping and the log writer each work on a whole batch
with a few array operations instead of a Python step per frame. It is also a read-only sequence of
python-can `Message`s, built on demand, for a listener that wants frames one by one (an operator's monitor,
a check of the ids on the bus). A bus that can hand its frames over as a batch (`recv_frames`, the
simulator's virtual bus) never builds a `Message` at all; any other bus's messages are turned into a batch
once, in the receiver.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import overload

import can
import numpy as np

from drivers.imu.layout import EXTENDED_ID_FLAG

#: flag bits of a frame (the `/can/raw` log records carry the same bits)
FLAG_FD, FLAG_BRS, FLAG_ESI, FLAG_REMOTE, FLAG_ERROR = 0x01, 0x02, 0x04, 0x08, 0x10
#: the data width that holds any frame (CAN FD: 64 bytes)
FD_WIDTH = 64


def message_flags(m: can.Message) -> int:
    """The flag bits of one python-can message."""
    if not (m.is_fd or m.is_remote_frame or m.is_error_frame or m.error_state_indicator):
        return 0
    return ((FLAG_FD if m.is_fd else 0) | (FLAG_BRS if m.bitrate_switch else 0)
            | (FLAG_ESI if m.error_state_indicator else 0) | (FLAG_REMOTE if m.is_remote_frame else 0)
            | (FLAG_ERROR if m.is_error_frame else 0))


class CanFrameBatch(Sequence[can.Message]):
    """n CAN frames as arrays (never changed after construction; a new batch for any change):

    - `timestamps` (n,) float64: receive time, s
    - `ids` (n,) int64: arbitration id, `EXTENDED_ID_FLAG` set for a 29-bit id
    - `data` (n, width) uint8, C-contiguous, width >= 8: each frame's bytes from column 0, zeros after
    - `lengths` (n,) int64: data bytes of each frame
    - `flags` (n,) uint8: `FLAG_*` bits
    """

    __slots__ = ("timestamps", "ids", "data", "lengths", "flags")

    def __init__(self, timestamps: np.ndarray, ids: np.ndarray, data: np.ndarray, lengths: np.ndarray,
                 flags: np.ndarray | None = None):
        n = len(ids)
        self.timestamps = np.asarray(timestamps, np.float64)
        self.ids = np.asarray(ids, np.int64)
        data = np.asarray(data, np.uint8)
        if data.ndim != 2 or len(data) != n or len(self.timestamps) != n or len(lengths) != n:
            raise ValueError(f"a frame batch needs n timestamps, ids, lengths and (n, width) data; got "
                             f"{len(self.timestamps)}, {n}, {len(lengths)} and {data.shape}")
        if data.shape[1] < 8 or not data.flags.c_contiguous:
            padded = np.zeros((n, max(8, data.shape[1])), np.uint8)
            padded[:, :data.shape[1]] = data
            data = padded
        self.data = data
        self.lengths = np.asarray(lengths, np.int64)
        self.flags = np.zeros(n, np.uint8) if flags is None else np.asarray(flags, np.uint8)

    @classmethod
    def from_messages(cls, messages: Sequence[can.Message]) -> "CanFrameBatch":
        """The batch of python-can `messages` (one pass over them)."""
        if isinstance(messages, CanFrameBatch):
            return messages
        messages = list(messages)
        n = len(messages)
        flag = EXTENDED_ID_FLAG
        ids = np.array([m.arbitration_id | flag if m.is_extended_id else m.arbitration_id for m in messages],
                       np.int64)
        datas = [m.data if m.data is not None else b"" for m in messages]
        sizes = [len(d) for d in datas]
        longest = max(sizes, default=0)
        width = max(8, longest)
        if n and min(sizes) == width:   # every frame as wide as the array (the usual batch): their bytes joined
            buf = bytearray().join(datas)
        else:
            buf = bytearray(n * width)
            for i, d in enumerate(datas):
                buf[i * width:i * width + len(d)] = d
        timestamps = np.array([m.timestamp for m in messages], np.float64)
        flags = np.zeros(n, np.uint8)
        # classic data frames (the usual batch) have no flag: only the others are looked at twice
        for i, m in enumerate(messages):
            if m.is_fd or m.is_remote_frame or m.is_error_frame or m.error_state_indicator:
                flags[i] = message_flags(m)
        return cls(timestamps, ids, np.frombuffer(buf, np.uint8).reshape(n, width), np.array(sizes, np.int64),
                   flags)

    @classmethod
    def concat(cls, batches: Sequence["CanFrameBatch"]) -> "CanFrameBatch":
        """The frames of `batches` in order, as one batch."""
        if len(batches) == 1:
            return batches[0]
        width = max([b.data.shape[1] for b in batches], default=8)
        n = sum(len(b) for b in batches)
        data = np.zeros((n, width), np.uint8)
        at = 0
        for b in batches:
            data[at:at + len(b), :b.data.shape[1]] = b.data
            at += len(b)
        return cls(np.concatenate([b.timestamps for b in batches]) if batches else np.zeros(0),
                   np.concatenate([b.ids for b in batches]) if batches else np.zeros(0, np.int64), data,
                   np.concatenate([b.lengths for b in batches]) if batches else np.zeros(0, np.int64),
                   np.concatenate([b.flags for b in batches]) if batches else np.zeros(0, np.uint8))

    def restamped(self, timestamps: np.ndarray) -> "CanFrameBatch":
        """The same frames with other receive times."""
        return CanFrameBatch(timestamps, self.ids, self.data, self.lengths, self.flags)

    def select(self, rows: np.ndarray | slice) -> "CanFrameBatch":
        """The frames at `rows` (a slice or a boolean/index array), as a batch."""
        return CanFrameBatch(self.timestamps[rows], self.ids[rows], np.ascontiguousarray(self.data[rows]),
                             self.lengths[rows], self.flags[rows])

    def data_frames(self) -> "CanFrameBatch":
        """The frames that carry data (not error or remote frames)."""
        keep = (self.flags & (FLAG_REMOTE | FLAG_ERROR)) == 0
        return self if keep.all() else self.select(keep)

    def decoder_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(ids, data, lengths, timestamps) for the decoders, the data as wide as the longest frame (>= 8)."""
        width = max(8, int(self.lengths.max(initial=0)))
        data = self.data if width == self.data.shape[1] else np.ascontiguousarray(self.data[:, :width])
        return self.ids, data, self.lengths, self.timestamps

    def newest_s(self) -> float:
        """The latest receive time (NaN times left out; -inf for no frame)."""
        t = self.timestamps
        return float(np.fmax.reduce(t, initial=-np.inf))

    # -- the sequence of python-can messages ---------------------------------------------------
    def __len__(self) -> int:
        return len(self.ids)

    def message(self, i: int) -> can.Message:
        """Frame `i` as a python-can `Message`."""
        key, flags, n = int(self.ids[i]), int(self.flags[i]), int(self.lengths[i])
        return can.Message(timestamp=float(self.timestamps[i]), arbitration_id=key & ~EXTENDED_ID_FLAG,
                           is_extended_id=bool(key & EXTENDED_ID_FLAG), is_fd=bool(flags & FLAG_FD),
                           bitrate_switch=bool(flags & FLAG_BRS), error_state_indicator=bool(flags & FLAG_ESI),
                           is_remote_frame=bool(flags & FLAG_REMOTE), is_error_frame=bool(flags & FLAG_ERROR),
                           dlc=n, data=None if flags & FLAG_REMOTE else bytes(self.data[i, :n]),
                           check=False)

    @overload
    def __getitem__(self, i: int) -> can.Message: ...

    @overload
    def __getitem__(self, i: slice) -> "CanFrameBatch": ...

    def __getitem__(self, i):
        if isinstance(i, slice):
            return self.select(i)
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"frame {i} of a batch of {n}")
        return self.message(i % n if n else i)

    def __iter__(self) -> Iterator[can.Message]:
        return (self.message(i) for i in range(len(self)))

    def messages(self) -> list[can.Message]:
        """Every frame as a python-can `Message`."""
        return list(self)

    def __repr__(self) -> str:
        return f"CanFrameBatch({len(self)} frames)"


__all__ = ["FD_WIDTH", "FLAG_BRS", "FLAG_ERROR", "FLAG_ESI", "FLAG_FD", "FLAG_REMOTE", "CanFrameBatch",
           "message_flags"]
