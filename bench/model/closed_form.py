"""Exact (noise-free, closed-form) IMU outputs at positions and over constant-rate turns.

Used by the Monte-Carlo evaluation (vectorised over black boxes) and to build exact
observations for the solver; the sampled simulated world is checked against it.
"""

from __future__ import annotations

import math

import numpy as np

from bench.model.earth import Site
from bench.model.imu import ImuCoefficients
from bench.model.kinematics import attitude, frame_matrix_parts, split_at_frame
from bench.model.observations import DIRECTION_SIGN, FRAME_INDEX, PositionObservation, RotationObservation
from bench.model.units import DEG


def position_outputs(angles_deg: np.ndarray, imu: ImuCoefficients, site: Site, black_box_rad=None,
                     mounting=None) -> tuple[np.ndarray, np.ndarray]:
    """Gyro and accelerometer outputs (counts/s) at rest at each position.

    `angles_deg` (K, 3); `black_box_rad` None, (3, 3) or (R, 3, 3) -> outputs (K, 3) or (R, K, 3).
    """
    angles = np.asarray(angles_deg, dtype=float) * DEG
    bb = None if black_box_rad is None else np.asarray(black_box_rad, dtype=float)
    if bb is not None and bb.ndim == 3:
        angles, bb = angles[None, :, :], bb[:, None, :, :]
    c_tb = attitude(angles, bb, mounting)
    return imu.gyro_output(c_tb @ site.earth_rate_enu), imu.acc_output(c_tb @ site.specific_force_enu)


def turn_rates_dps(turns, rate_dps) -> np.ndarray:
    """Each turn's rate (K,): its own `rate_dps` when it has one (a schedule step of a version-2 "rotations" or a
    "verification" schedule), else `rate_dps` (one rate, or one per turn)."""
    default = np.broadcast_to(np.asarray(rate_dps, dtype=float), (len(turns),))
    return np.array([own if (own := getattr(turn, "rate_dps", None)) is not None else default[k]
                     for k, turn in enumerate(turns)], dtype=float)


def turn_closed_form(turns, site: Site, rate_dps, black_box_rad=None,
                     mounting=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation vector, Earth integral (both rad, body axes) and duration of constant-rate turns.

    `turns` are objects with start_deg, frame, direction, revolutions; each turns at its own
    `rate_dps` if it has one, else at `rate_dps` (`turn_rates_dps`). Over whole
    revolutions at constant rate the frame matrix averages to its axial part P, so
    the Earth integral is `T L P R w_ie`. Shapes (R, K, 3) for black boxes (R, 3, 3),
    else (K, 3); durations (K,).
    """
    bb = None if black_box_rad is None else np.asarray(black_box_rad, dtype=float)
    batch = bb.shape[:-2] if bb is not None else ()
    rot, earth, durations = [], [], []
    for turn, rate in zip(turns, turn_rates_dps(turns, rate_dps)):
        k = FRAME_INDEX[turn.frame]
        duration = 360.0 * turn.revolutions / float(rate)
        left, right = split_at_frame(np.asarray(turn.start_deg, dtype=float) * DEG, k, bb, mounting)
        p, _, _ = frame_matrix_parts(k)
        axis = left @ p.diagonal()          # frame axis in body = L e_axis (P = e e^T)
        rot.append(np.broadcast_to(DIRECTION_SIGN[turn.direction] * 2.0 * math.pi * turn.revolutions * axis,
                                   batch + (3,)))
        earth.append(np.broadcast_to(duration * (left @ p @ right @ site.earth_rate_enu), batch + (3,)))
        durations.append(duration)
    return np.stack(rot, axis=-2), np.stack(earth, axis=-2), np.array(durations)


def turn_integrals(turns, imu: ImuCoefficients, site: Site, rate_dps, black_box_rad=None,
                   mounting=None) -> tuple[np.ndarray, np.ndarray]:
    """Gyro outputs integrated over each constant-rate turn (counts) and the durations."""
    rot, earth, durations = turn_closed_form(turns, site, rate_dps, black_box_rad, mounting)
    bias_counts = durations[:, None] * (imu.gyro_scale * imu.gyro_bias)
    return (rot + earth) @ imu.gyro_matrix.T + bias_counts, durations


def exact_observations(position_angles_deg, turns, imu: ImuCoefficients, site: Site, rate_dps: float = 10.0,
                       black_box_rad=None, mounting=None, dwell_s: float = 60.0,
                       sample_rate_hz: float = 1000.0) -> tuple[list[PositionObservation], list[RotationObservation]]:
    """Noise-free observations of a schedule on a (possibly erroneous) table.

    Rotation observations carry the nominal Earth integral, as the solver would get
    from the recorded (ideal-table) trajectory.
    """
    positions = []
    if len(position_angles_deg):
        gyro, acc = position_outputs(position_angles_deg, imu, site, black_box_rad, mounting)
        n = int(round(dwell_s * sample_rate_hz))
        positions = [PositionObservation(tuple(a), dwell_s, n, g, f, np.zeros(3), np.zeros(3), label=f"P{k + 1:02d}")
                     for k, (a, g, f) in enumerate(zip(position_angles_deg, gyro, acc))]
    rotations = []
    if len(turns):
        integral, durations = turn_integrals(turns, imu, site, rate_dps, black_box_rad, mounting)
        _, earth_nominal, _ = turn_closed_form(turns, site, rate_dps, mounting=mounting)
        for k, turn in enumerate(turns):
            rotations.append(RotationObservation(
                tuple(turn.start_deg), turn.frame, turn.direction, turn.revolutions, float(durations[k]),
                int(round(durations[k] * sample_rate_hz)), integral[k], earth_integral_rad=earth_nominal[k],
                label=f"R{k + 1:02d}"))
    return positions, rotations
