"""The stream decoder: frames in pieces, samples out, in bounded memory (a log chunk by chunk, the live
receiver poll by poll).

`StreamDecoder.feed(...)` takes the next frames in arrival order (the arrays
`decode_frames` takes) and `finish()` ends the stream: the samples and counts are exactly
those of `decode_frames` given all the frames at once (the tests hold the two to that),
whatever the cuts; the rules are in `drivers.imu.rules`. The state carried from piece to
piece is small: the last counter seen (for unwrapping), the reorder head, the first
counter, and the accepted frames of the counters still inside the reorder window (at most
`reorder_window` x messages frames once duplicates are dropped). A counter at or below
head - window can receive no more frames (a frame that old is late), so its sample is
final and emitted; so is a complete sample with every older counter resolved (a live
consumer gets each sample as soon as it can be had: a later frame of it is a duplicate).
`flush()` resolves everything pending without ending the stream (the end of a recording
on a bus that stays open); `finish()` ends it.
"""

from __future__ import annotations

import numpy as np

from drivers.errors import ImuFrameError
from drivers.imu.layout import ImuLayout, default_layout
from drivers.imu.numbering import FrameNumberer
from drivers.imu.rules import FrameScreen, SampleColumns, as_arrays, extract, unwrap_steps
from drivers.imu.samples import ImuSampleBlock, ImuStats


class StreamDecoder:
    """Decode frames given piece by piece; `samples()` after `finish()` is `decode_frames`' block."""

    def __init__(self, layout: ImuLayout | None = None, rate_hz: float = 1000.0, reorder_window: int = 8):
        if not (isinstance(reorder_window, int) and reorder_window >= 1):
            raise ImuFrameError(f"reorder_window must be a positive integer, got {reorder_window!r}")
        self.layout = layout if layout is not None else default_layout()
        # a time-stamped layout (sbg-ecan): frames numbered first, then decoded with the numbered layout
        self._numberer = FrameNumberer(self.layout, rate_hz) if self.layout.time_stamp is not None else None
        if self._numberer is not None:
            self.layout = self._numberer.numbered_layout
        self.rate_hz = float(rate_hz)
        self.window = reorder_window
        self._screen = FrameScreen(self.layout)
        self._columns = SampleColumns(self.layout)
        self.stats = ImuStats()
        self._blocks: list[ImuSampleBlock] = []
        self._c_last: np.ndarray | None = None   # the last valid frame's raw counter (1 element, its dtype)
        self._u_last = self._head = self._u0 = self._next = 0
        self._start = 0           # frames of counters below it are late: the first counter; after a flush, head + 1
        self._left = False        # a flush counted a sample left mid-sample: frames after it make it lost
        # accepted frames of counters not resolved yet: data rows, times, counters, messages, heads at arrival
        self._pending: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._finished = False
        self._counters_seen = 0   # counters with a frame, resolved so far

    def feed(self, ids, data, lengths=None, timestamps=None) -> None:
        """The next frames, in arrival order (arrays as `decode_frames` takes them)."""
        if self._finished:
            raise ImuFrameError("this stream is finished")
        ids, data, lengths, timestamps = as_arrays(ids, data, lengths, timestamps)
        if self._numberer is not None:
            before = self._numberer.before_start
            ids, data, lengths, timestamps = self._numberer.arrays(ids, data, lengths, timestamps)
            late = self._numberer.before_start - before
            self.stats.frames += late
            self.stats.late += late
        n, stats, layout = len(ids), self.stats, self.layout
        stats.frames += n
        if not n:
            return
        if self._left:   # the stream went on after a flush: the sample it cut was lost after all
            self._left = False
            stats.left_mid_sample -= 1
            stats.incomplete_samples += 1
        msg_index, valid, n_known, n_length_ok = self._screen.screen(ids, data, lengths)
        stats.unknown_id += n - n_known
        stats.wrong_length += n_known - n_length_ok
        n_valid = int(np.count_nonzero(valid))
        stats.crc_errors += n_length_ok - n_valid
        if not n_valid:
            return
        vi = None if n_valid == n else valid.nonzero()[0]
        c = self._screen.counters(data, msg_index, valid, vi)
        first = self._c_last is None
        if first:
            self._u_last = self._head = self._u0 = self._next = self._start = int(c[0])
            self._c_last = np.asarray(c[:1]).copy()
        d = unwrap_steps(np.concatenate([np.asarray(self._c_last, dtype=c.dtype), c]), layout.counter_bits)
        u = np.add.accumulate(d, dtype=np.int64)   # (np.cumsum: the same, with more overhead)
        u += self._u_last
        self._c_last = np.asarray(c[-1:]).copy()
        self._u_last = int(u[-1])
        if int(np.minimum.reduce(d)) >= 0 and int(u[0]) >= max(self._head, self._start, self._next):
            # counters never going back, from the head on (the usual piece): none late, out of order or of an
            # emitted sample, and each frame's head is its own counter
            self._head = self._u_last
            stats.frames_ok += n_valid
            if vi is None:
                new = (data, timestamps, u, msg_index.astype(np.int64), u)
            else:
                new = (np.ascontiguousarray(data[vi]), timestamps[vi], u, msg_index[vi].astype(np.int64), u)
        else:
            new = self._accepted(data, timestamps, msg_index, vi, u)
        if self._pending is not None:
            waiting = self._pending
            if waiting[0].shape[1] != new[0].shape[1]:
                # pieces as wide as their longest frame (a log or bus mixing 8- and 64-byte frames): the
                # narrower data padded with zeros, past every used frame's length
                width = max(waiting[0].shape[1], new[0].shape[1])
                waiting, new = (_widened(waiting[0], width), *waiting[1:]), (_widened(new[0], width), *new[1:])
            new = tuple(np.concatenate([p, q]) for p, q in zip(waiting, new))   # type: ignore[assignment]
        self._pending = new
        self._resolve(self._complete_through(self._head - self.window))

    def _accepted(self, data, timestamps, msg_index, vi, u):
        """Rule 3 for a piece's valid frames (`vi`: their rows, None for all; `u`: their unwrapped counters):
        the frames used, as (data rows, times, counters, messages, heads at arrival); late frames and
        frames of samples emitted already counted."""
        stats, n, n_valid = self.stats, len(data), len(u)
        head = np.maximum.accumulate(u)
        np.maximum(head, self._head, out=head)
        self._head = int(head[-1])
        accepted = (u > head - self.window) & (u >= self._start)
        n_accepted = int(np.count_nonzero(accepted))
        stats.late += n_valid - n_accepted
        emitted = accepted & (u < self._next)   # a frame of a sample emitted complete already
        if np.count_nonzero(emitted):
            n_emitted = int(np.count_nonzero(emitted))
            stats.duplicates += n_emitted
            n_accepted -= n_emitted
            accepted &= ~emitted
        # counted at arrival, as used (a duplicate found among them later is taken back off by `_dedupe`)
        stats.frames_ok += n_accepted
        stats.out_of_order += int(np.count_nonzero(accepted & (u < head)))
        if vi is None and n_accepted == n:   # every frame good and in time: no gathers
            return data, timestamps, u, msg_index.astype(np.int64), head
        rows = accepted.nonzero()[0] if vi is None else vi[accepted]
        return (np.ascontiguousarray(data[rows]), timestamps[rows], u[accepted], msg_index[rows].astype(np.int64),
                head[accepted])

    def flush(self) -> None:
        """Resolve every pending counter as at the end of the stream, which goes on: later frames of the
        counters resolved are late, and a sample counted as left mid-sample becomes an incomplete one when
        more frames come."""
        if self._finished:
            raise ImuFrameError("this stream is finished")
        if self._c_last is not None:
            self._resolve(self._head, final=True)
            self._start = self._head + 1

    def finish(self) -> tuple[ImuSampleBlock, ImuStats]:
        """End of the stream: every counter up to the newest is resolved; the samples and the counts."""
        if not self._finished:
            self.flush()
            self._finished = True
        return self.samples(), self.stats

    def take_block(self) -> ImuSampleBlock:
        """The samples resolved since the last take, in counter order, as one block (possibly empty)."""
        blocks = self.take()
        if len(blocks) == 1:
            return blocks[0]
        return ImuSampleBlock.concatenate(blocks, self.rate_hz) if blocks else ImuSampleBlock.empty(self.rate_hz)

    def take(self) -> list[ImuSampleBlock]:
        """The blocks of samples resolved since the last `take`, in counter order, handed over and forgotten
        (a consumer that takes after every `feed` holds the samples one piece at a time; `samples()` and
        `finish()` then give only what was resolved since)."""
        blocks, self._blocks = self._blocks, []
        return blocks

    def samples(self) -> ImuSampleBlock:
        """The samples resolved so far (since the last `take`), in counter order."""
        if len(self._blocks) > 1:
            self._blocks = [ImuSampleBlock.concatenate(self._blocks)]
        return self._blocks[0] if self._blocks else ImuSampleBlock.empty(self.rate_hz)

    def _resolve(self, cutoff: int, final: bool = False) -> None:
        """Emit the samples of the counters from `_next` up to `cutoff` (inclusive); keep the rest pending."""
        if self._pending is None:
            return
        if cutoff < self._next:   # nothing final yet: what waits is kept at one frame per (counter, message)
            self._pending = self._dedupe(*self._pending)
            return
        data, t, u, k, h = self._pending
        now = u <= cutoff
        n_now = int(np.count_nonzero(now))
        if n_now == len(u):   # everything waiting resolves (a live poll of whole samples)
            self._pending = None
        elif np.count_nonzero(now[:n_now]) == n_now:   # the usual case, the final counters first: slices, not gathers
            rest = tuple(a[n_now:].copy() for a in self._pending)   # (small: copied, the piece may go)
            data, t, u, k, h = (a[:n_now] for a in self._pending)
            self._pending = self._dedupe(*rest)
        else:
            later = ~now
            rest = tuple(a[later] for a in self._pending)
            data, t, u, k, h = data[now], t[now], u[now], k[now], h[now]
            self._pending = self._dedupe(*rest) if len(rest[2]) else None
        du = u[1:] - u[:-1]
        # in order: a counter's frames are consecutive and in message order, so nothing repeats
        in_order = np.count_nonzero((du > 0) | ((du == 0) & (k[1:] > k[:-1]))) == len(du)
        if not in_order:
            data, t, u, k, h = self._dedupe(data, t, u, k, h)
        stats, n_msgs = self.stats, len(self.layout.messages)
        lo, self._next = self._next, cutoff + 1
        if not len(u):
            stats.counter_gaps += cutoff - lo + 1
            return
        if in_order:
            steps = du.nonzero()[0]
            bounds = np.empty(len(steps) + 2, np.int64)   # each counter's first frame, then the end
            bounds[0], bounds[-1] = 0, len(u)
            np.add(steps, 1, out=bounds[1:-1])
            starts = bounds[:-1]
            counters = u[starts]
            present = bounds[1:] - starts
            complete = present == n_msgs
            firsts = starts[complete]
            if len(firsts) * n_msgs == len(u):   # every sample complete, frames in order: strided views, no gathers
                block = self._columns.block(data, None, counters.copy(), t[n_msgs - 1::n_msgs].copy(), self.rate_hz)
            else:
                def frames_of(m):
                    return firsts + m
                last = t[firsts + n_msgs - 1] if len(firsts) else t[:0]
                block = self._columns.block(data, frames_of, counters[complete].copy(), last, self.rate_hz)
        else:
            counters, row = np.unique(u, return_inverse=True)
            row = row.reshape(-1)
            present = np.bincount(row, minlength=len(counters))
            complete = present == n_msgs
            raw = np.zeros((len(counters), 8), np.int64)
            for m, message in enumerate(self.layout.messages):
                sel = np.flatnonzero(k == m)
                for column, sig in message.values:
                    raw[row[sel], column] = extract(data, sel, sig)
            last_frame = np.full(len(counters), -1, np.int64)
            np.maximum.at(last_frame, row, np.arange(len(u)))
            block = ImuSampleBlock.from_raw(self.layout, counters[complete], t[last_frame[complete]], raw[complete],
                                            self.rate_hz)
        joined = int(lo == self._u0 and counters[0] == self._u0 and not complete[0])
        # the newest counter's sample, incomplete at the end of the stream, was cut off by its end (not the
        # first counter: that one is `joined`)
        left = int(final and int(counters[-1]) == self._head and not complete[-1]
                   and self._counters_seen + len(counters) > 1)
        self._counters_seen += len(counters)
        self._left = self._left or bool(left)
        stats.joined_mid_sample += joined
        stats.left_mid_sample += left
        n_complete = int(np.count_nonzero(complete))
        stats.samples += n_complete
        stats.incomplete_samples += len(complete) - n_complete - joined - left
        stats.counter_gaps += (cutoff - lo + 1) - len(counters)
        if len(block):
            self._blocks.append(block)

    def _complete_through(self, cutoff: int) -> int:
        """The last counter to resolve now: `cutoff` (the reorder window has passed it), or past it the last of
        the unbroken run of complete samples that follows (rule 4: a sample leaves once it is complete and
        every older counter is resolved)."""
        assert self._pending is not None
        first = max(cutoff + 1, self._next)
        u, k = self._pending[2], self._pending[3]
        later = u >= first
        rel = u[later] - first               # 0 .. reorder window - 1: what waits lies within the window
        if not len(rel):
            return cutoff
        present = np.zeros((int(np.maximum.reduce(rel)) + 1, len(self.layout.messages)), bool)
        present[rel, k[later]] = True        # (a repeated frame sets its mark again)
        complete = np.logical_and.reduce(present, axis=1)
        run = int(complete.argmin())
        if complete[run]:   # all complete
            run = len(complete)
        return first + run - 1 if run else cutoff

    def _dedupe(self, data, t, u, k, h):
        """The first frame of each (counter, message) only; the others counted as duplicates."""
        if len(u) < 2:
            return data, t, u, k, h
        key = (u - u.min()) * len(self.layout.messages) + k
        if int(key.max()) < (1 << 15):
            # what waits spans at most the reorder window: a 16-bit key sorts in linear time (radix)
            key_order = np.argsort(key.astype(np.int16), kind="stable")
        else:
            key_order = np.argsort(key, kind="stable")
        sk = key[key_order]
        repeat = np.zeros(len(u), bool)
        repeat[key_order[1:]] = sk[1:] == sk[:-1]
        dups = int(np.count_nonzero(repeat))
        if not dups:
            return data, t, u, k, h
        self.stats.duplicates += dups
        self.stats.frames_ok -= dups
        self.stats.out_of_order -= int(np.count_nonzero(repeat & (u < h)))
        keep = ~repeat
        return data[keep], t[keep], u[keep], k[keep], h[keep]


def _widened(data: np.ndarray, width: int) -> np.ndarray:
    """`data` (frames x bytes) padded with zero bytes to `width` columns."""
    if data.shape[1] == width:
        return data
    out = np.zeros((len(data), width), np.uint8)
    out[:, :data.shape[1]] = data
    return out


def decode_stream(pieces, layout: ImuLayout | None = None, rate_hz: float = 1000.0,
                  reorder_window: int = 8) -> tuple[ImuSampleBlock, ImuStats]:
    """`decode_frames` over an iterable of (ids, data, lengths, timestamps) pieces."""
    decoder = StreamDecoder(layout, rate_hz, reorder_window)
    for piece in pieces:
        decoder.feed(*piece)
    return decoder.finish()


__all__ = ["StreamDecoder", "decode_stream"]
