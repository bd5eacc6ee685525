"""The higher-order part of a compensation: the extended model's families a result holds (issue 30,
docs/explanation/extended-model.md#compensation).

The model adds, per sensor s, an input-equivalent error `e_s` before the scale factor:
`F_s = Kg_s (u_s + D0_s + eg_s)`, `J_s = Ka_s (a_s + K0_s + ea_s)`. Its inverse takes the error off the raw output
in counts/s and then applies the linear compensation; the gyros first (at the linear specific force), then the
accelerometers (at the compensated rate). The error is evaluated at the input less the error at the measured
input (one fixed-point step: `e(x - e(x))`):

    f0 = C_acc (J - b_acc)
    x_s = (F_s - b_gyro_s) / Kg_s,    eg(x) = sum_j Gg_sj f0_j + Ag_s/2 |x_s| + Ng_s x_s^2
    w_b = C_gyro (F - b_gyro - Kg eg(x - eg(x)))
    x_s = (J_s - b_acc_s) / Ka_s,     ea(x) = Aa_s/2 |x_s| + Qa_s x_s^2 + x_s sum_j Ca_sj f0_j
    f_b = C_acc (J - b_acc - Ka (ea(x - ea(x)) - La (|w_b|^2 - w_b_s^2)))

The fixed-point step leaves a remainder of the order of the error times its relative size squared; it matters
where the error is of the order of the input (a gyro's g-sensitivity at rest, against the asymmetry's |x|). The
cross terms use the centre's specific force instead of each accelerometer's, and the lever arm only its component
along the sensor's own axis (the one a body-axis turn shows): a component across it moves the output by the
misalignment times the centripetal force.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.errors import InputError
from bench.model.extended import FAMILIES, SCALAR_TERMS, TERMS, ExtendedFamily
from bench.model.families import BODY_AXES, SENSOR_AXES
from bench.model.result import CalibrationResult

#: family -> its SI unit (what the exports write)
SI_UNITS = {"gyro_g_sensitivity": "rad/s per m/s^2", "gyro_asymmetry": "1", "gyro_nonlinearity": "per rad/s",
            "acc_asymmetry": "1", "acc_second_order": "per m/s^2", "acc_cross": "per m/s^2", "acc_lever_arm": "m"}
#: families whose value is a (3, 3) matrix: rows the sensors x, y, z, columns the body axes X, Y, Z
MATRIX_TERMS = ("gyro_g_sensitivity", "acc_cross")

#: the inverse, in the order it is applied (the exports write these)
EQUATIONS = {
    "gyro": "f0 = C_acc (J - b_acc); x_s = (F_s - b_gyro_s)/Kg_s; eg_s(x) = sum_j Gg_sj f0_j + Ag_s/2 |x_s| "
            "+ Ng_s x_s^2; w_b = C_gyro (F - b_gyro - Kg eg(x - eg(x)))",
    "acc": "x_s = (J_s - b_acc_s)/Ka_s; ea_s(x) = Aa_s/2 |x_s| + Qa_s x_s^2 + x_s sum_j Ca_sj f0_j; "
           "f_b = C_acc (J - b_acc - Ka (ea(x - ea(x)) - La (|w_b|^2 - w_b_s^2)))",
}


class HigherOrderError(InputError):
    """A result whose extended coefficients do not make whole families."""


@dataclass(frozen=True)
class HigherOrderTerm:
    """One family's coefficients in SI: (3,) per sensor or (3, 3) rows sensors, columns body axes."""

    family: ExtendedFamily
    value: np.ndarray
    sigma: np.ndarray            # 1-sigma, NaN: unknown (0 on the cross terms' diagonal, which is no coefficient)

    @property
    def term(self) -> str:
        return self.family.term

    @property
    def unit(self) -> str:
        return SI_UNITS[self.family.term]


@dataclass(frozen=True)
class HigherOrderCompensation:
    """The families a result holds, in `TERMS` order."""

    terms: dict[str, HigherOrderTerm]

    def value(self, term: str) -> np.ndarray | None:
        found = self.terms.get(term)
        return None if found is None else found.value

    @property
    def has_gyro(self) -> bool:
        return any(FAMILIES[t].sensor == "gyro" for t in self.terms)

    @property
    def has_acc(self) -> bool:
        return any(FAMILIES[t].sensor == "acc" for t in self.terms)

    def acc_error(self, acc_input: np.ndarray, force: np.ndarray) -> np.ndarray:
        """The accelerometers' input-equivalent errors (..., 3), m/s^2, at their inputs `a_s` (m/s^2) and the
        centre's specific force (m/s^2), both (..., 3)."""
        a = acc_input
        error = np.zeros(np.shape(a))
        if (asym := self.value("acc_asymmetry")) is not None:
            error += 0.5 * asym * np.abs(a)
        if (second := self.value("acc_second_order")) is not None:
            error += second * a * a
        if (cross := self.value("acc_cross")) is not None:
            error += a * (force @ cross.T)
        return error

    def lever_arm_force(self, body_rate: np.ndarray) -> np.ndarray | float:
        """The specific force along each accelerometer's axis beyond the centre's (..., 3), m/s^2, at the body rate
        (rad/s): the centripetal `-La_s (|w|^2 - w_s^2)` of r_s = La_s e_s (0 without lever arms)."""
        lever = self.value("acc_lever_arm")
        if lever is None:
            return 0.0
        w_sq = body_rate * body_rate
        return -lever * (w_sq.sum(axis=-1, keepdims=True) - w_sq)

    def gyro_error(self, gyro_input: np.ndarray, input_sq: np.ndarray, force: np.ndarray) -> np.ndarray:
        """The gyros' input-equivalent errors (..., 3), rad/s, at their inputs `u_s` (rad/s), the mean of `u_s^2`
        ((rad/s)^2: `u_s^2` for a sample, more for a mean over a turn that ramps) and the specific force (m/s^2)."""
        error = np.zeros(np.shape(gyro_input))
        if (sens := self.value("gyro_g_sensitivity")) is not None:
            error += force @ sens.T
        if (asym := self.value("gyro_asymmetry")) is not None:
            error += 0.5 * asym * np.abs(gyro_input)
        if (nonlin := self.value("gyro_nonlinearity")) is not None:
            error += nonlin * input_sq
        return error


def _complete(result: CalibrationResult, family: ExtendedFamily) -> bool | None:
    """True: every coefficient of the family is in the result; False: none; None: some (a damaged result)."""
    present = [n in result.coefficients for n in family.names]
    return True if all(present) else False if not any(present) else None


def higher_order_of(result: CalibrationResult) -> HigherOrderCompensation | None:
    """The higher-order part of a result's compensation (None: the result holds only the 30 coefficients;
    HigherOrderError for a family with some of its coefficients missing)."""
    terms: dict[str, HigherOrderTerm] = {}
    for term in TERMS:
        if term in SCALAR_TERMS:
            continue            # the time offset is no per-sample correction (`time_offset_of`)
        family = FAMILIES[term]
        whole = _complete(result, family)
        if whole is None:
            missing = [n for n in family.names if n not in result.coefficients]
            raise HigherOrderError(f"the result holds part of the {family.title} ({', '.join(missing[:3])} missing): "
                                   "a compensation needs each family whole")
        if not whole:
            continue
        coefficients = result.coefficients
        shape = (3, 3) if term in MATRIX_TERMS else (3,)
        value, sigma = np.zeros(shape), np.zeros(shape)
        for name in family.names:
            c = coefficients[name]
            axes = name.split("_", 1)[1]
            index = (SENSOR_AXES.index(axes[1]), BODY_AXES.index(axes[0])) if len(axes) == 2 \
                else SENSOR_AXES.index(axes)
            value[index] = c.value * family.result_to_si
            sigma[index] = c.sigma * family.result_to_si if math.isfinite(c.sigma) else math.nan
        terms[term] = HigherOrderTerm(family, value, sigma)
    if not terms:
        return None
    return HigherOrderCompensation(terms)


def time_offset_of(result: CalibrationResult) -> tuple[float, float] | None:
    """The gyro-to-accelerometer time offset of a result (s) and its 1-sigma (NaN: unknown); None: not solved."""
    found = result.coefficients.get(FAMILIES["time_offset"].names[0])
    if found is None:
        return None
    factor = FAMILIES["time_offset"].result_to_si
    return found.value * factor, found.sigma * factor if math.isfinite(found.sigma) else math.nan


__all__ = ["EQUATIONS", "MATRIX_TERMS", "SI_UNITS", "HigherOrderCompensation", "HigherOrderError", "HigherOrderTerm",
           "higher_order_of", "time_offset_of"]
