"""The turntable's part of a verification error's uncertainty.

A verification compares compensated outputs with the inputs of an ideal table; a real
table (and the simulated one, whose black-box angles are drawn from `[sim] black_box_arcsec`)
points each dwell and turns each axis a little off. The same prior the calibration's
uncertainty budget uses for the table (`bench.solve.inputs.budget_inputs`: `[table]
pointing_accuracy_arcsec`, a table check, or the simulated table's black-box RMS) is pushed
through the verification: each of the nine black-box angles is stepped by +-1 arcsec, the
exact change of every dwell's and turn's outputs (the calibration's own IMU model on the
stepped table, `bench.model.closed_form`) is added to the observations, the errors are
computed again, and `sqrt(diag(J C J^T))` (J the errors' derivatives by the angles, C the
prior's covariance) is each error's 1-sigma from the table. First order: the angles are
arcseconds.

The calibration's coefficient sigmas carry the calibration's own table part; the two are
added as independent (the same table errs in both, so this may over-state U, never under-).
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from bench.model.closed_form import position_outputs, turn_integrals
from bench.model.earth import Site
from bench.model.observations import PositionObservation, RotationObservation
from bench.model.result import CalibrationResult
from bench.model.table_prior import TablePrior
from bench.model.units import ARCSEC
from bench.solve.budget import probe_boxes
from bench.solve.extract import Extraction

_STEP_RAD = 1.0 * ARCSEC

#: (positions, rotations) -> error name -> value: the verification's errors of some observations
ErrorsOf = Callable[[list[PositionObservation], list[RotationObservation]], dict[str, float]]


def _stepped_positions(obs: list[PositionObservation], calibration: CalibrationResult, site: Site, boxes: np.ndarray,
                       mounting) -> list[list[PositionObservation]]:
    """Per box, the dwells with each mean moved by the box's exact change of the outputs."""
    if not obs:
        return [[] for _ in boxes]
    imu = calibration.imu_coefficients()
    angles = np.array([o.angles_deg for o in obs])
    gyro0, acc0 = position_outputs(angles, imu, site, None, mounting)
    gyro, acc = position_outputs(angles, imu, site, boxes, mounting)     # (R, K, 3)
    return [[dataclasses.replace(o, gyro_mean=o.gyro_mean + gyro[r, k] - gyro0[k],
                                 acc_mean=o.acc_mean + acc[r, k] - acc0[k]) for k, o in enumerate(obs)]
            for r in range(len(boxes))]


def _stepped_rotations(obs: list[RotationObservation], rates_dps: dict[str, float], calibration: CalibrationResult,
                       site: Site, boxes: np.ndarray, mounting) -> list[list[RotationObservation]]:
    """Per box, the turns with each integral moved by the box's exact change of the integral."""
    out: list[list[RotationObservation]] = [[] for _ in boxes]
    if not obs:
        return out
    imu = calibration.imu_coefficients()
    for o in obs:
        rate = rates_dps.get(o.label)
        if rate is None or not rate > 0:            # (the errors leave such a turn out anyway)
            for r in range(len(boxes)):
                out[r].append(o)
            continue
        ideal, _ = turn_integrals([o], imu, site, rate, None, mounting)            # (1, 3)
        stepped, _ = turn_integrals([o], imu, site, rate, boxes, mounting)         # (R, 1, 3)
        for r in range(len(boxes)):
            out[r].append(dataclasses.replace(o, gyro_integral=o.gyro_integral + stepped[r, 0] - ideal[0]))
    return out


def table_sigmas(extraction: Extraction, rates_dps: dict[str, float], calibration: CalibrationResult, site: Site,
                 prior: TablePrior, errors_of: ErrorsOf, mounting=None) -> dict[str, float]:
    """Error name -> its 1-sigma from the table's pointing error (the error's unit)."""
    boxes = probe_boxes(_STEP_RAD)                  # +step on each angle, then -step on each
    positions = _stepped_positions(extraction.positions, calibration, site, boxes, mounting)
    rotations = _stepped_rotations(extraction.rotations, rates_dps, calibration, site, boxes, mounting)
    stepped = [errors_of(positions[r], rotations[r]) for r in range(len(boxes))]
    names = set(stepped[0]).intersection(*stepped[1:])
    out = {}
    for name in names:
        jac = np.array([(stepped[j][name] - stepped[9 + j][name]) / (2.0 * _STEP_RAD) for j in range(9)])
        out[name] = float(np.sqrt(max(jac @ prior.covariance_rad2 @ jac, 0.0)))
    return out


__all__ = ["table_sigmas"]
