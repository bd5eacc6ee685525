"""Solver observations from a run's record: one per dwell, one per turn (the log is the source of truth).

Inputs are what a run log holds: the sequencer's events (each finished observation
step carries the IMU counter window it recorded; `bench.log.events` parses them), the decoded IMU samples (unwrapped
counters, per-sample increments) and the polled table states. The same function
serves the live run (which solves from the log it just wrote) and `bench solve`.

- Dwell: mean output rate over the window's samples, with block-mean standard errors
  (`bench.model.observations.mean_and_standard_error`). Missing samples (counter gaps) only
  shorten the dwell; they are reported, naming the dwell.
- Turn: the gyro increments summed over the window (rest to rest). A turn with a
  missing sample cannot be integrated and is left out, with the reason. The Earth-rate
  integral is nominal: the window length times the Earth rate at the initial attitude,
  plus the change while the frame moves, integrated along the frame angles the
  controller reported (piecewise linear between polls). Where the motion sits inside
  the window does not matter because a turn of whole revolutions starts and ends in
  the same attitude.
- Lost samples are told apart by where they fell (`Extraction.lost_in_windows`): inside a
  dwell's or turn's counter window, or outside every one (moves, settles: no observation
  uses those samples).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from bench.log.events import Event, TurnRecord, finished_observation_steps, malformed_observation_steps
from bench.model.earth import Site
from bench.model.kinematics import FRAMES
from bench.model.motion import Piece
from bench.model.observations import (
    PositionObservation,
    RotationObservation,
    mean_and_standard_error,
    rounding_bias_variance,
    turn_earth_integral,
)
from bench.model.quality import FailureKind, QualityFailure, window_loss
from bench.model.units import DEG
from drivers.imu.layout import describe_status


@dataclass
class Extraction:
    positions: list[PositionObservation] = field(default_factory=list)
    rotations: list[RotationObservation] = field(default_factory=list)
    problems: list[QualityFailure] = field(default_factory=list)   # one per step left out or degraded
    #: unit -> samples missing from the sample counters inside its dwell or turn window (units without loss absent)
    lost_in_windows: dict[str, int] = field(default_factory=dict)
    lost_outside: int = 0       # lost samples outside every window (`bench.solve.from_logs` counts them)
    #: (unit, earlier log, later log): a unit two logs completed, the later log's observation kept
    replaced: list[tuple[str, str, str]] = field(default_factory=list)

    @property
    def units(self) -> list[str]:
        return [o.label for o in self.positions] + [o.label for o in self.rotations]

    def lost_samples(self) -> dict[str, Any]:
        """Where the samples lost on the IMU link fell, as a result records it (`run.lost_samples`): `total`,
        `in_windows` (unit -> count, the windows of the dwells and turns) and `outside_windows`."""
        inside = sum(self.lost_in_windows.values())
        return {"total": inside + self.lost_outside, "in_windows": dict(sorted(self.lost_in_windows.items())),
                "outside_windows": self.lost_outside}


def without_windows(lost: dict[str, Any], units: set[str]) -> dict[str, Any]:
    """`Extraction.lost_samples()` with the samples lost in the windows of `units` counted as outside every window
    (the windows a subset solve does not use)."""
    moved = sum(n for unit, n in lost["in_windows"].items() if unit in units)
    return {"total": lost["total"], "in_windows": {u: n for u, n in lost["in_windows"].items() if u not in units},
            "outside_windows": lost["outside_windows"] + moved}


def missing_in_window(counter: np.ndarray, window: slice, first: int, last: int) -> int:
    """Counters of [first, last] missing from `counter` (sorted, unique; `window` its part inside), counted only
    between the first and the last counter decoded: a window reaching past them was cut, not lost on the link."""
    if not len(counter):
        return 0
    lo, hi = max(first, int(counter[0])), min(last, int(counter[-1]))
    return max(0, hi - lo + 1 - (window.stop - window.start)) if lo <= hi else 0


_PIECES_AT_ONCE = 256   # table-state pieces per Earth-rate integral call (see `_turn_earth_integral`)


def _window(counter: np.ndarray, first: int, last: int) -> slice:
    lo, hi = np.searchsorted(counter, [first, last + 1])
    return slice(int(lo), int(hi))


def _turn_earth_integral(site: Site, turn: TurnRecord, samples_duration_s: float, t0: float, t1: float,
                         state_time_s: np.ndarray, state_angles_deg: np.ndarray, mounting) -> np.ndarray:
    k = FRAMES.index(turn.frame)
    start_nominal = np.asarray(turn.start_deg, dtype=float)
    rest = [Piece(0.0, start_nominal[k] * DEG, 0.0, 0.0)]
    base = turn_earth_integral(site, start_nominal, k, rest, 0.0, samples_duration_s, mounting=mounting)
    inside = np.flatnonzero((state_time_s >= t0) & (state_time_s <= t1))
    # the states in time order, one per time (a recorded log's already are; a log from outside may repeat)
    times, first = np.unique(state_time_s[inside], return_index=True)
    if len(times) < 2:
        return base
    # Frame angle in the schedule's nominal terms (the controller's is multi-turn).
    theta = (state_angles_deg[inside[first], k] - turn.target_deg[k] + start_nominal[k]) * DEG
    pieces = [Piece(float(times[i]), float(theta[i]), float((theta[i + 1] - theta[i]) / (times[i + 1] - times[i])), 0.0)
              for i in range(len(times) - 1)]
    pieces.append(Piece(float(times[-1]), float(theta[-1]), 0.0, 0.0))
    span = float(times[-1] - times[0])
    # the integral is additive over time: many states are taken a block at a time (its cost grows with the
    # square of the pieces given at once)
    moving = np.zeros(3)
    for a in range(0, len(pieces) - 1, _PIECES_AT_ONCE):
        b = min(a + _PIECES_AT_ONCE, len(pieces) - 1)
        moving = moving + turn_earth_integral(site, start_nominal, k, pieces[a:b + 1], float(times[a]),
                                              float(times[b]), mounting=mounting)
    at_rest = turn_earth_integral(site, start_nominal, k, rest, 0.0, span, mounting=mounting)
    return base + moving - at_rest


def _rate_squared(turn: TurnRecord, t0: float, t1: float, state_time_s: np.ndarray,
                  state_angles_deg: np.ndarray) -> float | None:
    """Integral of the turning frame's squared rate (rad^2/s) between the polled table states (piecewise
    constant rate between polls; None without two polls in the turn)."""
    k = FRAMES.index(turn.frame)
    inside = np.flatnonzero((state_time_s >= t0) & (state_time_s <= t1))
    times, first = np.unique(state_time_s[inside], return_index=True)
    if len(times) < 2:
        return None
    theta = state_angles_deg[inside[first], k] * DEG
    return float(np.sum(np.diff(theta) ** 2 / np.diff(times)))


def extract_observations(events: Sequence[Event], counter: np.ndarray, gyro_counts: np.ndarray, acc_counts: np.ndarray,
                         rate_hz: float, site: Site, state_time_s: np.ndarray, state_angles_deg: np.ndarray,
                         mounting=None, status: np.ndarray | None = None,
                         status_invalid: int = 0, status_required: int = 0,
                         output_step: tuple[float, ...] | None = None) -> Extraction:
    """Observations of every finished dwell and turn, in the order the units were listed (P.., R..).

    A dwell or turn holding a sample whose `status` has any of the `status_invalid` bits (a fault, a saturated
    output, outputs not yet valid), or lacking any of the `status_required` bits (sbg-ecan's health bits), is
    left out, saying so: its mean or integral would be silently wrong.

    `output_step` (6 channels, counts/s): an IMU that sends each sample's value rounded on its own
    (`ImuLayout.output_step`, sbg-ecan); its rounding enters the dwells' standard errors and each turn's
    `rounding_var` (`bench.model.observations.rounding_bias_variance`); None: a counter output."""
    out = Extraction(problems=[QualityFailure(FailureKind.MALFORMED_STEP, line, unit)
                               for unit, line in malformed_observation_steps(events).items()])
    counter = np.asarray(counter, dtype=np.int64)
    resolution = None if output_step is None else np.asarray(output_step, dtype=float)
    flagged = None
    if status is not None and (status_invalid or status_required):
        status = np.asarray(status, dtype=np.int64)
        flagged = (status & status_invalid) | (~status & status_required)
    for unit, (started, finished) in sorted(finished_observation_steps(events).items()):
        record, counters = finished.record, finished.window
        assert record is not None and counters is not None        # a usable finished step has both
        first, last = counters.first, counters.last
        window = _window(counter, first, last)
        n = window.stop - window.start
        expected = last - first + 1
        missing = missing_in_window(counter, window, first, last)
        if missing:
            out.lost_in_windows[unit] = missing
        if n == 0:
            out.problems.append(QualityFailure(
                FailureKind.NO_SAMPLES, f"{unit}: no IMU samples in its window (counters {first}..{last}); left out",
                unit))
            continue
        if flagged is not None and flagged[window].any():
            bits = int(np.bitwise_or.reduce(flagged[window]))
            out.problems.append(QualityFailure(
                FailureKind.FLAGGED, f"{unit}: {int(np.count_nonzero(flagged[window]))} of {n} samples flagged "
                f"unusable by the IMU ({describe_status(bits, status_invalid, status_required)}); left out", unit))
            continue
        if not isinstance(record, TurnRecord):
            if n < expected:
                out.problems.append(window_loss(unit, False, expected - n, expected))
            gyro_mean, gyro_std, gyro_sem = mean_and_standard_error(
                gyro_counts[window] * rate_hz, duration_s=n / rate_hz,
                output_step=None if resolution is None else resolution[:3])
            acc_mean, acc_std, acc_sem = mean_and_standard_error(
                acc_counts[window] * rate_hz, duration_s=n / rate_hz,
                output_step=None if resolution is None else resolution[3:])
            out.positions.append(PositionObservation(record.angles_deg, n / rate_hz, n, gyro_mean, acc_mean,
                                                     gyro_std, acc_std, gyro_sem, acc_sem, label=unit,
                                                     start_s=first / rate_hz, output_step=output_step))
        else:
            if n < expected:
                out.problems.append(window_loss(unit, True, expected - n, expected))
                continue
            t0 = started.time_s if started is not None else -np.inf
            earth = _turn_earth_integral(site, record, n / rate_hz, t0, finished.time_s, state_time_s,
                                         state_angles_deg, mounting)
            out.rotations.append(RotationObservation(
                record.start_deg, record.frame, record.direction, record.revolutions, n / rate_hz, n,
                gyro_counts[window].sum(axis=0), earth_integral_rad=earth, label=unit,
                start_s=first / rate_hz, acc_integral=acc_counts[window].sum(axis=0),
                rate_sq_integral=_rate_squared(record, t0, finished.time_s, state_time_s, state_angles_deg)))
    if resolution is not None:
        _turn_rounding(out, resolution[:3])
    return out


def _turn_rounding(out: Extraction, gyro_step: np.ndarray) -> None:
    """Each turn's rounding variance (counts^2): the part of the per-sample rounding (counts/s) that the gyros'
    own noise does not dither away, constant over the turn's window T at worst, hence times T^2. The noise is
    the dwells' pooled per-sample scatter (none without dwells: the undithered worst case, step^2/12)."""
    stds = [o.gyro_std for o in out.positions if o.gyro_std is not None]
    std = np.sqrt(np.mean(np.square(stds), axis=0)) if stds else np.zeros(3)
    per_second = rounding_bias_variance(std, gyro_step)
    for o in out.rotations:
        o.rounding_var = per_second * o.duration_s ** 2
