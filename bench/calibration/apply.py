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
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from itertools import chain, repeat
from pathlib import Path

import numpy as np
import orjson

from bench import __version__
from bench.calibration.compensation import Compensation
from bench.log.bulk_messages import add_records
from bench.log.format import SCHEMAS, TOPIC_SAMPLES
from bench.log.json_records import JsonMessage, json_records
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


#: samples formatted at once (a few MB of text for the MCAP's two topics)
BLOCK_SAMPLES = 10_000
#: of those, the samples whose MCAP records are laid out at once (their texts stay in the CPU's cache)
RECORD_ROWS = 2_000
#: one CSV row: counter, time_s, imu_time_s, three rates, three forces (17 significant digits read back exactly);
#: the format of a block holding a value that is not finite (JSON text has none: `_texts` cannot print it)
_CSV_ROW = "%d," + ",".join(["%.17g"] * 8) + "\n"
Progress = Callable[[int, int], None]
#: the literal text of an `/imu/samples` body (the run log's) around its nine fields (`_columns`)
_RAW_TEXT = (b'{"counter":', b',"time_s":', b',"imu_time_s":', b',"gyro_counts":[', b'],"acc_counts":[',
             b'],"gyro_rate":[', b'],"acc_rate":[', b'],"temperature_c":', b',"status":', b"}")
#: the same for an `/imu/compensated` body's five fields (`_columns`), up to its units
_COMPENSATED_TEXT = (b'{"counter":', b',"time_s":', b',"imu_time_s":', b',"angular_rate":[', b'],"specific_force":[')


def _blocks(n: int, size: int | None = None) -> Iterator[tuple[int, int]]:
    size = size or BLOCK_SAMPLES
    for lo in range(0, n, size):
        yield lo, min(n, lo + size)


def _pieces(literals: Sequence[bytes], columns: Sequence[np.ndarray]) -> tuple[bytes | np.ndarray, ...]:
    """literals[0], columns[0], literals[1], ..., literals[-1]: a `JsonMessage`'s body."""
    pieces: list[bytes | np.ndarray] = []
    for literal, column in zip(literals, columns):
        pieces += [literal, column]
    return (*pieces, literals[-1])


def _texts(values: np.ndarray) -> list[bytes]:
    """Each row of `values` ((n,) or (n, k), int64 or float64) as JSON numbers joined by commas, printed by
    orjson in C: an integer's digits, a float's shortest text that reads back as the same float (as `repr`,
    written `1e-5` for `1e-05`), null for NaN and infinities."""
    text = orjson.dumps(np.ascontiguousarray(values), option=orjson.OPT_SERIALIZE_NUMPY)
    return text[1:-1].split(b",") if values.ndim == 1 else text[2:-2].split(b"],[")


def _rows(literals: Sequence[bytes], columns: Sequence[np.ndarray]) -> Iterator[tuple[bytes, ...]]:
    """Per row: literals[0], columns[0]'s text, literals[1], ..., literals[-1] (one more literal than columns)."""
    parts: list[Iterable[bytes]] = [repeat(literals[0])]
    for literal, column in zip(literals[1:], columns):
        parts += [_texts(column), repeat(literal)]
    return zip(*parts)


def write_csv(samples: CompensatedSamples, path: str | Path, progress: Progress | None = None) -> None:
    """The samples as CSV, a block of `BLOCK_SAMPLES` rows formatted at once; `progress(done, total)` after each."""
    rs, fs = _SUFFIX[samples.rate_unit], _SUFFIX[samples.force_unit]
    values = np.column_stack([samples.time_s, samples.imu_time_s, samples.angular_rate, samples.specific_force])
    with open(path, "wb") as f:
        f.write(",".join(["counter", "time_s", "imu_time_s", *(f"rate_{a}_{rs}" for a in "xyz"),
                          *(f"force_{a}_{fs}" for a in "xyz")]).encode() + b"\n")
        for lo, hi in _blocks(len(samples)):
            block = values[lo:hi]
            if np.isfinite(block).all():
                f.write(b"".join(chain.from_iterable(_rows((b"", b",", b"\n"), (samples.counter[lo:hi], block)))))
            else:
                rows = np.column_stack([samples.counter[lo:hi], block]).tolist()
                f.write("".join(map(_CSV_ROW.__mod__, map(tuple, rows))).encode())
            if progress is not None:
                progress(hi, len(samples))


def _columns(samples: CompensatedSamples, imu_time_s: np.ndarray, lo: int,
             hi: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The columns of samples lo..hi's `/imu/samples` and `/imu/compensated` bodies (`_RAW_TEXT`,
    `_COMPENSATED_TEXT`); the three both bodies hold (counter, time_s, imu_time_s) are the same arrays: printed
    once. `imu_time_s`: the samples', computed once (the property divides every counter each time)."""
    block, rate = samples.raw, float(samples.raw.rate_hz)
    gyro, acc = block.gyro_counts[lo:hi], block.acc_counts[lo:hi]
    times = [block.counter[lo:hi], block.receive_time_s[lo:hi], imu_time_s[lo:hi]]
    return ([*times, gyro, acc, gyro * rate, acc * rate, block.temperature_c[lo:hi], block.status[lo:hi]],
            [*times, samples.angular_rate[lo:hi], samples.specific_force[lo:hi]])


def write_mcap(samples: CompensatedSamples, path: str | Path, *, compensation: Compensation, source_log: str,
               progress: Progress | None = None) -> None:
    """A new MCAP file: raw samples on `/imu/samples`, compensated ones on `/imu/compensated`, each sample's two
    messages one after the other (the file in log-time order); the records of `RECORD_ROWS` samples laid out at
    once from their columns (`bench.log.json_records`: the bytes of a JSON document per message) and written into
    the chunks (`bench.log.bulk_messages`), `progress(done, total)` after each block of `BLOCK_SAMPLES`."""
    # local: the mcap writer is needed only for this output
    from mcap.writer import CompressionType, Writer

    units = f'"rate_unit":{json.dumps(samples.rate_unit)},"force_unit":{json.dumps(samples.force_unit)}}}'
    compensated_text = (*_COMPENSATED_TEXT, b"]," + units.encode())
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
        imu_time_s = samples.imu_time_s
        for lo, hi in _blocks(len(samples)):
            for a, b in _blocks(hi - lo, RECORD_ROWS):     # a few thousand rows: their texts stay in the cache
                raw_columns, compensated_columns = _columns(samples, imu_time_s, lo + a, lo + b)
                times = log_times_s[lo + a:lo + b]
                log_times_ns = np.where(times > 0.0, np.rint(times * 1e9), 0.0).astype(np.int64)
                # raw, compensated, raw, ...: two messages a sample at its log time
                records, sizes = json_records([JsonMessage(raw_channel, _pieces(_RAW_TEXT, raw_columns)),
                                               JsonMessage(comp_channel, _pieces(compensated_text,
                                                                                 compensated_columns))],
                                              log_times_ns)
                add_records(writer, np.tile([raw_channel, comp_channel], b - a), np.repeat(log_times_ns, 2),
                            sizes, records)
            if progress is not None:
                progress(hi, len(samples))
        writer.finish()


__all__ = ["BLOCK_SAMPLES", "COMPENSATED_SCHEMA", "TOPIC_COMPENSATED", "CompensatedSamples", "apply_to_log",
           "compensate_block", "log_samples", "write_csv", "write_mcap"]
