"""Apply a compensation to a run log's IMU samples (`bench apply`; the verification uses the same code).

The samples are decoded from the log's raw CAN frames (`/can/raw`, the source of truth)
with the DBC and signal mapping the log records, exactly as `bench solve` reads them
(`bench.log.reader.read_log`: bounded, a hostile file ends in one line). Each sample's
increments times the sample rate are the raw outputs in counts/s; `Compensation.compensate`
turns them into body rates and specific forces (mean over the sample interval).

Outputs:
- CSV: `counter,time_s,imu_time_s,rate_x,rate_y,rate_z,force_x,force_y,force_z` with the
  units in the header names (`rate_x_dps`, `force_x_g`, ...);
- MCAP: a **new** file (the input log is never modified) with the raw samples on
  `/imu/samples` (the run log's schema) and the compensated ones on `/imu/compensated`
  (`turntable_bench.CompensatedImuSample`), both at the samples' log times, so that
  Foxglove plots them side by side; metadata `compensation` names the calibration and the
  source log. The other topics stay in the run log (open both files in Foxglove).

Times follow the run log's convention everywhere: `time_s` is when the sample was complete on
the run clock (the log time of the run log's own `/imu/samples` message), `imu_time_s` is
counter / sample rate (the IMU's own time base).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench import __version__
from bench.calibration.compensation import Compensation
from bench.log.format import SCHEMAS, TOPIC_SAMPLES
from bench.log.reader import RunLog, read_log
from bench.log.run_info import layout_and_config_from_log
from drivers.imu import ImuSampleBlock

TOPIC_COMPENSATED = "/imu/compensated"
COMPENSATED_SCHEMA = "turntable_bench.CompensatedImuSample"
_VEC3 = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
COMPENSATED_SCHEMA_BODY = {
    "title": COMPENSATED_SCHEMA, "type": "object",
    "description": "One IMU sample compensated with a calibration: u_b = C (y - b) (bench.calibration)",
    "properties": {
        "counter": {"type": "integer", "description": "unwrapped sample counter"},
        "time_s": {"type": "number", "description": "when the sample was complete, on the run clock, s "
                                                    "(the message's log time)"},
        "imu_time_s": {"type": "number", "description": "counter / sample rate, s (the IMU's own time base)"},
        "angular_rate": {**_VEC3, "description": "body angular rate about X, Y, Z (unit in rate_unit)"},
        "specific_force": {**_VEC3, "description": "body specific force along X, Y, Z (unit in force_unit)"},
        "rate_unit": {"type": "string"},
        "force_unit": {"type": "string"},
    },
}
#: unit -> suffix of a CSV column name
_SUFFIX = {"rad/s": "rps", "deg/s": "dps", "m/s^2": "mps2", "g": "g"}


@dataclass
class CompensatedSamples:
    """A log's samples, raw (counts/s) and compensated (in `rate_unit`, `force_unit`)."""

    raw: ImuSampleBlock          # the decoded samples (increments in counts, counter, log times)
    angular_rate: np.ndarray     # (n, 3) rate_unit
    specific_force: np.ndarray   # (n, 3) force_unit
    rate_unit: str
    force_unit: str

    def __len__(self) -> int:
        return len(self.raw)

    @property
    def counter(self) -> np.ndarray:
        return self.raw.counter

    @property
    def time_s(self) -> np.ndarray:
        """Run clock of the frame that completed each sample, s (the run log's `time_s`)."""
        return self.raw.receive_time_s

    @property
    def imu_time_s(self) -> np.ndarray:
        """counter / rate: the IMU's own time base, s (the run log's `imu_time_s`)."""
        return self.raw.time_s


def compensate_block(compensation: Compensation, block: ImuSampleBlock, *, rate_unit: str = "rad/s",
                     force_unit: str = "m/s^2") -> CompensatedSamples:
    """Compensate decoded samples (the one code path of `bench apply` and the verification)."""
    rate, force = compensation.compensate(block.gyro_rate, block.acc_rate, rate_unit=rate_unit, force_unit=force_unit)
    return CompensatedSamples(block, rate, force, rate_unit, force_unit)


def log_samples(log: RunLog) -> ImuSampleBlock:
    """The IMU samples of a log, decoded from its raw frames with the log's own layout and rate
    (`LogError` when the log holds no way to decode them)."""
    setup = layout_and_config_from_log(log)
    block, _stats = log.imu_samples(setup.layout, setup.rate_hz)
    return block


def apply_to_log(compensation: Compensation, log_path: str, *, rate_unit: str = "rad/s",
                 force_unit: str = "m/s^2") -> tuple[CompensatedSamples, RunLog]:
    """Read a run log and compensate its samples (LogError: not a usable run log)."""
    log = read_log(log_path)
    return compensate_block(compensation, log_samples(log), rate_unit=rate_unit, force_unit=force_unit), log


def write_csv(samples: CompensatedSamples, path: str | Path) -> None:
    rs, fs = _SUFFIX[samples.rate_unit], _SUFFIX[samples.force_unit]
    with open(path, "w", encoding="utf-8", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(["counter", "time_s", "imu_time_s", *(f"rate_{a}_{rs}" for a in "xyz"),
                         *(f"force_{a}_{fs}" for a in "xyz")])
        for c, t, it, w, a in zip(samples.counter.tolist(), samples.time_s.tolist(), samples.imu_time_s.tolist(),
                                  samples.angular_rate.tolist(), samples.specific_force.tolist()):
            writer.writerow([c, repr(t), repr(it), *map(repr, w), *map(repr, a)])


def _ns(time_s: float) -> int:
    return int(round(time_s * 1e9)) if time_s > 0.0 else 0


def _num(x: float) -> str:
    return repr(x) if math.isfinite(x) else "null"


def write_mcap(samples: CompensatedSamples, path: str | Path, *, compensation: Compensation, source_log: str) -> None:
    """A new MCAP file: raw samples on `/imu/samples`, compensated ones on `/imu/compensated`."""
    # local: the mcap writer is needed only for this output
    from mcap.writer import CompressionType, Writer

    block, rate = samples.raw, float(samples.raw.rate_hz)
    with open(path, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile="", library=f"turntable-bench/{__version__}")
        raw_schema = writer.register_schema("turntable_bench.ImuSample", "jsonschema",
                                            json.dumps(SCHEMAS["turntable_bench.ImuSample"]).encode())
        comp_schema = writer.register_schema(COMPENSATED_SCHEMA, "jsonschema",
                                             json.dumps(COMPENSATED_SCHEMA_BODY).encode())
        raw_channel = writer.register_channel(TOPIC_SAMPLES, "json", raw_schema)
        comp_channel = writer.register_channel(TOPIC_COMPENSATED, "json", comp_schema)
        writer.add_metadata("compensation", {
            "source_log": Path(source_log).name, "calibration_run_id": compensation.run_id,
            "imu_model": compensation.imu_model, "imu_serial": compensation.imu_serial,
            "rate_unit": samples.rate_unit, "force_unit": samples.force_unit, "software_version": __version__})
        units = f'"rate_unit":{json.dumps(samples.rate_unit)},"force_unit":{json.dumps(samples.force_unit)}'
        for c, t, lt, g, a, temp, st, w, s in zip(
                block.counter.tolist(), block.time_s.tolist(), block.receive_time_s.tolist(),
                block.gyro_counts.tolist(), block.acc_counts.tolist(), block.temperature_c.tolist(),
                block.status.tolist(), samples.angular_rate.tolist(), samples.specific_force.tolist()):
            ns = _ns(lt)
            times = f'"time_s":{_num(lt)},"imu_time_s":{t!r}'
            raw = (f'{{"counter":{c},{times},"gyro_counts":[{",".join(map(_num, g))}],'
                   f'"acc_counts":[{",".join(map(_num, a))}],"gyro_rate":[{",".join(_num(x * rate) for x in g)}],'
                   f'"acc_rate":[{",".join(_num(x * rate) for x in a)}],"temperature_c":{_num(temp)},'
                   f'"status":{st}}}')
            comp = (f'{{"counter":{c},{times},"angular_rate":[{",".join(map(_num, w))}],'
                    f'"specific_force":[{",".join(map(_num, s))}],{units}}}')
            writer.add_message(raw_channel, ns, raw.encode(), ns)
            writer.add_message(comp_channel, ns, comp.encode(), ns)
        writer.finish()


__all__ = ["COMPENSATED_SCHEMA", "TOPIC_COMPENSATED", "CompensatedSamples", "apply_to_log", "compensate_block",
           "log_samples", "write_csv", "write_mcap"]
