"""Decoded IMU samples as arrays, and the link statistics both decoders report."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from drivers.imu.layout import ImuLayout


@dataclass
class ImuSampleBlock:
    """Consecutive decoded samples of one IMU, in counter order.

    `counter` is the unwrapped sample counter (int64; it starts at the first frame's
    raw counter value and never wraps). `time_s` = counter / rate_hz: the IMU's own time
    base. `receive_time_s` is the timestamp of the frame that completed each sample.
    Increments are per sample in output counts; a counter gap simply has no rows: the
    missing samples' increments are missing, never merged into a neighbour.
    """

    counter: np.ndarray         # (n,) int64
    receive_time_s: np.ndarray  # (n,) float64
    gyro_counts: np.ndarray     # (n, 3) float64
    acc_counts: np.ndarray      # (n, 3) float64
    temperature_c: np.ndarray   # (n,) float64, NaN when the layout has no temperature
    status: np.ndarray          # (n,) int64, 0 when the layout has no status
    rate_hz: float

    def __len__(self) -> int:
        return len(self.counter)

    @property
    def time_s(self) -> np.ndarray:
        """Sample times on the IMU's counter time base, s."""
        return self.counter / self.rate_hz

    @property
    def gyro_rate(self) -> np.ndarray:
        """Gyro outputs as rates, counts/s (increment * nominal rate)."""
        return self.gyro_counts * self.rate_hz

    @property
    def acc_rate(self) -> np.ndarray:
        """Accelerometer outputs as rates, counts/s."""
        return self.acc_counts * self.rate_hz

    @classmethod
    def empty(cls, rate_hz: float) -> "ImuSampleBlock":
        return cls(np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0),
                   np.zeros(0, np.int64), float(rate_hz))

    @classmethod
    def from_raw(cls, layout: ImuLayout, counter: np.ndarray, receive_time_s: np.ndarray, raw: np.ndarray,
                 rate_hz: float) -> "ImuSampleBlock":
        """Scale raw signal values, (n, 8) in COLUMNS order, into a block."""
        raw = np.asarray(raw, dtype=np.int64).reshape(-1, 8)
        values = raw.astype(np.float64) * np.asarray(layout.scale) + np.asarray(layout.offset)
        temperature = values[:, 6] if layout.has_column[6] else np.full(len(raw), np.nan)
        # The status word is an integer bit field: scale and offset do not apply.
        status = raw[:, 7].copy() if layout.has_column[7] else np.zeros(len(raw), np.int64)
        return cls(np.asarray(counter, dtype=np.int64), np.asarray(receive_time_s, dtype=np.float64),
                   values[:, 0:3].copy(), values[:, 3:6].copy(), temperature.copy(), status, float(rate_hz))

    @classmethod
    def concatenate(cls, blocks: list["ImuSampleBlock"], rate_hz: float | None = None) -> "ImuSampleBlock":
        """Join consecutive blocks of one IMU (an empty list needs `rate_hz`)."""
        if not blocks:
            return cls.empty(rate_hz if rate_hz is not None else 1.0)
        rate = blocks[0].rate_hz if rate_hz is None else float(rate_hz)
        arrays = {f.name: np.concatenate([getattr(b, f.name) for b in blocks])
                  for f in fields(cls) if f.name != "rate_hz"}
        return cls(**arrays, rate_hz=rate)


@dataclass
class ImuStats:
    """What happened to the frames of an IMU link.

    Every frame lands in exactly one of: frames_ok (used in a sample), crc_errors,
    wrong_length, unknown_id, late (its sample was already resolved, or it predates the
    first frame), duplicates (same id and counter as a frame already used). `out_of_order`
    counts the frames_ok that belonged to an older counter than one already seen. Every
    counter from the first to the newest resolved is exactly one of: samples (emitted),
    incomplete_samples (some but not all frames: dropped), counter_gaps (no frame at all),
    joined_mid_sample (the first counter's sample when it came incomplete: the bench began
    listening while it was being sent; not a loss, 0 or 1), left_mid_sample (the newest
    counter's sample when the stream ended incomplete: the bench stopped listening while it
    was being sent; not a loss, 0 or 1).
    """

    frames: int = 0
    frames_ok: int = 0
    crc_errors: int = 0
    wrong_length: int = 0
    unknown_id: int = 0
    late: int = 0
    duplicates: int = 0
    out_of_order: int = 0
    samples: int = 0
    incomplete_samples: int = 0
    counter_gaps: int = 0
    joined_mid_sample: int = 0
    left_mid_sample: int = 0

    def as_dict(self) -> dict[str, int]:
        return asdict(self)

    @property
    def frame_faults(self) -> int:
        """Frames not used in any sample."""
        return self.crc_errors + self.wrong_length + self.unknown_id + self.late + self.duplicates

    @property
    def lost_samples(self) -> int:
        """Samples the bench did not get: dropped incomplete ones plus counter gaps."""
        return self.incomplete_samples + self.counter_gaps

    def summary(self) -> str:
        """One line for logs and progress output."""
        return (f"{self.samples} samples, {self.lost_samples} lost ({self.counter_gaps} in counter gaps, "
                f"{self.incomplete_samples} incomplete); {self.frames} frames: {self.crc_errors} CRC errors, "
                f"{self.wrong_length} wrong length, {self.unknown_id} unknown id, {self.late} late, "
                f"{self.duplicates} duplicates, {self.out_of_order} out of order"
                + ("; joined mid-sample (its first sample dropped, not a loss)" if self.joined_mid_sample else "")
                + ("; left mid-sample (its last sample dropped, not a loss)" if self.left_mid_sample else ""))
