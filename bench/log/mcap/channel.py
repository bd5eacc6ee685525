"""One channel's messages as a walk gathers them: a part per chunk (`bench.log.mcap.parts`), their payload
lengths and log times."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from bench.log.mcap.chunks import ChunkRefused, DeferredChunk, InflateBudget, inflated_or_refusal
from bench.log.mcap.damage import Damage
from bench.log.mcap.parts import NOT_INFLATED, Joined, Part
from bench.log.threads import reader_threads


@dataclass
class ChannelData:
    """Messages of one channel in file order: one `Part` per chunk, their payload lengths and log times.

    A part in memory is `Joined` or `InChunk`; a `DeferredChunk` part (walked with `defer_topics`) is still
    compressed and unchecked: `inflate_deferred` decompresses and checks those, and says what it had to drop.
    A reader streaming the parts may put None where a part's chunk failed (`bench.log.reader`).
    """

    parts: list = field(default_factory=list)      # a `Part` per chunk (None: dropped)
    lengths: list = field(default_factory=list)    # int64 arrays, payload lengths, one per part
    log_times: list = field(default_factory=list)  # uint64 arrays, log times (ns), one per part
    not_kept: int = 0       # messages counted, not kept: a topic the walk was not asked to keep
    over_limit: int = 0     # messages counted, not kept: past the walk's limit for the topic

    def add(self, part: Part, lengths, log_times) -> None:
        self.parts.append(part)
        self.lengths.append(np.asarray(lengths, np.int64))
        self.log_times.append(np.asarray(log_times, np.uint64))

    def __len__(self) -> int:
        return sum(len(x) for x in self.lengths)

    @property
    def log_time_ns(self) -> np.ndarray:
        return np.concatenate(self.log_times) if self.log_times else np.zeros(0, np.uint64)

    @property
    def deferred_chunks(self) -> int:
        """Parts still compressed and unchecked."""
        return sum(p.compressed for p in self.parts if p is not None)

    def inflate_deferred(self, topic: str, budget: InflateBudget | None = None) -> list[Damage]:
        """Decompress and check the deferred parts (on worker threads); a part that fails, or does not fit
        what is left of the log's `budget`, is dropped and told as a `Damage` (its messages lost, on `topic`)."""
        todo = [k for k, p in enumerate(self.parts) if p is not None and p.compressed]
        if not todo:
            return []
        chunks: list[DeferredChunk] = [self.parts[k] for k in todo]
        refused: dict[int, ChunkRefused] = {}
        for k, c in zip(todo, chunks):
            if budget is None:
                break
            try:
                budget.take(c.size)
            except ChunkRefused as exc:
                refused[k] = exc
        inflate = [c for k, c in zip(todo, chunks) if k not in refused]
        threads = reader_threads()
        if len(inflate) >= 3 and threads > 1:
            with ThreadPoolExecutor(threads, thread_name_prefix="mcap-inflate") as pool:
                answers = iter(list(pool.map(inflated_or_refusal, inflate)))
        else:
            answers = iter([inflated_or_refusal(c) for c in inflate])
        damage, dropped = [], set()
        for k, chunk in zip(todo, chunks):
            answer = refused.get(k) or next(answers)
            if isinstance(answer, ChunkRefused):
                damage.append(Damage("chunk", chunk.offset, str(answer), chunk.start_ns, chunk.end_ns,
                                     {topic: len(chunk.offsets)}))
                dropped.add(k)
            else:
                self.parts[k] = answer
        if dropped:
            keep = [k for k in range(len(self.parts)) if k not in dropped]
            self.parts, self.lengths, self.log_times = ([x[k] for k in keep] for x in
                                                        (self.parts, self.lengths, self.log_times))
        return damage

    def _gathered(self) -> list[Joined]:
        """Every part joined (kept so)."""
        if self.deferred_chunks:
            raise RuntimeError(NOT_INFLATED)
        for k, part in enumerate(self.parts):
            if not isinstance(part, Joined):
                self.parts[k] = Joined(part.joined(self.lengths[k]))
        return self.parts

    def payloads(self, limit: int | None = None) -> list[bytes]:
        """One bytes per message (the first `limit` messages only, when given: see `keep_first`)."""
        if limit is not None:
            self.keep_first(limit)
        out: list[bytes] = []
        for part, lengths in zip(self._gathered(), self.lengths):
            out += _split(part.data, lengths)
        return out

    def keep_first(self, limit: int) -> int:
        """Keep the first `limit` messages only (the parts after them are dropped unread); how many went."""
        dropped, seen = 0, 0
        for k, lengths in enumerate(self.lengths):
            if seen + len(lengths) > limit:
                keep = limit - seen
                dropped = len(self) - limit
                self.parts = self.parts[:k] + [self.parts[k].head(keep, lengths)]
                self.lengths = self.lengths[:k] + [lengths[:keep]]
                self.log_times = self.log_times[:k] + [self.log_times[k][:keep]]
                break
            seen += len(lengths)
        return dropped

    def part_bytes(self, k: int) -> bytes:
        """Part `k`'s payloads back to back, without keeping them (for one pass over a large channel:
        the parts in their chunk stay there)."""
        return self.parts[k].joined(self.lengths[k])

    def first_byte(self, k: int, offset: int) -> int:
        """Byte `offset` of part `k`'s payloads back to back (without joining them)."""
        return self.parts[k].byte_at(offset, self.lengths[k])

    def part_payloads(self, k: int) -> list[bytes]:
        """Part `k`'s payloads, one bytes per message."""
        return _split(self.part_bytes(k), self.lengths[k])

    def release(self, k: int) -> None:
        """Let part `k`'s payloads go (read once and not needed again: the chunk they point into can be freed)."""
        self.parts[k] = Joined(b"")

    def compact(self) -> None:
        """Join the parts' payloads now: the decompressed chunks they point into can then be freed."""
        self._gathered()

    def joined_parts(self) -> Iterator[bytes]:
        """`part_bytes` of every part, in order."""
        for k in range(len(self.parts)):
            yield self.part_bytes(k)

    def joined(self) -> bytes:
        """All payloads back to back."""
        parts = self._gathered()
        return parts[0].data if len(parts) == 1 else b"".join(p.data for p in parts)


def _split(joined: bytes, lengths: np.ndarray) -> list[bytes]:
    """Payloads back to back, one bytes each."""
    ends = np.cumsum(lengths).tolist()
    return [joined[e - n:e] for e, n in zip(ends, lengths.tolist())]
