"""The simulated UOT turntable: true frame motion plus black-box errors (no I/O, no clock).

Each axis (outer, middle, inner) is a sorted list of constant-acceleration
`bench.model.motion.Piece`s in rad, rad/s, rad/s^2. Commands take the simulated time `t`
(s) at which they are issued and replace that axis's future from `t` on. Angles are
absolute and never wrapped; a positive angle rate is the paper's "clockwise", so a CCW
turn has a negative angle rate (docs/explanation/model.md#frame-rotations).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.model import kinematics
from bench.model.earth import Site
from bench.model.motion import Piece, PieceArrays, active_piece, piece_arrays, sample_piece_arrays, trapezoid_pieces
from bench.model.units import DEG
from schedules.loader import Direction, Frame

FRAMES = kinematics.FRAMES


@dataclass(frozen=True)
class TableLimits:
    """Per-axis rate and acceleration limits (outer, middle, inner) in deg/s and deg/s^2."""

    max_rate_dps: tuple[float, float, float] = (200.0, 200.0, 300.0)
    max_accel_dps2: tuple[float, float, float] = (50.0, 50.0, 100.0)

    def __post_init__(self) -> None:
        for name in ("max_rate_dps", "max_accel_dps2"):
            values = tuple(float(v) for v in np.ravel(getattr(self, name)))
            if len(values) != 3 or not all(math.isfinite(v) and v > 0 for v in values):
                raise ValueError(f"{name} must be three positive finite values, got {getattr(self, name)}")
            object.__setattr__(self, name, values)


def _frame_index(frame: Frame | int) -> int:
    if isinstance(frame, (int, np.integer)) and 0 <= int(frame) < 3:
        return int(frame)
    if isinstance(frame, str) and frame.lower() in FRAMES:
        return FRAMES.index(frame.lower())
    raise ValueError(f"frame must be one of {FRAMES} (or 0-2), got {frame!r}")


def _checked(value: float, limit: float, name: str, k: int) -> float:
    """One axis's rate or accel in display units; outside (0, limit] -> ValueError."""
    value = float(value)
    if not (math.isfinite(value) and 0 < value <= limit):
        raise ValueError(f"{name} for the {FRAMES[k]} axis must be in (0, {limit}], got {value}")
    return value


def _per_axis(value, limit: tuple[float, float, float], name: str) -> np.ndarray:
    """A scalar or 3-sequence (None -> the limits) checked against the limits, in display units."""
    values = limit if value is None else np.broadcast_to(np.asarray(value, dtype=float), (3,))
    return np.array([_checked(values[k], limit[k], name, k) for k in range(3)])


class SimTable:
    """True motion of a UOT table: three axes of constant-acceleration pieces + black box.

    The IMU is taken to sit at the centre of rotation: `specific_force` has no
    lever-arm (centripetal or tangential) terms, only gravity's specific force.
    """

    def __init__(self, site: Site | None = None, black_box_rad: np.ndarray | None = None,
                 mounting: np.ndarray | None = None, limits: TableLimits = TableLimits(),
                 start_deg=(0.0, 0.0, 0.0)):
        self.site = site if site is not None else Site()
        self.black_box = None if black_box_rad is None else np.asarray(black_box_rad, dtype=float).reshape(3, 3)
        self.mounting = None if mounting is None else np.asarray(mounting, dtype=float).reshape(3, 3)
        self.limits = limits
        start = np.asarray(start_deg, dtype=float).reshape(3) * DEG
        self._axes: list[list[Piece]] = [[Piece(0.0, float(th), 0.0, 0.0)] for th in start]
        # each axis's pieces as arrays, with the pieces they were made from (Pieces are immutable: the same
        # pieces, compared element by element, identity first, mean the same arrays)
        self._arrays: list[tuple[tuple[Piece, ...], PieceArrays] | None] = [None, None, None]
        self._starts: tuple[tuple[tuple[Piece, ...], ...], np.ndarray] | None = None

    # -- command helpers -----------------------------------------------------------
    def _accel_limit(self, k: int) -> float:
        return self.limits.max_accel_dps2[k] * DEG

    def _accel(self, k: int, accel_dps2: float | None) -> float:
        """Axis k's commanded accel in rad/s^2 (None -> the limit)."""
        lim = self.limits.max_accel_dps2[k]
        return _checked(lim if accel_dps2 is None else accel_dps2, lim, "accel_dps2", k) * DEG

    def _cut(self, k: int, t: float) -> tuple[float, float]:
        """Drop axis k's pieces from t on; return its (angle, rate) at t."""
        pieces = self._axes[k]
        active = active_piece(pieces, t)
        theta, rate = active.at(max(t, active.t0))
        self._axes[k] = [p for p in pieces if p.t0 < t]
        return theta, rate

    def _to_rest(self, k: int, t: float, accel: float) -> tuple[float, float]:
        """Cut axis k at t and append a deceleration to rest; return (rest time, rest angle)."""
        theta, rate = self._cut(k, t)
        if rate == 0.0:
            return t, theta
        piece = Piece(t, theta, rate, -math.copysign(accel, rate))
        t_rest = t + abs(rate) / accel
        self._axes[k].append(piece)
        return t_rest, piece.at(t_rest)[0]

    def _move_axis(self, k: int, t: float, target: float, rate: float, accel: float) -> float:
        """Rest-to-rest move of axis k to `target` (rad), after stopping it if it moves at t."""
        t_start, theta = self._to_rest(k, t, self._accel_limit(k))
        if target == theta:
            self._axes[k].append(Piece(t_start, target, 0.0, 0.0))
            return t_start
        pieces = trapezoid_pieces(t_start, theta, target - theta, rate, accel)
        end = pieces[-1].t0
        pieces[-1] = Piece(end, target, 0.0, 0.0)  # land exactly on the commanded angle
        self._axes[k].extend(pieces)
        return end

    # -- commands ----------------------------------------------------------------
    def move_to(self, t: float, angles_deg, rate_dps=None, accel_dps2=None) -> float:
        """Move all three axes (starting together, each its own trapezoid) to absolute angles.

        Returns the time the last axis comes to rest. Rate/accel default to the limits
        (scalar or per axis); values above the limits raise ValueError.
        """
        target = np.asarray(angles_deg, dtype=float).reshape(3) * DEG
        rate = _per_axis(rate_dps, self.limits.max_rate_dps, "rate_dps") * DEG
        accel = _per_axis(accel_dps2, self.limits.max_accel_dps2, "accel_dps2") * DEG
        if not np.all(np.isfinite(target)):
            raise ValueError(f"angles_deg must be finite, got {angles_deg}")
        return max(self._move_axis(k, t, float(target[k]), float(rate[k]), float(accel[k])) for k in range(3))

    def move_axis(self, t: float, frame: Frame | int, angle_deg: float, rate_dps: float | None = None,
                  accel_dps2: float | None = None) -> float:
        """Rest-to-rest move of one frame to an absolute angle, the others untouched; returns its rest time."""
        k = _frame_index(frame)
        if not math.isfinite(angle_deg):
            raise ValueError(f"angle_deg must be finite, got {angle_deg}")
        rate = _checked(self.limits.max_rate_dps[k] if rate_dps is None else rate_dps,
                        self.limits.max_rate_dps[k], "rate_dps", k) * DEG
        return self._move_axis(k, t, float(angle_deg) * DEG, rate, self._accel(k, accel_dps2))

    def turn(self, t: float, frame: Frame | int, direction: Direction, revolutions: int, rate_dps: float,
             accel_dps2: float | None = None) -> float:
        """Rest-to-rest turn of one frame by whole revolutions; returns the time it is at rest.

        "ccw" decreases the angle by 360*N deg (a positive right-handed rotation about the
        frame axis), "cw" increases it.
        """
        k = _frame_index(frame)
        d = direction.lower() if isinstance(direction, str) else direction
        if d not in ("ccw", "cw"):
            raise ValueError(f"direction must be 'ccw' or 'cw', got {direction!r}")
        if int(revolutions) != revolutions or revolutions < 1:
            raise ValueError(f"revolutions must be a positive whole number, got {revolutions}")
        rate = _checked(rate_dps, self.limits.max_rate_dps[k], "rate_dps", k) * DEG
        accel = self._accel(k, accel_dps2)
        t_start, theta = self._to_rest(k, t, self._accel_limit(k))
        distance = (-1.0 if d == "ccw" else 1.0) * 2.0 * math.pi * int(revolutions)
        pieces = trapezoid_pieces(t_start, theta, distance, rate, accel)
        self._axes[k].extend(pieces)
        return pieces[-1].t0

    def set_rate(self, t: float, frame: Frame | int, rate_dps: float, accel_dps2: float | None = None) -> float:
        """Rate mode: ramp one frame to the signed angle rate (deg/s) and hold it; returns when reached."""
        k = _frame_index(frame)
        lim = self.limits.max_rate_dps[k]
        if not (math.isfinite(rate_dps) and abs(rate_dps) <= lim):
            raise ValueError(f"|rate_dps| for the {FRAMES[k]} axis must be <= {lim}, got {rate_dps}")
        accel = self._accel(k, accel_dps2)
        target = float(rate_dps) * DEG
        theta, rate = self._cut(k, t)
        t_end = t
        if target != rate:
            ramp = Piece(t, theta, rate, math.copysign(accel, target - rate))
            t_end = t + abs(target - rate) / accel
            theta = ramp.at(t_end)[0]
            self._axes[k].append(ramp)
        self._axes[k].append(Piece(t_end, theta, target, 0.0))
        return t_end

    def stop(self, t: float, accel_dps2: float | None = None) -> float:
        """All axes decelerate to rest at the max (or given) accel; returns when the last one rests."""
        accel = _per_axis(accel_dps2, self.limits.max_accel_dps2, "accel_dps2") * DEG
        ends = []
        for k in range(3):
            t_rest, theta = self._to_rest(k, t, float(accel[k]))
            self._axes[k].append(Piece(t_rest, theta, 0.0, 0.0))
            ends.append(t_rest)
        return max(ends)

    # -- sampling (vectorised over times) ---------------------------------------
    def _piece_arrays(self, k: int) -> PieceArrays:
        """Axis k's pieces as `piece_arrays` (made again only when its pieces changed)."""
        pieces, cached = tuple(self._axes[k]), self._arrays[k]
        if cached is not None and cached[0] == pieces:
            return cached[1]
        arrays = piece_arrays(pieces)
        self._arrays[k] = (pieces, arrays)
        return arrays

    def piece_starts(self) -> np.ndarray:
        """The start times of every axis's pieces, sorted, each once (where the motion may have a kink)."""
        pieces = tuple(tuple(axis) for axis in self._axes)
        if self._starts is None or self._starts[0] != pieces:
            self._starts = (pieces, np.unique(np.concatenate([self._piece_arrays(k)[0] for k in range(3)])))
        return self._starts[1]

    def _sample(self, times) -> tuple[np.ndarray, np.ndarray]:
        times = np.asarray(times, dtype=float)
        flat = times.reshape(-1)
        th, rt = zip(*(sample_piece_arrays(self._piece_arrays(k), flat) for k in range(3)))
        shape = times.shape + (3,)
        return np.stack(th, axis=-1).reshape(shape), np.stack(rt, axis=-1).reshape(shape)

    def angles(self, times) -> np.ndarray:
        """Frame angles (rad), shape times.shape + (3,): (n, 3) for an array, (3,) for a scalar."""
        return self._sample(times)[0]

    def frame_rates(self, times) -> np.ndarray:
        """Frame angle rates d(angle)/dt (rad/s, paper convention), shape times.shape + (3,)."""
        return self._sample(times)[1]

    def _evaluate(self, times) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(C_t^b, body rate, specific force) at times, shapes times.shape + (3, 3) / (3,) / (3,).

        Consecutive times with identical angles and rates (axes at rest) share one
        kinematics evaluation, which makes long dwells cheap; the results are the same
        as evaluating each time on its own.
        """
        times = np.asarray(times, dtype=float)
        angles, rates = self._sample(times.reshape(-1))
        first = np.ones(len(angles), dtype=bool)
        first[1:] = np.any((angles[1:] != angles[:-1]) | (rates[1:] != rates[:-1]), axis=1)
        index = np.cumsum(first) - 1
        angles, rates = angles[first], rates[first]
        c_tb, frame_motion = kinematics.attitude_and_body_rate(angles, rates, self.black_box, self.mounting)
        w_b = c_tb @ self.site.earth_rate_enu + frame_motion
        f_b = c_tb @ self.site.specific_force_enu
        return tuple(x[index].reshape(times.shape + x.shape[1:]) for x in (c_tb, w_b, f_b))

    def attitude(self, times) -> np.ndarray:
        """True `C_t^b` including black box and mounting, shape times.shape + (3, 3)."""
        return self._evaluate(times)[0]

    def body_rate(self, times) -> np.ndarray:
        """Inertial body angular velocity (rad/s), shape times.shape + (3,).

        `C_t^b w_ie_t` (Earth rate) plus the frame motion relative to the ground
        (`kinematics.body_rate_from_frame_rates`).
        """
        return self._evaluate(times)[1]

    def specific_force(self, times) -> np.ndarray:
        """Specific force in body axes (m/s^2): `C_t^b f_t`, shape times.shape + (3,).

        The IMU is assumed at the centre of rotation: no centripetal or tangential
        lever-arm terms are modelled.
        """
        return self._evaluate(times)[2]

    def body_rate_and_specific_force(self, times) -> tuple[np.ndarray, np.ndarray]:
        """`(body_rate(times), specific_force(times))` with one evaluation of the motion."""
        return self._evaluate(times)[1:]

    # -- inspection -----------------------------------------------------------------
    def pieces(self, frame: Frame | int) -> list[Piece]:
        """A copy of one axis's trajectory (Pieces are immutable)."""
        return list(self._axes[_frame_index(frame)])

    def axis_at(self, t: float, frame: Frame | int) -> tuple[float, float, float]:
        """(angle rad, rate rad/s, accel rad/s^2) of one frame at time t."""
        p = active_piece(self._axes[_frame_index(frame)], t)
        theta, rate = p.at(max(t, p.t0))
        return theta, rate, (p.accel if t >= p.t0 else 0.0)

    def is_at_rest(self, t: float) -> bool:
        """True when every axis has zero rate and zero acceleration at t."""
        for pieces in self._axes:
            p = active_piece(pieces, t)
            if p.accel != 0.0 or p.at(max(t, p.t0))[1] != 0.0:
                return False
        return True
