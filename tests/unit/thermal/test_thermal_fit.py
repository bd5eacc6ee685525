"""The thermal polynomial fit: degree chosen by the data, uncertainties that hold, the model file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.model.result import CalibrationResult, coefficient_table
from bench.model.run_section import RunInfo
from bench.thermal.fit import ThermalFitError, fit_coefficient
from bench.thermal.model import ThermalFormatError, ThermalModel, fit_thermal_model, point_from_result

TEMPS = np.array([-20.0, 0.0, 25.0, 50.0])


def _poly(coeffs, t, ref=25.0):
    return sum(c * (np.asarray(t) - ref) ** k for k, c in enumerate(coeffs))


FIVE_TEMPS = np.array([-20.0, 0.0, 25.0, 50.0, 70.0])


@pytest.mark.parametrize("truth, degree", [([3.0], 0), ([3.0, 0.05], 1), ([3.0, 0.05, 0.002], 2),
                                           ([3.0, 0.0, 0.0, 1e-4], 3)])
def test_noise_free_points_give_the_true_degree_and_polynomial(truth, degree):
    sigma = np.full(5, 0.01)
    fit = fit_coefficient("D0_x", "deg/h", FIVE_TEMPS, _poly(truth, FIVE_TEMPS), sigma)
    assert fit.degree == degree
    assert fit.polynomial == pytest.approx(truth, rel=1e-9, abs=1e-12)
    assert fit.value(10.0) == pytest.approx(_poly(truth, 10.0), rel=1e-12)


def test_the_degree_leaves_at_least_one_degree_of_freedom():
    """Issue 33: a cubic was put through 4 temperatures (it fits any 4 values exactly, nothing checks it)."""
    cubic = _poly([3.0, 0.0, 0.0, 1e-4], TEMPS)
    fit = fit_coefficient("D0_x", "deg/h", TEMPS, cubic, np.full(4, 0.01))
    assert fit.degree == 2 and fit.dof == 1 and fit.sigma_scale > 1.0     # the misfit shows, scaled into sigma
    assert fit_coefficient("D0_x", "deg/h", TEMPS[:2], cubic[:2], np.full(2, 0.01)).degree == 0
    assert fit_coefficient("D0_x", "deg/h", TEMPS[:1], cubic[:1], np.full(1, 0.01)).degree == 0


def test_over_many_seeds_terms_and_interpolated_values_scatter_as_their_sigmas_say():
    """Independent Gaussian errors, no common part: z-scores of the terms and of values between the
    temperatures are standard normal (the common-mode allowance only widens c0)."""
    truth = [1.0, 0.02, 3e-4]
    rng = np.random.default_rng(12)
    temps = np.array([-40.0, -20.0, 0.0, 25.0, 50.0, 70.0])
    z_terms, z_values, degrees = [], [], []
    for _ in range(400):
        sigma = rng.uniform(0.01, 0.03, len(temps))
        y = _poly(truth, temps) + sigma * rng.standard_normal(len(temps))
        fit = fit_coefficient("K0_x", "g", temps, y, sigma, common_sigmas=np.zeros(len(temps)))
        degrees.append(fit.degree)
        if fit.degree == 2:
            z_terms += list((fit.polynomial[1:] - truth[1:]) / fit.sigma[1:])
            z_values += [(fit.value(t) - _poly(truth, t)) / fit.sigma_at(t) for t in (-30.0, 10.0, 60.0)]
    assert np.mean(np.array(degrees) == 2) > 0.95         # the quadratic term is 5 sigma: found
    for z in (np.array(z_terms), np.array(z_values)):
        assert abs(np.mean(z)) < 0.15 and 0.85 < np.std(z) < 1.15
        assert np.mean(np.abs(z) > 3) < 0.01


def test_a_term_that_is_not_there_is_rarely_chosen():
    rng = np.random.default_rng(3)
    degrees = [fit_coefficient("K0_x", "g", TEMPS, 1.0 + 0.01 * rng.standard_normal(4), np.full(4, 0.01)).degree
               for _ in range(500)]
    assert np.mean(np.array(degrees) > 0) < 0.05          # alpha 0.01 per comparison


def test_an_error_common_to_every_temperature_is_covered_by_the_band():
    """The same offset in every point (the table's black box): without a split of the sigmas the band
    at every temperature still covers it; the temperature terms are not biased by it."""
    truth = [5.0, 0.1]
    rng = np.random.default_rng(8)
    z = []
    for _ in range(300):
        sigma = np.full(4, 0.2)
        common = 0.19 * rng.standard_normal()           # nearly all of each point's sigma is shared
        y = _poly(truth, TEMPS) + common + np.sqrt(0.2 ** 2 - 0.19 ** 2) * rng.standard_normal(4)
        fit = fit_coefficient("Kg_x", "counts/s per deg/s", TEMPS, y, sigma)
        z.append((fit.value(10.0) - _poly(truth, 10.0)) / fit.sigma_at(10.0))
        assert fit.degree == 1 and abs(fit.polynomial[1] - 0.1) < 3 * fit.sigma[1]
    z = np.array(z)
    assert np.std(z) < 1.0 and np.mean(np.abs(z) > 3) < 0.01
    # and without the allowance (saying the common part is 0) the same data would be overconfident
    y = _poly(truth, TEMPS) + 0.5 + 0.01 * rng.standard_normal(4)
    naive = fit_coefficient("Kg_x", "u", TEMPS, y, np.full(4, 0.2), common_sigmas=np.zeros(4))
    careful = fit_coefficient("Kg_x", "u", TEMPS, y, np.full(4, 0.2))
    assert careful.sigma_at(10.0) > 1.9 * naive.sigma_at(10.0)


def test_more_scatter_than_the_sigmas_say_scales_the_covariance():
    y = np.array([0.0, 1.0, 0.0, 1.0, 0.0, 1.0])
    fit = fit_coefficient("D0_x", "deg/h", np.linspace(-20, 50, 6), y, np.full(6, 0.01))
    assert fit.sigma_scale > 10 and fit.dof > 0


def test_bad_points_are_refused():
    with pytest.raises(ThermalFitError, match="positive finite sigma"):
        fit_coefficient("D0_x", "deg/h", TEMPS, np.ones(4), np.array([0.1, np.nan, 0.1, 0.1]))
    with pytest.raises(ThermalFitError, match="as many"):
        fit_coefficient("D0_x", "deg/h", TEMPS, np.ones(3), np.ones(4))


# -- the model over results --------------------------------------------------------------------

def _result(temperature_c, values, sigmas, with_temperature=True):
    r = CalibrationResult(coefficient_table(values, sigmas))
    if with_temperature:
        r.temperature = {"mean_c": temperature_c, "min_c": temperature_c - 0.1, "max_c": temperature_c + 0.1}
    return r


def test_the_model_fits_every_shared_coefficient_and_notes_the_others(tmp_path):
    points = []
    for t in TEMPS:
        values = {"D0_x": _poly([0.05, 0.002], t), "K0_y": 1e-4, "Kg_x": 36000.0 + 0.3 * (t - 25)}
        sigmas = {"D0_x": 0.001, "K0_y": 1e-6, "Kg_x": float("nan") if t == 0 else 0.01}
        if t == 50.0:
            del values["K0_y"]
        points.append(point_from_result(_result(t, values, sigmas), f"r{t:g}.json"))
    model = fit_thermal_model(points)
    assert set(model.fits) == {"D0_x"}
    assert model.fits["D0_x"].degree == 1
    assert any("K0_y" in n and "r50.json" in n for n in model.notes)
    assert any("Kg_x" in n and "no uncertainty" in n and "r0.json" in n for n in model.notes)
    fit = model.fits["D0_x"]
    assert fit.prediction_sigma(0.0) == pytest.approx(np.hypot(fit.sigma_at(0.0), 0.001))
    assert fit.prediction_sigma(10.0) > fit.sigma_at(10.0)
    # round trip through the file
    path = tmp_path / "thermal.json"
    model.save(path)
    back = ThermalModel.load(path)
    assert back.evaluate(10.0) == model.evaluate(10.0)
    assert [p.temperature_c for p in back.points] == [p.temperature_c for p in model.points]


def test_a_result_without_temperature_needs_one_given():
    r = _result(0.0, {"D0_x": 0.1}, {"D0_x": 0.01}, with_temperature=False)
    with pytest.raises(Exception, match="records no IMU temperature.*FILE@DEGC"):
        point_from_result(r, "a.json")
    assert point_from_result(r, "a.json", -5.0).temperature_c == -5.0
    with pytest.raises(ThermalFitError, match="two temperatures"):
        fit_thermal_model([point_from_result(r, "a.json", 1.0)])
    with pytest.raises(ThermalFitError, match="one temperature"):
        fit_thermal_model([point_from_result(r, "a.json", 1.0), point_from_result(r, "b.json", 1.0)])


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d.update(format="x"), "not a turntable-bench/thermal file"),
    (lambda d: d.update(version=9), "version 9 is not supported"),
    (lambda d: d["thermal_model"].update(version=2), "thermal_model: not a"),
    (lambda d: d["thermal_model"]["coefficients"].update(Zz_q={}), "unknown coefficient name"),
    (lambda d: d["thermal_model"]["coefficients"]["D0_x"].update(degree=3), "D0_x: malformed"),
    (lambda d: d["thermal_model"]["coefficients"]["D0_x"].update(polynomial=[float("nan"), 1.0]), "NaN is not a"),
])
def test_a_bad_thermal_file_is_one_clear_error(mutate, message):
    points = [point_from_result(_result(t, {"D0_x": 0.1 * t}, {"D0_x": 0.01}), f"r{t:g}") for t in TEMPS]
    data = json.loads(fit_thermal_model(points).dumps())
    mutate(data)
    with pytest.raises(ThermalFormatError, match=message):
        ThermalModel.loads(json.dumps(data), "t.json")
    with pytest.raises(ThermalFormatError, match="t.json:1: invalid JSON"):
        ThermalModel.loads("{", "t.json")


def test_calibrations_of_different_imus_are_refused():
    points = []
    for t, serial in ((0.0, "A-1"), (25.0, "A-1"), (50.0, "B-7")):
        r = _result(t, {"D0_x": 0.1}, {"D0_x": 0.01})
        r.run = RunInfo.from_dict({"imu": {"model": "m", "serial": serial}}, complete=False)
        points.append(point_from_result(r, f"r{t:g}.json"))
    with pytest.raises(ThermalFitError, match="different IMUs.*'B-7'"):
        fit_thermal_model(points)
    fit_thermal_model(points[:2])


# -- the budget's common part (the table's, the site's) -----------------------------------------

def _budgeted_points(values_by_t, table_sigma, noise_sigma):
    """Results whose D0_x sigma is a budget of a table part (common) and a noise part (independent)."""
    from bench.solve.budget import NOISE, TABLE

    budget = {NOISE: noise_sigma, TABLE: table_sigma}
    sigma = float(np.hypot(noise_sigma, table_sigma))
    return [_with_temperature(CalibrationResult(coefficient_table({"D0_x": v}, {"D0_x": sigma}, {"D0_x": budget})), t)
            for t, v in values_by_t.items()]


def _with_temperature(result, t):
    result.temperature = {"mean_c": t}
    return point_from_result(result, f"r{t:g}")


def test_the_budgets_common_part_goes_to_c0_and_leaves_the_terms_their_independent_sigma():
    """The table's part of each calibration's sigma (common to every temperature) dominates: c0's sigma is
    about that common part, the temperature terms are as sure as the independent (noise) parts make them,
    and a quadratic term the noise resolves is found; without the split (results with no budget) the
    common part was counted as independent, hiding the term and widening the slope by ~10x."""
    truth = [0.05, 0.002, 2e-5]
    table, noise = 0.02, 0.001
    rng = np.random.default_rng(5)
    offset = table * rng.standard_normal()              # one table, one error at every temperature
    values = {float(t): float(_poly(truth, t)) + offset + noise * rng.standard_normal() for t in TEMPS}
    fit = fit_thermal_model(_budgeted_points(values, table, noise)).fits["D0_x"]
    independent = fit_coefficient("D0_x", "deg/h", TEMPS, list(values.values()), np.full(4, noise),
                                  common_sigmas=np.zeros(4))
    assert fit.degree == 2 == independent.degree
    assert fit.common_sigma == pytest.approx(table)
    assert fit.sigma[0] == pytest.approx(np.hypot(table, independent.sigma[0]), rel=1e-6)
    assert fit.sigma[0] == pytest.approx(table, rel=0.05)
    assert fit.sigma[1:] == pytest.approx(independent.sigma[1:], rel=1e-6)     # not inflated by the table
    assert all(abs(fit.polynomial[k] - truth[k]) < 3 * fit.sigma[k] for k in range(3))
    # the old rule (no budget to split): every sigma taken as independent, the quadratic term lost in it
    sigma = float(np.hypot(table, noise))
    unsplit = fit_thermal_model([_with_temperature(_result(t, {"D0_x": v}, {"D0_x": sigma}, False), t)
                                 for t, v in values.items()]).fits["D0_x"]
    assert unsplit.degree < 2 and unsplit.sigma[1] > 10 * fit.sigma[1]


def test_a_direction_cosine_diagonal_is_not_split():
    """A diagonal is second order in its row's off-diagonals: the table's error in it changes with their
    temperature terms, so its budget's table part is not taken as common (the old bound on c0 stays)."""
    from bench.solve.budget import NOISE, TABLE

    budget = {NOISE: 1e-9, TABLE: 4e-8}
    sigma = float(np.hypot(1e-9, 4e-8))
    points = [_with_temperature(CalibrationResult(coefficient_table({"Eg_Xx": 1.0 - 1e-8 * k}, {"Eg_Xx": sigma},
                                                                    {"Eg_Xx": budget})), t)
              for k, t in enumerate(TEMPS)]
    fit = fit_thermal_model(points).fits["Eg_Xx"]
    assert fit.common_sigma == pytest.approx(sigma) and fit.sigmas == pytest.approx(np.full(4, sigma))
