"""The errors left after compensation, in physical units, from a verification run's observations.

The verification plan's dwells and turns are extracted as for a solve
(`bench.solve.extract`), then compensated with the calibration under test through the
same `Compensation` that `bench apply` uses (with the extended model's terms when the
result holds them: a dwell's means as samples, a turn's mean rate with its mean squared
input and axial specific force), and compared with their nominal inputs on an ideal table:

- positions: per accelerometer axis i, the compensated mean specific force minus the
  nominal one is fitted as `e_i = b_i + S_i . f_nominal` (weighted least squares): `b_i` is
  the **accelerometer bias error** (ug), `S_ii` the **scale-factor error** (ppm), `S_ij` the
  **misalignment** (arcsec: axis i's sensitivity to body axis j, the error of `Ea_Ji`).
  The compensated mean rate minus the nominal Earth rate, averaged, is the **gyro bias
  error** (deg/h);
- turns: for each body axis and rate, the compensated angle of a CCW and a CW turn minus
  the nominal `+-2 pi N u + Earth` (rad). Half the difference of the two, over `2 pi N`,
  is the **gyro scale-factor error** along the axis (ppm) and the **misalignment** towards
  the two other axes (arcsec, the error of `Eg_Kv`), the bias cancelling between the two.

Every error comes with its expanded uncertainty `U = 2 sqrt(s_meas^2 + s_cal^2 + s_table^2)`:
the verification data's own 1-sigma (dwell standard errors, turn integral sigmas; scaled up
by the residual scatter), the calibration's 1-sigma of the coefficient the error measures,
and the turntable's part (`bench.verify.table_part`: the pointing prior of the calibration's
budget pushed through the verification). Without a known prior a note says U leaves the
table out.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.calibration.compensation import Compensation, TriadCompensation
from bench.model.earth import Site
from bench.model.extended import FAMILIES
from bench.model.families import BODY_AXES, SENSOR_AXES
from bench.model.kinematics import attitude
from bench.model.observations import PositionObservation, RotationObservation, turn_axis_in_body
from bench.model.quality import texts
from bench.model.result import CalibrationResult
from bench.model.table_prior import TablePrior
from bench.model.units import ARCSEC, DEG, DEG_PER_HOUR, G0, MICRO_G
from bench.solve.calibrate import pooled_gyro_noise
from bench.solve.extract import Extraction
from bench.solve.methods import SolverError, fit_per_sensor, nominal_position_inputs
from bench.verify.table_part import table_sigmas

#: verification quantity -> (unit, what it is); the keys of `[acceptance.verification]` limits
QUANTITIES = {
    "gyro_bias_dph": ("deg/h", "gyro bias"),
    "gyro_scale_ppm": ("ppm", "gyro scale factor"),
    "gyro_misalignment_arcsec": ("arcsec", "gyro misalignment"),
    "acc_bias_ug": ("ug", "accelerometer bias"),
    "acc_scale_ppm": ("ppm", "accelerometer scale factor"),
    "acc_misalignment_arcsec": ("arcsec", "accelerometer misalignment"),
    # an extended result's gyro families (bench.model.extended; unit: the result's)
    "gyro_g_sensitivity_dph_per_g": ("deg/h per g", "gyro g-sensitivity"),
    "gyro_asymmetry_ppm": ("ppm", "gyro scale-factor asymmetry"),
    "gyro_nonlinearity_ppm_per_dps": ("ppm per deg/s", "gyro scale-factor nonlinearity"),
}
#: the quantities only the verification of a result with higher-order families determines
EXTENDED_QUANTITIES = ("gyro_g_sensitivity_dph_per_g", "gyro_asymmetry_ppm", "gyro_nonlinearity_ppm_per_dps")
COVERAGE_K = 2.0
_RATE_DECIMALS = 6


@dataclass(frozen=True)
class VerificationError:
    """One error after compensation: `name` (`gyro scale x @ 20 deg/s`), value and expanded uncertainty."""

    quantity: str          # a key of QUANTITIES
    name: str
    value: float
    uncertainty: float     # expanded, k = 2
    unit: str
    table_part: float = 0.0     # the turntable's part of `uncertainty` (expanded, k = 2; 0: not included)

    def __post_init__(self) -> None:        # plain floats (numpy scalars in, JSON out)
        object.__setattr__(self, "value", float(self.value))
        object.__setattr__(self, "uncertainty", float(self.uncertainty))
        object.__setattr__(self, "table_part", float(self.table_part))

    @property
    def within_uncertainty(self) -> bool:
        return bool(abs(self.value) <= self.uncertainty)

    def to_json(self) -> dict[str, Any]:
        return {"quantity": self.quantity, "name": self.name, "value": _finite(self.value),
                "uncertainty": _finite(self.uncertainty),
                "table_part": _finite(self.table_part), "k": COVERAGE_K, "unit": self.unit,
                "within_uncertainty": self.within_uncertainty}


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@dataclass
class Verification:
    """The errors of a verification run, and what could not be verified."""

    errors: list[VerificationError] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: where U's turntable part came from (the pointing prior's source); None: U leaves the table out
    table_source: str | None = None

    def of(self, quantity: str) -> list[VerificationError]:
        return [e for e in self.errors if e.quantity == quantity]

    def table_line(self) -> str:
        """What U says of the turntable, one line: included (from where), or left out and what that means."""
        if self.table_source is not None:
            return f"U includes the turntable's pointing error ({self.table_source})"
        return ("U leaves out the turntable's pointing error (not known: set [table] pointing_accuracy_arcsec or "
                "[table] check), so an error may exceed U by the table's part")

    def to_json(self) -> dict[str, Any]:
        return {"errors": [e.to_json() for e in self.errors], "notes": list(self.notes),
                "coverage_k": COVERAGE_K, "table_in_uncertainty": self.table_source, "table": self.table_line()}


def _sigma_of(result: CalibrationResult, name: str) -> float:
    c = result.coefficients.get(name)
    return c.sigma if c is not None and math.isfinite(c.sigma) else 0.0


def _relative_sigma_of(result: CalibrationResult, name: str) -> float:
    c = result.coefficients.get(name)
    return c.sigma / abs(c.value) if c is not None and math.isfinite(c.sigma) and c.value else 0.0


def _expanded(*sigmas: float) -> float:
    return COVERAGE_K * math.sqrt(sum(s * s for s in sigmas))


def _mapped_sigma(triad: TriadCompensation, sigma_counts: np.ndarray | None) -> np.ndarray:
    """1-sigma of compensated inputs for independent output sigmas (counts/s or counts)."""
    return np.sqrt((triad.matrix ** 2) @ (np.asarray(sigma_counts, dtype=float) ** 2))


def position_errors(obs: list[PositionObservation], compensation: Compensation, calibration: CalibrationResult,
                    site: Site, mounting=None) -> list[VerificationError]:
    """Accelerometer bias, scale and misalignment errors and gyro bias errors from the dwells."""
    angles = np.array([o.angles_deg for o in obs])
    f_nominal, w_nominal = nominal_position_inputs(angles, site, mounting)
    acc_mean = np.array([o.acc_mean for o in obs])
    gyro_mean = np.array([o.gyro_mean for o in obs])
    # as `bench apply` compensates samples (with the extended model's terms when the result holds them)
    w_compensated, f_compensated = compensation.compensate(gyro_mean, acc_mean)
    f_error = f_compensated - f_nominal
    w_error = w_compensated - w_nominal
    acc_sem = [o.standard_error("acc") for o in obs]
    gyro_sem = [o.standard_error("gyro") for o in obs]
    f_sigma = (np.array([_mapped_sigma(compensation.acc, s) for s in acc_sem])
               if all(s is not None for s in acc_sem) else None)
    w_sigma = (np.array([_mapped_sigma(compensation.gyro, s) for s in gyro_sem])
               if all(s is not None for s in gyro_sem) else None)
    errors = []
    acc_fit = fit_per_sensor(np.column_stack([np.ones(len(obs)), f_nominal]), f_error, f_sigma)
    for i, s in enumerate(SENSOR_AXES):
        sigma = np.sqrt(np.diag(acc_fit.cov[i]))
        bias = acc_fit.params[i, 0]
        errors.append(VerificationError("acc_bias_ug", f"acc bias {s}", bias / MICRO_G,
                                        _expanded(sigma[0] / MICRO_G, _sigma_of(calibration, f"K0_{s}") * G0 / MICRO_G),
                                        "ug"))
    for i, s in enumerate(SENSOR_AXES):
        sigma = np.sqrt(np.diag(acc_fit.cov[i]))
        errors.append(VerificationError("acc_scale_ppm", f"acc scale {s}", acc_fit.params[i, 1 + i] * 1e6,
                                        _expanded(sigma[1 + i] * 1e6, _relative_sigma_of(calibration, f"Ka_{s}") * 1e6),
                                        "ppm"))
    for i, s in enumerate(SENSOR_AXES):
        sigma = np.sqrt(np.diag(acc_fit.cov[i]))
        for j, axis in enumerate(BODY_AXES):
            if i != j:
                errors.append(VerificationError(
                    "acc_misalignment_arcsec", f"acc misalignment {s} to {axis}", acc_fit.params[i, 1 + j] / ARCSEC,
                    _expanded(sigma[1 + j] / ARCSEC, _sigma_of(calibration, f"Ea_{axis}{s}") / ARCSEC), "arcsec"))
    gyro_fit = fit_per_sensor(np.ones((len(obs), 1)), w_error, w_sigma)
    for i, s in enumerate(SENSOR_AXES):
        bias_sigma = math.sqrt(gyro_fit.cov[i, 0, 0])
        errors.append(VerificationError("gyro_bias_dph", f"gyro bias {s}", gyro_fit.params[i, 0] / DEG_PER_HOUR,
                                        _expanded(bias_sigma / DEG_PER_HOUR, _sigma_of(calibration, f"D0_{s}")),
                                        "deg/h"))
    if compensation.higher_order is not None:
        errors += _g_sensitivity_errors(f_nominal, w_error, w_sigma, calibration)
    return errors


def _g_sensitivity_errors(f_nominal: np.ndarray, w_error: np.ndarray, w_sigma: np.ndarray | None,
                          calibration: CalibrationResult) -> list[VerificationError]:
    """Gyro g-sensitivity errors: per gyro i, the dwells' rate errors fitted as `b_i + G_i . f_nominal`; `G_ij`
    (deg/h per g) is what the compensation left of gyro i's sensitivity to the specific force along body axis j."""
    fit = fit_per_sensor(np.column_stack([np.ones(len(f_nominal)), f_nominal]), w_error, w_sigma)
    to_result = 1.0 / FAMILIES["gyro_g_sensitivity"].result_to_si
    errors = []
    for i, s in enumerate(SENSOR_AXES):
        sigma = np.sqrt(np.diag(fit.cov[i]))
        for j, axis in enumerate(BODY_AXES):
            errors.append(VerificationError(
                "gyro_g_sensitivity_dph_per_g", f"gyro g-sensitivity {s} to {axis}", fit.params[i, 1 + j] * to_result,
                _expanded(sigma[1 + j] * to_result, _sigma_of(calibration, f"Gg_{axis}{s}")), "deg/h per g"))
    return errors


def _turn_error(obs: RotationObservation, compensation: Compensation, site: Site, mounting,
                noise_density: np.ndarray | None) -> tuple[int, float, np.ndarray, np.ndarray] | None:
    """(axis k, sign of the axis, error vector rad, its 1-sigma rad) of one turn; None if not along an axis."""
    u = turn_axis_in_body(obs.start_deg, obs.frame_index, mounting=mounting)
    k = int(np.argmax(np.abs(u)))
    if abs(abs(u[k]) - 1.0) > 1e-9:
        return None
    start = attitude(np.asarray(obs.start_deg) * DEG, mounting=mounting)
    # the extended model's terms over the turn: the mean specific force is its axial part (exact for a vertical
    # axis, as the solve takes it) and the mean squared input the turn's squared-rate integral
    force = float(u @ (start @ site.specific_force_enu)) * u
    input_sq = None if obs.rate_sq_integral is None else u * u * obs.rate_sq_integral / obs.duration_s
    angle = compensation.body_rate(obs.gyro_integral / obs.duration_s, force, input_sq) * obs.duration_s
    earth = obs.earth_integral_rad
    if earth is None:
        earth = obs.duration_s * float(u @ (start @ site.earth_rate_enu)) * u
    nominal = obs.sign * 2.0 * math.pi * obs.revolutions * u + earth
    # the integral's noise: its own sigma, else the static dwells' white-noise density over the turn's length
    counts_sigma = obs.gyro_integral_sigma
    if counts_sigma is None and noise_density is not None:
        counts_sigma = noise_density * math.sqrt(obs.duration_s)
    sigma = _mapped_sigma(compensation.gyro, counts_sigma) if counts_sigma is not None else np.zeros(3)
    # in the frame of +axis k: a turn about -X is a turn about +X the other way
    sign = 1.0 if u[k] > 0 else -1.0
    return k, sign * obs.sign, angle - nominal, sigma


def rotation_errors(obs: list[RotationObservation], rates_dps: dict[str, float], compensation: Compensation,
                    calibration: CalibrationResult, site: Site, mounting=None,
                    noise_density: np.ndarray | None = None) -> tuple[list[VerificationError], list[str]]:
    """Gyro scale-factor (per axis and rate) and misalignment errors from CCW/CW turn pairs (`noise_density`:
    the gyros' white noise, counts/s sqrt(s), for turns without their own integral sigma)."""
    groups: dict[tuple[int, float], dict[float, list]] = {}
    notes = []
    for o in obs:
        found = _turn_error(o, compensation, site, mounting, noise_density)
        if found is None:
            notes.append(f"{o.label}: the turn's axis is not along a body axis: not used")
            continue
        k, direction, error, sigma = found
        rate = round(rates_dps.get(o.label, math.nan), _RATE_DECIMALS)
        groups.setdefault((k, rate), {}).setdefault(direction, []).append(
            (error, sigma, o.revolutions, o.duration_s, o.rate_sq_integral))
    errors = []
    for (k, rate), by_direction in sorted(groups.items()):
        at = f" @ {rate:g} deg/s" if math.isfinite(rate) else ""
        if set(by_direction) != {1.0, -1.0}:
            notes.append(f"turns about body {BODY_AXES[k]}{at}: no CCW/CW pair, not used")
            continue
        (e_p, s_p, n_p, *_), (e_m, s_m, n_m, *_) = by_direction[1.0][0], by_direction[-1.0][0]
        if n_p != n_m:
            notes.append(f"turns about body {BODY_AXES[k]}{at}: CCW and CW of different revolutions, not used")
            continue
        # e_p = +2 pi N m + b T, e_m = -2 pi N m + b T (m: the scale error along k and the leaks into v)
        span = 2.0 * (2.0 * math.pi * n_p)
        diff, sigma = (e_p - e_m) / span, np.hypot(s_p, s_m) / span
        sensor = SENSOR_AXES[k]
        scale_sigma_cal = _relative_sigma_of(calibration, f"Kg_{sensor}") * 1e6
        errors.append(VerificationError("gyro_scale_ppm", f"gyro scale {sensor}{at}", diff[k] * 1e6,
                                        _expanded(sigma[k] * 1e6, scale_sigma_cal), "ppm"))
        for v in range(3):
            if v != k:
                errors.append(VerificationError(
                    "gyro_misalignment_arcsec", f"gyro misalignment {SENSOR_AXES[v]} to {BODY_AXES[k]}{at}",
                    diff[v] / ARCSEC, _expanded(sigma[v] / ARCSEC,
                                                _sigma_of(calibration, f"Eg_{BODY_AXES[k]}{SENSOR_AXES[v]}") / ARCSEC),
                    "arcsec"))
    if compensation.higher_order is not None:
        family_errors, family_notes = _turn_family_errors(groups, calibration)
        errors += family_errors
        notes += family_notes
    return errors, notes


def _turn_family_errors(groups: dict[tuple[int, float], dict[float, list]], calibration: CalibrationResult
                        ) -> tuple[list[VerificationError], list[str]]:
    """Gyro asymmetry and nonlinearity errors from the CCW/CW pairs about each body axis at three rates or more.

    Half the sum of a pair's angle errors along the turn axis k is what a reversal does not cancel,
    `b T + Ag_k/2 2 pi N + Ng_k Q` (T the turn's duration, Q its squared-rate integral; b the bias and the
    g-sensitivity along the axis, left by the compensation during the turns): one weighted fit over the rates
    separates the three, its `Ag` and `Ng` are the errors of the families (the bias goes with 1/rate, the
    asymmetry not at all, the nonlinearity with the rate)."""
    by_axis: dict[int, list[tuple[float, float, float, float, float]]] = {}
    notes = []
    for (k, _rate), by_direction in sorted(groups.items()):
        if set(by_direction) != {1.0, -1.0}:
            continue                                # (noted with the scale factor)
        (e_p, s_p, n_p, t_p, q_p), (e_m, s_m, n_m, t_m, q_m) = by_direction[1.0][0], by_direction[-1.0][0]
        if n_p != n_m or q_p is None or q_m is None:
            continue
        by_axis.setdefault(k, []).append((0.5 * (e_p[k] + e_m[k]), 0.5 * math.hypot(s_p[k], s_m[k]),
                                          0.5 * (t_p + t_m), 2.0 * math.pi * n_p, 0.5 * (q_p + q_m)))
    asymmetry_to_result = 2.0 / FAMILIES["gyro_asymmetry"].result_to_si      # the fit's Ag/2 -> ppm
    nonlinearity_to_result = 1.0 / FAMILIES["gyro_nonlinearity"].result_to_si
    errors = []
    for k in range(3):
        rows = by_axis.get(k, [])
        if len(rows) < 3:
            notes.append(f"turns about body {BODY_AXES[k]}: CCW/CW pairs at {len(rows)} rate(s), 3 are needed for "
                         "the gyro asymmetry and nonlinearity errors")
            continue
        half_sum, sigma, duration, angle, rate_sq = (np.array(c) for c in zip(*rows))
        try:
            fit = fit_per_sensor(np.column_stack([duration, angle, rate_sq]), half_sum[:, None],
                                 sigma[:, None] if np.all(sigma > 0) else None)
        except SolverError as exc:
            notes.append(f"turns about body {BODY_AXES[k]}: {exc}: no gyro asymmetry or nonlinearity errors")
            continue
        # three rates without the turns' noise (a noise-free simulation): the fit has no scatter to scale by, its
        # own part of U is left out (NaN otherwise)
        fit_sigma = np.nan_to_num(np.sqrt(np.diag(fit.cov[0])))
        sensor = SENSOR_AXES[k]
        errors.append(VerificationError(
            "gyro_asymmetry_ppm", f"gyro asymmetry {sensor}", fit.params[0, 1] * asymmetry_to_result,
            _expanded(fit_sigma[1] * asymmetry_to_result, _sigma_of(calibration, f"Ag_{sensor}")), "ppm"))
        errors.append(VerificationError(
            "gyro_nonlinearity_ppm_per_dps", f"gyro nonlinearity {sensor}", fit.params[0, 2] * nonlinearity_to_result,
            _expanded(fit_sigma[2] * nonlinearity_to_result, _sigma_of(calibration, f"Ng_{sensor}")),
            "ppm per deg/s"))
    return errors, notes


def _errors(positions: list[PositionObservation], rotations: list[RotationObservation], rates_dps: dict[str, float],
            compensation: Compensation, calibration: CalibrationResult, site: Site,
            mounting=None) -> tuple[list[VerificationError], list[str]]:
    """The errors these dwells and turns determine, and notes on what they cannot."""
    errors: list[VerificationError] = []
    notes = []
    if len(positions) >= 4:
        try:
            errors += position_errors(positions, compensation, calibration, site, mounting)
        except SolverError as exc:
            notes.append(f"positions: {exc}: no accelerometer or gyro bias errors")
    else:
        notes.append(f"{len(positions)} positions: at least 4 are needed for the accelerometer and gyro bias errors")
    if rotations:
        density = pooled_gyro_noise(positions)
        turn_errors, turn_notes = rotation_errors(rotations, rates_dps, compensation, calibration, site, mounting,
                                                  density)
        errors += turn_errors
        notes += turn_notes
    else:
        notes.append("no turns: no gyro scale-factor or misalignment errors")
    return errors, notes


def verify_extraction(extraction: Extraction, rates_dps: dict[str, float], compensation: Compensation,
                      calibration: CalibrationResult, site: Site, mounting=None,
                      table: TablePrior | None = None) -> Verification:
    """All the errors the verification's observations determine (a note for what they cannot); with `table`
    (the turntable's pointing prior, as the calibration's budget has it) each U includes the table's part
    (`bench.verify.table_part`), without it a note says that U leaves the table out."""
    errors, notes = _errors(extraction.positions, extraction.rotations, rates_dps, compensation, calibration, site,
                            mounting)
    out = Verification(notes=texts(extraction.problems) + notes)
    if table is None:
        out.errors = errors
        return out

    def errors_of(positions: list[PositionObservation], rotations: list[RotationObservation]) -> dict[str, float]:
        found, _ = _errors(positions, rotations, rates_dps, compensation, calibration, site, mounting)
        return {e.name: e.value for e in found}

    sigmas = table_sigmas(extraction, rates_dps, calibration, site, table, errors_of, mounting)
    out.errors = [dataclasses.replace(e, uncertainty=math.hypot(e.uncertainty, COVERAGE_K * sigmas.get(e.name, 0.0)),
                                      table_part=COVERAGE_K * sigmas.get(e.name, 0.0)) for e in errors]
    out.table_source = table.source
    return out


__all__ = ["COVERAGE_K", "EXTENDED_QUANTITIES", "QUANTITIES", "Verification", "VerificationError", "position_errors",
           "rotation_errors", "verify_extraction"]
