"""The run log's polled table states and recorded IMU samples as arrays (what `bench.log.reader.RunLog` gives
for `/table/state` and `/imu/samples`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class TableStates:
    """The polled table states, in log order."""

    time_s: np.ndarray      # (n,)
    angles_deg: np.ndarray  # (n, 3) outer, middle, inner
    rates_dps: np.ndarray   # (n, 3)
    status: np.ndarray      # (n, 3) int64 AxisStatus bits
    estop: np.ndarray       # (n,) bool
    modes: list             # n tuples of 3 mode strings
    fault_text: list        # n strings

    def __len__(self) -> int:
        return len(self.time_s)

    @classmethod
    def concatenate(cls, parts: list["TableStates"]) -> "TableStates":
        if len(parts) == 1:
            return parts[0]
        return cls(np.concatenate([p.time_s for p in parts]), np.concatenate([p.angles_deg for p in parts]),
                   np.concatenate([p.rates_dps for p in parts]), np.concatenate([p.status for p in parts]),
                   np.concatenate([p.estop for p in parts]), [m for p in parts for m in p.modes],
                   [t for p in parts for t in p.fault_text])

    @classmethod
    def from_dicts(cls, rows: list[dict]) -> "TableStates":
        n = len(rows)

        def vec(key, dtype=float):
            try:   # numpy reads None as NaN for floats; anything else odd takes the explicit route
                return np.array([r[key] for r in rows], dtype).reshape(n, 3)
            except (TypeError, ValueError):
                return np.array([[np.nan if v is None else v for v in r[key]] for r in rows], dtype).reshape(n, 3)

        try:
            time_s = np.array([r["time_s"] for r in rows], float).reshape(n)
        except (TypeError, ValueError):
            time_s = np.array([np.nan if r["time_s"] is None else r["time_s"] for r in rows], float).reshape(n)
        return cls(time_s,
                   vec("angles_deg"), vec("rates_dps"), vec("status", np.int64),
                   np.array([bool(r.get("estop")) for r in rows], bool).reshape(n),
                   [tuple(r["modes"]) for r in rows], [str(r.get("fault_text", "")) for r in rows])


@dataclass
class ImuRecords:
    """The decoded samples as recorded on `/imu/samples` (possibly decimated), in log order.

    Derived data for viewing: the solver decodes the raw frames instead
    (`RunLog.imu_samples`, a `drivers.imu.ImuSampleBlock`); see `bench.sim.imu.ImuSamples`
    for how the three sample arrays differ.
    """

    counter: np.ndarray         # (n,) int64
    imu_time_s: np.ndarray      # (n,) counter / rate: the IMU's own time base
    receive_time_s: np.ndarray  # (n,) the message log times: when each sample was complete, on the run clock
    gyro_counts: np.ndarray     # (n, 3)
    acc_counts: np.ndarray      # (n, 3)
    temperature_c: np.ndarray   # (n,) NaN where not recorded
    status: np.ndarray          # (n,) int64

    def __len__(self) -> int:
        return len(self.counter)


def imu_records_from_rows(rows: list[dict], times: np.ndarray) -> ImuRecords:
    """`/imu/samples` rows as arrays (KeyError/TypeError/ValueError when a row lacks a field or has a wrong one)."""
    n = len(rows)
    records = ImuRecords(np.array([r["counter"] for r in rows], np.int64),
                         # logs before 2026-11-24 hold counter / rate in "time_s" and no "imu_time_s"
                         np.array([r.get("imu_time_s", r["time_s"]) for r in rows], float), times,
                         np.array([r["gyro_counts"] for r in rows], float).reshape(n, 3),
                         np.array([r["acc_counts"] for r in rows], float).reshape(n, 3),
                         np.array([np.nan if r["temperature_c"] is None else r["temperature_c"] for r in rows],
                                  float),
                         np.array([r["status"] for r in rows], np.int64))
    if any(a.shape != (n,) for a in (records.counter, records.imu_time_s, records.temperature_c, records.status)):
        raise ValueError("a scalar field holds an array")
    return records
