"""One-axis motion as pieces of constant acceleration (trapezoidal moves, turns, rate mode).

Angles in rad, rates in rad/s, accelerations in rad/s^2, time in s. A trajectory is a
sorted list of `Piece`s; each holds from its `t0` until the next piece starts.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Piece:
    """Constant acceleration from `t0`: theta(t) = theta0 + rate0*dt + accel*dt^2/2."""

    t0: float
    theta0: float
    rate0: float
    accel: float

    def at(self, t: float) -> tuple[float, float]:
        dt = t - self.t0
        return self.theta0 + self.rate0 * dt + 0.5 * self.accel * dt * dt, self.rate0 + self.accel * dt


def trapezoid_timing(distance: float, max_rate: float, max_accel: float) -> tuple[float, float, float]:
    """(ramp time, cruise time, peak rate) of a rest-to-rest move over |distance|.

    A move too short to reach `max_rate` becomes a triangle with a lower peak.
    """
    if max_rate <= 0 or max_accel <= 0:
        raise ValueError(f"max_rate and max_accel must be positive, got {max_rate}, {max_accel}")
    d = abs(distance)
    if d * max_accel >= max_rate * max_rate:
        ramp = max_rate / max_accel
        return ramp, (d - max_rate * ramp) / max_rate, max_rate
    peak = math.sqrt(d * max_accel)
    return peak / max_accel, 0.0, peak


def trapezoid_pieces(t0: float, theta0: float, distance: float, max_rate: float,
                     max_accel: float) -> list[Piece]:
    """Pieces of a rest-to-rest trapezoidal move by signed `distance`, ending in a hold."""
    sign = 1.0 if distance >= 0 else -1.0
    ramp, cruise, peak = trapezoid_timing(distance, max_rate, max_accel)
    a, v = sign * max_accel, sign * peak
    pieces = [Piece(t0, theta0, 0.0, a)]
    theta = theta0 + 0.5 * a * ramp * ramp
    t = t0 + ramp
    if cruise > 0:
        pieces.append(Piece(t, theta, v, 0.0))
        theta += v * cruise
        t += cruise
    pieces.append(Piece(t, theta, v, -a))
    # The hold lands exactly on the target so that whole revolutions stay whole.
    pieces.append(Piece(t + ramp, theta0 + distance, 0.0, 0.0))
    return pieces


def active_piece(pieces: list[Piece], t: float) -> Piece:
    """The piece in effect at time t (the first one before it starts)."""
    # (the pieces are in time order: a bisection on their start times, as np.searchsorted side="right" finds it)
    k = bisect.bisect_right(pieces, t, key=_start_time) - 1
    return pieces[max(0, k)]


def _start_time(piece: Piece) -> float:
    return piece.t0


#: (start times, start angles, start rates, accelerations) of a trajectory's pieces
PieceArrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def piece_arrays(pieces: Sequence[Piece]) -> PieceArrays:
    """(start times, start angles, start rates, accelerations) of `pieces` as arrays."""
    return (np.array([p.t0 for p in pieces]), np.array([p.theta0 for p in pieces]),
            np.array([p.rate0 for p in pieces]), np.array([p.accel for p in pieces]))


def sample_piece_arrays(arrays: PieceArrays, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`sample_pieces` of the pieces whose `piece_arrays` are `arrays`."""
    times = np.asarray(times, dtype=float)
    t0, th0, v0, a = arrays
    k = np.clip(np.searchsorted(t0, times, side="right") - 1, 0, len(t0) - 1)
    dt = np.maximum(times - t0[k], 0.0)
    return th0[k] + v0[k] * dt + 0.5 * a[k] * dt * dt, v0[k] + a[k] * dt


def sample_pieces(pieces: list[Piece], times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Angle and rate of a trajectory at `times` (vectorised). Before the first piece it holds."""
    return sample_piece_arrays(piece_arrays(pieces), times)


# Gauss-Legendre nodes for integrating smooth functions over one piece.
_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)


def trig_integrals(pieces: list[Piece], t_start: float, t_end: float) -> tuple[float, float]:
    """(int cos(theta) dt, int sin(theta) dt) over [t_start, t_end] along the trajectory.

    Exact on constant-rate pieces; 48-point Gauss-Legendre on accelerating pieces
    (smooth integrands over at most a few radians: machine precision).
    """
    starts = [p.t0 for p in pieces]
    edges = [t_start] + [b for b in starts if t_start < b < t_end] + [t_end]
    ic = is_ = 0.0
    for a, b in zip(edges[:-1], edges[1:]):
        if b <= a:
            continue
        k = int(np.searchsorted(starts, 0.5 * (a + b), side="right")) - 1
        # Before the first piece the axis holds its first angle.
        piece = pieces[k] if k >= 0 else Piece(a, pieces[0].theta0, 0.0, 0.0)
        th_a, rate_a = piece.at(a)
        th_b, _ = piece.at(b)
        if piece.accel == 0.0 and rate_a != 0.0:
            ic += (math.sin(th_b) - math.sin(th_a)) / rate_a
            is_ += (math.cos(th_a) - math.cos(th_b)) / rate_a
        elif piece.accel == 0.0:
            ic += math.cos(th_a) * (b - a)
            is_ += math.sin(th_a) * (b - a)
        else:
            t = 0.5 * (a + b) + 0.5 * (b - a) * _GL_X
            th = piece.theta0 + piece.rate0 * (t - piece.t0) + 0.5 * piece.accel * (t - piece.t0) ** 2
            w = 0.5 * (b - a) * _GL_W
            ic += float(w @ np.cos(th))
            is_ += float(w @ np.sin(th))
    return ic, is_
