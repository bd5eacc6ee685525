"""Where one channel's messages of one chunk are held: the `Part` protocol and the parts held in memory.

A walk gathers each channel's messages chunk by chunk (`bench.log.mcap.channel.ChannelData`); each chunk's
messages are one part, with their payload lengths and log times kept beside it. A part is one of:
- `Joined`: the payloads back to back (copied out of their chunk, or the messages outside chunks);
- `InChunk`: the decompressed chunk and where its payloads start in it (nothing copied until used: most
  readers never touch the high-rate JSON topics; the chunk stays in memory while the part lives);
- `bench.log.mcap.chunks.DeferredChunk` (and its `ChunkSlice`): still compressed and unchecked, or left in
  the file; `inflated()` decompresses and checks it (`ChunkRefused` if it fails) and gives an `InChunk`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

NOT_INFLATED = "inflate_deferred() first: this channel has deferred chunks"


class Part(Protocol):
    """One channel's messages of one chunk; `lengths` (their payload lengths) is kept beside the part."""

    #: still compressed (and unchecked): `inflated()` first, the other methods raise RuntimeError
    compressed: bool

    def inflated(self) -> Part:
        """The part with its payloads in memory (itself when they are): `ChunkRefused` if its chunk fails."""
        ...

    def located(self, lengths: np.ndarray) -> tuple[bytes, np.ndarray]:
        """(a buffer, where each payload starts in it)."""
        ...

    def joined(self, lengths: np.ndarray) -> bytes:
        """The payloads back to back (a copy unless they already are)."""
        ...

    def head(self, count: int, lengths: np.ndarray) -> Part:
        """The part of its first `count` messages."""
        ...

    def byte_at(self, offset: int, lengths: np.ndarray) -> int:
        """Byte `offset` of the payloads back to back (without joining them)."""
        ...

    def declared_bytes(self, lengths: np.ndarray) -> int:
        """What it takes in memory once inflated (a deferred chunk: its declared uncompressed size)."""
        ...


class Joined:
    """Payloads back to back."""

    compressed = False

    def __init__(self, data: bytes):
        self.data = data

    def inflated(self) -> Joined:
        return self

    def located(self, lengths: np.ndarray) -> tuple[bytes, np.ndarray]:
        return self.data, np.cumsum(lengths) - lengths

    def joined(self, lengths: np.ndarray) -> bytes:
        return self.data

    def head(self, count: int, lengths: np.ndarray) -> Joined:
        return Joined(self.data[:int(lengths[:count].sum())])

    def byte_at(self, offset: int, lengths: np.ndarray) -> int:
        return self.data[offset]

    def declared_bytes(self, lengths: np.ndarray) -> int:
        return int(lengths.sum())


class InChunk:
    """Payloads where they lie in a decompressed chunk (`data`), starting at `starts`."""

    compressed = False

    def __init__(self, data: bytes, starts: np.ndarray):
        self.data, self.starts = data, starts

    def inflated(self) -> InChunk:
        return self

    def located(self, lengths: np.ndarray) -> tuple[bytes, np.ndarray]:
        return self.data, self.starts

    def joined(self, lengths: np.ndarray) -> bytes:
        return gather(self.data, self.starts, lengths)

    def head(self, count: int, lengths: np.ndarray) -> InChunk:
        return InChunk(self.data, self.starts[:count])

    def byte_at(self, offset: int, lengths: np.ndarray) -> int:
        i = int(np.searchsorted(np.cumsum(lengths), offset, side="right"))
        before = int(lengths[:i].sum())
        return self.data[int(self.starts[i]) + offset - before]

    def declared_bytes(self, lengths: np.ndarray) -> int:
        return int(lengths.sum())


def gather(data: bytes, starts: np.ndarray, lengths: np.ndarray) -> bytes:
    """The payloads at `starts` (of `lengths`) in `data`, back to back. Payloads of one length at one stride
    (a chunk of equal messages: what bulk frames and bombs look like) are copied as one strided array; the
    others one slice each."""
    n = len(starts)
    if n > 1:
        length, stride = int(lengths[0]), int(starts[1] - starts[0])
        if (stride >= length > 0 and (lengths == length).all()
                and (np.diff(starts) == stride).all() and int(starts[-1]) + length <= len(data)):
            return np.ndarray((n, length), np.uint8, data, int(starts[0]), (stride, 1)).tobytes()
    whole = memoryview(data)
    return b"".join([whole[a:b] for a, b in zip(starts.tolist(), (starts + lengths).tolist())])


@dataclass(frozen=True)
class MessageCut:
    """Messages of `topics` longer than `max_bytes` go through `shrink(payload) -> payload` as they are gathered,
    one at a time, before anything holds them all (a JSON message with a 1 MB text, kept by the thousand, would
    be parsed in bulk later)."""

    topics: frozenset[str]
    max_bytes: int
    shrink: Callable[[bytes], bytes]

    def apply(self, data, starts: np.ndarray, lengths: np.ndarray) -> tuple[bytes, np.ndarray, np.ndarray]:
        """The payloads at `starts` (of `lengths`) in `data`, the long ones shrunk, back to back: (joined,
        their starts, their lengths)."""
        whole = memoryview(data)
        payloads = [bytes(whole[a:a + n]) if n <= self.max_bytes else self.shrink(bytes(whole[a:a + n]))
                    for a, n in zip(starts.tolist(), lengths.tolist())]
        new_lengths = np.array([len(p) for p in payloads], np.int64)
        new_starts = np.concatenate([[0], np.cumsum(new_lengths)[:-1]]).astype(np.int64)
        return b"".join(payloads), new_starts, new_lengths
