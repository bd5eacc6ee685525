"""`[model] terms`: the extended model's families (issue 30), checked with file, line and key."""

from __future__ import annotations

import pytest

from tests.unit.config.test_config import BASE, error_of, parse


def test_absent_means_the_30_coefficients():
    assert parse(BASE).model_terms == ()


def test_families_and_auto_are_read():
    assert parse(BASE + '\n[model]\nterms = ["acc_second_order", "gyro_g_sensitivity"]\n').model_terms == (
        "acc_second_order", "gyro_g_sensitivity")
    assert parse(BASE + '\n[model]\nterms = ["auto"]\n').model_terms == ("auto",)


@pytest.mark.parametrize("value, words", [
    ('["gyro_wobble"]', "unknown family 'gyro_wobble'"),
    ('"auto"', "must be a list"),
    ('["auto", "acc_cross"]', "stands alone"),
    ('["acc_cross", "acc_cross"]', "listed twice"),
])
def test_a_bad_value_is_one_line_with_its_place(value, words):
    error = str(error_of(BASE + f"\n[model]\nterms = {value}\n"))
    assert "bench.toml" in error and "model.terms" in error and words in error and "\n" not in error


def test_an_unknown_key_is_refused():
    assert "model" in str(error_of(BASE + '\n[model]\nfamilies = ["acc_cross"]\n'))
