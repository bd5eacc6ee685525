"""Which higher-order families a schedule observes, and how well (issue 30 item 3, `bench schedules analyze`).

The plan's exact observations of the simulated IMU are weighted as a noisy IMU's would be (white noise and
quantisation per dwell or turn, as `bench.schedule_design.sensitivity`) and solved with each family of
`bench.model.extended` in turn (`bench.solve.extended.predicted_sigmas`). A family is **observed** when its
columns leave the fit full rank; it is **confounded** with another when each is observed alone but not the two
together. The predicted 1-sigma is the sample-noise part (the budget's other parts come on top).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from bench.model.closed_form import exact_observations, turn_rates_dps
from bench.model.earth import Site
from bench.model.extended import FAMILIES, TERMS
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu
from bench.model.kinematics import attitude
from bench.model.units import DEG, MICRO_G
from bench.solve.extended import predicted_sigmas
from bench.solve.methods import SolverError

#: the families each kind of schedule can show on its own (the lever arms need positions and turns)
POSITION_TERMS = ("gyro_g_sensitivity", "acc_asymmetry", "acc_second_order", "acc_cross")
ROTATION_TERMS = ("gyro_asymmetry", "gyro_nonlinearity")


@dataclass
class FamilyObservability:
    term: str
    observed: bool
    sigma: dict[str, float]              # coefficient -> predicted 1-sigma (result units), when observed
    confounded_with: list[str]           # families observed alone that this one cannot be told from
    reason: str = ""                     # why not observed


def _observations(angles_deg, turns, noise: NoiseModel, dwell_s: float, rate_dps: float, accel_dps2: float,
                  site: Site, imu: ImuCoefficients, mounting=None):
    angles = np.zeros((0, 3)) if angles_deg is None else np.asarray(angles_deg, dtype=float).reshape(-1, 3)
    positions, rotations = exact_observations(angles, list(turns), imu, site, rate_dps=rate_dps, dwell_s=dwell_s,
                                              mounting=mounting)
    gyro_density = max(noise.gyro_arw_deg_rt_h * DEG / 60.0, 1e-12)       # rad/s * sqrt(s)
    acc_density = max(noise.acc_vrw_ug_rt_hz * MICRO_G, 1e-12)            # m/s^2 * sqrt(s)
    positions = [dataclasses.replace(o, gyro_sem=imu.gyro_scale * gyro_density / math.sqrt(o.duration_s),
                                     acc_sem=imu.acc_scale * acc_density / math.sqrt(o.duration_s))
                 for o in positions]
    accel = accel_dps2 * DEG
    rates = turn_rates_dps(list(turns), rate_dps) * DEG        # each turn's own rate, else rate_dps
    # the accelerometer sums at the start attitude's force: exact for a turn about a vertical axis, the only turns
    # the lever arms use (a lever arm of the simulated IMU is zero)
    forces = np.array([attitude(np.asarray(o.start_deg, dtype=float) * DEG) @ site.specific_force_enu
                       for o in rotations]).reshape(-1, 3)
    rotations = [dataclasses.replace(o, gyro_integral_sigma=imu.gyro_scale * gyro_density * math.sqrt(o.duration_s),
                                     rate_sq_integral=rate * 2.0 * math.pi * o.revolutions - rate ** 3 / (3.0 * accel),
                                     acc_integral=imu.acc_output(force) * o.duration_s)
                 for o, rate, force in zip(rotations, rates, forces)]
    return positions, rotations


def extended_observability(angles_deg, turns, noise: NoiseModel, dwell_s: float = 60.0, rate_dps: float = 10.0,
                           accel_dps2: float = 5.0, site: Site | None = None,
                           terms: tuple[str, ...] | None = None, mounting=None) -> list[FamilyObservability]:
    """Per family of `terms` (default: the ones a schedule of this kind can show), whether the plan observes it,
    the predicted 1-sigma of its coefficients and the families it is confounded with; for an IMU mounted with
    `mounting` (`C_i^b`, None: the fixture's axes), in its own axes."""
    site = site or Site()
    imu = default_sim_imu()
    positions, rotations = _observations(angles_deg, turns, noise, dwell_s, rate_dps, accel_dps2, site, imu,
                                         mounting)
    if terms is None:
        terms = tuple(t for t in TERMS if (t in POSITION_TERMS and positions) or (t in ROTATION_TERMS and rotations)
                      or (t == "acc_lever_arm" and positions and rotations))
    prior = imu if not rotations else None

    def sigmas(chosen: tuple[str, ...]) -> dict[str, float] | str:
        try:
            return predicted_sigmas(positions, rotations, site, chosen, mounting, gyro_prior=prior)
        except SolverError as exc:
            return str(exc)

    alone = {t: sigmas((t,)) for t in terms}
    out = []
    for term in terms:
        result = alone[term]
        if isinstance(result, str):
            out.append(FamilyObservability(term, False, {}, [], result))
            continue
        confounded = [other for other in terms if other != term and isinstance(alone[other], dict)
                      and isinstance(sigmas((term, other)), str)]
        out.append(FamilyObservability(term, True, {n: result[n] for n in FAMILIES[term].names if n in result},
                                       confounded))
    return out


def observability_lines(rows: list[FamilyObservability]) -> list[str]:
    """The report of `extended_observability` as text lines."""
    lines = []
    for row in rows:
        family = FAMILIES[row.term]
        if not row.observed:
            lines.append(f"  {row.term:<20} not observed ({row.reason})")
            continue
        worst = max(row.sigma.values()) if row.sigma else math.nan
        lines.append(f"  {row.term:<20} observed: 1-sigma up to {worst:.3g} {family.result_unit}"
                     + (f"; confounded with {', '.join(row.confounded_with)}" if row.confounded_with else ""))
        lines.append("      " + ", ".join(f"{name} {value:.3g}" for name, value in row.sigma.items()))
    return lines


__all__ = ["FamilyObservability", "POSITION_TERMS", "ROTATION_TERMS", "extended_observability",
           "observability_lines"]
