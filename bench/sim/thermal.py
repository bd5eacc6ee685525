"""The simulated IMU's case temperature: first order behind an ambient temperature.

dT/dt = (T_ambient(t) - T) / tau. Between two evaluation times the ambient is taken as
linear (first-order hold), for which the step is exact; a constant ambient is exact at
any step. The ambient is a number or a function of simulated time (a pure function
taking an array of increasing times in s and returning degC: a profile, later the
simulated chamber's air temperature), and can be replaced while running (`set_ambient`).
"""

from __future__ import annotations

import math
from typing import Callable, Union

import numpy as np

from bench.sim.first_order import first_order_filter

#: an ambient temperature: constant degC, or simulated time (s, an array) -> degC
Ambient = Union[float, Callable[[np.ndarray], np.ndarray]]


def profile(times_s, temperatures_c) -> Callable[[np.ndarray], np.ndarray]:
    """A piecewise-linear ambient through (time, temperature) points, constant beyond the ends."""
    t = np.asarray(times_s, dtype=float)
    y = np.asarray(temperatures_c, dtype=float)
    if t.ndim != 1 or t.shape != y.shape or len(t) < 1 or np.any(np.diff(t) <= 0):
        raise ValueError("a profile needs increasing times and as many temperatures")
    return lambda s: np.interp(np.asarray(s, dtype=float), t, y)


class CaseTemperature:
    """The case temperature of one IMU, advanced in increasing simulated time."""

    def __init__(self, time_constant_s: float, ambient: Ambient, initial_c: float | None = None,
                 start_time_s: float = 0.0):
        if not (math.isfinite(time_constant_s) and time_constant_s > 0):
            raise ValueError(f"time_constant_s must be positive, got {time_constant_s}")
        self.time_constant_s = float(time_constant_s)
        self.time_s = float(start_time_s)
        self._ambient: Ambient = ambient
        self.temperature_c = float(self.ambient_at(np.array([self.time_s]))[0] if initial_c is None else initial_c)
        # what the case went through: for a result's temperature section
        self.count, self.total, self.low, self.high = 0, 0.0, math.inf, -math.inf

    def set_ambient(self, ambient: Ambient) -> None:
        """A new ambient from now on (a setpoint change, a chamber attached)."""
        self._ambient = ambient

    def ambient_at(self, times_s: np.ndarray) -> np.ndarray:
        if callable(self._ambient):
            return np.broadcast_to(np.asarray(self._ambient(times_s), dtype=float), np.shape(times_s))
        return np.full(np.shape(times_s), float(self._ambient))

    def advance(self, times_s: np.ndarray) -> np.ndarray:
        """Case temperatures at `times_s` (increasing, after the current time); the state moves to the last."""
        times = np.asarray(times_s, dtype=float).reshape(-1)
        if len(times) == 0:
            return times.copy()
        ts = np.concatenate([[self.time_s], times])
        h = np.diff(ts)
        if np.any(h <= 0):
            raise ValueError("case temperature times must increase")
        if not callable(self._ambient):       # a constant ambient: the closed form, exact at any step
            u0 = float(self._ambient)
            out = u0 + (self.temperature_c - u0) * np.exp(-(times - self.time_s) / self.time_constant_s)
            return self._moved(times, out)
        u = self.ambient_at(ts)
        tau = self.time_constant_s
        e = np.exp(-h / tau)
        slope_tau = np.diff(u) / h * tau
        # exact step for a linear ambient: T1 = e T0 + (u1 - s tau) - e (u0 - s tau)
        g = (u[1:] - slope_tau) - e * (u[:-1] - slope_tau)
        if np.allclose(e, e[0], rtol=0, atol=1e-15):
            out, _ = first_order_filter(1.0, e[0], g, np.array([e[0] * self.temperature_c]))
        else:
            out, temp = np.empty_like(g), self.temperature_c
            for k in range(len(g)):
                temp = e[k] * temp + g[k]
                out[k] = temp
        return self._moved(times, out)

    def _moved(self, times: np.ndarray, out: np.ndarray) -> np.ndarray:
        self.time_s, self.temperature_c = float(times[-1]), float(out[-1])
        self.count += len(out)
        self.total += float(out.sum())
        self.low, self.high = min(self.low, float(out.min())), max(self.high, float(out.max()))
        return out

    def summary(self) -> dict[str, float] | None:
        """Mean, min and max of the temperatures advanced through so far (None before any)."""
        if not self.count:
            return None
        return {"mean_c": self.total / self.count, "min_c": self.low, "max_c": self.high, "samples": self.count}

    def reset_summary(self) -> None:
        self.count, self.total, self.low, self.high = 0, 0.0, math.inf, -math.inf


__all__ = ["Ambient", "CaseTemperature", "profile"]
