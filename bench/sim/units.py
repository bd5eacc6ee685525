"""Several simulated IMUs on one simulated table: each unit its own truth, mounting, noise and bus.

A unit mounted on the fixture with the rotation `C_i^b` (fixture to the unit's body axes) sees the table's motion
rotated: `mounted_view` is the table as that unit sees it (the same trajectory, every command included, with the
mounting in the kinematics chain, exactly as `SimTable(mounting=...)` computes it). `unit_truth` gives unit k of a
run its own true coefficients, drawn about the configured ones, so that the units of one run differ as real ones do.
A unit with a lever arm (`placed_terms`) sits off the rotation centre: its accelerometers see the table's motion there.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from bench.model.families import BODY_AXES, SENSOR_AXES
from bench.model.higher_order import HigherOrderTerms
from bench.model.imu import ImuCoefficients, NoiseModel
from bench.sim.table import SimTable
from drivers.imu.layout import ImuLayout

#: 1-sigma of how far unit k >= 1's truth lies from the configured one: relative scale, gyro bias (deg/h),
#: accelerometer bias (g), direction-cosine off-diagonals
UNIT_SPREAD = {"scale": 2e-4, "D0": 0.03, "K0": 1e-4, "cosine": 3e-4}


@dataclass(frozen=True)
class SimUnit:
    """One simulated IMU of a run of several: its truth, noise, rate, frame layout (ids offset already), noise
    seed, mounting (rows: the unit's axes in fixture coordinates; None: the fixture's) and the bus it sends on."""

    coefficients: ImuCoefficients
    noise: NoiseModel
    rate_hz: float
    layout: ImuLayout
    seed: int
    mounting: tuple[tuple[float, ...], ...] | None
    bus: str
    #: its higher-order truth (`placed_terms`: its lever arm); None: the 30-coefficient model alone
    higher_order: HigherOrderTerms | None = None


def mounted_view(table: SimTable, mounting) -> SimTable:
    """`table` as a unit mounted with `mounting` on its inner frame sees it: the same pieces (the view shares the
    axes' lists, which every command changes in place), the mounting after the table's own."""
    view = copy.copy(table)
    rotation = np.asarray(mounting, dtype=float).reshape(3, 3)
    view.mounting = rotation if table.mounting is None else rotation @ table.mounting
    return view


def placed_terms(terms: HigherOrderTerms | None, lever_arm_body_m) -> HigherOrderTerms | None:
    """`terms` with the unit placed at `lever_arm_body_m` (its body axes, m) from the table's rotation centre:
    every accelerometer's own lever arm moves by it, so each sees the centripetal and tangential acceleration of
    the table's motion there. `terms` itself when the unit has no lever arm (bit for bit as before)."""
    if lever_arm_body_m is None:
        return terms
    placed = copy.deepcopy(terms) if terms is not None else HigherOrderTerms()
    placed.acc_lever_arm = placed.acc_lever_arm + np.asarray(lever_arm_body_m, dtype=float)[None, :]
    return placed


def unit_truth(base: ImuCoefficients, index: int, seed: int) -> ImuCoefficients:
    """Unit `index`'s true coefficients: unit 0's are `base`, every other unit's drawn about them (`UNIT_SPREAD`;
    the same for the same seed and index), each direction-cosine row of unit length."""
    if index == 0:
        return base
    rng = np.random.default_rng([seed, index])
    values = base.to_canonical()
    for name in sorted(values):
        family = name.split("_")[0]
        if family in ("Kg", "Ka"):
            values[name] *= 1.0 + UNIT_SPREAD["scale"] * rng.standard_normal()
        elif family in ("D0", "K0"):
            values[name] += UNIT_SPREAD[family] * rng.standard_normal()
        elif name[-2].upper() != name[-1].upper():           # an off-diagonal direction cosine
            values[name] += UNIT_SPREAD["cosine"] * rng.standard_normal()
    for prefix in ("Eg", "Ea"):
        for sensor in SENSOR_AXES:
            row = [f"{prefix}_{axis}{sensor}" for axis in BODY_AXES]
            norm = float(np.sqrt(sum(values[name] ** 2 for name in row)))
            values.update({name: values[name] / norm for name in row})
    return ImuCoefficients.from_canonical(values)


def unit_seed(seed: int, index: int) -> int:
    """Unit `index`'s noise seed: unit 0 keeps the run's, the others their own streams."""
    return seed if index == 0 else int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


__all__ = ["UNIT_SPREAD", "SimUnit", "mounted_view", "placed_terms", "unit_seed", "unit_truth"]
