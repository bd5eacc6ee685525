"""The gyro-to-accelerometer time offset from the turns' timing (`bench.model.turn_timing`; issue 30,
docs/explanation/extended-model.md#time-offset).

Two weighted least squares, each with its scatter tested against its sigmas (an inconsistent one is scaled up by
chi-square / dof, the budget's "unexplained"):
- the accelerometers' delay behind the table, tau_a: each accelerometer's phase in each turn is
  `phi_g + w tau_a`, one nuisance phase `phi_g` per group of turns with the same frame, start and sensor (the
  attitude and misalignments, which do not change with the direction), so only groups turned at two rates
  (both directions) tell tau_a;
- the gyros' delay behind the table, tau_g: the weighted mean of each gyro's delay in each turn.
The offset is `tau_a - tau_g` (the accelerometers late: positive), a common clock offset of IMU and table cancels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc

from bench.model.observations import RotationObservation
from bench.solve.budget import CONSISTENCY_ALPHA
from bench.solve.methods import SolverError


@dataclass(frozen=True)
class TimeOffsetEstimate:
    """The offset (s) with its sigma from the sample noise and the whole (noise, scaled up where inconsistent)."""

    value_s: float
    noise_sigma_s: float
    sigma_s: float
    acc_delay_s: float
    gyro_delay_s: float
    turns: int


def _consistent_scale(chi2: float, dof: int) -> float:
    """The variance factor: chi2/dof where the scatter is inconsistent with the sigmas, else 1."""
    return chi2 / dof if dof > 0 and chdtrc(dof, chi2) < CONSISTENCY_ALPHA else 1.0


def acc_delay(rotations: list[RotationObservation]) -> tuple[float, float, float, int]:
    """(tau_a, noise variance, variance, turns used) from the accelerometers' phases."""
    groups: dict[tuple, list[tuple[float, float, float]]] = {}
    for o in rotations:
        timing = o.timing
        assert timing is not None
        for s in range(3):
            phase, sigma = float(timing.acc_phase_rad[s]), float(timing.acc_phase_sigma_rad[s])
            if math.isfinite(phase) and math.isfinite(sigma) and sigma > 0:
                key = (o.frame, tuple(round(a, 6) for a in o.start_deg), s)
                groups.setdefault(key, []).append((timing.rate_rad_s, phase, sigma))
    sxx = sxy = 0.0
    rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    turns = 0
    for members in groups.values():
        rates, phases, sigmas = (np.array(x) for x in zip(*members))
        if np.ptp(rates) <= 1e-9 * np.max(np.abs(rates)):
            continue                        # one rate only: its phase is all nuisance
        phases = phases[0] + np.angle(np.exp(1j * (phases - phases[0])))     # unwrapped about the first
        w = 1.0 / sigmas ** 2
        x = rates - np.sum(w * rates) / np.sum(w)
        y = phases - np.sum(w * phases) / np.sum(w)
        sxx += float(np.sum(w * x * x))
        sxy += float(np.sum(w * x * y))
        rows.append((x, y, w))
        turns += len(members)
    if sxx == 0.0:
        raise SolverError("time_offset: no turn about an axis across gravity was made in both directions from one "
                          "start with its accelerometers seeing the gravity sinusoid")
    tau = sxy / sxx
    chi2 = sum(float(np.sum(w * (y - tau * x) ** 2)) for x, y, w in rows)
    dof = sum(len(x) - 1 for x, _, _ in rows) - 1
    return tau, 1.0 / sxx, _consistent_scale(chi2, dof) / sxx, turns


def gyro_delay(rotations: list[RotationObservation]) -> tuple[float, float, float]:
    """(tau_g, noise variance, variance) from the gyros' delays."""
    delays = np.array([o.timing.gyro_delay_s for o in rotations if o.timing is not None]).reshape(-1)
    sigmas = np.array([o.timing.gyro_delay_sigma_s for o in rotations if o.timing is not None]).reshape(-1)
    keep = np.isfinite(delays) & np.isfinite(sigmas) & (sigmas > 0)
    if not keep.any():
        raise SolverError("time_offset: no turn shows a gyro's rate ramps (its delay behind the table)")
    w = 1.0 / sigmas[keep] ** 2
    tau = float(np.sum(w * delays[keep]) / np.sum(w))
    chi2 = float(np.sum(w * (delays[keep] - tau) ** 2))
    var = 1.0 / float(np.sum(w))
    return tau, var, _consistent_scale(chi2, int(keep.sum()) - 1) * var


def estimate_time_offset(rotations: list[RotationObservation]) -> TimeOffsetEstimate:
    """The gyro-to-accelerometer time offset from the turns that carry their timing (SolverError: none tells it)."""
    timed = [o for o in rotations if o.timing is not None]
    if not timed:
        raise SolverError("time_offset: the turns carry no timing (samples against the table's angle)")
    tau_a, noise_a, var_a, turns = acc_delay(timed)
    tau_g, noise_g, var_g = gyro_delay(timed)
    return TimeOffsetEstimate(tau_a - tau_g, math.sqrt(noise_a + noise_g), math.sqrt(var_a + var_g), tau_a, tau_g,
                              turns)


__all__ = ["TimeOffsetEstimate", "acc_delay", "estimate_time_offset", "gyro_delay"]
