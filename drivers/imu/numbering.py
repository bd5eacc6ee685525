"""Sample numbers for a time-stamped layout (sbg-ecan): frames without a counter, made decodable.

SBG's IMU messages carry no sample counter: IMU_INFO holds a microsecond time stamp and
IMU_ACCEL / IMU_GYRO nothing that ties them to it. The rule (docs/hardware/can.md, sbg-ecan):
- a time-stamp frame (known id, right length) opens a sample; its number is the time stamp
  in sample periods, `first + round((t - t_first) * rate)`, the time stamp unwrapped over
  its width (32 bits: 71.6 minutes), `first = floor(t_first * rate)`;
- every other frame of the layout belongs to the sample opened last (frames are sent in
  order; the format has nothing to detect otherwise: a data frame after a lost time-stamp
  frame lands on the sample before, where it counts as a duplicate);
- a data frame before the first time-stamp frame has no sample: it is counted as late
  (its sample began before the stream was joined) and not used.
Numbered frames carry their number in 8 bytes after their own (`ImuLayout.numbered`), so the
counter decoders (`decode_frames`, `StreamDecoder`) apply unchanged, with
every rule of theirs (reorder window, duplicates, gaps, joined / left mid-sample). A frame of
a known id and the wrong length keeps its bytes and gets length 0: it is counted wrong_length.
"""

from __future__ import annotations

import math

import numpy as np

from drivers.imu.layout import SAMPLE_NUMBER_BITS, ImuLayout, SignalLayout

_NUMBER_MASK = (1 << SAMPLE_NUMBER_BITS) - 1


def _unsigned(rows: np.ndarray, sig: SignalLayout) -> np.ndarray:
    """The unsigned signal `sig` (at most 62 bits: the time stamp) in each row of frame bytes, as int64."""
    window = np.zeros(len(rows), np.uint64)
    for b in range(sig.first_byte, sig.last_byte + 1):
        shift = 8 * (sig.last_byte - b) if sig.big_endian else 8 * (b - sig.first_byte)
        window |= rows[:, b].astype(np.uint64) << np.uint64(shift)
    return ((window >> np.uint64(sig.window_shift)) & np.uint64(sig.mask)).astype(np.int64)


class FrameNumberer:
    """The numbering state of one stream (the last time stamp, the sample open now)."""

    def __init__(self, layout: ImuLayout, rate_hz: float):
        rule = layout.time_stamp
        if rule is None:
            raise ValueError("only a time-stamped layout is numbered")
        self.layout, self.rate_hz = layout, float(rate_hz)
        self.numbered_layout = layout.numbered(rate_hz)
        self._signal = rule.signal
        self._per_tick = rate_hz * rule.unit_s            # samples per time-stamp tick
        self._modulus = 1 << rule.signal.length
        self._info_key = layout.messages[0].key
        self._lengths = {m.key: m.length for m in layout.messages}
        self._first_tick: int | None = None   # the first time stamp (unwrapped ticks start there)
        self._first_number = 0
        self._last_raw = 0
        self._ticks = 0                       # the last time stamp, unwrapped
        self._current: int | None = None      # the number of the sample opened last
        #: data frames before the first time stamp (counted late by the decoders)
        self.before_start = 0

    def _open(self, raw: int) -> int:
        """The number of a sample whose time stamp is `raw`."""
        if self._first_tick is None:
            self._first_tick = self._ticks = raw
            self._first_number = math.floor(raw * self._per_tick + 1e-6)   # (a whole period: exactly)
        else:
            d = (raw - self._last_raw) % self._modulus
            self._ticks += d - self._modulus if d >= self._modulus >> 1 else d
        self._last_raw = raw
        self._current = self._first_number + round((self._ticks - self._first_tick) * self._per_tick)
        return self._current

    # -- arrays (the bulk and stream decoders) --------------------------------------------
    def arrays(self, ids: np.ndarray, data: np.ndarray, lengths: np.ndarray, timestamps: np.ndarray):
        """(ids, data, lengths, timestamps) numbered, as `decode_frames` takes them (data C-contiguous uint8,
        width >= 8); frames before the first time stamp are left out and counted in `before_start`."""
        n = len(ids)
        expected = np.full(n, -1, np.int64)
        for key, length in self._lengths.items():
            expected[ids == key] = length
        known = expected >= 0
        right = known & (lengths == expected)
        info = np.flatnonzero(right & (ids == self._info_key))
        numbers = np.full(n, -1, np.int64)
        opened = np.full(n, -1, np.int64)     # per frame: the time-stamp frame before it in this piece
        carried = self._current               # the sample open when this piece began
        if len(info):
            raw = _unsigned(data[info], self._signal)
            if self._first_tick is None:
                self._open(int(raw[0]))
            d = np.diff(np.concatenate([[self._last_raw], raw])) % self._modulus
            d[d >= self._modulus >> 1] -= self._modulus
            ticks = self._ticks + np.cumsum(d)
            numbers[info] = self._first_number + np.round((ticks - self._first_tick) * self._per_tick).astype(np.int64)
            self._ticks, self._last_raw, self._current = int(ticks[-1]), int(raw[-1]), int(numbers[info[-1]])
            opened[info] = info
            np.maximum.accumulate(opened, out=opened)
        data_frames = right & (ids != self._info_key)
        after = data_frames & (opened >= 0)
        numbers[after] = numbers[opened[after]]
        before = data_frames & (opened < 0)
        if carried is not None:
            numbers[before] = carried
            before[:] = False
        return self._pack(ids, data, lengths, timestamps, known, right, numbers, before)

    def _pack(self, ids, data, lengths, timestamps, known, right, numbers, before):
        keep = ~before
        self.before_start += int(np.count_nonzero(before))
        width = max(data.shape[1], max(self._lengths.values()) + 8)
        out = np.zeros((len(ids), width), np.uint8)
        out[:, :data.shape[1]] = data
        rows = np.flatnonzero(right & keep)
        number_bytes = (numbers[rows] & _NUMBER_MASK).astype("<u8").view(np.uint8).reshape(-1, 8)
        new_lengths = np.where(known & ~right, 0, lengths)
        for key, length in self._lengths.items():
            mine = ids[rows] == key
            out[rows[mine], length:length + 8] = number_bytes[mine]
            new_lengths[rows[mine]] = length + 8
        return ids[keep], out[keep], new_lengths[keep], timestamps[keep]
