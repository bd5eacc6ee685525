"""Verification of an extended-model calibration (issue 30 item 6): the verification compensates its dwells and
turns with the result's higher-order terms, as `bench apply` does. On verify-default acquired in memory from the
simulated IMU with the tactical-MEMS truth (noise off, ideal table), the true calibration with its extended
coefficients leaves no error; the same 30 coefficients without them leave the higher-order terms' errors."""

from __future__ import annotations

import pytest

from bench.calibration.compensation import compensation_of
from bench.model.higher_order import HigherOrderTerms, preset
from bench.model.result import CalibrationResult, coefficient_table
from bench.verify.errors import verify_extraction
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
    assert not with_terms.notes and len(with_terms.errors) == len(without.errors) == 3 + 3 + 6 + 3 + 3 * 3 * 3
    # |error| / U (U here is the calibration's 1e-6 sigmas): the extended compensation leaves its remainder; the 30
    # coefficients leave the accelerometers' second order and asymmetry as biases of up to 240 ug (their U grows
    # with the residual scatter). The gyros' terms leave no error these quantities show: the g-sensitivity averages
    # out over the positions, asymmetry and nonlinearity cancel between a CCW and a CW turn.
    ratio = {e.name: abs(e.value) / e.uncertainty for e in with_terms.errors}
    worst = max(ratio, key=ratio.__getitem__)
    assert ratio[worst] < 0.1, (worst, ratio[worst])
    assert max(abs(e.value) / e.uncertainty for e in without.of("acc_bias_ug")) > 10.0    # measured: 23
