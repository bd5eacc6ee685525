"""How an IMU's coefficients vary with its case temperature: polynomials around a reference.

A coefficient `name` (canonical, display units) at case temperature T is

    value(T) = value(T_ref) + c1 (T - T_ref) + c2 (T - T_ref)^2 + c3 (T - T_ref)^3

with `c_k` in display unit per degC^k (`[sim.imu.thermal]`, the simulated IMU's truth).
Every family can vary: scale factors, biases and the off-diagonal direction cosines;
a direction-cosine row stays a unit vector (its diagonal follows from the
off-diagonals at each temperature), so a diagonal has no polynomial of its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from bench.model.families import BODY_AXES, RESULT_UNITS, SENSOR_AXES, canonical_names
from bench.model.imu import ImuCoefficients

#: the highest power of (T - T_ref) a thermal polynomial may have
MAX_THERMAL_DEGREE = 3
#: the direction-cosine diagonals: they follow from their row's off-diagonals
DIAGONAL_NAMES = frozenset(f"{axes}_{a}{s}" for axes in ("Eg", "Ea")
                           for a, s in zip(BODY_AXES, SENSOR_AXES))
#: the names a thermal polynomial may be given for, in canonical order
THERMAL_NAMES = tuple(n for n in canonical_names() if n not in DIAGONAL_NAMES)


@dataclass(frozen=True)
class ImuThermal:
    """The thermal behaviour of a (simulated) IMU: case dynamics and coefficient polynomials."""

    reference_c: float = 25.0
    #: first-order time constant of the case temperature following its ambient, s
    time_constant_s: float = 600.0
    #: canonical name -> (c1, c2, c3...) display unit per degC^k, k = 1.. (at most 3 terms)
    polynomials: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
    #: the ambient temperature when nothing else drives it (`bench run --sim`), degC
    ambient_c: float = 25.0
    #: case temperature at the start; None: soaked at the ambient
    initial_c: float | None = None

    def __post_init__(self) -> None:
        for name, terms in self.polynomials.items():
            if name not in THERMAL_NAMES:
                raise ValueError(f"no thermal polynomial for {name!r} (a direction-cosine diagonal follows from "
                                 "its row; known: the other canonical names)")
            if not 1 <= len(terms) <= MAX_THERMAL_DEGREE:
                raise ValueError(f"{name}: 1 to {MAX_THERMAL_DEGREE} polynomial terms, got {len(terms)}")
        if not (math.isfinite(self.time_constant_s) and self.time_constant_s > 0):
            raise ValueError(f"time_constant_s must be positive, got {self.time_constant_s}")

    def delta(self, name: str, temperature_c) -> np.ndarray:
        """value(T) - value(T_ref) of `name` in display units (0 without a polynomial)."""
        dt = np.asarray(temperature_c, dtype=float) - self.reference_c
        out = np.zeros_like(dt)
        for k, c in enumerate(self.polynomials.get(name, ()), start=1):
            out = out + c * dt ** k
        return out

    def polynomial(self, name: str, base: ImuCoefficients) -> list[float]:
        """[value(T_ref), c1, c2, c3] of `name` in display units (zeros beyond its terms)."""
        terms = list(self.polynomials.get(name, ()))
        return [base.to_canonical()[name]] + terms + [0.0] * (MAX_THERMAL_DEGREE - len(terms))

    def canonical_at(self, base: ImuCoefficients, temperature_c: float) -> dict[str, float]:
        """All 30 coefficients at `temperature_c` in display units (`base` holds them at the reference)."""
        arrays = self.arrays_at(base, np.array([float(temperature_c)]))
        return ImuCoefficients(*(a[0] for a in arrays)).to_canonical()

    def coefficients_at(self, base: ImuCoefficients, temperature_c: float) -> ImuCoefficients:
        return ImuCoefficients(*(a[0] for a in self.arrays_at(base, np.array([float(temperature_c)]))))

    def arrays_at(self, base: ImuCoefficients, temperature_c: np.ndarray) -> tuple[np.ndarray, ...]:
        """The coefficients (SI) at each of m temperatures: gyro_scale (m, 3), gyro_bias (m, 3),
        gyro_axes (m, 3, 3), acc_scale, acc_bias, acc_axes: `ImuCoefficients`' fields, stacked."""
        temps = np.asarray(temperature_c, dtype=float).reshape(-1)
        m = len(temps)
        out = []
        for prefix, field_name in (("Kg", "gyro_scale"), ("D0", "gyro_bias"), ("Eg", "gyro_axes"),
                                   ("Ka", "acc_scale"), ("K0", "acc_bias"), ("Ea", "acc_axes")):
            values = np.broadcast_to(getattr(base, field_name), (m,) + getattr(base, field_name).shape).copy()
            factor = RESULT_UNITS[prefix][1]
            if prefix in ("Eg", "Ea"):
                for i, s in enumerate(SENSOR_AXES):
                    row = [f"{prefix}_{a}{s}" for a in BODY_AXES]
                    if not any(n in self.polynomials for n in row):
                        continue          # the row as given, bit for bit
                    for j, n in enumerate(row):
                        if j != i:
                            values[:, i, j] += self.delta(n, temps) * factor
                    off = sum(values[:, i, j] ** 2 for j in range(3) if j != i)
                    values[:, i, i] = np.copysign(np.sqrt(1.0 - off), getattr(base, field_name)[i, i])
            else:
                for i, s in enumerate(SENSOR_AXES):
                    name = f"{prefix}_{s}"
                    if name in self.polynomials:
                        values[:, i] += self.delta(name, temps) * factor
            out.append(values)
        return tuple(out)


__all__ = ["DIAGONAL_NAMES", "ImuThermal", "MAX_THERMAL_DEGREE", "THERMAL_NAMES"]
