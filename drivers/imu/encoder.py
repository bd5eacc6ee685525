"""The sending side of an IMU layout: samples -> DBC frames (for the simulator and tests).

Increments are quantised sigma-delta style: each channel emits the differences of the
rounded running sum (the rounding remainder is carried to the next sample and the next
call), so the sum of the sent increments over any span differs from the true sum by
less than one signal resolution step; the calibration integrates increments.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from drivers.errors import ImuFrameError
from drivers.imu.crc import crc8_columns, crc8_raw, id_bytes
from drivers.imu.layout import (
    COLUMNS,
    SBG_ACCELS_IN_RANGE,
    SBG_GYROS_IN_RANGE,
    STATUS_COLUMN,
    TEMPERATURE_COLUMN,
    ImuLayout,
    ImuStatus,
    SignalLayout,
    default_layout,
)


@dataclass
class EncodedFrames:
    """Frames in send order: every message of sample 0, then sample 1, ...

    `ids` carry `EXTENDED_ID_FLAG` for 29-bit ids; frame i is `data[i, :lengths[i]]`;
    `sample` is the index of the sample each frame belongs to.
    """

    ids: np.ndarray      # (N,) int64
    data: np.ndarray     # (N, width) uint8
    lengths: np.ndarray  # (N,) int64
    sample: np.ndarray   # (N,) int64

    def __len__(self) -> int:
        return len(self.ids)

    def frame(self, i: int) -> tuple[int, bytes]:
        return int(self.ids[i]), bytes(self.data[i, :self.lengths[i]])


def _insert(data: np.ndarray, sig: SignalLayout, raw: np.ndarray) -> None:
    """OR the raw values (int64, in range) into the signal's bytes of every row (all its bytes in one step)."""
    nbytes = sig.last_byte - sig.first_byte + 1
    bits = (raw.astype(np.uint64) & np.uint64(sig.mask)) << np.uint64(sig.window_shift)
    shifts = _byte_shifts(nbytes, sig.big_endian)
    data[:, sig.first_byte:sig.first_byte + nbytes] |= ((bits[:, None] >> shifts) & np.uint64(0xFF)).astype(np.uint8)


def _classic_frames(length: int, signals: list[tuple[SignalLayout, np.ndarray]]) -> np.ndarray | None:
    """The (n, length) bytes of frames of at most 8 bytes holding `signals` (raw int64 values, in range): each
    frame is built as one integer per byte order (the live path's `shift`s), then laid out as bytes: the bytes
    `_insert` writes signal by signal, in a few operations per signal instead of a dozen. None for a longer frame
    or a signal outside the frame (`_insert` does those)."""
    if length > 8 or any(sig.last_byte >= length for sig, _ in signals):
        return None
    words: dict[bool, np.ndarray | None] = {False: None, True: None}    # little-endian, big-endian signals
    for sig, values in signals:
        bits = (values.astype(np.uint64) & np.uint64(sig.mask)) << np.uint64(sig.shift)
        word = words[sig.big_endian]
        words[sig.big_endian] = bits if word is None else word | bits
    out: np.ndarray | None = None
    for big_endian, word in words.items():
        if word is None:
            continue
        # a big-endian frame of `length` bytes is the last `length` bytes of its integer's 8
        as_bytes = word.astype(">u8" if big_endian else "<u8").view(np.uint8).reshape(-1, 8)
        part = as_bytes[:, 8 - length:] if big_endian else as_bytes[:, :length]
        out = part if out is None else out | part
    if out is None:
        return None
    return np.ascontiguousarray(out)


@functools.lru_cache(maxsize=64)
def _byte_shifts(nbytes: int, big_endian: bool) -> np.ndarray:
    """The right shift that brings each of a signal's bytes, first to last, to the low byte."""
    return np.array([8 * (nbytes - 1 - b) if big_endian else 8 * b for b in range(nbytes)], np.uint64)


def _check_range(sig: SignalLayout, raw: np.ndarray, what: str) -> None:
    lo, hi = (-(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1) if sig.signed else (0, (1 << sig.length) - 1)
    bad = np.flatnonzero((raw < lo) | (raw > hi))
    if len(bad):
        raise ImuFrameError(f"{what} of sample {bad[0]} needs raw value {raw[bad[0]]}, outside signal "
                            f"{sig.name}'s range {lo}..{hi}")


#: the status bit a saturating encoder sets in a sample whose output it clipped (docs/hardware/can.md: over-range)
OVER_RANGE_BIT = int(ImuStatus.OVER_RANGE)


class ImuEncoder:
    """Samples -> frames for one layout; carries the quantisation remainders between calls.

    `saturate`: an increment beyond its signal's range is clipped to the range and the sample's status gets
    `OVER_RANGE_BIT`, as an IMU whose output saturates reports it (the clipped excess is lost, the carried
    remainder is not disturbed); without it such an increment raises `ImuFrameError`.
    """

    def __init__(self, layout: ImuLayout | None = None, saturate: bool = False, rate_hz: float | None = None):
        self.layout = layout if layout is not None else default_layout()
        self.saturate = saturate
        #: a time-stamped layout (sbg-ecan) sends rates and a time stamp: it needs the sample rate
        self.rate_hz = rate_hz
        if self.layout.time_stamp is not None and not (rate_hz is not None and rate_hz > 0):
            raise ImuFrameError("a time-stamped layout is encoded at a sample rate: give rate_hz")
        self.saturated_samples = 0
        self._remainder = np.zeros(6)   # per channel, in units of the signal resolution
        self._width = max(m.length for m in self.layout.messages)

    def _raw_columns(self, counter, gyro_counts, acc_counts, temperature_c, status) -> tuple[np.ndarray, np.ndarray]:
        lay = self.layout
        counter = np.asarray(counter)
        n = len(counter)
        raw = np.zeros((n, len(COLUMNS)), np.int64)
        values = np.concatenate([np.asarray(gyro_counts, float).reshape(n, 3),
                                 np.asarray(acc_counts, float).reshape(n, 3)], axis=1)
        if not np.isfinite(values).all():
            raise ImuFrameError("IMU increments must be finite")
        if lay.time_stamp is not None:
            # rates and accelerations, each sample rounded on its own (the format sends values, not increments)
            assert self.rate_hz is not None
            rounded = np.round((values * self.rate_hz - np.asarray(lay.offset[:6])) / np.asarray(lay.scale[:6]))
            if np.abs(rounded).max(initial=0.0) >= 2.0 ** 62:
                raise ImuFrameError("IMU outputs too large for the layout's resolution")
            raw[:, :6] = rounded.astype(np.int64)
            remainder = self._remainder
        else:
            target = (values - np.asarray(lay.offset[:6])) / np.asarray(lay.scale[:6])
            total = self._remainder + np.cumsum(target, axis=0)
            rounded = np.round(total)
            if np.abs(rounded).max(initial=0.0) >= 2.0 ** 62:
                raise ImuFrameError("IMU increments too large for the layout's resolution")
            cum = rounded.astype(np.int64)
            raw[:, :6] = np.diff(cum, axis=0, prepend=np.zeros((1, 6), np.int64))
            remainder = total[-1] - rounded[-1] if n else self._remainder
        if lay.has_column[TEMPERATURE_COLUMN]:
            temp = np.broadcast_to(np.asarray(25.0 if temperature_c is None else temperature_c, float), (n,))
            if not (np.isfinite(temp).all() and np.abs(temp).max(initial=0.0) < 1e6):
                raise ImuFrameError("temperature must be finite and plausible (|t| < 1e6 degC)")
            scale, offset = lay.scale[TEMPERATURE_COLUMN], lay.offset[TEMPERATURE_COLUMN]
            raw[:, TEMPERATURE_COLUMN] = np.round((temp - offset) / scale)
        if lay.has_column[STATUS_COLUMN]:
            status = lay.healthy_status() if status is None else status
            raw[:, STATUS_COLUMN] = np.broadcast_to(np.asarray(status, np.int64), (n,))
        return raw, remainder

    def encode(self, counter, gyro_counts, acc_counts, temperature_c=None, status=None) -> EncodedFrames:
        """Frames for n samples: `counter` (n,) the IMU's sample counter (its low bits are sent),
        `gyro_counts`/`acc_counts` (n, 3) increments in output counts, `temperature_c` and
        `status` scalars or (n,) (default 25 degC, the layout's healthy status). Out-of-range values raise
        `ImuFrameError` and leave the carried remainder unchanged. A time-stamped layout (sbg-ecan) sends
        `counter` as its time stamp (counter / rate_hz, in the stamp's unit, wrapped to its width) and the
        increments as values per second (increment x rate_hz), each rounded to the signal's resolution.
        """
        lay = self.layout
        counter = np.asarray(counter, dtype=np.int64).reshape(-1)
        n, n_msgs = len(counter), len(lay.messages)
        raw, remainder = self._raw_columns(counter, gyro_counts, acc_counts, temperature_c, status)
        counter_raw = counter & ((1 << lay.counter_bits) - 1)
        if self.saturate:
            self._clip(raw)
        for m in lay.messages:
            for column, sig in m.values:
                _check_range(sig, raw[:, column], COLUMNS[column])
        data = np.zeros((n, n_msgs, self._width), np.uint8)
        stamp = lay.time_stamp
        for k, m in enumerate(lay.messages):
            signals = [(sig, raw[:, column]) for column, sig in m.values]
            if stamp is None:
                signals.insert(0, (m.counter, counter_raw))
            elif k == 0:   # the time-stamp message: the sample's time, wrapped to the stamp's width
                assert self.rate_hz is not None   # (checked at construction)
                ticks = np.round(counter / (self.rate_hz * stamp.unit_s)).astype(np.int64)
                signals.insert(0, (stamp.signal, ticks & np.int64(stamp.signal.mask)))
            block = _classic_frames(m.length, signals)
            if block is None:
                block = np.zeros((n, m.length), np.uint8)
                for sig, values in signals:
                    _insert(block, sig, values)
            if m.crc_byte is not None:
                keep = [j for j in range(m.length) if j != m.crc_byte]
                block[:, m.crc_byte] = crc8_columns(crc8_raw(id_bytes(m.frame_id, m.is_extended_id)), block[:, keep])
            data[:, k, :m.length] = block
        self._remainder = np.array(remainder, dtype=float)
        ids = np.tile(np.array(lay.keys, np.int64), n)
        lengths = np.tile(np.array([m.length for m in lay.messages], np.int64), n)
        return EncodedFrames(ids, data.reshape(n * n_msgs, self._width), lengths,
                             np.repeat(np.arange(n, dtype=np.int64), n_msgs))

    def _clip(self, raw: np.ndarray) -> None:
        """Clip the six channels to their signals' ranges; flag the clipped samples as over-range."""
        clipped = np.zeros((len(raw), 2), bool)   # per sample: a gyro clipped, an accelerometer clipped
        for m in self.layout.messages:
            for column, sig in m.values:
                if column >= 6:
                    continue
                lo, hi = (-(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1) if sig.signed else (0, sig.mask)
                out = (raw[:, column] < lo) | (raw[:, column] > hi)
                if out.any():
                    raw[:, column] = np.clip(raw[:, column], lo, hi)
                    clipped[:, column // 3] |= out
        any_clipped = clipped.any(axis=1)
        if any_clipped.any():
            self.saturated_samples += int(any_clipped.sum())
            if self.layout.has_column[STATUS_COLUMN] and self.layout.status_required:
                # sbg-ecan: the "within range" bit of the saturated sensor kind is cleared
                raw[clipped[:, 0], STATUS_COLUMN] &= ~SBG_GYROS_IN_RANGE
                raw[clipped[:, 1], STATUS_COLUMN] &= ~SBG_ACCELS_IN_RANGE
            elif self.layout.has_column[STATUS_COLUMN]:
                raw[any_clipped, STATUS_COLUMN] |= OVER_RANGE_BIT

    def encode_sample(self, counter: int, gyro_counts, acc_counts, temperature_c: float | None = None,
                      status: int | None = None) -> list[tuple[int, bytes]]:
        """The (key, data) frames of one sample."""
        frames = self.encode([counter], np.reshape(gyro_counts, (1, 3)), np.reshape(acc_counts, (1, 3)),
                             temperature_c, status)
        return [frames.frame(i) for i in range(len(frames))]


def encode_block(block, layout: ImuLayout | None = None) -> EncodedFrames:
    """Frames for an `ImuSampleBlock` (its values already lie on the layout's resolution)."""
    status = block.status if (layout or default_layout()).has_column[STATUS_COLUMN] else None
    temperature = block.temperature_c if np.isfinite(block.temperature_c).all() else None
    return ImuEncoder(layout, rate_hz=block.rate_hz).encode(block.counter, block.gyro_counts, block.acc_counts,
                                                            temperature, status)
