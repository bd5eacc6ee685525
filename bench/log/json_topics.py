"""The JSON topics of a run log, message by message (a log from outside is hostile): each parsed
(`parse_json_rows`: one `json.loads` for a batch, message by message only when that fails), each row checked
for the fields and types its reader relies on, and what is malformed or past a reader's limit said as
`Damage` (counted as lost); `table_states_of` and `imu_records_of` turn the two array topics into arrays, a
batch at a time. Used by `bench.log.reader`."""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
from collections.abc import Callable, Iterator
from typing import TypeVar

import numpy as np

from bench.log.events import Event
from bench.log.format import TOPIC_SAMPLES, TOPIC_STATE
from bench.log.mcap import ChannelData, Damage
from bench.log.topic_arrays import ImuRecords, TableStates, imu_records_from_rows
from drivers.chamber import ChamberAlarms, ChamberState

#: an alarm text from the log is cut to this many characters
MAX_ALARM_TEXT = 500
#: a message of a kept JSON topic longer than this (a table or chamber state is ~300 bytes, an event a few kB) is
#: parsed alone as it is gathered and its strings cut to `MAX_CUT_TEXT` characters (`shrink_message`)
MAX_JSON_MESSAGE_BYTES = 64 << 10
MAX_CUT_TEXT = 4096
_T = TypeVar("_T")
#: messages of an array topic parsed at once (what is parsed at once stays small)
_JSON_BATCH = 1 << 16

_INT64 = (-(1 << 63), 1 << 63)


def is_int(x) -> bool:
    """A JSON integer (or boolean) that fits an int64."""
    return type(x) in (int, bool) and _INT64[0] <= x < _INT64[1]


def is_number(x) -> bool:
    """A JSON number numpy reads as a float64, or null (NaN)."""
    return x is None or type(x) is float or is_int(x)


def is_vec3(v, item=is_number) -> bool:
    return type(v) is list and len(v) == 3 and all(map(item, v))


def state_row_ok(r: dict) -> bool:
    """Whether a `/table/state` row converts (`TableStates.from_dicts`): every field of the right shape."""
    try:
        return (is_number(r["time_s"]) and is_vec3(r["angles_deg"]) and is_vec3(r["rates_dps"])
                and is_vec3(r["status"], is_int) and type(r["modes"]) is list and len(r["modes"]) == 3)
    except KeyError:
        return False


def sample_row_ok(r: dict) -> bool:
    """Whether an `/imu/samples` row converts (`bench.log.topic_arrays.imu_records_from_rows`)."""
    try:
        return (is_int(r["counter"]) and is_number(r["time_s"]) and is_number(r.get("imu_time_s", 0.0))
                and is_vec3(r["gyro_counts"])
                and is_vec3(r["acc_counts"]) and is_number(r["temperature_c"]) and is_int(r["status"]))
    except KeyError:
        return False


def parse_topic(d: ChannelData, topic: str, limit: int, convert: Callable[[dict], _T | None],
            damage: list[Damage]) -> list[_T]:
    """The first `limit` messages of a JSON topic, each `convert`ed (None: malformed); those past the limit and
    the malformed ones are said in `damage` (counted as lost)."""
    skipped = d.keep_first(limit) + d.over_limit
    if skipped:
        damage.append(not_read_damage(topic, skipped, limit))
    rows, bad = parse_json_rows(d.payloads())
    items = []
    for r in filter(None, rows):
        item = convert(r)
        if item is None:
            bad += 1
        else:
            items.append(item)
    if bad:
        damage.append(malformed_damage(topic, bad))
    return items


def numbers_ok(value, depth: int = 0) -> bool:
    """Whether every number in a parsed JSON value is finite and every integer fits an int64 (the recorder
    writes no other: 1e999, NaN or a 400-digit integer in a message is hostile), nested at most 16 deep."""
    kind = type(value)
    if kind is float:
        return math.isfinite(value)
    if kind is int:
        return _INT64[0] <= value < _INT64[1]
    if kind is dict:
        return depth < 16 and all(numbers_ok(v, depth + 1) for v in value.values())
    if kind is list:
        return depth < 16 and all(numbers_ok(v, depth + 1) for v in value)
    return True


def event_row(r: dict) -> Event | None:
    """An `/events` message, or None when it cannot be one, its fields have the wrong types or a number in it
    is out of range (`numbers_ok`)."""
    if not numbers_ok(r):
        return None
    try:
        return Event.from_dict(r)
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError):
        return None


def chamber_state_row(r: dict) -> ChamberState | None:
    """A `/chamber/state` message as the recorder writes it (`ChamberRecorder.on_chamber_state`), or None when a
    field is missing or of the wrong type (a non-finite temperature is recorded as null: NaN here)."""
    def number(key: str) -> float:
        """The field as a float, NaN for null (TypeError for anything but a number or null)."""
        value = r.get(key)
        if value is None:
            return math.nan
        if type(value) not in (int, float):
            raise TypeError(key)
        number = float(value)   # OverflowError past a float
        if not math.isfinite(number):
            raise ValueError(key)
        return number

    try:
        time_s = number("time_s")
        ramp = None if r.get("ramp_c_per_min") is None else number("ramp_c_per_min")   # None: no ramp
        alarms, text, running = r.get("alarms", 0), r.get("alarm_text", ""), r.get("running")
        if (not math.isfinite(time_s) or type(alarms) is not int or not 0 <= alarms < 1 << 32
                or type(text) is not str or type(running) is not bool):
            return None
        return ChamberState(time_s=time_s, temperature_c=number("temperature_c"), setpoint_c=number("setpoint_c"),
                            ramp_c_per_min=ramp, running=running, alarms=ChamberAlarms(alarms),
                            alarm_text=text[:MAX_ALARM_TEXT])
    except (TypeError, ValueError, OverflowError):
        return None


def utc_text_ok(text: object) -> bool:
    """Whether `text` is an ISO 8601 date and time that converts to UTC within years 1..9999 (what the records
    database and the reports do with it): `0001-01-01T00:00:00+05:00` is not."""
    if not isinstance(text, str) or len(text) > 64:
        return False
    try:
        when = datetime.datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
        if when.tzinfo is not None:
            when.astimezone(datetime.UTC)
    except (ValueError, OverflowError):
        return False
    return True


def metadata_damage(metadata: dict[str, dict[str, str]]) -> list[Damage]:
    """The run metadata's dates (`run.*_utc`) that are not dates in UTC, each dropped from `metadata` and said as
    damage (a date the records or a report cannot convert would end the command after it has written)."""
    run = metadata.get("run")
    if not isinstance(run, dict):
        return []
    damage = []
    for key in [k for k in run if k.endswith("_utc")]:
        value = run[key]
        if value and not utc_text_ok(value):
            del run[key]
            damage.append(Damage("metadata", 0, f"run.{key} {value[:40]!r} is not a date and time in UTC; dropped"))
    return damage


def _cut_strings(value, depth: int = 0):
    """`value` with every string longer than `MAX_CUT_TEXT` cut to it (None past 16 levels of nesting)."""
    if type(value) is str:
        return value[:MAX_CUT_TEXT]
    if depth >= 16:
        return None
    if type(value) is dict:
        return {k[:MAX_CUT_TEXT]: _cut_strings(v, depth + 1) for k, v in value.items()}
    if type(value) is list:
        return [_cut_strings(v, depth + 1) for v in value]
    return value


def shrink_message(payload: bytes) -> bytes:
    """A JSON message over `MAX_JSON_MESSAGE_BYTES`, parsed alone and its strings cut to `MAX_CUT_TEXT` characters
    (an alarm text of 1 MB), or `b"0"` (malformed: not an object) when it does not parse or is still too long
    (a huge array). Called as the message is gathered, so no reader ever holds or parses the long form in bulk."""
    try:
        row = json.loads(payload, parse_constant=_no_constant)
    except (ValueError, RecursionError):
        return b"0"
    if type(row) is not dict:
        return b"0"
    cut = json.dumps(_cut_strings(row), separators=(",", ":")).encode()
    return cut if len(cut) <= MAX_JSON_MESSAGE_BYTES else b"0"


def not_read_damage(topic: str, count: int, limit: int) -> Damage:
    """`count` messages on `topic` past the `limit` the reader parses: not read, counted as lost."""
    return Damage("message", 0, f"{count} {topic} messages past the first {limit} not read", lost={topic: count})


def malformed_damage(topic: str, count: int) -> Damage:
    """`count` messages on `topic` that could not be parsed: skipped, and counted as lost."""
    return Damage("message", 0, f"{count} malformed {topic} messages skipped", lost={topic: count})


def _no_constant(name: str):
    """NaN and Infinity are not JSON (the recorder never writes them): the message holding one is malformed."""
    raise ValueError(f"{name} is not a number")


def parse_json_rows(payloads: list[bytes]) -> tuple[list, int]:
    """Each message of a JSON channel as a dict (None where malformed) and the malformed count."""
    try:
        rows = json.loads(b"[" + b",".join(payloads) + b"]", parse_constant=_no_constant)
        if len(rows) == len(payloads) and all(isinstance(r, dict) for r in rows):
            return rows, 0
    except (ValueError, RecursionError):   # RecursionError: arrays nested too deep
        pass
    rows, bad = [], 0
    for p in payloads:
        try:
            r = json.loads(p, parse_constant=_no_constant)
            if not isinstance(r, dict):
                raise ValueError("not an object")
            rows.append(r)
        except (ValueError, RecursionError):
            rows.append(None)
            bad += 1
    return rows, bad


def _json_batches(d: ChannelData, topic: str, limit: int,
                  damage: list[Damage]) -> Iterator[tuple[list, np.ndarray, int]]:
    """(rows, log times ns, malformed count) of the topic's messages in batches of `_JSON_BATCH`; rows are
    dicts, None where malformed. Messages past the first `limit` are not parsed: said in `damage`, counted
    as lost."""
    skipped = d.keep_first(limit)
    if skipped:
        damage.append(not_read_damage(topic, skipped, limit))
    payloads, times = d.payloads(), d.log_time_ns
    for a in range(0, len(payloads), _JSON_BATCH):
        rows, bad = parse_json_rows(payloads[a:a + _JSON_BATCH])
        yield rows, times[a:a + _JSON_BATCH], bad


def table_states_of(d: ChannelData | None, limit: int, damage: list[Damage]) -> TableStates:
    """The `/table/state` messages (the first `limit`) as arrays; malformed messages are skipped, and they and
    those past the limit said in `damage`."""
    if d is None or not len(d):
        return TableStates.from_dicts([])
    parts, bad = [], 0
    for rows, _, malformed in _json_batches(d, TOPIC_STATE, limit, damage):
        bad += malformed
        rows = [r for r in rows if r is not None]
        try:
            parts.append(TableStates.from_dicts(rows))
        except (KeyError, TypeError, ValueError, OverflowError):   # keep the rows that check out
            good = [r for r in rows if state_row_ok(r)]
            bad += len(rows) - len(good)
            parts.append(TableStates.from_dicts(good))
    if bad:
        damage.append(malformed_damage(TOPIC_STATE, bad))
    return TableStates.concatenate(parts)


def imu_records_of(d: ChannelData | None, limit: int, damage: list[Damage]) -> ImuRecords:
    """The `/imu/samples` messages as arrays (as `table_states_of`)."""
    if d is None or not len(d):
        return imu_records_from_rows([], np.zeros(0))
    parts, bad = [], 0
    for rows, times, malformed in _json_batches(d, TOPIC_SAMPLES, limit, damage):
        bad += malformed
        times = times[[i for i, r in enumerate(rows) if r is not None]] / 1e9
        rows = [r for r in rows if r is not None]
        try:
            parts.append(imu_records_from_rows(rows, times))
        except (KeyError, TypeError, ValueError, OverflowError):   # some rows lack fields: keep the others
            good = [k for k, r in enumerate(rows) if sample_row_ok(r)]
            bad += len(rows) - len(good)
            parts.append(imu_records_from_rows([rows[k] for k in good], times[good]))
    if bad:
        damage.append(malformed_damage(TOPIC_SAMPLES, bad))
    return ImuRecords(*(np.concatenate([getattr(p, f.name) for p in parts])
                        for f in dataclasses.fields(ImuRecords)))


__all__ = ["MAX_ALARM_TEXT", "MAX_CUT_TEXT", "MAX_JSON_MESSAGE_BYTES", "chamber_state_row", "event_row",
           "imu_records_of", "is_int", "is_number", "is_vec3", "malformed_damage", "metadata_damage",
           "not_read_damage", "numbers_ok", "parse_json_rows", "parse_topic", "sample_row_ok", "shrink_message",
           "state_row_ok", "table_states_of", "utc_text_ok"]
