"""What the records database holds, as Python values: a run (`RunInfo`), how a result came to be
(`Derivation`), the lines of `bench db list` and `bench db results`, and the conversions of a
result file's values into columns (finite floats, JSON a column can hold, the verdict's word).
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass
from typing import Any

from bench.acceptance.verdict import stored_outcome


def utc(text: Any) -> dt.datetime | None:
    """A naive UTC datetime from an ISO 8601 text (`2026-11-24T02:49:01Z`), or None."""
    if not isinstance(text, str) or not text.strip():
        return None
    try:
        when = dt.datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
        # 0001-01-01T00:00:00+05:00 is before the first UTC datetime: OverflowError, an unusable time
        return when.astimezone(dt.UTC).replace(tzinfo=None) if when.tzinfo is not None else when
    except (ValueError, OverflowError):
        return None


def now() -> dt.datetime:
    return dt.datetime.now(dt.UTC).replace(tzinfo=None)


@dataclass(frozen=True)
class RunInfo:
    """What the database holds of one run (the fields of `schema.runs`)."""

    run_id: str
    model: str
    serial: str
    kind: str = "calibration"
    mode: str = ""
    log_path: str | None = None
    log_sha256: str | None = None
    operator: str = ""
    site: dict | None = None
    table_url: str = ""
    plan: str = ""
    software_version: str = ""
    started_utc: dt.datetime | None = None
    finished_utc: dt.datetime | None = None
    outcome: str = ""
    log_complete: bool | None = None      # False: the log had no MCAP footer (still recording, or cut off)
    #: the equipment it used, as its log's `lab` metadata names it: (tag, serial; "" when the log has none)
    equipment: tuple[tuple[str, str], ...] = ()
    #: a unit of a run of several IMUs: the run it is one unit of (its record's run id is `<run-id>.<serial>`)
    bench_run: str | None = None


#: `results.origin`: the result `bench run` wrote; `bench solve` of the whole intact log; what-if solves of a
#: subset; solves of a damaged log (steps lost or left out); one temperature block of a thermal run (its
#: headline block, the result named after the run, is the run's)
ORIGINS = ("run", "re-solve", "subset", "damaged", "block")


@dataclass(frozen=True)
class Derivation:
    """How a result came to be (`results.origin`, `.derivation`, `.log_sha256`)."""

    origin: str = "run"
    text: str = ""
    log_sha256: str | None = None


@dataclass(frozen=True)
class ResultRow:
    """One result of a run (`bench db results`): `truth` marks the run's record of truth."""

    result_id: int
    run_id: str
    origin: str | None
    derivation: str | None
    software_version: str
    solved_utc: dt.datetime | None
    verdict: str | None
    promoted_utc: dt.datetime | None
    path: str | None
    truth: bool


@dataclass(frozen=True)
class RunRow:
    """One line of `bench db list`."""

    run_id: str
    model: str
    serial: str
    kind: str
    started_utc: dt.datetime | None
    finished_utc: dt.datetime | None
    outcome: str
    operator: str
    plan: str
    results: int
    verdict: str | None
    log_path: str | None
    truth_id: int | None = None           # the run's record of truth (None: no result, or only derived ones)
    truth_origin: str | None = None       # the record of truth's origin ("run", "re-solve", None: none, or legacy)
    promoted: bool = False                # the record of truth was promoted by a user
    log_complete: bool | None = None


def verdict_word(verdict: dict | None) -> str | None:
    """"pass", "fail" or "not checked" (a verdict no check ran for is not a pass, nor a failure)."""
    if verdict is None:
        return None
    word = verdict.get("verdict")
    if word in ("pass", "fail", "not checked"):
        return str(word)
    # an older file: by the rule of today's verdicts (a PASS no check ran for is NOT CHECKED)
    return stored_outcome(verdict).lower()


def finite(value: Any) -> float | None:
    """A finite float from a number in a file, else None (10**400 overflows float: None, not OverflowError)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None


def json_safe(value: Any) -> Any:
    """`value` with every NaN or infinity as None: a JSON column holds what JSON can say (PostgreSQL refuses NaN,
    which a result file from another tool may hold; the bench writes none)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_safe(v) for v in value]
    return value


def dict_or_none(value: Any) -> dict | None:
    return value if isinstance(value, dict) else None


def coefficient_row(result_id: int, name: str, entry: Any) -> dict[str, Any] | None:
    """A `coefficients` row; None for an entry without a finite value (nothing to record)."""
    entry = entry if isinstance(entry, dict) else {}
    value = finite(entry.get("value"))
    if value is None:
        return None
    extra = {k: v for k, v in entry.items() if k not in ("value", "sigma", "unit")}
    return {"result_id": result_id, "name": str(name)[:32], "value": value, "sigma": finite(entry.get("sigma")),
            "unit": str(entry.get("unit", ""))[:64], "budget": json_safe(extra) or None}


__all__ = ["ORIGINS", "Derivation", "ResultRow", "RunInfo", "RunRow", "coefficient_row", "dict_or_none", "finite",
           "json_safe", "now", "utc", "verdict_word"]
