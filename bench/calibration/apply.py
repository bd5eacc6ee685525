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

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

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


#: samples formatted at once (one string of ~3 MB for the MCAP's raw topic)
BLOCK_SAMPLES = 10_000
#: one CSV row: counter, time_s, imu_time_s, three rates, three forces (17 significant digits read back exactly)
_CSV_ROW = "%d," + ",".join(["%.17g"] * 8) + "\n"
_VEC = "[%.17g,%.17g,%.17g]"
#: one `/imu/samples` body (the run log's), from the 17 columns of `_raw_columns`
_RAW_BODY = ('{"counter":%d,"time_s":%.17g,"imu_time_s":%.17g,"gyro_counts":' + _VEC + ',"acc_counts":' + _VEC
             + ',"gyro_rate":' + _VEC + ',"acc_rate":' + _VEC + ',"temperature_c":%.17g,"status":%d}')
#: one `/imu/compensated` body, from the 9 columns of `_compensated_columns`, up to its units
_COMPENSATED_BODY = ('{"counter":%d,"time_s":%.17g,"imu_time_s":%.17g,"angular_rate":' + _VEC
                     + ',"specific_force":' + _VEC)
Progress = Callable[[int, int], None]


def _blocks(n: int) -> Iterator[tuple[int, int]]:
    for lo in range(0, n, BLOCK_SAMPLES):
        yield lo, min(n, lo + BLOCK_SAMPLES)


def _formatted(template: str, columns: np.ndarray) -> str:
    """Every row of `columns` through `template`, one per line, in C (no Python call per row)."""
    return "\n".join(map(template.__mod__, map(tuple, columns.tolist())))


def write_csv(samples: CompensatedSamples, path: str | Path, progress: Progress | None = None) -> None:
    """The samples as CSV, a block of `BLOCK_SAMPLES` rows formatted at once; `progress(done, total)` after each."""
    rs, fs = _SUFFIX[samples.rate_unit], _SUFFIX[samples.force_unit]
    columns = np.column_stack([samples.counter, samples.time_s, samples.imu_time_s, samples.angular_rate,
                               samples.specific_force])
    with open(path, "w", encoding="utf-8", newline="") as f:
        f.write(",".join(["counter", "time_s", "imu_time_s", *(f"rate_{a}_{rs}" for a in "xyz"),
                          *(f"force_{a}_{fs}" for a in "xyz")]) + "\n")
        for lo, hi in _blocks(len(samples)):
            f.write("".join(map(_CSV_ROW.__mod__, map(tuple, columns[lo:hi].tolist()))))
            if progress is not None:
                progress(hi, len(samples))


def _num(x: float) -> str:
    return repr(x) if math.isfinite(x) else "null"


def _raw_columns(samples: CompensatedSamples) -> np.ndarray:
    block, rate = samples.raw, float(samples.raw.rate_hz)
    return np.column_stack([block.counter, block.receive_time_s, block.time_s, block.gyro_counts, block.acc_counts,
                            block.gyro_counts * rate, block.acc_counts * rate, block.temperature_c, block.status])


def _compensated_columns(samples: CompensatedSamples) -> np.ndarray:
    return np.column_stack([samples.counter, samples.time_s, samples.imu_time_s, samples.angular_rate,
                            samples.specific_force])


def _json_bodies(template: str, columns: np.ndarray, nullable: tuple[int, ...] = ()) -> list[bytes]:
    """JSON bodies of `columns` through `template`: non-finite values become null (JSON has no NaN); a block
    with one elsewhere than in the `nullable` columns is written value by value (`_num`)."""
    finite = np.isfinite(columns)
    if not finite[:, [k for k in range(columns.shape[1]) if k not in nullable]].all():
        whole = [kind == "%d" for kind in re.findall(r"%\.17g|%d", template)]
        parts = template.replace("%.17g", "%s").replace("%d", "%s")
        return [(parts % tuple(str(int(x)) if is_int else _num(x) for is_int, x in zip(whole, row))).encode()
                for row in columns.tolist()]
    text = _formatted(template, columns)
    if nullable and not finite[:, list(nullable)].all():
        text = text.replace(":nan,", ":null,").replace(":inf,", ":null,").replace(":-inf,", ":null,")
    return text.encode().split(b"\n")


def write_mcap(samples: CompensatedSamples, path: str | Path, *, compensation: Compensation, source_log: str,
               progress: Progress | None = None) -> None:
    """A new MCAP file: raw samples on `/imu/samples`, compensated ones on `/imu/compensated`; the bodies of a
    block of `BLOCK_SAMPLES` samples formatted at once, `progress(done, total)` after each block."""
    # local: the mcap writer is needed only for this output
    from mcap.writer import CompressionType, Writer

    units = f'"rate_unit":{json.dumps(samples.rate_unit)},"force_unit":{json.dumps(samples.force_unit)}'
    compensated_body = _COMPENSATED_BODY + "," + units.replace("%", "%%") + "}"
    raw_columns, compensated_columns = _raw_columns(samples), _compensated_columns(samples)
    log_times_s = samples.time_s
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
        add = writer.add_message
        for lo, hi in _blocks(len(samples)):
            times = log_times_s[lo:hi]
            log_times_ns = np.where(times > 0.0, np.rint(times * 1e9), 0.0).astype(np.int64).tolist()
            raw = _json_bodies(_RAW_BODY, raw_columns[lo:hi], nullable=(1, 15))      # time_s, temperature_c
            compensated = _json_bodies(compensated_body, compensated_columns[lo:hi], nullable=(1,))
            for ns, raw_body, compensated_body_bytes in zip(log_times_ns, raw, compensated):
                add(raw_channel, ns, raw_body, ns)
                add(comp_channel, ns, compensated_body_bytes, ns)
            if progress is not None:
                progress(hi, len(samples))
        writer.finish()


__all__ = ["BLOCK_SAMPLES", "COMPENSATED_SCHEMA", "TOPIC_COMPENSATED", "CompensatedSamples", "apply_to_log",
           "compensate_block", "log_samples", "write_csv", "write_mcap"]
