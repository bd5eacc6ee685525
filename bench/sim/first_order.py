"""The first-order recursion y[k] = phi * y[k-1] + gain * x[k], column by column, state carried.

The simulators' Gauss-Markov noise and a case temperature behind a linear ambient are this recursion.
`scipy.signal.lfilter([gain], [1, -phi], x, axis=0, zi=state)` computes it with the same operations in
the same order (its transposed direct form: y = state + gain*x, then state = phi*y), so the two agree
bit for bit (tests/unit/sim/test_first_order.py holds them equal). It is written out here because
importing scipy.signal costs about half a second of every simulated run's start (it imports
scipy.stats, scipy.optimize and scipy.interpolate), against a few hundredths for the loop.
"""

from __future__ import annotations

import numpy as np


def first_order_filter(gain: float, phi: float, x: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(y, state after): `x` (n,) or (n, m) runs down axis 0; `state` (m,) or (1, m), or one value for (n,),
    is phi times the output before x[0] (lfilter's `zi`); the state after has the same shape."""
    x = np.asarray(x, np.float64)
    state = np.asarray(state, np.float64)
    gained = gain * x
    columns = gained.reshape(len(x), int(np.prod(x.shape[1:])))
    start = state.reshape(-1).tolist()
    y = np.empty_like(columns)
    phi = float(phi)
    for c, carried in enumerate(start):
        out: list[float] = []
        append = out.append
        for value in columns[:, c].tolist():
            carried += value          # y[k] = state + gain * x[k]
            append(carried)
            carried = phi * carried   # the state for the next sample
        y[:, c] = out
    after = phi * y[-1] if len(y) else np.array(start)
    return y.reshape(gained.shape), after.reshape(state.shape)
