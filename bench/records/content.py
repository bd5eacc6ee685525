"""What `bench db import` takes from a file, checked where it enters: hostile content is one `IngestError` line.

A file from outside may hold anything JSON can: 10**400 (an int no float holds), 5,000-digit
integers (Python's parser refuses them), nesting thousands deep, dates before year 1 in UTC,
run ids of a megabyte. Each is refused with its field named before anything is written, so a
folder import records the other files and reports this one; the database's column limits
(`bench.records.schema`) are checked here, not left to the server (PostgreSQL refuses a text
longer than its column, which would end the whole import as a database error).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import math
import os
import stat
import sys
from pathlib import Path
from typing import Any

from bench.errors import InputError

#: the largest JSON file `bench db import` reads (a result file of 30 coefficients and a budget is ~60 kB)
MAX_JSON_BYTES = 16 << 20
#: the deepest nesting a result file may have (the bench writes 5 levels)
MAX_DEPTH = 64


class IngestError(InputError):
    """A file that is not a result, a table-check result, a noise result or a run log this software reads."""


class NotRecorded(IngestError):
    """A file the bench writes that holds nothing the records keep (said in one line, not a failure)."""


def regular_file(path: Path) -> os.stat_result:
    """The file's status; IngestError for a FIFO, device, socket or folder (reading one blocks or never ends)."""
    info = os.stat(path)
    if not stat.S_ISREG(info.st_mode):
        raise IngestError("not a regular file (a FIFO, device or socket is never read)")
    return info


def read_json(path: Path) -> tuple[dict[str, Any], str]:
    """(the JSON object, the SHA-256 of the bytes): a regular file of at most `MAX_JSON_BYTES`, size-checked
    before reading, at most `MAX_DEPTH` deep, no number beyond the parser's limits."""
    info = regular_file(path)
    if info.st_size > MAX_JSON_BYTES:
        raise IngestError(f"{info.st_size} bytes, more than a result file holds (at most {MAX_JSON_BYTES})")
    with open(path, "rb") as f:
        raw = f.read(MAX_JSON_BYTES + 1)
    if len(raw) > MAX_JSON_BYTES:
        raise IngestError(f"more than {MAX_JSON_BYTES} bytes (it grew while read)")
    try:
        data = json.loads(raw)
    except RecursionError as exc:
        raise IngestError("JSON nested too deeply") from exc
    except UnicodeDecodeError as exc:
        raise IngestError(f"not UTF-8 JSON (byte {exc.start})") from exc
    except ValueError as exc:      # JSONDecodeError, and an integer of more digits than Python converts
        if "integer string conversion" in str(exc):
            raise IngestError(f"not JSON this software reads: an integer of more than {sys.get_int_max_str_digits()} "
                              "digits") from exc
        raise IngestError(f"not JSON ({str(exc)[:120]})") from exc
    if not isinstance(data, dict):
        raise IngestError("not a result file (a JSON object)")
    if depth(data) > MAX_DEPTH:
        raise IngestError(f"JSON nested more than {MAX_DEPTH} levels deep")
    return data, hashlib.sha256(raw).hexdigest()


def depth(value: Any) -> int:
    """How deep `value` nests (a scalar: 0), without recursion."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, level = stack.pop()
        children = item.values() if isinstance(item, dict) else item if isinstance(item, list) else None
        if children is None:
            continue
        deepest = max(deepest, level)
        if level <= MAX_DEPTH:
            stack.extend((child, level + 1) for child in children)
    return deepest


def text(value: Any, name: str, limit: int) -> str:
    """A text field (None: empty), stripped; IngestError if it is not text or longer than its column."""
    if value is None:
        return ""
    if isinstance(value, bool) or not isinstance(value, (str, int, float)):
        raise IngestError(f"{name} is not text")
    if isinstance(value, int) and value.bit_length() > 64:
        raise IngestError(f"{name} is a {value.bit_length()}-bit integer, not text")
    shown = str(value).strip()
    if len(shown) > limit:
        raise IngestError(f"{name} is {len(shown)} characters, more than {limit}")
    return shown


def date(value: Any, name: str) -> dt.datetime | None:
    """A naive UTC datetime from an ISO 8601 text (None: absent); IngestError if it is not one or it lies outside
    the years 1..9999 in UTC (0001-01-01T00:00:00+05:00 is)."""
    if value is None or value == "":
        return None
    if not isinstance(value, str) or len(value) > 64:
        raise IngestError(f"{name} is not an ISO 8601 date")
    try:
        when = dt.datetime.fromisoformat(value.strip().replace("Z", "+00:00"))
        return when.astimezone(dt.UTC).replace(tzinfo=None) if when.tzinfo is not None else when
    except ValueError as exc:
        raise IngestError(f"{name} {value[:40]!r} is not an ISO 8601 date") from exc
    except OverflowError as exc:
        raise IngestError(f"{name} {value[:40]!r} lies outside the years 1..9999 in UTC") from exc


def number(value: Any, name: str) -> float | None:
    """A coefficient's number: a float, None when absent or NaN (unknown); IngestError for an infinity or an
    integer beyond a float's range (10**400)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise IngestError(f"{name} is not a number")
    try:
        as_float = float(value)
    except OverflowError as exc:
        raise IngestError(f"{name} is an integer of {len(str(value))} digits, beyond a float's range") from exc
    if math.isinf(as_float):
        raise IngestError(f"{name} is infinite")
    return None if math.isnan(as_float) else as_float


def coefficients(table: Any, where: str = "coefficients") -> dict[str, dict[str, Any]]:
    """A result's coefficients table checked: names of at most 32 characters, finite numbers (NaN: unknown)."""
    if table is None:
        return {}
    if not isinstance(table, dict):
        raise IngestError(f"{where} is not an object")
    for name, entry in table.items():
        text(name, f"{where} name {name[:40]!r}", 32)
        if not isinstance(entry, dict):
            raise IngestError(f"{where}.{name} is not an object")
        number(entry.get("value"), f"{where}.{name}.value")
        number(entry.get("sigma"), f"{where}.{name}.sigma")
        text(entry.get("unit"), f"{where}.{name}.unit", 64)
    return table


__all__ = ["IngestError", "MAX_DEPTH", "MAX_JSON_BYTES", "NotRecorded", "coefficients", "date", "depth", "number",
           "read_json", "regular_file", "text"]
