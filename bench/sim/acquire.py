"""Run a schedule through the simulated world and reduce it to solver observations.

A stand-in for the sequencer + log extraction until those exist: it moves the
`SimTable`, lets the `SimImu` sample the true motion, and computes per-position means
and per-turn rest-to-rest integrals exactly as the solver expects them.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from bench.model.kinematics import triple
from bench.model.observations import (
    FRAME_INDEX,
    PositionObservation,
    RotationObservation,
    mean_and_standard_error,
    rate_squared_integral,
    turn_earth_integral,
)
from bench.model.turn_timing import turn_timing
from bench.plan.compiler import PlanTiming
from bench.sim.imu import ImuSamples, SimImu
from bench.sim.table import SimTable

#: The in-memory acquisition takes the same timing as a compiled plan (revolutions and
#: move overhead are not used here: turns keep their own revolutions).
AcquisitionTiming = PlanTiming
_DEFAULT_TIMING = AcquisitionTiming()


def _window(samples: ImuSamples, t0: float, t1: float) -> np.ndarray:
    """Mask of the samples whose whole interval lies inside [t0, t1]."""
    dt = 1.0 / samples.rate_hz
    return (samples.time_s - dt >= t0 - 1e-9) & (samples.time_s <= t1 + 1e-9)


def _frame_motion(table: SimTable, k: int) -> tuple[Callable[[np.ndarray], np.ndarray],
                                                    Callable[[np.ndarray], np.ndarray]]:
    """Frame k's angle (rad) and rate (rad/s) as functions of time: the table's encoder, exact."""
    def angle(t: np.ndarray) -> np.ndarray:
        return table.angles(t)[:, k]

    def rate(t: np.ndarray) -> np.ndarray:
        return table.frame_rates(t)[:, k]
    return angle, rate


def acquire(table: SimTable, imu: SimImu, position_angles_deg, turns,
            timing: AcquisitionTiming = _DEFAULT_TIMING, turn_timings: bool = False) -> tuple[
                list[PositionObservation], list[RotationObservation]]:
    """Observe every position (dwell) then every turn (rest to rest) of a schedule.

    `turns` are objects with start_deg, frame, direction, revolutions (schedule steps); a turn with its own
    `rate_dps` (not None) turns at that rate, the others at `timing.turn_rate_dps`. `turn_timings`: also reduce
    each turn's samples to the timing the time offset needs (`bench.model.turn_timing`) against the table's exact
    angle.
    The nominal Earth integral of each turn is computed from the table's commanded
    trajectory without the black box, as the solver would from recorded angles.
    """
    t = imu.last_time_s
    positions: list[PositionObservation] = []
    for k, angles in enumerate(position_angles_deg):
        arrive = table.move_to(t, angles, timing.move_rate_dps, timing.move_accel_dps2)
        start = arrive + timing.settle_s
        end = start + timing.dwell_s
        block = imu.generate(table, end)
        mask = _window(block, start, end)
        n = int(mask.sum())
        gyro_mean, gyro_std, gyro_sem = mean_and_standard_error(block.gyro_rate[mask], duration_s=n / block.rate_hz)
        acc_mean, acc_std, acc_sem = mean_and_standard_error(block.acc_rate[mask], duration_s=n / block.rate_hz)
        positions.append(PositionObservation(
            triple(angles), n / block.rate_hz, n, gyro_mean, acc_mean, gyro_std, acc_std,
            gyro_sem, acc_sem, label=f"P{k + 1:02d}", start_s=start))
        t = end
    rotations: list[RotationObservation] = []
    for k, turn in enumerate(turns):
        arrive = table.move_to(t, turn.start_deg, timing.move_rate_dps, timing.move_accel_dps2)
        window_start = arrive + timing.settle_s
        own_rate_dps = getattr(turn, "rate_dps", None)
        stop = table.turn(window_start + timing.rest_s, turn.frame, turn.direction, turn.revolutions,
                          timing.turn_rate_dps if own_rate_dps is None else own_rate_dps, timing.turn_accel_dps2)
        window_end = stop + timing.rest_s
        block = imu.generate(table, window_end)
        mask = _window(block, window_start, window_end)
        n = int(mask.sum())
        first = block.time_s[mask][0] - 1.0 / block.rate_hz
        last = block.time_s[mask][-1]
        seen = None
        if turn_timings:
            seen = turn_timing(block.time_s[mask], block.rate_hz, block.gyro_counts[mask], block.acc_counts[mask],
                               *_frame_motion(table, FRAME_INDEX[turn.frame]))
        earth = turn_earth_integral(table.site, turn.start_deg, FRAME_INDEX[turn.frame],
                                    table.pieces(turn.frame), first, last, mounting=table.mounting)
        rotations.append(RotationObservation(
            triple(turn.start_deg), turn.frame, turn.direction, turn.revolutions,
            n / block.rate_hz, n, block.gyro_counts[mask].sum(axis=0), earth_integral_rad=earth,
            label=f"R{k + 1:02d}", start_s=float(first), acc_integral=block.acc_counts[mask].sum(axis=0),
            rate_sq_integral=rate_squared_integral(table.pieces(turn.frame), float(first), float(last)),
            timing=seen))
        t = window_end
    return positions, rotations
