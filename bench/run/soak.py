"""The soak decision: is the IMU at the chamber's temperature yet? Decided on the IMU's own temperature.

`SoakTracker` takes the IMU's temperatures as they arrive (the decoded samples'
`temperature_c`, one mean per drained block) and the chamber's readings, and says when a
`SoakStep` is done: the chamber air within `chamber_tolerance_c` of the setpoint, then
the IMU's temperature rate (the least-squares slope over the last `rate_window_s`) below
`rate_c_per_min` without a break for `stable_s`. The chamber reaching its setpoint only
starts the watch: an IMU that lags the air (its case and mount) keeps the soak going
until it has settled itself. Pure computation on the sequencer's clock times; the
sequencer turns its decisions into events (`bench.log.events.SoakStatus` is what it says at each check).
"""

from __future__ import annotations

import collections

import numpy as np

from bench.log.events import SoakStatus
from bench.plan.steps import SoakStep


class SoakTracker:
    """The soak of one `SoakStep` from `start_s` (the rate over the step's `rate_window_s`)."""

    def __init__(self, step: SoakStep, start_s: float):
        self.step, self.start_s, self.rate_window_s = step, float(start_s), float(step.rate_window_s)
        self._points: collections.deque[tuple[float, float]] = collections.deque()
        self._chamber_c: float | None = None
        self._at_setpoint = False
        self._steady_since: float | None = None
        self._last_decision = ""

    def add_imu(self, time_s: float, temperature_c: float) -> None:
        """One IMU temperature (a block's mean) at `time_s`."""
        self._points.append((float(time_s), float(temperature_c)))
        while self._points and self._points[0][0] < time_s - self.rate_window_s:
            self._points.popleft()

    def add_chamber(self, temperature_c: float) -> None:
        self._chamber_c = float(temperature_c)

    def rate_c_per_min(self, now_s: float) -> float | None:
        """The IMU's temperature slope over the window, degC/min; None until the window is (nearly) covered."""
        if len(self._points) < 3 or self._points[0][0] > now_s - 0.9 * self.rate_window_s:
            return None
        t = np.array([p[0] for p in self._points])
        y = np.array([p[1] for p in self._points])
        t = t - t.mean()
        return float((t * (y - y.mean())).sum() / (t * t).sum() * 60.0)

    def status(self, now_s: float) -> SoakStatus:
        """Where the soak stands now; `decision` is set when something changed since the last call."""
        step = self.step
        rate = self.rate_c_per_min(now_s)
        if self._chamber_c is not None and abs(self._chamber_c - step.setpoint_c) <= step.chamber_tolerance_c:
            self._at_setpoint = True       # once reached, the watch on the IMU has started
        steady = self._at_setpoint and rate is not None and abs(rate) < step.rate_c_per_min
        if steady and self._steady_since is None:
            self._steady_since = now_s
        elif not steady:
            self._steady_since = None
        steady_for = now_s - self._steady_since if self._steady_since is not None else 0.0
        done = self._steady_since is not None and steady_for >= step.stable_s - 1e-9
        decision = ("done" if done else "imu_steady" if steady else "imu_settling" if self._at_setpoint
                    else "chamber_approaching")
        changed = decision if decision != self._last_decision else ""
        self._last_decision = decision
        imu = self._points[-1][1] if self._points else None
        return SoakStatus(now_s, imu, rate, self._chamber_c, self._at_setpoint, steady_for, done, changed)

    def timed_out(self, now_s: float) -> bool:
        return now_s - self.start_s > self.step.max_soak_s


#: the soak's decisions, as the events' `data["soak"]` say them
SOAK_DECISIONS = {
    "chamber_approaching": "chamber air not yet at the setpoint",
    "imu_settling": "chamber air at the setpoint; waiting for the IMU's temperature to settle",
    "imu_steady": "IMU temperature steady; counting the stable time",
    "done": "IMU soaked",
}

__all__ = ["SOAK_DECISIONS", "SoakTracker"]
