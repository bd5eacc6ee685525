"""The per-coefficient uncertainty budget (issue 15): components, combined and expanded
uncertainty, the table's part from configuration, the residual test, and a small
seed-fixed coverage study that fails when the stated uncertainties are wrong."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from scipy import integrate

from bench.config.load import ConfigError, parse_config
from bench.model.closed_form import exact_observations
from bench.model.earth import Site
from bench.model.families import RESULT_UNITS
from bench.model.imu import NoiseModel, default_sim_imu
from bench.model.observations import turn_axis_in_body
from bench.model.result import CalibrationResult
from bench.model.table_prior import TablePrior, from_check, from_datasheet
from bench.model.units import ARCSEC
from bench.report.markdown import markdown_report
from bench.sim.acquire import AcquisitionTiming, acquire
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from bench.solve.budget import BIAS_INSTABILITY, NOISE, TABLE, TURN_ANGLE, UNEXPLAINED, BudgetInputs, gm_mean_kernel
from bench.solve.calibrate import solve
from bench.solve.inputs import budget_inputs
from bench.solve.methods import gyro_bias_from_positions, solve_gyros
from schedules import load_builtin
from studies.coverage import calibration_coverage

SITE = Site(30.27)
FAST = AcquisitionTiming(dwell_s=10.0, settle_s=1.0, move_rate_dps=60.0, move_accel_dps2=40.0, turn_rate_dps=20.0,
                         turn_accel_dps2=20.0, rest_s=1.0)

SHORT = AcquisitionTiming(dwell_s=5.0, settle_s=0.5, move_rate_dps=60.0, move_accel_dps2=40.0, turn_rate_dps=30.0,
                          turn_accel_dps2=20.0, rest_s=0.5)


def _plan(pos: str, rot: str):
    return [p.angles_deg for p in load_builtin(pos).positions], list(load_builtin(rot).rotations)


def _noisy(pos="optimal-24", rot="optimal-5s6r", box_arcsec=20.0, seed=3):
    positions, turns = _plan(pos, rot)
    box = np.random.default_rng(seed).standard_normal((3, 3)) * box_arcsec * ARCSEC
    return acquire(SimTable(SITE, black_box_rad=box), SimImu(default_sim_imu(), NoiseModel(), rate_hz=50.0, seed=seed),
                   positions, turns, FAST)


def test_gauss_markov_kernel_matches_numerical_integration():
    tau = 300.0
    starts, durations = np.array([0.0, 70.0, 500.0]), np.array([60.0, 40.0, 10.0])
    k = gm_mean_kernel(starts, durations, tau)
    for i in range(3):
        for j in range(3):
            value, _ = integrate.dblquad(lambda s, t: math.exp(-abs(t - s) / tau), starts[i], starts[i] + durations[i],
                                         starts[j], starts[j] + durations[j])
            assert k[i, j] == pytest.approx(value / durations[i] / durations[j], rel=1e-6)


def test_budget_components_combine_to_sigma_and_expand_by_k():
    obs_p, obs_r = _noisy()
    inputs = BudgetInputs(table=TablePrior.uniform(20.0, "test"), gyro_bias_instability=1e-8,
                          acc_bias_instability=2e-5, turn_rate_dps=20.0)
    result = solve(obs_p, obs_r, SITE, budget_inputs=inputs).to_result()
    for c in result.coefficients.values():
        assert c.budget and c.sigma == pytest.approx(math.sqrt(sum(v * v for v in c.budget.values())), rel=1e-12)
        assert c.expanded == pytest.approx(2.0 * c.sigma) and c.k == 2.0
    assert {NOISE, TABLE} <= set(result.coefficients["K0_x"].budget)
    again = CalibrationResult.loads(result.dumps())
    assert again.coefficients["Ea_Yx"].budget == result.coefficients["Ea_Yx"].budget
    assert again.to_json()["version"] == 2


def test_a_plan_that_cancels_an_angle_to_first_order_is_credited():
    """Same table prior, same noise-free data: the optimal plan's table part of the biases is far below the
    traditional plan's, which is first order in the angles."""
    imu = default_sim_imu()
    parts = {}
    for plan, (pos, rot) in {"optimal": ("optimal-24", "optimal-5s6r"),
                             "traditional": ("traditional-12", "traditional-3s6r")}.items():
        positions, turns = _plan(pos, rot)
        obs_p, obs_r = exact_observations(positions, turns, imu, SITE)
        cal = solve(obs_p, obs_r, SITE, budget_inputs=BudgetInputs(table=TablePrior.uniform(20.0, "t")))
        parts[plan] = {fam: math.hypot(*(cal.budget.components[f"{fam}_{s}"][TABLE] for s in "xyz"))
                       for fam in ("K0", "D0", "Kg")}
    # biases: first order cancelled (paper Table 2); gyro scale: 3.5e-8 against 2.4e-7 (paper Table 4)
    for fam, ratio in (("K0", 1e-3), ("D0", 1e-3), ("Kg", 0.2)):
        assert parts["optimal"][fam] < ratio * parts["traditional"][fam], (fam, parts)


def test_without_the_table_part_the_report_says_so_and_flags_it():
    obs_p, obs_r = _noisy()
    result = solve(obs_p, obs_r, SITE).to_result()
    assert any("NOT included" in f for f in result.quality.flags)
    assert result.quality.uncertainty["table_included"] is False
    assert "the turntable's pointing error is NOT included" in markdown_report(result)


def test_old_result_files_still_read_and_the_report_says_they_have_no_budget():
    old = {"format": "turntable-bench/result", "version": 1,
           "coefficients": {"Kg_x": {"value": 36000.0, "sigma": 0.1, "unit": "counts/s per deg/s"}}}
    result = CalibrationResult.from_json(old)
    assert result.coefficients["Kg_x"].budget is None and math.isnan(result.coefficients["Kg_x"].expanded)
    assert "no uncertainty budget" in markdown_report(result)


def test_the_residual_test_names_a_bad_step_and_widens_only_as_a_flagged_fallback():
    obs_p, obs_r = _noisy()
    inputs = BudgetInputs(table=TablePrior.uniform(20.0, "test"), turn_rate_dps=20.0)
    clean = solve(obs_p, obs_r, SITE, budget_inputs=inputs)
    assert all(c.consistent for c in clean.budget.consistency)
    assert not any(UNEXPLAINED in parts for parts in clean.budget.components.values())
    bad = obs_p[6]
    bad.acc_mean = bad.acc_mean + np.array([0.0, 40.0, 0.0])      # 1 mg on y at P07: the IMU moved
    cal = solve(obs_p, obs_r, SITE, budget_inputs=inputs)
    flagged = [f for f in cal.flags if "inconsistent with the uncertainty budget" in f]
    assert len(flagged) == 1 and "accelerometers y" in flagged[0] and "P07" in flagged[0]
    assert UNEXPLAINED in cal.budget.components["K0_y"] and UNEXPLAINED not in cal.budget.components["K0_x"]


def test_a_table_with_pointing_error_gets_the_chi2_the_budget_predicts():
    """The case of the issue: with a black box in the data, the noise-only chi2 is huge; against the
    budget's predicted scatter it is not, and no scaling is applied."""
    obs_p, obs_r = _noisy(box_arcsec=60.0)
    cal = solve(obs_p, obs_r, SITE, budget_inputs=BudgetInputs(table=TablePrior.uniform(60.0, "t"), turn_rate_dps=20))
    assert max(cal.gyros.fit.chi2_per_dof) > 100           # against the sample noise alone
    assert all(c.consistent for c in cal.budget.consistency), [c.to_json() for c in cal.budget.consistency]


def test_table_prior_from_configuration(tmp_path):
    base = ('format = "turntable-bench/config"\nversion = 1\n[site]\nlatitude_deg = 30.27\n[table]\n'
            'url = "sim"\ndialect = "scpi"\n{table}\n[imu]\ninterface = "virtual"\nchannel = "t"\nrate_hz = 200.0\n'
            '[plan]\npositions = "optimal-24"\n')
    assert parse_config(base.format(table="")).table.pointing is None
    overall = parse_config(base.format(table="pointing_accuracy_arcsec = 10")).table.pointing
    assert np.allclose(overall.sigma_rad, 10 * ARCSEC)
    per_frame = parse_config(base.format(table="orthogonality_arcsec = 3\n[table.pointing_accuracy_arcsec]\n"
                                               "outer = 5\nmiddle = 6\ninner = 7")).table.pointing
    assert np.allclose(per_frame.sigma_rad / ARCSEC, [[3, 3, 5], [3, 3, 6], [3, 3, 7]])
    with pytest.raises(ConfigError, match="orthogonality_arcsec"):
        parse_config(base.format(table="orthogonality_arcsec = 3"))
    check = {"format": "turntable-bench/table-check", "correlation": np.eye(4).tolist(),
             "combinations": [{"coefficients": {"alpha_o": 1.0}, "value_arcsec": 12.0, "sigma_arcsec": 0.5},
                              {"coefficients": {"beta_o": 1.0}, "value_arcsec": -3.0, "sigma_arcsec": 0.5},
                              {"coefficients": {"alpha_m": 1.0, "alpha_i": 1.0}, "value_arcsec": 0.0,
                               "sigma_arcsec": 0.5},
                              {"coefficients": {"beta_m": 1.0, "beta_i": 1.0}, "value_arcsec": 0.0,
                               "sigma_arcsec": 0.5}]}
    path = tmp_path / "t.table-check.json"
    path.write_text(json.dumps(check))
    prior = parse_config(base.format(table=f'check = "{path}"\npointing_accuracy_arcsec = 20')).table.pointing
    sig = prior.sigma_rad / ARCSEC
    assert sig[0, 0] == pytest.approx(12.0, abs=0.1) and sig[0, 1] == pytest.approx(3.0, abs=0.2)   # measured
    assert sig[0, 2] == pytest.approx(20.0) and sig[2, 2] == pytest.approx(20.0)                 # gammas: the prior
    # the middle/inner sum is measured near 0: their sum's variance is small, each angle keeps the prior's split
    cov = prior.covariance_rad2 / ARCSEC ** 2
    assert cov[3, 3] + cov[6, 6] + 2 * cov[3, 6] < 1.0 and sig[1, 0] > 10
    path.write_text('{"format": "something else"}')
    with pytest.raises(ConfigError, match="table.check.*not a turntable-bench/table-check"):
        parse_config(base.format(table=f'check = "{path}"'))
    assert from_datasheet(5.0).source.startswith("datasheet")
    assert from_check(check, None, "x").source.endswith("(no [table] pointing_accuracy_arcsec)")


@pytest.mark.slow
def test_coverage_small_study_is_within_its_binomial_bounds():
    """40 seed-fixed simulated calibrations on a traditional plan with a 20" table (the case where the
    noise-only sigma was 800 times too small): the truth lies within U (k = 2) and within sigma about as
    often as a normal error would. Bounds are wide (40 draws, correlated coefficients) but both ways:
    an uncertainty that is too large fails as much as one too small."""
    tallies = calibration_coverage("traditional", 20.0, draws=40, seed=7, factors=(1.0,), timing=SHORT, rate_hz=25.0)
    n, within_1, within_2 = tallies[1.0].coverage()
    assert n == 40 * 24
    assert 0.55 <= within_1 <= 0.82, within_1
    assert 0.88 <= within_2 <= 0.99, within_2


def test_noisy_dwells_keep_the_optimal_plans_cancellation():
    """Weights from each dwell's own standard error differ at random and broke the optimal plan's
    first-order cancellation (K0 table part about 4e-6 g at 20"); pooled weights keep it."""
    obs_p, obs_r = _noisy()
    cal = solve(obs_p, obs_r, SITE, budget_inputs=BudgetInputs(table=TablePrior.uniform(20.0, "t"), turn_rate_dps=20))
    for s in "xyz":
        assert cal.budget.components[f"K0_{s}"][TABLE] < 1e-7, cal.budget.components[f"K0_{s}"]
        assert cal.budget.components[f"Ka_{s}"][TABLE] < 0.05 * cal.budget.components[f"Ka_{s}"][NOISE]


def test_the_turn_angle_part_matches_a_monte_carlo_of_turn_angle_errors():
    """Each turn's angle off by delta_k (1-sigma 50 arcsec, independent): the budget's turn-angle part of every
    gyro scale factor, axis and bias is the scatter of the re-solved coefficients over 200 draws (5 % binomial)."""
    imu = default_sim_imu()
    positions, turns = _plan("optimal-24", "optimal-5s6r")
    obs_p, obs_r = exact_observations(positions, turns, imu, SITE)
    sigma_rad = 50.0 * ARCSEC
    cal = solve(obs_p, obs_r, SITE, budget_inputs=BudgetInputs(turn_angle_sigma_rad=sigma_rad))
    assert not any("angle error" in f for f in cal.flags)
    turned = np.array([o.sign * turn_axis_in_body(o.start_deg, o.frame_index) for o in obs_r]) @ imu.gyro_matrix.T
    rng = np.random.default_rng(5)
    draws = []
    for _ in range(200):        # the solve's own gyro fits, without a budget each time (SI)
        delta = rng.standard_normal(len(obs_r)) * sigma_rad
        moved = [dataclasses.replace(o, gyro_integral=o.gyro_integral + d * t) for o, d, t in zip(obs_r, delta, turned)]
        gyros = solve_gyros(moved, SITE)
        bias = gyro_bias_from_positions(obs_p, SITE, gyros)
        draws.append((gyros.scale[0], gyros.scale[2], gyros.axes[0, 1], gyros.axes[2, 0], bias.value[1]))
    for name, spread in zip(("Kg_x", "Kg_z", "Eg_Yx", "Eg_Xz", "D0_y"), np.std(draws, axis=0)):
        part = cal.budget.components[name][TURN_ANGLE] * RESULT_UNITS[name[:2]][1]
        assert part == pytest.approx(spread, rel=0.15), (name, part / spread)
    # without the figure: flagged, and not in sigma
    plain = solve(obs_p, obs_r, SITE, budget_inputs=BudgetInputs())
    assert any("turns' angle error" in f and "NOT included" in f for f in plain.flags)
    assert TURN_ANGLE not in plain.budget.components["Kg_x"]
    assert "turn_angle_error_arcsec" in markdown_report(plain.to_result())


def test_config_keys_feed_the_correlation_time_and_the_turn_angle(tmp_path):
    base = ('format = "turntable-bench/config"\nversion = 1\n[site]\nlatitude_deg = 30.27\n[table]\n'
            'url = "tcp://127.0.0.1:5000"\ndialect = "scpi"\n{table}\n[imu]\ninterface = "virtual"\nchannel = "t"\n'
            'rate_hz = 200.0\n[imu.identity]\n{identity}\n[plan]\npositions = "optimal-24"\n')
    default = parse_config(base.format(table="", identity=""))
    assert budget_inputs(default, sim=False).correlation_time_s == 300.0
    assert budget_inputs(default, sim=False).turn_angle_sigma_rad is None
    assert budget_inputs(default, sim=True).turn_angle_sigma_rad == 0.0      # the simulated table stops exactly
    config = parse_config(base.format(table="turn_angle_error_arcsec = 1.5",
                                      identity="gyro_bias_stability_dph = 0.01\nbias_correlation_time_s = 40"))
    inputs = budget_inputs(config, sim=False)
    assert inputs.correlation_time_s == 40.0 and inputs.turn_angle_sigma_rad == pytest.approx(1.5 * ARCSEC)
    for table, identity, line, key, message in (
            ("", "bias_correlation_time_s = 0", 14, "imu.identity.bias_correlation_time_s", "must be > 0"),
            ("", "bias_correlation_time_s = 1e7", 14, "imu.identity.bias_correlation_time_s", "must be <= 1e+06 s"),
            ("turn_angle_error_arcsec = -1", "", 8, "table.turn_angle_error_arcsec", "must be >= 0"),
            ("turn_angle_error_arcsec = 'one'", "", 8, "table.turn_angle_error_arcsec", "must be a finite number")):
        with pytest.raises(ConfigError) as caught:
            parse_config(base.format(table=table, identity=identity), source="bench.toml")
        assert str(caught.value).startswith(f"bench.toml:{line}: {key}: {message}"), str(caught.value)
    # the correlation time changes the bias-instability part (noise-free data: the part is the budget's alone)
    imu = default_sim_imu()
    positions, turns = _plan("traditional-12", "traditional-3s6r")
    obs_p, obs_r = exact_observations(positions, turns, imu, SITE)
    parts = {tau: solve(obs_p, obs_r, SITE, budget_inputs=dataclasses.replace(
        inputs, correlation_time_s=tau)).budget.components["D0_x"][BIAS_INSTABILITY] for tau in (40.0, 3000.0)}
    assert parts[40.0] < 0.5 * parts[3000.0], parts     # a short correlation time averages down over the run
