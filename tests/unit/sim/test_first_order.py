"""The simulators' first-order recursion is scipy.signal.lfilter's, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from bench.sim.first_order import first_order_filter


@pytest.mark.parametrize("n", [1, 2, 7, 400, 1000])
def test_columns_are_lfilters_bit_for_bit_and_the_state_carries(n):
    rng = np.random.default_rng(n)
    for _ in range(20):
        phi = float(np.exp(-rng.uniform(1e-4, 2.0)))
        gain = float(rng.uniform(0.01, 10.0) * np.sqrt(1.0 - phi * phi))
        state = rng.standard_normal((1, 3))
        x = rng.standard_normal((n, 3))
        expected, expected_state = lfilter([gain], [1.0, -phi], x, axis=0, zi=state)
        y, after = first_order_filter(gain, phi, x, state)
        assert y.tobytes() == expected.tobytes() and after.tobytes() == expected_state.tobytes()
        assert after.shape == (1, 3)
    # two calls in a row are one call
    x = rng.standard_normal((2 * n, 3))
    whole, _ = first_order_filter(0.5, 0.9, x, np.zeros((1, 3)))
    head, carried = first_order_filter(0.5, 0.9, x[:n], np.zeros((1, 3)))
    tail, _ = first_order_filter(0.5, 0.9, x[n:], carried)
    assert np.concatenate([head, tail]).tobytes() == whole.tobytes()


def test_one_column_as_the_case_temperature_filters_it():
    g = np.linspace(0.1, 0.3, 50)
    expected, expected_state = lfilter([1.0], [1.0, -0.97], g, zi=[0.97 * 25.0])
    y, after = first_order_filter(1.0, 0.97, g, np.array([0.97 * 25.0]))
    assert y.tobytes() == expected.tobytes() and after.tobytes() == expected_state.tobytes()


def test_no_samples_keep_the_state():
    y, after = first_order_filter(1.0, 0.5, np.zeros((0, 3)), np.ones((1, 3)))
    assert y.shape == (0, 3) and after.tolist() == [[1.0, 1.0, 1.0]]
