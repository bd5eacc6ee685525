"""The simulated truth of a thermal model: what a simulated IMU's polynomials say each fitted coefficient is."""

from __future__ import annotations

import numpy as np

from bench.model.imu import ImuCoefficients
from bench.model.thermal import MAX_THERMAL_DEGREE, THERMAL_NAMES, ImuThermal
from bench.thermal.model import ThermalModel


def attach_sim_truth(model: ThermalModel, truth: ImuThermal, imu: ImuCoefficients) -> None:
    """Set `model.sim_truth` (per fitted coefficient, the true polynomial about the truth's reference)."""
    model.sim_truth = {name: truth.polynomial(name, imu) if name in THERMAL_NAMES
                       else diagonal_truth(truth, imu, name, model.range_c) for name in model.fits}
    model.sim_truth_reference_c = truth.reference_c


def diagonal_truth(truth: ImuThermal, imu: ImuCoefficients, name: str, range_c: tuple[float, float]) -> list[float]:
    """A direction-cosine diagonal follows its row (unit length), a smooth function of temperature
    that is not a polynomial: its truth is the cubic through it over the calibrated range
    (least squares on a fine grid; the quartic remainder is far below any calibration's sigma)."""
    grid = np.linspace(range_c[0], range_c[1], 64)
    exact = [truth.canonical_at(imu, t)[name] for t in grid]
    reference = imu.to_canonical()[name]
    x = grid - truth.reference_c
    terms = np.linalg.lstsq(x[:, None] ** np.arange(1, MAX_THERMAL_DEGREE + 1), np.asarray(exact) - reference,
                            rcond=None)[0]
    return [reference] + terms.tolist()


__all__ = ["attach_sim_truth", "diagonal_truth"]
