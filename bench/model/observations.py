"""Per-step observations: what the solver needs from a position dwell or a turn.

The same records come from the simulated world today and from MCAP logs later,
so the solver never sees raw samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.model.earth import Site
from bench.model.kinematics import FRAMES, frame_axes_in_body, frame_matrix_parts, split_at_frame, triple
from bench.model.motion import Piece, trig_integrals
from bench.model.turn_timing import TurnTiming
from bench.model.units import DEG
from schedules.loader import Direction, Frame

FRAME_INDEX = {name: k for k, name in enumerate(FRAMES)}
DIRECTION_SIGN: dict[Direction, int] = {"ccw": 1, "cw": -1}


def _vec3(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f"{name} must have 3 components, got {a.shape[0]}")
    return a


@dataclass
class PositionObservation:
    """Mean outputs (counts/s) over a dwell at one table position, with sample statistics.

    `*_std` are the standard deviations of the per-sample rates; `*_sem` the 1-sigma of
    the mean (from block means, see `mean_and_standard_error`). Without `*_sem` the
    white-noise value std/sqrt(n) is used.
    """

    angles_deg: tuple[float, float, float]
    duration_s: float
    sample_count: int
    gyro_mean: np.ndarray
    acc_mean: np.ndarray
    gyro_std: np.ndarray | None = None
    acc_std: np.ndarray | None = None
    gyro_sem: np.ndarray | None = None
    acc_sem: np.ndarray | None = None
    label: str = ""
    #: when the dwell's window began (s, on the IMU's time base): the bias-instability part of
    #: the uncertainty budget correlates steps by their distance in time (None: unknown)
    start_s: float | None = None
    #: the six channels' output step (counts/s) of an IMU that rounds each sample on its own (sbg-ecan), whose
    #: rounding the budget checks is dithered by the IMU's noise; None: a counter output
    output_step: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        self.angles_deg = triple(_vec3(self.angles_deg, "angles_deg"))
        self.gyro_mean = _vec3(self.gyro_mean, "gyro_mean")
        self.acc_mean = _vec3(self.acc_mean, "acc_mean")
        for name in ("gyro_std", "acc_std", "gyro_sem", "acc_sem"):
            if getattr(self, name) is not None:
                setattr(self, name, _vec3(getattr(self, name), name))
        if self.sample_count < 1 or not self.duration_s > 0:
            raise ValueError("a position observation needs at least one sample and a positive duration")

    def standard_error(self, which: str) -> np.ndarray | None:
        """1-sigma of the mean for 'gyro' or 'acc', or None when unknown."""
        sem = self.gyro_sem if which == "gyro" else self.acc_sem
        if sem is not None:
            return sem
        std = self.gyro_std if which == "gyro" else self.acc_std
        return None if std is None else std / math.sqrt(self.sample_count)


#: The output step of an IMU counter: one count (pulse). The mean rate over a dwell of
#: T seconds cannot be known better than about one count / T, whatever the scatter says.
COUNT_RESOLUTION = 1.0


_TERMS = 32


def rounding_bias_variance(std: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Variance of the part of per-sample rounding to `step` that no averaging removes, per channel.

    An IMU that sends each sample's value rounded on its own (sbg-ecan: 0.001 rad/s, 0.01 m/s^2) errs by up
    to step/2 per sample. Noise of sigma >~ step/2 dithers the rounding: its error is then white (it is in
    the samples' scatter, hence in the standard error) and its mean over a window is (with x the signal's
    position within a step, uniform) sum_k step/(pi k) (-1)^k exp(-2 pi^2 k^2 sigma^2/step^2) sin(2 pi k x/step):
    variance sum_k step^2/(2 pi^2 k^2) exp(-4 pi^2 k^2 sigma^2/step^2), step^2/12 without noise, negligible
    from sigma = step/2 on. `std`: the per-sample scatter as sent (rounding included), so
    sigma^2 = std^2 - step^2/12 (at least 0).
    """
    step = np.asarray(step, dtype=float)
    ratio2 = np.maximum(np.asarray(std, dtype=float) ** 2 / step ** 2 - 1.0 / 12.0, 0.0)   # (sigma/step)^2
    a = 4.0 * math.pi ** 2 * ratio2
    k = np.arange(1, _TERMS + 1, dtype=float)[:, None]
    series = np.sum(np.exp(-a * k ** 2) / k ** 2, axis=0)
    series += np.exp(-a * (_TERMS + 1) ** 2) / (_TERMS + 0.5)   # the tail (sum of 1/k^2 beyond: ~1/(K + 1/2))
    return step ** 2 * series / (2.0 * math.pi ** 2)


def mean_and_standard_error(rates: np.ndarray, blocks: int = 20, duration_s: float | None = None,
                            resolution_counts: float = COUNT_RESOLUTION,
                            output_step: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, per-sample std and 1-sigma of the mean of per-sample rates (n, 3).

    The standard error comes from the scatter of `blocks` block means rather than from
    std/sqrt(n): per-sample quantisation of a counter output is large but does not
    accumulate (the summed count is exact), and slow noise shows in the block means.
    With `duration_s` it is floored at the quantisation of the dwell's summed count,
    `resolution_counts / (duration_s * sqrt(12))`: block means can agree to the last
    bit (quantised outputs, a noise-free simulator) and a zero standard error would
    give one dwell infinite weight. With `output_step` (counts/s per channel: an IMU sending each sample's
    rate rounded on its own, sbg-ecan) the sum is not exact: the rounding's part that averaging does not
    remove, `rounding_bias_variance`, is added to the standard error's variance instead.
    """
    rates = np.asarray(rates, dtype=float)
    n = len(rates)
    mean = rates.mean(axis=0)
    std = rates.std(axis=0, ddof=1) if n > 1 else np.zeros(rates.shape[1])
    blocks = min(blocks, n // 2)
    if blocks < 2:
        sem = std / math.sqrt(max(n, 1))
    else:
        size = n // blocks
        block_means = rates[: size * blocks].reshape(blocks, size, -1).mean(axis=1)
        sem = block_means.std(axis=0, ddof=1) / math.sqrt(blocks)
    if output_step is not None:
        sem = np.sqrt(sem ** 2 + rounding_bias_variance(std, output_step))
    elif duration_s is not None and duration_s > 0:
        sem = np.maximum(sem, resolution_counts / (duration_s * math.sqrt(12.0)))
    return mean, std, sem


@dataclass
class RotationObservation:
    """Gyro outputs integrated (counts) from rest to rest over a turn of whole revolutions.

    `earth_integral_rad` is the nominal (ideal-table) integral of the Earth rate in body
    axes over the same window; when absent the solver uses the constant-rate value
    `duration * (u . w_ie_b) u`.
    """

    start_deg: tuple[float, float, float]
    frame: Frame
    direction: Direction
    revolutions: int
    duration_s: float
    sample_count: int
    gyro_integral: np.ndarray
    earth_integral_rad: np.ndarray | None = None
    gyro_integral_sigma: np.ndarray | None = None
    label: str = ""
    start_s: float | None = None    # when the window began, as `PositionObservation.start_s`
    #: variance (counts^2) of the integral's output rounding, for an IMU that rounds each sample on its own
    #: (sbg-ecan); None: a counter output, whose integral is exact to one count (the budget's counter model)
    rounding_var: np.ndarray | None = None
    #: the accelerometer outputs summed over the same window (counts) and the integral of the turning frame's
    #: squared rate over it (rad^2/s): what the extended model's lever arms and nonlinearity need (None: unknown)
    acc_integral: np.ndarray | None = None
    rate_sq_integral: float | None = None
    #: the timing its samples show against the table's angle (`bench.model.turn_timing`; the extended model's time
    #: offset needs it; None: not reduced)
    timing: TurnTiming | None = None

    def __post_init__(self) -> None:
        self.start_deg = triple(_vec3(self.start_deg, "start_deg"))
        if self.frame not in FRAME_INDEX:
            raise ValueError(f"frame must be one of {', '.join(FRAME_INDEX)}, got {self.frame!r}")
        if self.direction not in DIRECTION_SIGN:
            raise ValueError(f"direction must be ccw or cw, got {self.direction!r}")
        if int(self.revolutions) != self.revolutions or self.revolutions < 1:
            raise ValueError(f"revolutions must be a whole number >= 1, got {self.revolutions!r}")
        self.gyro_integral = _vec3(self.gyro_integral, "gyro_integral")
        if self.earth_integral_rad is not None:
            self.earth_integral_rad = _vec3(self.earth_integral_rad, "earth_integral_rad")
        if self.gyro_integral_sigma is not None:
            self.gyro_integral_sigma = _vec3(self.gyro_integral_sigma, "gyro_integral_sigma")
        if self.rounding_var is not None:
            self.rounding_var = _vec3(self.rounding_var, "rounding_var")
        if self.acc_integral is not None:
            self.acc_integral = _vec3(self.acc_integral, "acc_integral")

    @property
    def frame_index(self) -> int:
        return FRAME_INDEX[self.frame]

    @property
    def sign(self) -> int:
        return DIRECTION_SIGN[self.direction]


def rate_squared_integral(pieces: list[Piece], t_start: float, t_end: float) -> float:
    """Integral of the squared frame rate (rad^2/s) over [t_start, t_end] along the trajectory (exact)."""
    starts = [p.t0 for p in pieces]
    edges = [t_start] + [b for b in starts if t_start < b < t_end] + [t_end]
    total = 0.0
    for a, b in zip(edges[:-1], edges[1:]):
        if b <= a:
            continue
        k = int(np.searchsorted(starts, 0.5 * (a + b), side="right")) - 1
        if k < 0:
            continue            # before the first piece the axis holds still
        _, rate_a = pieces[k].at(a)
        _, rate_b = pieces[k].at(b)
        accel = pieces[k].accel
        total += rate_a ** 2 * (b - a) if accel == 0.0 else (rate_b ** 3 - rate_a ** 3) / (3.0 * accel)
    return total


def turn_axis_in_body(start_deg, frame_index: int, black_box=None, mounting=None) -> np.ndarray:
    """Unit axis (body coordinates) about which a CCW turn of the frame rotates the body."""
    return frame_axes_in_body(np.asarray(start_deg, dtype=float) * DEG, black_box, mounting)[..., frame_index, :]


def turn_earth_integral(site: Site, start_deg, frame_index: int, pieces: list[Piece], t_start: float,
                        t_end: float, black_box=None, mounting=None) -> np.ndarray:
    """Integral over [t_start, t_end] of the Earth rate in body axes (rad) while one frame
    follows `pieces` (its angle in rad) and the other two stay at `start_deg`.

    Closed form: `C_t^b = L F(theta) R` with L, R fixed, so only int cos and int sin of
    the frame angle are needed.
    """
    start = np.asarray(start_deg, dtype=float) * DEG
    left, right = split_at_frame(start, frame_index, black_box, mounting)
    p, a, b = frame_matrix_parts(frame_index)
    ic, is_ = trig_integrals(pieces, t_start, t_end)
    integral_f = p * (t_end - t_start) + a * ic + b * is_
    return left @ integral_f @ right @ site.earth_rate_enu
