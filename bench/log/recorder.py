"""The run recorder: everything a run produces, into one MCAP file (docs/explanation/log-format.md).

Channels (message encoding "json" with a "jsonschema" Schema record, unless noted):

- `/table/state` (`turntable_bench.TableState`): every polled table state; log time = `state.time_s`.
- `/imu/samples` (`turntable_bench.ImuSample`): one message per decoded sample (every
  `imu_samples_topic_decimation`-th counter); log time = the sample's receive time.
- `/events` (`turntable_bench.Event`): `Event.to_dict()`; log time = `event.time_s`.
- `/log` (`foxglove.Log`): one line per event (fault -> ERROR, warning -> WARNING, else INFO).
- `/chamber/state` (`turntable_bench.ChamberState`, a run with a thermal chamber only: `chamber=True`):
  every polled chamber state; log time = `state.time_s`.
- `/tf` (`foxglove.FrameTransform`): per table state world->outer, outer->middle,
  middle->inner at the nominal frame angles (black-box errors are unknown to the bench).
- `/can/raw` (`turntable_bench.CanFrames`, message encoding `turntable-bench/can-frames-v1`):
  every raw CAN frame, losslessly, one message per `on_can_frames` batch. Layout: records
  concatenated, each `<d` timestamp_s, `<I` arbitration id (bit 31 set = 29-bit id), `<B`
  flags (bit0 FD, bit1 bitrate switch, bit2 error state indicator, bit3 remote, bit4 error
  frame), `<B` data length n, then n data bytes. Log time = the batch's newest frame
  timestamp (the sequencer stamps frames on the run clock).

Transform convention: docs/explanation/model.md#frame-rotations defines the frame matrices as coordinate transforms
`C_parent^child` (outer/inner `[[c,-s,0],[s,c,0],[0,0,1]]` about Z, middle
`[[c,0,s],[0,1,0],[-s,0,c]]` about Y; `v_child = C_parent^child v_parent`). A Foxglove
FrameTransform carries the child frame's orientation in the parent, i.e. the rotation
that maps child coordinates to parent coordinates: `(C_parent^child)^T`. For a frame angle
theta that is a right-handed rotation by -theta about the frame axis (the paper's positive
angle is "clockwise"), so the quaternion is `(axis * sin(-theta/2), cos(-theta/2))`.
"world" is the local ENU frame `t`.

Times: MCAP log times are unsigned nanoseconds on the run clock; a negative time is
recorded as 0. Metadata records are written when given; attachments any time before
`close()`. Chunks are zstd-compressed with CRCs and closed when they reach `chunk_size`
bytes, `chunk_interval_s` of wall time after the previous close (so a crash loses at
most about that much), and at every multiple of `chunk_run_interval_s` (default 5 s) of
run clock, the messages' log time: the first message at or past one starts a new chunk.
That rule makes the chunk boundaries of a simulated run (many simulated seconds per wall
second) the same on any machine, however fast or loaded (the wall-time rule only adds
boundaries); on hardware the run clock is the monotonic clock, so it adds one close per
interval. `/can/raw` and `/imu/samples` messages are held back and written at each close in
chunks of their own (the frames first): they are the bulk of a log, so a reader that needs
the events and states skips them without decompressing, and `bench.log.reader` streams the
frames chunk by chunk (and defers the samples, derived from the frames, until asked for).
Schema and Channel records are also written outside the first chunk, so a reader can
decode every later chunk even if the first one is damaged.
The recorder is single-threaded: call it from the sequencer's thread only.
"""

from __future__ import annotations

import errno
import json
import math
import os
import struct
import time
from typing import Any, Callable, Mapping, Sequence

from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Schema
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

import bench
from bench.errors import BenchError
from bench.log.bulk_messages import add_messages
from bench.log.events import Event, Fault, RunListener, RunWarning
from bench.log.format import (
    CAN_SCHEMA_NAME,
    CAN_SCHEMA_TEXT,
    CHAMBER_CHANNELS,
    CHAMBER_SCHEMA,
    CHAMBER_SCHEMA_NAME,
    CHANNELS,
    LOG_ERROR,
    LOG_INFO,
    LOG_WARNING,
    SCHEMAS,
    TF_FRAMES,
    TOPIC_CAN,
    TOPIC_CHAMBER,
    TOPIC_EVENTS,
    TOPIC_LOG,
    TOPIC_SAMPLES,
    TOPIC_STATE,
    TOPIC_TF,
    encode_can_batch,
    encode_can_frames,
    imu_sample_messages,
    json_number,
    unit_channels,
    unit_topics,
)
from drivers.imu.frames import CanFrameBatch

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
#: Default run-clock chunk interval, s: a chunk closes every this many seconds of recorded log time.
CHUNK_RUN_INTERVAL_S = 5.0
_NEVER = 1 << 64   # past every MCAP log time (uint64)


class RecorderError(BenchError):
    """The recorder cannot write (bad arguments, closed, or an I/O error).

    After an I/O error the recorder is broken: every later call raises it again and
    `close()` closes the file as it is (no summary: readable like a crashed run's log)."""


def _io_error_text(path: str, exc: BaseException, doing: str = "write") -> str:
    """One line for an I/O error on the log: "log disk full: ..." when it is, else the OS's reason."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"log disk full: cannot {doing} MCAP log {path}: {exc.strerror}"
    reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
    return f"cannot {doing} MCAP log {path}: {reason}"


def time_ns(time_s: float) -> int:
    """Seconds on the run clock -> MCAP log time (ns, >= 0; NaN -> 0)."""
    if not time_s > 0.0:    # also NaN
        return 0
    return int(round(time_s * 1e9))


def _stamp(time_s: float) -> str:
    ns = time_ns(time_s)
    return f'{{"sec":{ns // 1_000_000_000},"nsec":{ns % 1_000_000_000}}}'


_num = json_number


def _json_default(obj: Any) -> Any:
    """Event data may carry numpy scalars/arrays, enums, sets; anything else becomes its repr."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if hasattr(obj, "value") and hasattr(obj, "name"):
        return obj.value
    if isinstance(obj, (set, frozenset, tuple)):
        return list(obj)
    return repr(obj)


def _finite(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def to_json(obj: Any) -> bytes:
    """Strict JSON (non-finite floats -> null), numpy-tolerant."""
    try:
        return json.dumps(obj, default=_json_default, allow_nan=False, separators=(",", ":")).encode()
    except ValueError:
        obj = json.loads(json.dumps(obj, default=_json_default))
        return json.dumps(_finite(obj), allow_nan=False, separators=(",", ":")).encode()


def frame_quaternions(angles_deg: Sequence[float]) -> list[tuple[float, float, float, float]]:
    """(x, y, z, w) of outer-in-world, middle-in-outer, inner-in-middle at nominal frame angles.

    Each is the rotation `(C_parent^child)^T`: -theta about the frame axis (Z, Y, Z).
    """
    out: list[tuple[float, float, float, float]] = []
    for axis, angle_deg in zip((2, 1, 2), angles_deg):
        half = -math.radians(angle_deg) / 2.0
        q = [0.0, 0.0, 0.0, math.cos(half)]
        q[axis] = math.sin(half)
        out.append((q[0], q[1], q[2], q[3]))
    return out


class McapRecorder(RunListener):
    """Writes a run to an MCAP file; see the module docstring for channels and conventions.

    `metadata`: name -> {key: value} records written at once (values str; numbers are
    converted). A chunk is closed at `chunk_size` bytes, `chunk_interval_s` seconds of
    `clock` (a wall clock, used only for this) after the previous close, and before the
    first message whose log time (run clock) reaches the next multiple of
    `chunk_run_interval_s` seconds (None: no run-clock rule). `compression`: "zstd"
    (default), "lz4" or "none".
    """

    def __init__(self, path, *, metadata: Mapping[str, Mapping[str, str]] | None = None,
                 chunk_interval_s: float = 1.0, clock: Callable[[], float] = time.monotonic,
                 chunk_run_interval_s: float | None = CHUNK_RUN_INTERVAL_S,
                 imu_samples_topic_decimation: int = 1, chunk_size: int = 4 * 1024 * 1024,
                 compression: str = "zstd", chamber: bool = False, units: Sequence[str] = ()):
        if not (isinstance(imu_samples_topic_decimation, int) and imu_samples_topic_decimation >= 1):
            raise RecorderError(f"imu_samples_topic_decimation must be a positive integer, "
                                f"got {imu_samples_topic_decimation!r}")
        if not chunk_interval_s > 0:
            raise RecorderError(f"chunk_interval_s must be positive, got {chunk_interval_s!r}")
        if chunk_run_interval_s is not None and not (chunk_run_interval_s > 0 and math.isfinite(chunk_run_interval_s)):
            raise RecorderError(f"chunk_run_interval_s must be positive and finite (or None), "
                                f"got {chunk_run_interval_s!r}")
        if compression not in _COMPRESSION:
            raise RecorderError(f"compression must be one of {sorted(_COMPRESSION)}, got {compression!r}")
        self.path = str(path)
        # (`units`: the serials of a run's units other than its reference unit, each with its own topics)
        self._channels = {**CHANNELS, **(CHAMBER_CHANNELS if chamber else {}), **unit_channels(units)}
        self.chunk_interval_s = float(chunk_interval_s)
        self.chunk_run_interval_s = None if chunk_run_interval_s is None else float(chunk_run_interval_s)
        # run-clock rule: the next chunk close is due at log time `_run_due` (ns); -1 until the
        # first message sets it, past any log time when the rule is off
        self._run_step = 0 if chunk_run_interval_s is None else max(1, time_ns(chunk_run_interval_s))
        self._run_due = -1 if self._run_step else _NEVER
        self.decimation = imu_samples_topic_decimation
        self._clock = clock
        self.frames_written = 0
        self.samples_written = 0
        self.messages_written = 0
        self._closed = False
        self._broken: RecorderError | None = None    # the I/O error that broke the log (see RecorderError)
        self._chunk_size = chunk_size
        self._held_samples: list[tuple[int, bytes]] = []   # /imu/samples messages for the next samples chunk
        self._held_can: list[tuple[int, bytes]] = []       # /can/raw messages for the next frames chunk
        self._held_units: dict[str, list[tuple[int, bytes]]] = {}   # a unit's topic -> its held messages
        self._held_bytes = 0   # of all
        try:
            self._file = open(self.path, "wb")
        except OSError as exc:
            raise RecorderError(f"cannot create MCAP log {self.path}: {exc}") from exc
        try:
            self._writer = Writer(self._file, chunk_size=chunk_size, compression=_COMPRESSION[compression])
            self._writer.start(profile="", library=f"turntable-bench/{bench.__version__}; {LIBRARY_IDENTIFIER}")
            self._channel = self._register()
            for name, data in (metadata or {}).items():
                self._add_metadata(name, data)
            self._file.flush()
        except Exception as exc:
            self._file.close()
            if isinstance(exc, RecorderError):
                raise
            raise RecorderError(f"cannot start MCAP log {self.path}: {exc}") from exc
        self._last_close = clock()

    # -- setup -------------------------------------------------------------------------
    def _register(self) -> dict[str, int]:
        schema_ids: dict[str, int] = {}
        records = RecordBuilder()
        # The /can/raw schema's encoding names the binary layout its text describes (as "protobuf" does for
        # a protobuf schema): an empty encoding with data breaks the MCAP spec (`mcap doctor`: an error).
        encodings = {schema: schema_encoding for schema, schema_encoding, _ in self._channels.values()}
        schemas = {**SCHEMAS, **({CHAMBER_SCHEMA_NAME: CHAMBER_SCHEMA} if TOPIC_CHAMBER in self._channels else {})}
        bodies = {**{name: json.dumps(body, indent=1).encode() for name, body in schemas.items()},
                  CAN_SCHEMA_NAME: CAN_SCHEMA_TEXT.encode()}
        for name, data in bodies.items():
            encoding = encodings.get(name, "jsonschema")
            schema_ids[name] = self._writer.register_schema(name, encoding, data)
            Schema(id=schema_ids[name], name=name, encoding=encoding, data=data).write(records)
        channel_ids = {}
        for topic, (schema, _, encoding) in self._channels.items():
            channel_ids[topic] = self._writer.register_channel(topic, encoding, schema_ids[schema])
            Channel(id=channel_ids[topic], topic=topic, message_encoding=encoding, metadata={},
                    schema_id=schema_ids[schema]).write(records)
        # The Writer keeps these records inside the first chunk only; a copy in the data
        # section (allowed by the MCAP spec, identical records) keeps later chunks decodable.
        self._file.write(records.end())
        return channel_ids

    def _add_metadata(self, name: str, data: Mapping[str, Any]) -> None:
        if not isinstance(name, str) or not isinstance(data, Mapping):
            raise RecorderError(f"metadata must map a name to a dict of strings, got {name!r}: {type(data).__name__}")
        clean = {}
        for k, v in data.items():
            if isinstance(v, bool) or isinstance(v, (int, float)):
                v = str(v).lower() if isinstance(v, bool) else str(v)
            if not isinstance(k, str) or not isinstance(v, str):
                raise RecorderError(f"metadata {name!r}: key {k!r} must be a string with a string value, "
                                    f"got {type(v).__name__}")
            clean[k] = v
        self._writer.add_metadata(name, clean)

    # -- public writing API ------------------------------------------------------------
    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Write a metadata record now (e.g. the result summary at the end of a run)."""
        self._check_open()
        self._io(self._add_metadata, name, data)

    def add_attachment(self, name: str, media_type: str, data: bytes, log_time_s: float = 0.0) -> None:
        """Attach a file (schedule, DBC, result JSON) to the log: its log time is `log_time_s` on the
        run clock (when it was attached), its create time the wall clock's now (ns since the epoch)."""
        self._check_open()
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise RecorderError(f"attachment {name!r}: data must be bytes, got {type(data).__name__}")
        self._io(self._writer.add_attachment, time.time_ns(), time_ns(log_time_s), str(name), str(media_type),
                 bytes(data))

    def on_event(self, event: Event) -> None:
        self._check_open()
        t = time_ns(event.time_s)
        level = LOG_ERROR if isinstance(event, Fault) else LOG_WARNING if isinstance(event, RunWarning) else LOG_INFO
        text = event.message if event.step_unit is None else f"[{event.step_unit}] {event.message}"
        log = to_json({"timestamp": {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000}, "level": level,
                       "message": text, "name": f"sequencer.{event.kind}", "file": "", "line": 0})
        self._run_clock(t)
        self._io(self._put, TOPIC_EVENTS, t, to_json(event.to_dict()))
        self._io(self._put, TOPIC_LOG, t, log)
        self._tick()

    def on_table_state(self, state) -> None:
        self._check_open()
        t = time_ns(state.time_s)
        angles, rates = state.angles_deg, state.rates_dps
        body = (f'{{"time_s":{_num(state.time_s)},"angles_deg":[{",".join(map(_num, angles))}],'
                f'"rates_dps":[{",".join(map(_num, rates))}],'
                f'"modes":[{",".join(json.dumps(m.value) for m in state.modes)}],'
                f'"status":[{",".join(str(int(a.status)) for a in state.axes)}],'
                f'"estop":{"true" if state.estop else "false"},"fault_text":{json.dumps(state.fault_text)}}}')
        self._run_clock(t)
        self._io(self._put, TOPIC_STATE, t, body.encode())
        stamp = _stamp(state.time_s)
        finite = [a if math.isfinite(a) else 0.0 for a in angles]
        for k, (x, y, z, w) in enumerate(frame_quaternions(finite)):
            tf = (f'{{"timestamp":{stamp},"parent_frame_id":"{TF_FRAMES[k]}","child_frame_id":"{TF_FRAMES[k + 1]}",'
                  f'"translation":{{"x":0.0,"y":0.0,"z":0.0}},"rotation":{{"x":{x!r},"y":{y!r},"z":{z!r},"w":{w!r}}}}}')
            self._io(self._put, TOPIC_TF, t, tf.encode())
        self._tick()

    def on_chamber_state(self, state) -> None:
        if TOPIC_CHAMBER not in self._channel:
            raise RecorderError(f"MCAP log {self.path} has no {TOPIC_CHAMBER} channel (open it with chamber=True)")
        self._check_open()
        t = time_ns(state.time_s)
        body = to_json({"time_s": state.time_s, "temperature_c": state.temperature_c, "setpoint_c": state.setpoint_c,
                        "ramp_c_per_min": state.ramp_c_per_min, "running": bool(state.running),
                        "alarms": int(state.alarms), "alarm_text": state.alarm_text})
        self._run_clock(t)
        self._io(self._put, TOPIC_CHAMBER, t, body)
        self._tick()

    def on_imu(self, block) -> None:
        self._check_open()
        if not len(block):
            return
        self._run_clock(time_ns(float(block.receive_time_s.max())))
        self._io(self._put_samples, block)
        self._tick()

    def on_unit_imu(self, serial: str, block) -> None:
        """A unit's decoded samples (a run of several IMUs: a unit other than the reference one), on its topic."""
        self._check_open()
        if not len(block):
            return
        self._run_clock(time_ns(float(block.receive_time_s.max())))
        self._io(self._put_samples, block, unit_topics(serial)[1])
        self._tick()

    def on_unit_can_frames(self, serial: str, frames: Sequence) -> None:
        """A unit's raw CAN frames (as `on_unit_imu`), on its topic."""
        self._check_open()
        if not len(frames):
            return
        topic = unit_topics(serial)[0]
        payload, newest = encode_can_batch(frames) if isinstance(frames, CanFrameBatch) else encode_can_frames(frames)
        self._run_clock(time_ns(newest))
        self._io(self._hold_can, time_ns(newest), payload, topic)
        self.frames_written += len(frames)
        self._tick()

    def on_can_frames(self, frames: Sequence) -> None:
        self._check_open()
        if not len(frames):
            return
        try:
            payload, newest = (encode_can_batch(frames) if isinstance(frames, CanFrameBatch)
                               else encode_can_frames(frames))
        except (AttributeError, TypeError, struct.error) as exc:
            raise RecorderError(f"cannot encode CAN frames for {TOPIC_CAN}: {exc}") from exc
        self._run_clock(time_ns(newest))
        self._io(self._hold_can, time_ns(newest), payload)
        self.frames_written += len(frames)
        self._tick()

    def on_encoded_can_frames(self, payload: bytes, count: int, newest_s: float) -> None:
        """A batch of `count` frames already in the `/can/raw` encoding (`bench.log.format`), newest at
        `newest_s`: what a bulk writer (a benchmark's synthetic log, a converter) hands over without
        building a python-can message per frame."""
        self._check_open()
        if not count:
            return
        self._run_clock(time_ns(newest_s))
        self._io(self._hold_can, time_ns(newest_s), payload)
        self.frames_written += count
        self._tick()

    def flush(self) -> None:
        """Close the open chunk and push everything to the OS now."""
        self._check_open()
        self._io(self._close_chunks)
        self._last_close = self._clock()

    def close(self) -> None:
        """Write the summary and footer and close the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self._broken is not None:
            # the writer's state after a failed write is unknown (and the disk may still be full): the file
            # is closed as it is; the error was raised when it happened
            _close_quietly(self._file)
            return
        try:
            self._write_held()
            self._writer.finish()
            self._file.close()
        except Exception as exc:
            _close_quietly(self._file)
            raise RecorderError(_io_error_text(self.path, exc, "finish")) from exc

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def bytes_written(self) -> int:
        """Bytes handed to the file so far (the open chunk is not included)."""
        return self._file.tell() if not self._closed else _file_size(self.path)

    def __enter__(self) -> "McapRecorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- internals ---------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._broken is not None:
            raise RecorderError(str(self._broken))
        if self._closed:
            raise RecorderError(f"MCAP log {self.path} is closed")

    def _io(self, fn, *args) -> None:
        try:
            fn(*args)
        except (OSError, ValueError) as exc:
            self._broken = RecorderError(_io_error_text(self.path, exc))
            raise self._broken from exc

    def _put(self, topic: str, log_time: int, data: bytes) -> None:
        self._writer.add_message(self._channel[topic], log_time, data, log_time)
        self.messages_written += 1

    def _put_samples(self, block, topic: str = TOPIC_SAMPLES) -> None:
        messages = imu_sample_messages(block, self.decimation)
        if not messages:
            return
        if topic == TOPIC_SAMPLES:
            self._held_samples += messages
        else:
            self._held_units.setdefault(topic, []).extend(messages)
        self._held_bytes += sum(len(body) for _, body in messages)
        self.samples_written += len(messages)
        self.messages_written += len(messages)
        if self._held_bytes >= self._chunk_size:
            self._close_chunks()

    def _hold_can(self, log_time: int, payload: bytes, topic: str = TOPIC_CAN) -> None:
        """A `/can/raw` message (or a unit's), written at the next close in a chunk of frames only."""
        if topic == TOPIC_CAN:
            self._held_can.append((log_time, payload))
        else:
            self._held_units.setdefault(topic, []).append((log_time, payload))
        self._held_bytes += len(payload)
        self.messages_written += 1
        if self._held_bytes >= self._chunk_size:
            self._close_chunks()

    def _write_held(self) -> None:
        """Close the open chunk, then write the held frames, then the held samples, each in chunks holding
        nothing else."""
        writer = self._writer
        for topic, held in ((TOPIC_CAN, self._held_can), (TOPIC_SAMPLES, self._held_samples),
                            *self._held_units.items()):
            if not held:
                continue
            writer.flush()
            add_messages(writer, self._channel[topic], held)
        self._held_samples, self._held_can, self._held_bytes = [], [], 0
        self._held_units = {}

    def _close_chunks(self) -> None:
        self._write_held()
        self._writer.flush()

    def _run_clock(self, log_time: int) -> None:
        """Before writing messages at `log_time` (ns): close the chunk when that time reached the
        next multiple of the run-clock interval (the first message only arms the rule)."""
        due = self._run_due
        if log_time >= due:
            self._run_due = (log_time // self._run_step + 1) * self._run_step
            if due >= 0:    # (not the first message)
                self._io(self._close_chunks)
                self._last_close = self._clock()

    def _tick(self) -> None:
        now = self._clock()
        if now - self._last_close >= self.chunk_interval_s:
            self._io(self._close_chunks)
            self._last_close = now


def _close_quietly(file) -> None:
    """Close a file whose data cannot all be written (its buffer's flush fails again): the error is
    already on its way to the caller."""
    try:
        file.close()
    except OSError:
        pass


def _file_size(path: str) -> int:
    try:
        return os.path.getsize(path)
    except OSError:
        return 0


__all__ = ["CHUNK_RUN_INTERVAL_S", "McapRecorder", "RecorderError", "frame_quaternions", "time_ns", "to_json"]
