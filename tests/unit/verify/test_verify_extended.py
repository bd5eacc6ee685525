"""Verification of an extended-model calibration (issue 30 item 6): the verification compensates its dwells and
turns with the result's higher-order terms, as `bench apply` does. On verify-default acquired in memory from the
simulated IMU with the tactical-MEMS truth (noise off, ideal table), the true calibration with its extended
coefficients leaves no error; the same 30 coefficients without them leave the higher-order terms' errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.acceptance.limits import BEYOND_WARN
from bench.calibration.compensation import compensation_of
from bench.model.higher_order import HigherOrderTerms, preset
from bench.model.result import CalibrationResult, coefficient_table
from bench.verify.errors import EXTENDED_QUANTITIES, verify_extraction
from bench.verify.plan import verification_checks, write_verification
from studies.extended_coverage import truth_values
from tests.helpers.verification import SITE, acquire_verification


@pytest.fixture(scope="module")
def verification_data():
    """verify-default from the simulated IMU with the tactical-MEMS higher-order truth (noise off)."""
    terms = HigherOrderTerms.from_display(preset("tactical-mems"))
    extraction, rates, truth = acquire_verification(higher_order=terms)
    return extraction, rates, truth, terms


def _result(values: dict[str, float]) -> CalibrationResult:
    return CalibrationResult(coefficient_table(values, {n: 1e-6 * max(abs(v), 1e-3) for n, v in values.items()}))


def test_the_true_extended_calibration_leaves_no_error_and_the_30_leave_the_terms(verification_data):
    extraction, rates, truth, terms = verification_data
    extended = _result({**truth.to_canonical(), **truth_values(terms)})
    linear = _result(truth.to_canonical())
    with_terms = verify_extraction(extraction, rates, compensation_of(extended), extended, SITE)
    without = verify_extraction(extraction, rates, compensation_of(linear), linear, SITE)
    # a 30-coefficient result: the paper's quantities; an extended one adds the gyro families' (9 + 3 + 3)
    assert not with_terms.notes and len(without.errors) == 3 + 3 + 6 + 3 + 3 * 3 * 3
    assert len(with_terms.errors) == len(without.errors) + 9 + 3 + 3
    # |error| / U (U here is the calibration's 1e-6 sigmas): the extended compensation leaves its remainder; the 30
    # coefficients leave the accelerometers' second order and asymmetry as biases of up to 240 ug (their U grows
    # with the residual scatter). The gyros' terms leave no error the paper's quantities show: the g-sensitivity
    # averages out over the positions, asymmetry and nonlinearity cancel between a CCW and a CW turn.
    ratio = {e.name: abs(e.value) / e.uncertainty for e in with_terms.errors}
    worst = max(ratio, key=ratio.__getitem__)
    assert ratio[worst] < 0.1, (worst, ratio[worst])
    assert max(abs(e.value) / e.uncertainty for e in without.of("acc_bias_ug")) > 10.0    # measured: 23


#: gyro family -> (its verification quantity, the error's name for coefficient name's sensor and axis)
GYRO_FAMILIES = {
    "Gg": ("gyro_g_sensitivity_dph_per_g", lambda name: f"gyro g-sensitivity {name[4]} to {name[3]}"),
    "Ag": ("gyro_asymmetry_ppm", lambda name: f"gyro asymmetry {name[3]}"),
    "Ng": ("gyro_nonlinearity_ppm_per_dps", lambda name: f"gyro nonlinearity {name[3]}"),
}


def _gyro_family_errors(verification_data, changed: dict[str, float]) -> dict[str, float]:
    """The gyro families' errors (by name) of the true extended calibration with `changed` coefficients."""
    extraction, rates, truth, terms = verification_data
    result = _result({**truth.to_canonical(), **truth_values(terms), **changed})
    verification = verify_extraction(extraction, rates, compensation_of(result), result, SITE)
    assert not verification.notes
    return {e.name: e.value for quantity, _ in GYRO_FAMILIES.values() for e in verification.of(quantity)}


def test_the_true_gyro_families_leave_no_error(verification_data):
    errors = _gyro_family_errors(verification_data, {})
    assert len(errors) == 9 + 3 + 3
    # the truth's magnitudes: 2-10 deg/h per g, 120-200 ppm, 0.1-0.15 ppm per deg/s; the remainder (measured):
    # 0.0003 deg/h per g, 0.005 ppm, 1e-7 ppm per deg/s
    for name, value in errors.items():
        limit = 0.01 if "g-sensitivity" in name else 0.05 if "asymmetry" in name else 0.001
        assert abs(value) < limit, (name, value)


@pytest.mark.parametrize("key", sorted(GYRO_FAMILIES))
@pytest.mark.parametrize("change", ["dropped", "sign flipped"])
def test_a_wrong_gyro_family_shows_as_its_error(verification_data, key, change):
    """A family's coefficients set to zero leave the truth as its error, their sign flipped twice the truth: the
    error (true minus applied) is told per coefficient, and the other gyro families stay clean."""
    values = {n: v for n, v in truth_values(verification_data[3]).items() if n.startswith(f"{key}_")}
    factor = 0.0 if change == "dropped" else -1.0
    errors = _gyro_family_errors(verification_data, {n: factor * v for n, v in values.items()})
    _, error_name = GYRO_FAMILIES[key]
    for name, true_value in values.items():
        assert errors[error_name(name)] == pytest.approx((1.0 - factor) * true_value, rel=0.01, abs=1e-3 * abs(
            true_value)), name
    others = [n for n in errors if n not in {error_name(name) for name in values}]
    clean = _gyro_family_errors(verification_data, {})
    assert np.allclose([errors[n] for n in others], [clean[n] for n in others], atol=0.01)


def test_a_gyro_family_limit_fails_a_wrong_calibration_and_a_30_coefficient_one(verification_data):
    """`[acceptance.verification] gyro_asymmetry_ppm`: the true calibration passes, one with the asymmetry's sign
    flipped fails on every gyro, and a result of the 30 coefficients, which cannot be checked for it, fails."""
    extraction, rates, truth, terms = verification_data
    true_values = {**truth.to_canonical(), **truth_values(terms)}
    limits = {"gyro_asymmetry_ppm": 20.0}

    def failed(values: dict[str, float]) -> list[str]:
        result = _result(values)
        verification = verify_extraction(extraction, rates, compensation_of(result), result, SITE)
        return [c.name for c in verification_checks(verification, limits, BEYOND_WARN) if not c.passed]

    assert failed(true_values) == []
    flipped = {n: -v if n.startswith("Ag_") else v for n, v in true_values.items()}
    assert failed(flipped) == [f"verify gyro asymmetry {s}" for s in "xyz"]
    assert failed(truth.to_canonical()) == ["verify gyro scale-factor asymmetry"]


def test_the_extended_verification_file_matches_its_schema(verification_data, tmp_path):
    """`<run-id>.verify.json` of an extended result, with the gyro families' errors and their limits' checks, is
    valid against docs/reference/schemas/verification.schema.json."""
    jsonschema = pytest.importorskip("jsonschema", reason="the test extra installs jsonschema")
    from tests.e2e.test_schemas import validator

    extraction, rates, truth, terms = verification_data
    result = _result({**truth.to_canonical(), **truth_values(terms)})
    verification = verify_extraction(extraction, rates, compensation_of(result), result, SITE)
    checks = verification_checks(verification, {"gyro_nonlinearity_ppm_per_dps": 0.05}, BEYOND_WARN)
    json_path, _ = write_verification(tmp_path, "RUN", verification, checks, calibration="c.result.json",
                                      schedule="verify-default", log="RUN.mcap")
    document = json.loads(json_path.read_text(encoding="utf-8"))
    assert {e["quantity"] for e in document["errors"]} >= set(EXTENDED_QUANTITIES)
    assert jsonschema is not None
    assert [e.message for e in validator("verification").iter_errors(document)] == []
