"""Solver against closed-form observations: exact recovery on an ideal table."""

import json

import numpy as np
import pytest

from bench.model.closed_form import exact_observations
from bench.model.earth import Site
from bench.model.families import canonical_names
from bench.model.imu import default_sim_imu
from bench.model.result import CalibrationResult, ResultFormatError
from bench.model.units import ARCSEC
from bench.solve.calibrate import solve
from bench.solve.methods import SolverError
from schedules import load_builtin
from tests.helpers.solver import assert_recovered

SITE = Site(30.27)


def _schedule(pos_name, rot_name):
    pos = np.array([p.angles_deg for p in load_builtin(pos_name).positions])
    rot = list(load_builtin(rot_name).rotations)
    return pos, rot


@pytest.mark.parametrize("pos_name, rot_name", [
    ("optimal-24", "optimal-5s6r"), ("traditional-12", "traditional-3s6r"), ("all-64", "all-96")])
def test_ideal_table_noise_free_exact_recovery(pos_name, rot_name):
    imu = default_sim_imu()
    pos, rot = _schedule(pos_name, rot_name)
    positions, rotations = exact_observations(pos, rot, imu, SITE)
    cal = solve(positions, rotations, SITE)
    values, sigmas = cal.values_and_sigmas()
    assert sorted(values) == sorted(canonical_names())
    assert_recovered(values, imu)
    # residuals vanish on exact data
    assert np.abs(cal.accelerometers.fit.residuals).max() < 1e-6
    assert np.abs(cal.gyros.fit.residuals).max() < 1e-3


def test_recovery_with_mounting_rotation():
    from bench.model.kinematics import rot_z
    imu = default_sim_imu()
    pos, rot = _schedule("optimal-24", "optimal-5s6r")
    mount = rot_z(np.pi / 2)
    positions, rotations = exact_observations(pos, rot, imu, SITE, mounting=mount)
    values, _ = solve(positions, rotations, SITE, mounting=mount).values_and_sigmas()
    assert_recovered(values, imu)


def test_black_box_errors_reach_the_solution_at_the_expected_size():
    imu = default_sim_imu()
    pos, rot = _schedule("optimal-24", "optimal-5s6r")
    bb = np.random.default_rng(5).normal(0, 30 * ARCSEC, (3, 3))
    positions, rotations = exact_observations(pos, rot, imu, SITE, black_box_rad=bb)
    cal = solve(positions, rotations, SITE)
    values, _ = cal.values_and_sigmas()
    truth = imu.to_canonical()
    # axis errors are first order in the angle (inner zero offset), scale factors second order
    ea_err = max(abs(values[n] - truth[n]) for n in canonical_names() if n.startswith("Ea"))
    assert 5 * ARCSEC < ea_err < 200 * ARCSEC
    assert abs(values["Ka_x"] / truth["Ka_x"] - 1) < 1e-6


def test_too_few_or_degenerate_steps_are_refused():
    imu = default_sim_imu()
    pos = np.array([[0, 0, 0], [0, 180, 0], [0, 0, 180], [0, 180, 180]])   # Z up/down only
    positions, _ = exact_observations(pos, [], imu, SITE)
    with pytest.raises(SolverError, match="determine only"):
        solve(positions, [], SITE)
    with pytest.raises(SolverError, match="nothing to solve"):
        solve([], [], SITE)


def test_positions_only_needs_gyro_prior_for_gyro_bias():
    imu = default_sim_imu()
    pos, _ = _schedule("optimal-24", "optimal-5s6r")
    positions, _ = exact_observations(pos, [], imu, SITE)
    cal = solve(positions, [], SITE)
    values, _ = cal.values_and_sigmas()
    assert "D0_x" not in values and "Ka_x" in values
    assert any("gyro bias not solved" in f for f in cal.flags)
    values, _ = solve(positions, [], SITE, gyro_prior=imu).values_and_sigmas()
    assert values["D0_z"] == pytest.approx(imu.to_canonical()["D0_z"], abs=1e-6)


def test_result_json_round_trip(tmp_path):
    imu = default_sim_imu()
    pos, rot = _schedule("optimal-24", "optimal-5s6r")
    positions, rotations = exact_observations(pos, rot, imu, SITE)
    result = solve(positions, rotations, SITE).to_result(run={"run_id": "t1"}, sim_truth=imu)
    path = tmp_path / "r.result.json"
    result.save(path)
    data = json.loads(path.read_text())
    assert data["format"] == "turntable-bench/result" and data["version"] == 2
    assert data["coefficients"]["Kg_x"]["unit"] == "counts/s per deg/s"
    assert data["coefficients"]["D0_x"]["unit"] == "deg/h"
    assert data["coefficients"]["K0_x"]["unit"] == "g"
    assert set(data["sim_truth"]["coefficients"]) == set(canonical_names())
    assert len(data["residuals"]["positions"]) == 24 and len(data["residuals"]["rotations"]) == 6
    back = CalibrationResult.load(path)
    assert back.values() == result.values()
    assert back.to_json() == result.to_json()
    recovered = back.imu_coefficients()
    assert np.allclose(recovered.gyro_matrix, imu.gyro_matrix, rtol=1e-9)


def test_result_loader_rejects_foreign_files(tmp_path):
    bad = tmp_path / "x.json"
    bad.write_text('{"format": "other"}')
    with pytest.raises(ResultFormatError, match="not a turntable-bench/result"):
        CalibrationResult.load(bad)
    bad.write_text('{"format": "turntable-bench/result", "version": 99}')
    with pytest.raises(ResultFormatError, match="version 99"):
        CalibrationResult.load(bad)
    bad.write_text('{"format": "turntable-bench/result", "version": 1, "coefficients": {"Kq_x": {}}}')
    with pytest.raises(ResultFormatError, match="Kq_x"):
        CalibrationResult.load(bad)
    bad.write_text("{not json")
    with pytest.raises(ResultFormatError, match="x.json:1"):
        CalibrationResult.load(bad)
