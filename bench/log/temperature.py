"""The IMU's temperature over a run, from the temperatures its frames carried (a result's `temperature` section).

A calibration result is placed in temperature by it (`bench.thermal`): the mean, min
and max of every decoded sample's temperature in the run's logs. An IMU layout without
a temperature signal records none (NaN), and then there is no section.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bench.log.reader import RunLog
from drivers.imu.layout import ImuLayout


def imu_temperature(logs: list[RunLog], layout: ImuLayout | None, rate_hz: float) -> dict[str, Any] | None:
    """{mean_c, min_c, max_c, samples, source} over the logs' decoded samples, None when none has a temperature."""
    temps = [samples.temperature_c for samples, _ in (log.imu_samples(layout, rate_hz) for log in logs)]
    values = np.concatenate(temps) if temps else np.zeros(0)
    values = values[np.isfinite(values)]
    if not len(values):
        return None
    return {"mean_c": float(values.mean()), "min_c": float(values.min()), "max_c": float(values.max()),
            "samples": int(len(values)), "source": "IMU frames"}


__all__ = ["imu_temperature"]
