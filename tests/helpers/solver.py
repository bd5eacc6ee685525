"""Assertions shared by the solver tests (tests/unit/solve/test_solver.py, tests/unit/solve/test_acquire.py)."""

from __future__ import annotations

import pytest

from bench.model.families import canonical_names, family_of
from bench.model.imu import ImuCoefficients


def assert_recovered(values: dict, truth: ImuCoefficients):
    true_values = truth.to_canonical()
    for name in canonical_names():
        fam = family_of(name)
        got, want = values[name], true_values[name]
        if fam in ("Kg", "Ka"):
            assert got == pytest.approx(want, rel=1e-9), name
        elif fam in ("Eg", "Ea"):
            assert abs(got - want) < 1e-12, name
        elif fam == "D0":   # deg/h; 1e-12 rad/s absolute is 2e-7 deg/h
            assert abs(got - want) < 1e-12 / 4.84813681109536e-06, name
        else:               # K0 in g; 1e-12 m/s^2 absolute
            assert abs(got - want) < 1e-12 / 9.80665, name
