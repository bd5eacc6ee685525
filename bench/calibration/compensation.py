"""The compensation of a calibration: the inverse of the IMU model (docs/explanation/model.md#imu-model).

The model, per sensor s (outputs `F`, `J` in counts/s):

    gyro:  F_s = Kg_s (Eg_s . w_b + D0_s)        accel:  J_s = Ka_s (Ea_s . f_b + K0_s)

per triad in matrix form `y = K E u + K d` with `K = diag(scale)`, `E` the rows of direction
cosines, `d` the biases (input units). Its inverse, what firmware applies:

    u_b = C (y - b),   C = (K E)^-1,   b = K d

`C` in SI input units per counts/s (rad/s per counts/s, m/s^2 per counts/s), `b` in counts/s
(the output at zero input). A positive bias `D0` raises the output, so it is subtracted.
Uncertainties (1-sigma) are propagated to first order from the result's coefficient
sigmas, taken as independent (the result file holds no covariances).

A result of the extended model (`[model] terms`) adds the higher-order families; `Compensation.compensate`
then takes their error off the raw outputs before the linear inverse (`bench.calibration.higher_order`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from bench.calibration.higher_order import HigherOrderCompensation, HigherOrderError, higher_order_of, time_offset_of
from bench.errors import InputError
from bench.model.families import BODY_AXES, RESULT_UNITS, SENSOR_AXES, canonical_names
from bench.model.result import CalibrationResult
from bench.model.units import DEG, G0

#: the two triads: (key, scale family, bias family, axes family, SI input unit, what it measures)
TRIADS = (("gyro", "Kg", "D0", "Eg", "rad/s", "body angular rate w_b"),
          ("acc", "Ka", "K0", "Ea", "m/s^2", "body specific force f_b"))
RAW_UNIT = "counts/s"

#: samples the extended model's compensation takes at once
_CHUNK = 8192
#: output units `compensate` can give: name -> factor SI -> that unit
RATE_UNITS = {"rad/s": 1.0, "deg/s": 1.0 / DEG}
FORCE_UNITS = {"m/s^2": 1.0, "g": 1.0 / G0}

EQUATIONS = {
    "gyro": "w_b = C_gyro (F - b_gyro); C_gyro = (diag(Kg) Eg)^-1, b_gyro = diag(Kg) D0",
    "acc": "f_b = C_acc (J - b_acc); C_acc = (diag(Ka) Ea)^-1, b_acc = diag(Ka) K0",
}


class CompensationError(InputError):
    """A result that does not give a full compensation (a coefficient missing, a singular matrix)."""


@dataclass(frozen=True)
class TriadCompensation:
    """`u_b = matrix (y - bias_counts)` for one triad, with 1-sigma uncertainties (NaN: unknown)."""

    sensor: str                 # "gyro" | "acc"
    input_unit: str             # SI unit of u_b: "rad/s" | "m/s^2"
    matrix: np.ndarray          # (3, 3) input_unit per counts/s
    bias_counts: np.ndarray     # (3,) counts/s
    matrix_sigma: np.ndarray    # (3, 3)
    bias_sigma: np.ndarray      # (3,)
    scale: np.ndarray           # (3,) the model's K per sensor axis, counts/s per input_unit
    input_bias: np.ndarray      # (3,) the model's bias d in input_unit (bias_counts = scale * input_bias)

    @property
    def axes(self) -> np.ndarray:
        """The model's direction cosines E (3, 3), dimensionless: `(diag(scale) E)^-1 = matrix`."""
        return np.linalg.inv(self.matrix) / self.scale[:, None]

    @property
    def matrix_unit(self) -> str:
        return f"{self.input_unit} per {RAW_UNIT}"

    def apply(self, outputs: np.ndarray) -> np.ndarray:
        """Compensated inputs (..., 3) in SI for raw outputs (..., 3) in counts/s."""
        # matrix @ (y - b).T: the same products and sums as (y - b) @ matrix.T, a tenth of its time on (n, 3)
        return (self.matrix @ (np.asarray(outputs, dtype=float) - self.bias_counts).T).T


@dataclass(frozen=True)
class Compensation:
    """The compensation of both triads, and who it is for (from the result's `run`)."""

    gyro: TriadCompensation
    acc: TriadCompensation
    imu_model: str = ""
    imu_serial: str = ""
    run_id: str = ""
    calibrated_utc: str = ""
    software_version: str = ""
    #: the extended model's families the result holds (None: only the 30 coefficients)
    higher_order: HigherOrderCompensation | None = None
    #: the gyro-to-accelerometer time offset (s) and its 1-sigma (NaN: unknown), when the result has one: exported,
    #: not compensated (it would take resampling one stream against the other)
    time_offset: tuple[float, float] | None = None

    def triads(self) -> tuple[TriadCompensation, TriadCompensation]:
        return self.gyro, self.acc

    def specific_force(self, acc_counts_per_s: np.ndarray, body_rate: np.ndarray) -> np.ndarray:
        """Specific forces (..., 3), m/s^2, for raw accelerometer outputs (counts/s); `body_rate` (rad/s, the
        compensated one) is what the lever arms need."""
        f0 = self.acc.apply(acc_counts_per_s)
        higher = self.higher_order
        if higher is None or not higher.has_acc:
            return f0
        x = (np.asarray(acc_counts_per_s, dtype=float) - self.acc.bias_counts) / self.acc.scale
        # at the input less the error at the measured input (one fixed-point step: bench.calibration.higher_order)
        error = higher.acc_error(x - higher.acc_error(x, f0), f0)
        error = error + higher.lever_arm_force(np.asarray(body_rate, dtype=float))
        return self.acc.apply(acc_counts_per_s - self.acc.scale * error)

    def body_rate(self, gyro_counts_per_s: np.ndarray, specific_force: np.ndarray,
                  input_sq: np.ndarray | None = None) -> np.ndarray:
        """Body rates (..., 3), rad/s, for raw gyro outputs (counts/s); `specific_force` (m/s^2, the linear estimate
        will do) is what the g-sensitivity needs, `input_sq` the mean squared gyro input ((rad/s)^2; default: the
        input's square)."""
        higher = self.higher_order
        if higher is None or not higher.has_gyro:
            return self.gyro.apply(gyro_counts_per_s)
        x = (np.asarray(gyro_counts_per_s, dtype=float) - self.gyro.bias_counts) / self.gyro.scale
        force = np.asarray(specific_force, dtype=float)
        # at the input less the error at the measured input (one fixed-point step: bench.calibration.higher_order)
        x = x - higher.gyro_error(x, x * x if input_sq is None else input_sq, force)
        error = higher.gyro_error(x, x * x if input_sq is None else input_sq, force)
        return self.gyro.apply(gyro_counts_per_s - self.gyro.scale * error)

    def compensate(self, gyro_counts_per_s: np.ndarray, acc_counts_per_s: np.ndarray, *,
                   rate_unit: str = "rad/s", force_unit: str = "m/s^2") -> tuple[np.ndarray, np.ndarray]:
        """Body rates and specific forces for raw outputs (counts/s), in the units asked for."""
        if self.higher_order is None:
            return (self.gyro.apply(gyro_counts_per_s) * RATE_UNITS[rate_unit],
                    self.acc.apply(acc_counts_per_s) * FORCE_UNITS[force_unit])
        gyro, acc = np.asarray(gyro_counts_per_s, dtype=float), np.asarray(acc_counts_per_s, dtype=float)
        if gyro.ndim == 2 and len(gyro) > _CHUNK:
            # in pieces whose temporaries stay in the cache: the higher-order terms take some thirty array operations
            parts = [self.compensate(gyro[lo:lo + _CHUNK], acc[lo:lo + _CHUNK], rate_unit=rate_unit,
                                     force_unit=force_unit) for lo in range(0, len(gyro), _CHUNK)]
            return np.concatenate([r for r, _ in parts]), np.concatenate([f for _, f in parts])
        gyro_counts_per_s, acc_counts_per_s = gyro, acc
        # the gyros first, at the linear specific force; then the accelerometers at the compensated rate (the lever
        # arms go with its square: at the linear rate, a gyro asymmetry of 200 ppm would leave ~1 ug at 150 deg/s);
        # then the gyros again at the compensated force (the g-sensitivity at the linear force, off by the
        # accelerometers' higher-order errors of ~200 ug, would leave ~0.002 deg/h)
        rate = self.body_rate(gyro_counts_per_s, self.acc.apply(acc_counts_per_s))
        force = self.specific_force(acc_counts_per_s, rate)
        if "gyro_g_sensitivity" in self.higher_order.terms:
            rate = self.body_rate(gyro_counts_per_s, force)
        return rate * RATE_UNITS[rate_unit], force * FORCE_UNITS[force_unit]


def _text(value: Any) -> str:
    return value if isinstance(value, str) else ""


def compensation_of(result: CalibrationResult) -> Compensation:
    """The compensation of a result holding all 30 coefficients (CompensationError otherwise)."""
    missing = [name for name in canonical_names() if name not in result.coefficients]
    if missing:
        raise CompensationError(f"the result lacks {len(missing)} of the 30 coefficients ({', '.join(missing[:4])}"
                                f"{', ...' if len(missing) > 4 else ''}): a compensation needs all of them")
    triads = [_triad(result, *spec) for spec in TRIADS]
    try:
        higher = higher_order_of(result)
    except HigherOrderError as exc:
        raise CompensationError(str(exc)) from exc
    run, imu = result.run, result.run.imu
    return Compensation(triads[0], triads[1], imu_model=_text(imu and imu.model), imu_serial=_text(imu and imu.serial),
                        run_id=_text(run.run_id), calibrated_utc=_text(run.finished_utc),
                        software_version=_text(run.software_version), higher_order=higher,
                        time_offset=time_offset_of(result))


def _triad(result: CalibrationResult, sensor: str, scale: str, bias: str, axes: str, unit: str,
           _what: str) -> TriadCompensation:
    c = result.coefficients

    def si(prefix: str, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
        factor = RESULT_UNITS[prefix][1]
        return (np.array([c[n].value * factor for n in names]),
                np.array([c[n].sigma * factor if math.isfinite(c[n].sigma) else math.nan for n in names]))

    k, k_sigma = si(scale, [f"{scale}_{s}" for s in SENSOR_AXES])
    d, d_sigma = si(bias, [f"{bias}_{s}" for s in SENSOR_AXES])
    rows = [[f"{axes}_{a}{s}" for a in BODY_AXES] for s in SENSOR_AXES]
    e = np.array([[c[n].value for n in row] for row in rows])
    e_sigma = np.array([[c[n].sigma for n in row] for row in rows])
    m = k[:, None] * e
    if not np.all(np.isfinite(m)) or abs(np.linalg.det(m)) <= 1e-12 * np.prod(np.linalg.norm(m, axis=1)):
        raise CompensationError(f"the {sensor} scale x direction-cosine matrix is singular or not finite: "
                                "it has no inverse")
    matrix = np.linalg.inv(m)
    # first order: dC = -C dM C; M_ij = k_i e_ij, so dM/dk_i = row i of E, dM/de_ij = k_i at (i, j)
    variance = np.zeros((3, 3))
    for i in range(3):
        variance += np.outer(matrix[:, i], e[i] @ matrix) ** 2 * k_sigma[i] ** 2
        for j in range(3):
            variance += (k[i] * np.outer(matrix[:, i], matrix[j, :])) ** 2 * e_sigma[i, j] ** 2
    bias_counts = k * d
    bias_sigma = np.hypot(d * k_sigma, k * d_sigma)
    return TriadCompensation(sensor, unit, matrix, bias_counts, np.sqrt(variance), bias_sigma, k, d)


__all__ = ["EQUATIONS", "FORCE_UNITS", "RATE_UNITS", "RAW_UNIT", "TRIADS", "Compensation", "CompensationError",
           "TriadCompensation", "compensation_of", "load_result"]




def load_result(path: str) -> CalibrationResult:
    """A result file from outside, bounded: a regular file of at most `MAX_INPUT_FILE_BYTES`, UTF-8 JSON
    (`InputError` in one line otherwise; OSError when it cannot be read)."""
    return CalibrationResult.load(path)
