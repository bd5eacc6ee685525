"""The gyro-to-accelerometer time offset (issue 30): the simulator's offset against the closed form (the gravity
sinusoid's phase lags by w dt), the turns' timing reduction and the estimator recovering a known offset within U,
zero when off, refused by a plan that cannot see it, and `auto` keeping it only when it is there."""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from bench.model.earth import Site
from bench.model.higher_order import HigherOrderTerms
from bench.model.imu import NoiseModel, default_sim_imu
from bench.model.turn_timing import turn_timing
from bench.model.units import DEG
from bench.sim.acquire import AcquisitionTiming, acquire
from bench.sim.imu import ImuSamples, SimImu
from bench.sim.table import SimTable
from bench.solve.extended import solve_extended
from bench.solve.methods import SolverError
from bench.solve.time_offset import estimate_time_offset
from schedules import load_builtin
from studies.time_offset_coverage import ACROSS_GRAVITY, observe

SITE = Site(30.27)
RATE_HZ = 200.0


def _turn_samples(offset_s: float, rate_dps: float = 30.0):
    """A noise-free turn of the inner frame about a horizontal axis: (samples, table)."""
    table = SimTable(SITE)
    arrive = table.move_to(0.0, [0.0, 90.0, 0.0])
    stop = table.turn(arrive + 2.0, "inner", "ccw", 2, rate_dps, 20.0)
    imu = SimImu(default_sim_imu(), NoiseModel.off(), rate_hz=RATE_HZ, seed=1,
                 higher_order=HigherOrderTerms(time_offset_s=offset_s) if offset_s else None)
    samples = imu.generate(table, stop + 1.0)
    at_rest = samples.time_s - 1.0 / RATE_HZ >= arrive + 1.0          # the turn's window: from rest to rest
    return ImuSamples(samples.counter[at_rest], samples.time_s[at_rest], samples.gyro_counts[at_rest],
                      samples.acc_counts[at_rest], RATE_HZ), table


def _timing(samples, table):
    return turn_timing(samples.time_s, samples.rate_hz, samples.gyro_counts, samples.acc_counts,
                       lambda t: table.angles(t)[:, 2], lambda t: table.frame_rates(t)[:, 2])


def test_the_gravity_sinusoid_lags_by_rate_times_offset():
    """Closed form: at a constant rate w the accelerometers' sinusoid in the frame angle is late by w dt in phase;
    the gyros' rate ramps are not late at all (a positive offset delays the accelerometers only)."""
    offset = 2e-3
    plain, table = _turn_samples(0.0)
    late, _ = _turn_samples(offset)
    t0, t1 = _timing(plain, table), _timing(late, table)
    assert t0 is not None and t1 is not None
    w = t1.rate_rad_s
    assert abs(w) == pytest.approx(30.0 * DEG, rel=1e-9)
    seen = np.isfinite(t1.acc_phase_rad)
    assert seen[:2].all()                        # the two accelerometers across the axis (z: its misalignment)
    np.testing.assert_allclose(t1.acc_phase_rad[seen] - t0.acc_phase_rad[seen], w * offset, rtol=1e-3)
    along = np.isfinite(t1.gyro_delay_s)
    np.testing.assert_allclose(t1.gyro_delay_s[along], 0.0, atol=1e-6)
    np.testing.assert_allclose(t0.gyro_delay_s[along], 0.0, atol=1e-6)


def test_a_negative_offset_shows_as_the_gyros_delay():
    plain, table = _turn_samples(0.0)
    late_gyros, _ = _turn_samples(-1e-3)
    t0, t1 = _timing(plain, table), _timing(late_gyros, table)
    assert t0 is not None and t1 is not None
    np.testing.assert_allclose(t1.acc_phase_rad, t0.acc_phase_rad, equal_nan=True)
    along = np.isfinite(t1.gyro_delay_s)
    assert along.any()
    np.testing.assert_allclose(t1.gyro_delay_s[along], 1e-3, rtol=2e-2)


def _cross_turns(offset_s: float, noise: NoiseModel, seed: int):
    imu = SimImu(default_sim_imu(), noise, rate_hz=100.0, seed=seed,
                 higher_order=HigherOrderTerms(time_offset_s=offset_s) if offset_s else None)
    table = SimTable(SITE)
    _, turns = acquire(table, imu, [], ACROSS_GRAVITY, AcquisitionTiming(), turn_timings=True)
    return turns


@pytest.mark.parametrize("offset_ms", [0.0, 0.5, -0.5])
def test_noise_free_offset_is_recovered(offset_ms):
    estimate = estimate_time_offset(_cross_turns(offset_ms * 1e-3, NoiseModel.off(), 1))
    assert estimate.value_s == pytest.approx(offset_ms * 1e-3, abs=2e-6)


@pytest.mark.parametrize("grade,offset_ms", [("nav-fog", None), ("tactical-mems", None), ("tactical-mems", 2.0),
                                             ("nav-fog", 0.0)])
def test_the_truth_lies_within_u(grade, offset_ms):
    """One draw each (studies/time_offset_coverage.py runs many): the truth within U = 2 sigma, with the grade's
    other higher-order terms on."""
    for seed in (11,):
        positions, turns, budget = observe(grade, offset_ms, seed)
        calibration = solve_extended(positions, turns, SITE, ["time_offset"], budget_inputs=budget)
        values, sigmas = calibration.values_and_sigmas()
        truth = {"nav-fog": 0.05, "tactical-mems": 0.5}[grade] if offset_ms is None else offset_ms
        assert abs(values["Dt"] - truth) <= 2.0 * sigmas["Dt"], (seed, values["Dt"], sigmas["Dt"])
        assert 0.0 < sigmas["Dt"] < 0.25
        result = calibration.to_result()
        assert result.coefficients["Dt"].unit == "ms" and result.coefficients["Dt"].budget
        significance = result.quality.significance
        assert significance is not None
        rows = [r for r in significance["coefficients"] if r["name"] == "Dt"]
        assert len(rows) == 1 and rows[0]["family"] == "time_offset"
        schema = json.loads((Path(__file__).resolve().parents[3] / "docs" / "reference" / "schemas"
                             / "result.schema.json").read_text(encoding="utf-8"))
        assert re.match(schema["properties"]["coefficients"]["propertyNames"]["pattern"], "Dt")


def test_auto_keeps_the_offset_only_when_it_is_there():
    positions, turns, budget = observe("nav-fog", 0.0, 21)
    fit = solve_extended(positions, turns, SITE, "auto", budget_inputs=budget).extended
    assert fit is not None and "time_offset" not in fit.terms and "time_offset" not in fit.left_out.get(
        "time_offset", "not observed")
    positions, turns, budget = observe("tactical-mems", 2.0, 21)
    fit = solve_extended(positions, turns, SITE, "auto", budget_inputs=budget).extended
    assert fit is not None and "time_offset" in fit.terms
    assert fit.tests["time_offset"].p_value < 1e-6


def test_a_plan_without_turns_across_gravity_both_ways_cannot_see_it():
    imu = SimImu(default_sim_imu(), NoiseModel(), rate_hz=100.0, seed=2,
                 higher_order=HigherOrderTerms(time_offset_s=5e-4))
    positions, turns = acquire(SimTable(SITE), imu, [p.angles_deg for p in load_builtin("optimal-24").positions],
                               list(load_builtin("optimal-5s6r").rotations), AcquisitionTiming(), turn_timings=True)
    with pytest.raises(SolverError, match="time_offset: no turn about an axis across gravity"):
        solve_extended(positions, turns, SITE, ["time_offset"])
    untimed = [dataclasses.replace(o, timing=None) for o in turns]
    with pytest.raises(SolverError, match="carry no timing"):
        estimate_time_offset(untimed)
    fit = solve_extended(positions, turns, SITE, "auto").extended
    assert fit is not None and "not observed" in fit.left_out["time_offset"]


def test_turn_timing_is_off_unless_asked():
    imu = SimImu(default_sim_imu(), NoiseModel.off(), rate_hz=100.0, seed=1)
    _, turns = acquire(SimTable(SITE), imu, [], ACROSS_GRAVITY[:1], AcquisitionTiming())
    assert turns[0].timing is None
    assert math.isfinite(turns[0].duration_s)


def test_the_exports_carry_the_offset_and_kalibr_keeps_its_own():
    """JSON, TOML, CSV and C carry Dt in seconds with its sigma; kalibr's `time_offset` (the IMU's clock against
    its reference sensor) stays 0 and a comment gives Dt; a result without Dt exports no time offset."""
    tomllib = pytest.importorskip("tomllib")
    from bench.calibration.compensation import compensation_of
    from bench.calibration.export import KalibrNoise, to_c_header, to_csv, to_json, to_toml, to_yaml
    from bench.model.result import CalibrationResult, coefficient_table
    values = {**default_sim_imu().to_canonical(), "Dt": 0.5}
    sigmas = {n: 1e-6 * max(abs(v), 1e-3) for n, v in values.items()} | {"Dt": 0.02}
    c = compensation_of(CalibrationResult(coefficient_table(values, sigmas)))
    assert c.time_offset is not None and c.higher_order is None
    doc = json.loads(to_json(c))
    assert doc["time_offset"]["value"] == pytest.approx(5e-4) and doc["time_offset"]["sigma"] == pytest.approx(2e-5)
    assert doc["version"] == 1 and tomllib.loads(to_toml(c)) == doc
    jsonschema = pytest.importorskip("jsonschema")
    schema = json.loads((Path(__file__).resolve().parents[3] / "docs" / "reference" / "schemas"
                         / "compensation.schema.json").read_text(encoding="utf-8"))
    jsonschema.validate(doc, schema)
    row = [r for r in to_csv(c).splitlines() if r.startswith("acc,time_offset,")]
    assert len(row) == 1 and row[0].endswith(",s") and float(row[0].split(",")[4]) == pytest.approx(5e-4)
    header = to_c_header(c)
    assert re.search(r"#define TB_IMU_TIME_OFFSET_S 0\.0005", header)
    yaml_text = to_yaml(c, KalibrNoise(200.0, 1e-4, 1e-6, 1e-3, 1e-5))
    assert "time_offset: 0.0" in yaml_text.splitlines() and "gyro-to-accelerometer offset" in yaml_text
    plain = compensation_of(CalibrationResult(coefficient_table(default_sim_imu().to_canonical())))
    assert plain.time_offset is None and "time_offset" not in json.loads(to_json(plain))
    assert "TIME_OFFSET" not in to_c_header(plain)
