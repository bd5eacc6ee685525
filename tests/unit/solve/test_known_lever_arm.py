"""A unit off the table's rotation centre (issue 31: `[[imu]] lever_arm_mm`): its accelerometers see the table's
centripetal and tangential acceleration there. Only the extended model's lever-arm fit reads the accelerometers
during turns: without the known lever arm it takes the unit's place for the accelerometers' own (a bias of about
120 sigma at 100 mm); with it, the fit is within U. The 30 coefficients do not read a turn's accelerometers."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bench.config.units import FACES
from bench.model.earth import Site
from bench.model.imu import NoiseModel, default_sim_imu
from bench.model.units import DEG_PER_HOUR, MICRO_G
from bench.sim.acquire import acquire
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from bench.sim.units import placed_terms
from bench.solve.budget import BudgetInputs
from bench.solve.calibrate import solve
from bench.solve.extended import solve_extended
from schedules import load_builtin

SITE = Site(30.27)
MOUNTING = np.array(FACES["x-up"], dtype=float)
#: 100 mm along the fixture's x: the x-up unit's y axis
LEVER_ARM_M = MOUNTING @ np.array([0.1, 0.0, 0.0])
LA = ("La_x", "La_y", "La_z")


def _observe(lever_arm_m, noise: NoiseModel):
    imu = SimImu(default_sim_imu(), noise, rate_hz=100.0, seed=3, higher_order=placed_terms(None, lever_arm_m))
    positions = [p.angles_deg for p in load_builtin("optimal-24").positions]
    return acquire(SimTable(SITE, mounting=MOUNTING), imu, positions, list(load_builtin("optimal-5s6r").rotations))


def _budget(noise: NoiseModel) -> BudgetInputs:
    return BudgetInputs(gyro_bias_instability=noise.gyro_bias_instability_dph * DEG_PER_HOUR,
                        acc_bias_instability=noise.acc_bias_instability_ug * MICRO_G,
                        correlation_time_s=noise.correlation_time_s, turn_angle_sigma_rad=0.0)


@pytest.fixture(scope="module")
def placed():
    """Observations of the unit 100 mm off centre (x-up) and at the centre, the same noise draw (no quantisation,
    whose roundings a tiny change would flip into another draw)."""
    noise = dataclasses.replace(NoiseModel(), quantise=False)
    return _observe(LEVER_ARM_M, noise), _observe(None, noise), _budget(noise)


def test_without_the_known_lever_arm_the_fit_takes_it_for_the_accelerometers(placed):
    (positions, turns), _, budget = placed
    values, sigmas = solve_extended(positions, turns, SITE, ["acc_lever_arm"], MOUNTING,
                                    budget_inputs=budget).values_and_sigmas()
    bias = {name: values[name] / sigmas[name] for name in LA}      # the truth: no lever arm of their own
    assert values["La_y"] == pytest.approx(100.0, abs=3.0 * sigmas["La_y"])      # mm: the unit's place
    assert bias["La_y"] > 50.0, bias
    assert abs(bias["La_x"]) < 3.0 and abs(bias["La_z"]) < 3.0, bias


def test_with_the_known_lever_arm_the_fit_is_within_u(placed):
    (positions, turns), (centre_positions, centre_turns), budget = placed
    calibration = solve_extended(positions, turns, SITE, ["acc_lever_arm"], MOUNTING, budget_inputs=budget,
                                 lever_arm_m=LEVER_ARM_M)
    values, sigmas = calibration.values_and_sigmas()
    for name in LA:
        assert abs(values[name]) <= 2.0 * sigmas[name], (name, values[name], sigmas[name])
    # as if the unit sat at the centre: the same fit to a small part of a sigma
    centre, _ = solve_extended(centre_positions, centre_turns, SITE, ["acc_lever_arm"], MOUNTING,
                               budget_inputs=budget).values_and_sigmas()
    for name in LA:
        assert abs(values[name] - centre[name]) < 0.1 * sigmas[name], name


def test_the_30_coefficients_do_not_see_the_lever_arm(placed):
    """Dwells are at rest: the unit's place moves them only by the Earth rate's centripetal force (5e-11 g)."""
    (positions, turns), (centre_positions, centre_turns), budget = placed
    values, sigmas = solve(positions, turns, SITE, MOUNTING, budget_inputs=budget).values_and_sigmas()
    centre, _ = solve(centre_positions, centre_turns, SITE, MOUNTING, budget_inputs=budget).values_and_sigmas()
    assert set(values) == set(centre) and len(values) == 30
    assert max(abs(values[n] - centre[n]) / sigmas[n] for n in values) < 1e-3


def test_no_lever_arm_leaves_the_truth_as_it_was():
    assert placed_terms(None, None) is None
    terms = placed_terms(None, [0.0, 0.1, 0.0])
    assert terms is not None and np.array_equal(terms.acc_lever_arm, np.tile([0.0, 0.1, 0.0], (3, 1)))
