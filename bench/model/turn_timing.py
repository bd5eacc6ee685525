"""What a turn's samples tell of the IMU's timing: the reduction behind the gyro-to-accelerometer time offset
(issue 30, docs/explanation/extended-model.md#time-offset).

A turn's window averaged or integrated hides a delay (rest to rest, the delayed signal has the same integral). The
samples inside it do not, against the turning frame's angle `theta(t)` and rate `w(t)` (the table's encoder):
- an accelerometer sees gravity's component across the axis turn as a sinusoid in the frame angle; at the constant
  cruise rate w, delayed by tau_a it is `c + A cos(theta(t) - phi - w tau_a)`: its phase against the angle moves
  by `w tau_a`, and `phi` (the attitude, the misalignments) does not change with the turn's direction;
- a gyro delayed by tau_g reads `p w(t - tau_g) ~ p w(t) - p tau_g dw/dt`: the ramps at the turn's start and end
  show it, per sample `p (theta_b - theta_a) - p tau_g (w_b - w_a)`.
Both are linear least squares per sensor on the samples, with the constant, a linear drift (the bias wandering) and
the sinusoid of the frame angle (g-sensitivity, Earth rate across the axis) as nuisance columns; the accelerometers
also take the second and third harmonics (second order, cross terms: the cruise covers no whole revolution). Their
scatter sets each sigma (white sample noise). Any clock offset between the IMU and the table moves tau_a and tau_g
alike: only their difference, the time offset, is the IMU's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

#: |rate - cruise rate| / cruise rate within which a sample counts as cruising
_CRUISE_TOLERANCE = 1e-6
#: the least angle (rad) the cruise must cover for the phase of a sinusoid in it to mean anything
_MIN_CRUISE_ANGLE = math.pi
#: the samples are summed in blocks of this length (s) before the fits: an output that counts pulses (rounding the
#: running sum) has a rounding error per sample that the next sample takes back, white only over long blocks (with
#: 0.25 s the nav-fog sigma was 1.8 times the estimates' spread; studies/time_offset_coverage.py --spread)
_BLOCK_S = 1.0
#: a sensor's delay or phase is kept only when its signal stands this many sigmas clear of zero
_MIN_SNR = 30.0


@dataclass
class TurnTiming:
    """One turn's timing observables (per sensor x, y, z; NaN where the sensor sees no usable signal)."""

    rate_rad_s: float             # the turning frame's cruise rate, signed (CCW > 0)
    acc_phase_rad: np.ndarray     # (3,) phase of each accelerometer's sinusoid in the frame angle
    acc_phase_sigma_rad: np.ndarray
    gyro_delay_s: np.ndarray      # (3,) each gyro's delay behind the frame's rate profile
    gyro_delay_sigma_s: np.ndarray

    def __post_init__(self) -> None:
        for name in ("acc_phase_rad", "acc_phase_sigma_rad", "gyro_delay_s", "gyro_delay_sigma_s"):
            setattr(self, name, np.asarray(getattr(self, name), dtype=float).reshape(3))


def _blocks(x: np.ndarray, size: int) -> np.ndarray:
    """Rows summed in consecutive blocks of `size` (the last, incomplete one dropped)."""
    n = (len(x) // size) * size
    return x[:n].reshape((n // size, size) + x.shape[1:]).sum(axis=1)


def _fit(design: np.ndarray, y: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Ordinary least squares of each column of y (n, 3) summed in blocks of `size` samples: (params (p, 3),
    covariances (3, p, p)) with the residual scatter as the noise."""
    design, y = _blocks(design, size), _blocks(y, size)
    scale = np.sqrt(np.sum(design * design, axis=0))
    scale[scale == 0.0] = 1.0
    x = design / scale
    q, r = np.linalg.qr(x)
    params = np.linalg.solve(r, q.T @ y)
    dof = max(len(y) - design.shape[1], 1)
    residual = y - x @ params
    variance = np.sum(residual * residual, axis=0) / dof
    r_inv = np.linalg.inv(r)
    unit = r_inv @ r_inv.T / np.outer(scale, scale)
    return params / scale[:, None], variance[:, None, None] * unit[None, :, :]


def turn_timing(sample_end_s: np.ndarray, rate_hz: float, gyro_counts: np.ndarray, acc_counts: np.ndarray,
                frame_angle_rad: Callable[[np.ndarray], np.ndarray],
                frame_rate_rad_s: Callable[[np.ndarray], np.ndarray]) -> TurnTiming | None:
    """The timing observables of one rest-to-rest turn from its samples (increments in counts, each over the
    `1/rate_hz` before its end time) and the turning frame's angle and rate as functions of time; None when the
    turn has no cruise long enough (see the module)."""
    end = np.asarray(sample_end_s, dtype=float)
    start = end - 1.0 / rate_hz
    mid = 0.5 * (start + end)
    size = max(1, int(round(_BLOCK_S * rate_hz)))
    if len(end) < 10 * size:
        return None
    theta_a, theta_b, theta_m = (np.asarray(frame_angle_rad(t), dtype=float) for t in (start, end, mid))
    rate_a, rate_b = (np.asarray(frame_rate_rad_s(t), dtype=float) for t in (start, end))
    dt = end - start
    drift = (mid - mid.mean()) * dt
    gyro_design = np.column_stack([dt, drift, theta_b - theta_a, rate_b - rate_a, np.cos(theta_m) * dt,
                                   np.sin(theta_m) * dt])
    gp, gc = _fit(gyro_design, np.asarray(gyro_counts, dtype=float), size)
    p, q = gp[2], gp[3]
    delay = -q / p
    # delta method for -q/p
    grad_p, grad_q = q / p ** 2, -1.0 / p
    delay_var = grad_p ** 2 * gc[:, 2, 2] + grad_q ** 2 * gc[:, 3, 3] + 2.0 * grad_p * grad_q * gc[:, 2, 3]
    usable = np.abs(p) > _MIN_SNR * np.sqrt(gc[:, 2, 2])
    gyro_delay = np.where(usable, delay, math.nan)
    gyro_sigma = np.where(usable, np.sqrt(delay_var), math.nan)
    # the cruise: both ends of a sample at the peak rate
    peak = float(np.max(np.abs(np.concatenate([rate_a, rate_b]))))
    if peak == 0.0:
        return None
    cruise_rate = float(rate_b[int(np.argmax(np.abs(rate_b)))])
    cruise = (np.abs(rate_a - cruise_rate) <= _CRUISE_TOLERANCE * peak) & \
             (np.abs(rate_b - cruise_rate) <= _CRUISE_TOLERANCE * peak)
    nan3 = np.full(3, math.nan)
    if np.count_nonzero(cruise) < 10 * size \
            or abs(float(theta_b[cruise][-1] - theta_a[cruise][0])) < _MIN_CRUISE_ANGLE:
        return TurnTiming(cruise_rate, nan3, nan3, gyro_delay, gyro_sigma)
    ta, tb, tm, dtc = theta_a[cruise], theta_b[cruise], mid[cruise], dt[cruise]
    columns = [dtc, (tm - tm.mean()) * dtc]
    for k in (1, 2, 3):
        # the exact integrals of cos(k theta) and sin(k theta) over each sample at the constant rate
        columns += [(np.sin(k * tb) - np.sin(k * ta)) / (k * cruise_rate),
                    -(np.cos(k * tb) - np.cos(k * ta)) / (k * cruise_rate)]
    ap, ac = _fit(np.column_stack(columns), np.asarray(acc_counts, dtype=float)[cruise], size)
    alpha, beta = ap[2], ap[3]
    amplitude2 = alpha * alpha + beta * beta
    phase = np.arctan2(beta, alpha)
    phase_var = (beta ** 2 * ac[:, 2, 2] + alpha ** 2 * ac[:, 3, 3] - 2.0 * alpha * beta * ac[:, 2, 3]) \
        / np.maximum(amplitude2, 1e-300) ** 2
    seen = np.sqrt(amplitude2) > _MIN_SNR * np.sqrt(0.5 * (ac[:, 2, 2] + ac[:, 3, 3]))
    return TurnTiming(cruise_rate, np.where(seen, phase, math.nan), np.where(seen, np.sqrt(phase_var), math.nan),
                      gyro_delay, gyro_sigma)


__all__ = ["TurnTiming", "turn_timing"]
