"""The live decoder: frames in one at a time, complete samples out as arrays.

Rules (the bulk decoder in `drivers.imu.bulk` implements exactly the same ones):
1. A frame is checked in order: known id, expected length, CRC. A failure is counted
   (unknown_id, wrong_length, crc_errors) and the frame is not used: its counter cannot
   be trusted, so its sample ends up incomplete.
2. Each valid frame's counter is unwrapped relative to the previous valid frame's
   (a step of more than half the counter range backwards counts as going back), so a
   16-bit counter becomes a monotonically increasing int64 sample index. The first
   valid frame's raw counter is the start.
3. `head` is the newest counter seen. A frame is late (counted, not used) if its counter
   is at or below head - reorder_window, or before the start; its sample was already
   resolved. A second frame for the same counter and id is a duplicate (counted, first
   kept). A used frame whose counter is below head is out_of_order (still used).
4. A sample is emitted once it has every mapped frame and every older counter is
   resolved, so samples leave in counter order. A counter leaves the window when head
   reaches counter + reorder_window: with some frames it is an incomplete sample
   (dropped, counted), with none it is a counter gap (counted per missing sample). The
   first counter's sample, incomplete, is counted as joined mid-sample instead: its first
   frames went out before the bench started listening, which loses nothing it could have had.
   `flush()` resolves everything still pending at the end of a stream; there the newest
   counter's sample, incomplete, is counted as left mid-sample (its last frames went out
   after the bench stopped listening), not as lost.
"""

from __future__ import annotations

import numpy as np

from drivers.errors import ImuConfigError, ImuFrameError
from drivers.imu.crc import linear_crc
from drivers.imu.layout import EXTENDED_ID_FLAG, ImuLayout, SignalLayout, default_layout
from drivers.imu.numbering import FrameNumberer
from drivers.imu.samples import ImuSampleBlock, ImuStats

_REC_HEAD = 3   # record: [mask, time of last used frame, counter, 8 raw column values]

_Chunk = tuple[int, int, list[int]]             # (first bit, index mask, CRC table)
_Value = tuple[int, bool, int, int, int, int]   # (record slot, big_endian, shift, mask, sign_bit, modulus)
# (length, message bit, CRC chunks, id constant, CRC shift, needs big-endian, counter big-endian,
#  counter shift, values)
_Handler = tuple[int, int, tuple[_Chunk, ...], int, int, bool, bool, int, tuple[_Value, ...]]


def _live_signal(sig: SignalLayout) -> tuple[bool, int, int, int, int]:
    """(big_endian, shift, mask, sign_bit, modulus) for the int extraction."""
    return (sig.big_endian, sig.shift, sig.mask, (1 << (sig.length - 1)) if sig.signed else 0, 1 << sig.length)


class SampleAssembler:
    """Stateful live decoder for one IMU layout (not thread-safe: one feeder)."""

    def __init__(self, layout: ImuLayout | None = None, rate_hz: float = 1000.0, reorder_window: int = 8):
        self.layout = layout if layout is not None else default_layout()
        if not (isinstance(reorder_window, int) and reorder_window >= 1):
            raise ImuConfigError(f"reorder_window must be a positive integer, got {reorder_window!r}")
        if not (rate_hz > 0 and rate_hz != float("inf")):
            raise ImuConfigError(f"rate_hz must be positive, got {rate_hz!r}")
        self.rate_hz, self.window = float(rate_hz), reorder_window
        # a time-stamped layout (sbg-ecan): frames numbered first, then assembled as a counter layout's
        self._numberer = FrameNumberer(self.layout, rate_hz) if self.layout.time_stamp is not None else None
        self._layout = self._numberer.numbered_layout if self._numberer is not None else self.layout
        self._full = (1 << len(self._layout.messages)) - 1
        self._modulus = 1 << self._layout.counter_bits
        self._handlers: dict[int, _Handler] = {}
        for k, m in enumerate(self._layout.messages):
            chunks: tuple[_Chunk, ...] = ()
            id_constant, crc_shift = 0, -1
            if m.crc_byte is not None:
                lin = linear_crc(m.length, m.crc_byte)
                chunks, crc_shift = lin.chunks, 8 * m.crc_byte
                id_constant = lin.id_constant(m.frame_id, m.is_extended_id)
            values = tuple((_REC_HEAD + col,) + _live_signal(sig) for col, sig in m.values)
            needs_be = m.counter.big_endian or any(sig.big_endian for _, sig in m.values)
            self._handlers[m.key] = (m.length, 1 << k, chunks, id_constant, crc_shift, needs_be,
                                     m.counter.big_endian, m.counter.shift, values)
        self._blank: list = [0, 0.0, 0] + [0] * 8   # a record: ints and one float
        self._stats = ImuStats()
        self._pending: dict[int, list] = {}
        self._done: list[list] = []
        self._done_t: list[float] = []
        self._prev: int | None = None   # unwrapped counter of the previous valid frame
        self._first: int | None = None  # counter of the first valid frame: its sample may have begun before we joined
        self._start = self._head = self._lowest = 0
        self._ending = False            # flush(): the newest counter's incomplete sample was cut by the end
        self._left = False              # a flush counted one as left mid-sample: frames after it make it lost

    # -- feeding ------------------------------------------------------------------
    def feed(self, arbitration_id: int, data: bytes, timestamp: float = 0.0, is_extended_id: bool = False) -> None:
        """One received frame."""
        self._run(((arbitration_id | (EXTENDED_ID_FLAG if is_extended_id else 0), data, timestamp),))

    def feed_frames(self, frames) -> None:
        """Many frames: an iterable of (key, data, timestamp), key = id | EXTENDED_ID_FLAG for 29-bit ids."""
        self._run(frames)

    def feed_messages(self, messages) -> None:
        """Many python-can `Message`s (anything with arbitration_id, is_extended_id, data, timestamp)."""
        flag = EXTENDED_ID_FLAG
        self._run((m.arbitration_id | flag if m.is_extended_id else m.arbitration_id, m.data, m.timestamp)
                  for m in messages)

    def _run(self, frames) -> None:
        numberer = self._numberer
        if numberer is None:
            self._assemble(frames)
            return
        before = numberer.before_start
        try:
            self._assemble(numberer.frames(frames))
        finally:   # data frames before the first time stamp: late (their sample began before we listened)
            late = numberer.before_start - before
            self._stats.frames += late
            self._stats.late += late

    def _assemble(self, frames) -> None:
        # Hot loop: everything in locals, state written back once (also on an exception).
        handlers, pending, blank = self._handlers, self._pending, self._blank
        full, window, modulus = self._full, self.window, self._modulus
        half, cmask = modulus >> 1, modulus - 1
        from_bytes = int.from_bytes
        s = self._stats
        total = ok = unknown = wrong = crc_err = late = dup = ooo = 0
        prev, start, head, lowest = self._prev, self._start, self._head, self._lowest
        try:
            for key, data, t in frames:
                total += 1
                h = handlers.get(key)
                if h is None:
                    unknown += 1
                    continue
                length, bit, chunks, crc, crc_shift, needs_be, cbig, cshift, values = h
                if len(data) != length:
                    wrong += 1
                    continue
                v = from_bytes(data, "little")
                if crc_shift >= 0:
                    for shift, mask, table in chunks:
                        crc ^= table[(v >> shift) & mask]
                    if crc != (v >> crc_shift) & 0xFF:
                        crc_err += 1
                        continue
                vb = from_bytes(data, "big") if needs_be else 0
                c = ((vb if cbig else v) >> cshift) & cmask
                if prev is None:
                    u = start = head = lowest = c
                    self._first = c
                else:
                    d = (c - prev) & cmask
                    u = prev + (d - modulus if d >= half else d)
                prev = u
                if u > head:
                    head = u
                elif u <= head - window or u < start:
                    late += 1
                    continue
                rec = pending.get(u)
                if rec is None:
                    if u < lowest:      # in the window, after the start, below lowest: emitted already
                        dup += 1
                        continue
                    rec = blank.copy()
                    rec[2] = u
                    pending[u] = rec
                elif rec[0] & bit:
                    dup += 1
                    continue
                rec[0] |= bit
                rec[1] = t
                if u < head:
                    ooo += 1
                for slot, big, shift, mask, sign, mod in values:
                    x = ((vb if big else v) >> shift) & mask
                    rec[slot] = x - mod if x & sign else x
                ok += 1
                if (rec[0] == full and u == lowest) or head - window >= lowest:
                    self._lowest = lowest
                    self._advance(head - window)
                    lowest = self._lowest
        except (TypeError, ValueError, AttributeError) as exc:
            total -= 1      # the offending item is not a frame: keep the books balanced
            raise ImuFrameError(f"not a CAN frame (arbitration id, data bytes, timestamp): {exc}") from exc
        finally:
            self._prev, self._start, self._head, self._lowest = prev, start, head, lowest
            if total and self._left:    # the stream went on after a flush: the sample it cut was lost after all
                self._left = False
                s.left_mid_sample -= 1
                s.incomplete_samples += 1
            s.frames += total
            s.frames_ok += ok
            s.unknown_id += unknown
            s.wrong_length += wrong
            s.crc_errors += crc_err
            s.late += late
            s.duplicates += dup
            s.out_of_order += ooo

    def _advance(self, limit: int) -> None:
        """Emit complete samples from the lowest pending counter; resolve counters <= limit."""
        pending, full, s = self._pending, self._full, self._stats
        lowest = self._lowest
        while True:
            rec = pending.get(lowest)
            if rec is not None and rec[0] == full:
                del pending[lowest]
                self._done_t.append(rec[1])
                rec[1] = 0
                self._done.append(rec)
                s.samples += 1
                lowest += 1
                continue
            if lowest > limit:
                break
            if rec is None:
                stop = min(min(pending), limit + 1) if pending else limit + 1
                s.counter_gaps += stop - lowest
                lowest = stop
            else:
                del pending[lowest]
                if lowest == self._first:   # its first frames went out before the stream was joined
                    s.joined_mid_sample += 1
                elif self._ending and lowest == self._head:   # its last ones after the stream ended
                    s.left_mid_sample += 1
                    self._left = True
                else:
                    s.incomplete_samples += 1
                lowest += 1
        self._lowest = lowest

    # -- output -------------------------------------------------------------------
    def flush(self) -> ImuSampleBlock:
        """End of stream: resolve every pending counter, return what is left to take."""
        if self._prev is not None:
            self._ending = True
            try:
                self._advance(self._head)
            finally:
                self._ending = False
            self._start = self._head + 1   # later frames of resolved counters are late
        return self.take_block()

    def take_block(self) -> ImuSampleBlock:
        """The samples completed since the last call, in counter order."""
        if not self._done:
            return ImuSampleBlock.empty(self.rate_hz)
        ints = np.array(self._done, dtype=np.int64)
        times = np.array(self._done_t, dtype=np.float64)
        self._done, self._done_t = [], []
        return ImuSampleBlock.from_raw(self._layout, ints[:, 2], times, ints[:, _REC_HEAD:], self.rate_hz)

    @property
    def stats(self) -> ImuStats:
        """A copy of the counts so far."""
        return ImuStats(**self._stats.as_dict())

    @property
    def pending_samples(self) -> int:
        """Counters with some frames, waiting for the rest or for the window to pass."""
        return len(self._pending)
