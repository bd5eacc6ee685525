"""The run log's format, owned in one place: topics, schemas, and the raw CAN record.

The recorder (`bench.log.recorder`) writes it, the reader (`bench.log.reader`) and
replay read it. The raw CAN frames on `/can/raw` use a compact binary encoding,
`turntable-bench/can-frames-v1` (described in `CAN_SCHEMA_TEXT`, which is also the
schema record in every log, with that same name as its schema encoding); `encode_can_frames`
and `decode_can_frames` are its two directions, side by side.
"""

from __future__ import annotations

import math
import struct
from array import array
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Sequence

import numpy as np

from bench.log.mcap import ChannelData
from bench.log.threads import reader_threads
from drivers.imu.frames import FLAG_BRS, FLAG_ERROR, FLAG_ESI, FLAG_FD, FLAG_REMOTE, CanFrameBatch

CAN_ENCODING = "turntable-bench/can-frames-v1"
EXTENDED_ID_FLAG = 1 << 31
#: One raw CAN record header: timestamp_s, id (bit 31 = extended), flags, data length; the data follow.
CAN_RECORD = struct.Struct("<dIBB")
HEADER_SIZE = CAN_RECORD.size           # 14 bytes
_T_END, _ID_END = 8, 12                 # end of the timestamp and of the id in the header
FLAGS_OFFSET, LENGTH_OFFSET = 12, 13    # where the flags and the data length byte sit
#: Data width of `RunLog.read_can_frames().data` when every frame fits a classic frame; CAN FD logs get 64.
CLASSIC_WIDTH, FD_WIDTH = 8, 64
#: The most data bytes a frame has (CAN FD): a record claiming more makes its message malformed.
MAX_DATA = FD_WIDTH


def record_dtype(data_field: tuple) -> np.dtype:
    """numpy dtype of one raw CAN record whose data is `data_field` (e.g. `("data", "u1", (8,))`)."""
    return np.dtype([("t", "<f8"), ("id", "<u4"), ("flags", "u1"), ("len", "u1"), data_field])


TOPIC_STATE, TOPIC_SAMPLES, TOPIC_EVENTS, TOPIC_LOG, TOPIC_TF, TOPIC_CAN = (
    "/table/state", "/imu/samples", "/events", "/log", "/tf", "/can/raw")
TF_FRAMES = ("world", "outer", "middle", "inner")
LOG_INFO, LOG_WARNING, LOG_ERROR = 2, 3, 4

_TIME = {"type": "object", "title": "time",
         "properties": {"sec": {"type": "integer", "minimum": 0},
                        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}}
_VEC3 = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}

SCHEMAS: dict[str, dict[str, Any]] = {
    "turntable_bench.TableState": {
        "title": "turntable_bench.TableState", "description": "One read of the whole table (outer, middle, inner)",
        "type": "object",
        "properties": {
            "time_s": {"type": "number", "description": "reading time on the run clock, s"},
            "angles_deg": {**_VEC3, "description": "frame angles, deg (paper convention)"},
            "rates_dps": {**_VEC3, "description": "frame rates d(angle)/dt, deg/s"},
            "modes": {"type": "array", "items": {"type": "string", "enum": ["off", "position", "rate"]}},
            "status": {"type": "array", "items": {"type": "integer"},
                       "description": "AxisStatus bits: 1 enabled, 2 moving, 4 in position, 8 fault, 16 e-stop, "
                                      "32 limit"},
            "estop": {"type": "boolean"},
            "fault_text": {"type": "string"},
        },
    },
    "turntable_bench.ImuSample": {
        "title": "turntable_bench.ImuSample", "description": "One decoded IMU sample", "type": "object",
        "properties": {
            "counter": {"type": "integer", "description": "unwrapped sample counter"},
            "time_s": {"type": "number", "description": "when the sample was complete, on the run clock, s "
                                                        "(the message's log time)"},
            "imu_time_s": {"type": "number", "description": "counter / sample rate, s (the IMU's own time base)"},
            "gyro_counts": {**_VEC3, "description": "gyro increments this sample, output counts"},
            "acc_counts": {**_VEC3, "description": "accelerometer increments this sample, output counts"},
            "gyro_rate": {**_VEC3, "description": "gyro outputs as rates, counts/s"},
            "acc_rate": {**_VEC3, "description": "accelerometer outputs as rates, counts/s"},
            "temperature_c": {"type": ["number", "null"]},
            "status": {"type": "integer"},
        },
    },
    "turntable_bench.Event": {
        "title": "turntable_bench.Event", "description": "A sequencer event", "type": "object",
        "properties": {
            "time_s": {"type": "number"}, "kind": {"type": "string"}, "message": {"type": "string"},
            "state": {"type": ["string", "null"]}, "step_index": {"type": ["integer", "null"]},
            "step_unit": {"type": ["string", "null"]}, "data": {"type": "object"},
        },
    },
    "foxglove.Log": {
        "title": "foxglove.Log", "description": "A log message", "type": "object",
        "properties": {
            "timestamp": {**_TIME, "description": "Timestamp of log message"},
            "level": {"title": "foxglove.LogLevel", "description": "Log level",
                      "oneOf": [{"title": name, "const": k} for k, name in
                                enumerate(("UNKNOWN", "DEBUG", "INFO", "WARNING", "ERROR", "FATAL"))]},
            "message": {"type": "string", "description": "Log message"},
            "name": {"type": "string", "description": "Process or node name"},
            "file": {"type": "string", "description": "Filename"},
            "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"},
        },
    },
    "foxglove.FrameTransform": {
        "title": "foxglove.FrameTransform", "description": "A transform between two reference frames in 3D space",
        "type": "object",
        "properties": {
            "timestamp": {**_TIME, "description": "Timestamp of transform"},
            "parent_frame_id": {"type": "string", "description": "Name of the parent frame"},
            "child_frame_id": {"type": "string", "description": "Name of the child frame"},
            "translation": {"title": "foxglove.Vector3", "description": "Translation component of the transform",
                            "type": "object",
                            "properties": {k: {"type": "number", "description": f"{k} coordinate length"}
                                           for k in "xyz"}},
            "rotation": {"title": "foxglove.Quaternion", "description": "Rotation component of the transform",
                         "type": "object",
                         "properties": {k: {"type": "number", "description": f"{k} value"} for k in "xyzw"}},
        },
    },
}

#: a run with a thermal chamber has one more channel (the others' logs stay as they were)
TOPIC_CHAMBER = "/chamber/state"
CHAMBER_SCHEMA_NAME = "turntable_bench.ChamberState"
CHAMBER_SCHEMA: dict[str, Any] = {
    "title": CHAMBER_SCHEMA_NAME, "description": "One read of the thermal chamber's controller", "type": "object",
    "properties": {
        "time_s": {"type": "number", "description": "reading time on the run clock, s"},
        "temperature_c": {"type": "number", "description": "chamber air temperature (process value), degC"},
        "setpoint_c": {"type": "number", "description": "the controller's setpoint, degC"},
        "ramp_c_per_min": {"type": ["number", "null"], "description": "ramp rate, degC/min (0 steps; null: the "
                                                                      "dialect has none)"},
        "running": {"type": "boolean", "description": "temperature control on"},
        "alarms": {"type": "integer", "description": "alarm bits: 1 over-temperature, 2 under-temperature, "
                                                     "4 door open, 8 sensor fault, 16 equipment fault"},
        "alarm_text": {"type": "string"},
    },
}
CHAMBER_CHANNELS: dict[str, tuple[str, str, str]] = {TOPIC_CHAMBER: (CHAMBER_SCHEMA_NAME, "jsonschema", "json")}

CAN_SCHEMA_NAME = "turntable_bench.CanFrames"
CAN_SCHEMA_TEXT = """turntable-bench/can-frames-v1: raw CAN frames, lossless, little-endian binary.
A message is a batch of frames: records concatenated with no padding, each
  float64   timestamp_s   the frame's receive time on the run clock, s
  uint32    id            arbitration id; bit 31 set = extended (29-bit) id
  uint8     flags         bit0 CAN FD, bit1 bitrate switch, bit2 error state indicator,
                          bit3 remote frame, bit4 error frame
  uint8     length        number of data bytes that follow (0..64)
  length x uint8          data
The message log time is the newest timestamp of its batch.
"""

#: topic -> schema name, schema encoding, message encoding
CHANNELS: dict[str, tuple[str, str, str]] = {
    TOPIC_STATE: ("turntable_bench.TableState", "jsonschema", "json"),
    TOPIC_SAMPLES: ("turntable_bench.ImuSample", "jsonschema", "json"),
    TOPIC_EVENTS: ("turntable_bench.Event", "jsonschema", "json"),
    TOPIC_LOG: ("foxglove.Log", "jsonschema", "json"),
    TOPIC_TF: ("foxglove.FrameTransform", "jsonschema", "json"),
    TOPIC_CAN: (CAN_SCHEMA_NAME, CAN_ENCODING, CAN_ENCODING),
}


def unit_topics(serial: str) -> tuple[str, str]:
    """The raw CAN frames' and the decoded samples' topics of a unit of a run of several IMUs, other than the
    reference unit (whose are `/can/raw` and `/imu/samples`, as a single IMU's): `/imu/<serial>/can/raw`,
    `/imu/<serial>/samples`."""
    return f"/imu/{serial}/can/raw", f"/imu/{serial}/samples"


def unit_channels(serials: Sequence[str]) -> dict[str, tuple[str, str, str]]:
    """The channels of the units `serials` (`unit_topics`), in the encodings of `/can/raw` and `/imu/samples`."""
    out: dict[str, tuple[str, str, str]] = {}
    for serial in serials:
        can_topic, samples_topic = unit_topics(serial)
        out[can_topic], out[samples_topic] = CHANNELS[TOPIC_CAN], CHANNELS[TOPIC_SAMPLES]
    return out


def encode_can_frames(frames: Sequence) -> tuple[bytes, float]:
    """python-can `Message`s -> (`can-frames-v1` bytes, newest timestamp)."""
    pack = CAN_RECORD.pack
    parts: list = []
    append = parts.append
    newest = -math.inf
    for m in frames:
        data = m.data if m.data is not None else b""
        t = m.timestamp
        if t > newest:
            newest = t
        flags = 0
        if m.is_fd or m.is_remote_frame or m.is_error_frame or m.error_state_indicator:
            flags = ((FLAG_FD if m.is_fd else 0) | (FLAG_BRS if m.bitrate_switch else 0)
                     | (FLAG_ESI if m.error_state_indicator else 0) | (FLAG_REMOTE if m.is_remote_frame else 0)
                     | (FLAG_ERROR if m.is_error_frame else 0))
        append(pack(t, m.arbitration_id | EXTENDED_ID_FLAG if m.is_extended_id else m.arbitration_id, flags,
                    len(data)))
        append(data)
    return b"".join(parts), newest


def encode_can_batch(batch: CanFrameBatch) -> tuple[bytes, float]:
    """A `CanFrameBatch` -> (`can-frames-v1` bytes, newest timestamp): the bytes `encode_can_frames` gives for
    the same frames, laid out with array operations (a run's every poll: no Python step per frame)."""
    n, width = batch.data.shape
    ids, lengths = batch.ids, batch.lengths
    if n and (int(ids.min()) < 0 or int(ids.max()) >= 1 << 32 or int(lengths.max()) > 255
              or int(lengths.min()) < 0):
        raise struct.error("a CAN id or data length out of range for the raw CAN record")
    records = np.empty(n, record_dtype(("data", "u1", (width,))))
    records["t"], records["id"], records["flags"] = batch.timestamps, ids, batch.flags
    records["len"], records["data"] = lengths, batch.data
    rows = records.view(np.uint8).reshape(n, HEADER_SIZE + width)
    if n and int(lengths.min()) == width:
        return rows.tobytes(), batch.newest_s()
    # each record is its header and its own length of data: the rows' leading bytes, concatenated
    keep = np.arange(HEADER_SIZE + width) < (HEADER_SIZE + lengths)[:, None]
    return rows[keep].tobytes(), batch.newest_s()


def json_number(x: float) -> str:
    """A float as a JSON number (null for NaN/inf, which JSON cannot carry)."""
    x = float(x)
    return repr(x) if math.isfinite(x) else "null"


#: receive times below this (s) make log times that fit int64 (ns): converted as arrays
_ARRAY_TIME_LIMIT_S = 9.0e9


#: below this magnitude a whole float's `repr` is its integer's digits and ".0" (from 1e16 on it is 1e+16)
_WHOLE_REPR_LIMIT = 1.0e15


def _whole_numbers(values: np.ndarray) -> bool:
    """True when every value is a whole number below `_WHOLE_REPR_LIMIT` and none is -0.0 (whose repr keeps
    its sign): then `repr(x) == f"{int(x)}.0"` for each."""
    if not values.size:
        return False
    with np.errstate(invalid="ignore"):
        small = np.abs(values) < _WHOLE_REPR_LIMIT      # (False for NaN and inf)
    if not small.all() or not (np.floor(values) == values).all():
        return False
    return not (np.signbit(values) & (values == 0.0)).any()


def imu_sample_messages(block, decimation: int = 1) -> list[tuple[int, bytes]]:
    """The `/imu/samples` messages of an `ImuSampleBlock`: (log time ns, JSON body) of every `decimation`-th
    counter. The arithmetic (scaling, the log time) is done on whole columns, each value printed by `repr`
    (the shortest text that reads back as the same float); a non-finite value is null."""
    counter = block.counter
    keep = None
    if decimation > 1:
        keep = counter % decimation == 0
        if not keep.any():
            return []

    def col(a: np.ndarray) -> np.ndarray:
        return a if keep is None else a[keep]

    rate = float(block.rate_hz)
    counters, recv = col(counter), col(np.asarray(block.receive_time_s, np.float64))
    gyro, acc = col(block.gyro_counts), col(block.acc_counts)
    imu_times = (counters.astype(np.float64) / rate).tolist()
    if np.isfinite(recv).all() and (recv < _ARRAY_TIME_LIMIT_S).all():
        times = np.where(recv > 0.0, recv * 1e9 + 0.5, 0.0).astype(np.int64).tolist()
        recv_text = list(map(repr, recv.tolist()))
    else:
        times = [int(r * 1e9 + 0.5) if r > 0.0 else 0 for r in recv.tolist()]
        recv_text = [json_number(r) for r in recv.tolist()]
    temperature = col(np.asarray(block.temperature_c, np.float64))
    temps = (list(map(repr, temperature.tolist())) if np.isfinite(temperature).all()
             else [json_number(x) for x in temperature.tolist()])
    values = np.concatenate([gyro, acc, gyro * rate, acc * rate], axis=1)
    if _whole_numbers(values):
        # counts (and their rates at a whole rate) are whole numbers: printed as integers plus ".0", which is
        # their `repr`, at a fraction of its cost
        bodies = [f'{{"counter":{c},"time_s":{r},"imu_time_s":{it!r},"gyro_counts":[{g0}.0,{g1}.0,{g2}.0],'
                  f'"acc_counts":[{a0}.0,{a1}.0,{a2}.0],"gyro_rate":[{gr0}.0,{gr1}.0,{gr2}.0],'
                  f'"acc_rate":[{ar0}.0,{ar1}.0,{ar2}.0],"temperature_c":{temp},"status":{st}}}'
                  for c, r, it, (g0, g1, g2, a0, a1, a2, gr0, gr1, gr2, ar0, ar1, ar2), temp, st
                  in zip(counters.tolist(), recv_text, imu_times, values.astype(np.int64).tolist(), temps,
                         col(block.status).tolist())]
    elif np.isfinite(values).all():
        rows = values.tolist()
        bodies = [f'{{"counter":{c},"time_s":{r},"imu_time_s":{it!r},"gyro_counts":[{g0!r},{g1!r},{g2!r}],'
                  f'"acc_counts":[{a0!r},{a1!r},{a2!r}],"gyro_rate":[{gr0!r},{gr1!r},{gr2!r}],'
                  f'"acc_rate":[{ar0!r},{ar1!r},{ar2!r}],"temperature_c":{temp},"status":{st}}}'
                  for c, r, it, (g0, g1, g2, a0, a1, a2, gr0, gr1, gr2, ar0, ar1, ar2), temp, st
                  in zip(counters.tolist(), recv_text, imu_times, rows, temps, col(block.status).tolist())]
    else:
        bodies = [f'{{"counter":{c},"time_s":{r},"imu_time_s":{it!r},'
                  f'"gyro_counts":[{",".join(map(json_number, row[0:3]))}],'
                  f'"acc_counts":[{",".join(map(json_number, row[3:6]))}],'
                  f'"gyro_rate":[{",".join(map(json_number, row[6:9]))}],'
                  f'"acc_rate":[{",".join(map(json_number, row[9:12]))}],'
                  f'"temperature_c":{temp},"status":{st}}}'
                  for c, r, it, row, temp, st
                  in zip(counters.tolist(), recv_text, imu_times, values.tolist(), temps, col(block.status).tolist())]
    return [(t, body.encode()) for t, body in zip(times, bodies)]


def _empty_can(width: int = CLASSIC_WIDTH):
    return (np.zeros(0), np.zeros(0, np.uint32), np.zeros((0, width), np.uint8), np.zeros(0, np.int64),
            np.zeros(0, np.uint8))


def _uniform_can_parts(d: ChannelData, release: bool = False):
    """The frames part by part (one chunk's messages each, still in cache) into the output arrays, on
    worker threads (numpy copies release the GIL), when the first record's length holds for whole parts;
    a part that is not whole records of that length takes the general route on its own, and the pieces
    are put together in order. `release`: drop each part once its frames are copied (the chunk it points
    into is freed as the arrays fill: what `read_log` holds at its peak is about the larger of the two,
    not their sum). ((timestamps, ids, data, lengths, flags), malformed messages), or None when not even
    the first record is readable."""
    sizes = [int(x.sum()) for x in d.lengths]
    first = next((k for k, size in enumerate(sizes) if size), None)
    if first is None or sizes[first] < HEADER_SIZE:
        return None
    length = d.first_byte(first, LENGTH_OFFSET)
    if length > MAX_DATA:
        return None
    rec = HEADER_SIZE + length
    whole = [size // rec if size % rec == 0 else 0 for size in sizes]
    n = sum(whole)
    width = CLASSIC_WIDTH if length <= CLASSIC_WIDTH else FD_WIDTH
    # 8 data bytes move as one uint64 per frame (classic frames: the common case)
    words = length == 8 == width
    dt = record_dtype(("data", "<u8") if words else ("data", "u1", (length,)))
    t, ids, flags = np.empty(n), np.empty(n, np.uint32), np.empty(n, np.uint8)
    data = (np.empty if length == width else np.zeros)((n, width), np.uint8)
    data_out = data.view("<u8").reshape(n) if words else data
    starts = np.concatenate(([0], np.cumsum(whole))).tolist()
    general: list[int] = []   # parts for the general route (list.append is atomic: the workers share it)

    def fill(parts: range) -> None:
        for k in parts:
            if not sizes[k]:
                continue
            if not whole[k]:
                general.append(k)
                continue
            arr = np.frombuffer(d.part_bytes(k), dt)
            if not (arr["len"] == length).all():
                general.append(k)
                continue
            a, b = starts[k], starts[k + 1]
            t[a:b] = arr["t"]
            ids[a:b] = arr["id"]
            if words:
                data_out[a:b] = arr["data"]
            else:
                data_out[a:b, :length] = arr["data"]
            flags[a:b] = arr["flags"]
            if release:
                d.release(k)

    workers = min(len(sizes) // 4, reader_threads())
    if workers > 1:
        step = -(-len(sizes) // workers)
        with ThreadPoolExecutor(workers, thread_name_prefix="can-frames") as pool:
            list(pool.map(fill, [range(a, min(a + step, len(sizes))) for a in range(0, len(sizes), step)]))
    else:
        fill(range(len(sizes)))
    if not general:
        return (t, ids, data, np.full(n, length, np.int64), flags), 0
    # some parts differ (mixed frame lengths, or malformed): the pieces in order, those parts decoded alone
    # (and dropped as they are, with `release`), then put together a field at a time (each field's pieces
    # are let go as it is done: what is held at once is the pieces and one field, not two copies of all)
    pieces, bad, other = [], 0, set(general)
    for k in range(len(sizes)):
        if k in other:
            piece, b = _general_can(d.part_payloads(k))
            pieces.append(list(piece))
            bad += b
            if release:
                d.release(k)
        elif sizes[k]:
            a, b = starts[k], starts[k + 1]
            pieces.append([t[a:b], ids[a:b], data[a:b], np.full(b - a, length, np.int64), flags[a:b]])
    top = max(p[2].shape[1] for p in pieces)
    fields = []
    for f in range(5):
        column = [p[f] if f != 2 or p[f].shape[1] == top else np.pad(p[f], ((0, 0), (0, top - p[f].shape[1])))
                  for p in pieces]
        fields.append(np.concatenate(column))
        del column
        for p in pieces:
            p[f] = None
    return tuple(fields), bad


def _frame_offsets(p: bytes, base: int, offsets: array) -> bool:
    """Append the record offsets within one `/can/raw` message (plus `base`) to `offsets`; False (nothing
    appended) if its framing is broken or a record claims more than `MAX_DATA` data bytes."""
    pos, n, mark = 0, len(p), len(offsets)
    while pos < n:
        if pos + HEADER_SIZE > n or p[pos + LENGTH_OFFSET] > MAX_DATA:
            del offsets[mark:]
            return False
        offsets.append(base + pos)
        pos += HEADER_SIZE + p[pos + LENGTH_OFFSET]
    if pos != n:
        del offsets[mark:]
        return False
    return True


def _general_can(payloads: list[bytes]) -> tuple[tuple, int]:
    """Frames of mixed lengths, message by message; malformed messages are dropped and counted."""
    good: list[bytes] = []
    offsets = array("q")
    base, bad = 0, 0
    for p in payloads:
        if not _frame_offsets(p, base, offsets):
            bad += 1
            continue
        good.append(p)
        base += len(p)
    if not offsets:
        return _empty_can(), bad
    joined = b"".join(good)
    buf = np.frombuffer(joined, np.uint8)
    offs = np.frombuffer(offsets, np.int64)
    # header fields read in place through unaligned views at every byte offset (no per-frame index arrays)
    t = np.ndarray((len(joined) - 7,), "<f8", joined, 0, (1,))[offs]
    ids = np.ndarray((len(joined) - 3 - _T_END,), "<u4", joined, _T_END, (1,))[offs]
    flags = buf[offs + FLAGS_OFFSET]
    lengths = buf[offs + LENGTH_OFFSET].astype(np.int64)
    width = CLASSIC_WIDTH if lengths.max() <= CLASSIC_WIDTH else FD_WIDTH
    data = np.zeros((len(offs), width), np.uint8)
    last = len(buf) - 1
    for c in range(width):   # column by column: memory of one column at a time
        has = lengths > c
        data[has, c] = buf[np.minimum(offs[has] + HEADER_SIZE + c, last)]
    return (t, ids, data, lengths, flags), bad


def decode_can_frames(d: ChannelData | None, *, release: bool = False) -> tuple[tuple, int]:
    """`/can/raw` messages -> ((timestamps, ids, data, lengths, flags), malformed messages dropped).
    `release`: `d` is not needed afterwards, its parts are dropped as they are decoded."""
    if d is None or not len(d):
        return _empty_can(), 0
    done = _uniform_can_parts(d, release)
    return done if done is not None else _general_can(d.payloads())


__all__ = ["unit_channels", "unit_topics",
           "CAN_ENCODING", "CAN_RECORD", "CAN_SCHEMA_NAME", "CAN_SCHEMA_TEXT", "CHAMBER_CHANNELS",
           "CHAMBER_SCHEMA", "CHAMBER_SCHEMA_NAME", "CHANNELS", "TOPIC_CHAMBER", "CLASSIC_WIDTH",
           "EXTENDED_ID_FLAG", "FD_WIDTH", "MAX_DATA", "FLAGS_OFFSET", "FLAG_BRS", "FLAG_ERROR", "FLAG_ESI", "FLAG_FD",
           "FLAG_REMOTE", "HEADER_SIZE", "LENGTH_OFFSET", "LOG_ERROR", "LOG_INFO", "LOG_WARNING", "SCHEMAS",
           "TF_FRAMES", "TOPIC_CAN", "TOPIC_EVENTS", "TOPIC_LOG", "TOPIC_SAMPLES", "TOPIC_STATE", "TOPIC_TF",
           "decode_can_frames", "encode_can_batch", "encode_can_frames", "imu_sample_messages", "json_number",
           "record_dtype"]
