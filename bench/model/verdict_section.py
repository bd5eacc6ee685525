"""The `verdict` section of a calibration result, as the acceptance verdict writes it
(`bench.acceptance.verdict.Verdict.to_json`, read back by `Verdict.to_section`): the outcome, the headline, the
worst check and every check.

Each part is a `bench.model.sections.Section`: read from a file it writes back what it read (an older file's
verdict has its entries in another order, no `failed`, and checks without a `kind`: those are None).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from bench.model.sections import ResultFormatError, Section, flag, list_of, number
from bench.model.sections import text as read_text


def _limit(value: Any, where: str) -> float | list[float]:
    """A check's limit: a number, or a range [low, high]."""
    if isinstance(value, list):
        if len(value) != 2:
            raise ResultFormatError(f"{where} must be a number or a range [low, high]")
        return [number(v, f"{where}[{i}]") for i, v in enumerate(value)]
    return number(value, where)


@dataclass
class CheckRecord(Section):
    """One check as the file keeps it (`bench.acceptance.verdict.Check.to_json`): `value`, `limit` and `ratio` are
    null when unknown or not finite (the file's null and a missing entry are told apart by `keys`)."""

    name: str | None = None
    kind: str | None = None             # "acceptance" | "quality" | "verification" (None: an older file's)
    value: float | None = None
    limit: float | list[float] | None = None
    unit: str | None = None
    passed: bool | None = None
    ratio: float | None = None
    text: str | None = None

    READERS = {"name": read_text, "kind": read_text, "value": number, "limit": _limit, "unit": read_text,
               "passed": flag, "ratio": number, "text": read_text}


@dataclass
class VerdictSection(Section):
    """A result's `verdict` section: `verdict` the outcome in lower case ("pass" | "fail" | "not checked"),
    `passed` and `failed`, the `headline`, the `worst` check's line (null: no check ran) and every check."""

    verdict: str | None = None
    passed: bool | None = None
    failed: bool | None = None
    headline: str | None = None
    worst: str | None = None
    checks: list[CheckRecord] | None = None

    READERS = {"verdict": read_text, "passed": flag, "failed": flag, "headline": read_text, "worst": read_text,
               "checks": list_of(CheckRecord.from_dict)}

    def _dumped(self, name: str) -> Any:
        if name == "checks":
            return None if self.checks is None else [c.to_dict() for c in self.checks]
        return super()._dumped(name)


__all__ = ["CheckRecord", "VerdictSection"]
