"""The verdict of a calibration: every check with its value and limit, and one of three outcomes.

`judge(result, limits, ...)` checks the result's coefficients against `AcceptanceLimits`,
the run's lost samples and residuals, and adds the run's quality failures (steps left out,
damage, outliers, an inconsistent budget: each a failed check of kind "quality") and the
verification's checks. A check's `ratio` says how close it came to its limit (|value| /
limit; for a range, the distance from its middle over half its width): at most 1 passes,
and the worst check is the one with the largest ratio (a failed one first).

The outcome is FAIL when any check failed, PASS when at least one check ran and all passed,
and NOT CHECKED when none ran (no acceptance limits, no verification, and no quality check
failed): the quality checks can only fail a result, never pass it, since a run with sound
data says nothing about whether the IMU meets a specification.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

from bench.acceptance.limits import AcceptanceLimits
from bench.model.families import RESULT_UNITS, canonical_names, family_of
from bench.model.result import CalibrationResult
from bench.model.verdict_section import VerdictSection

#: the three outcomes of a verdict (as the result file stores them: lower case)
PASS, FAIL, NOT_CHECKED = "PASS", "FAIL", "NOT CHECKED"
#: the kinds of check: a configured acceptance limit, a quality check of the run, a verification check
ACCEPTANCE, QUALITY, VERIFICATION = "acceptance", "quality", "verification"
_KIND_TITLE = {ACCEPTANCE: "acceptance", QUALITY: "quality", VERIFICATION: "verification"}


@dataclass(frozen=True)
class Check:
    """One check: `name` (`Kg_x value`, `lost samples`), its value and its limit, in `unit`."""

    name: str
    value: float | None             # None: unknown (a missing coefficient, an unknown sigma)
    limit: float | tuple[float, float] | None
    unit: str
    passed: bool
    ratio: float                    # how close to the limit: <= 1 passes (inf when unknown)
    note: str = ""
    signed: bool = False            # a difference, limited in magnitude: "within/beyond +-limit"
    kind: str = ACCEPTANCE          # ACCEPTANCE (a configured limit), QUALITY or VERIFICATION

    def describe(self) -> str:
        """`Kg_x sigma 0.02 > 0.01 counts/s per deg/s` (one line)."""
        unit = f" {self.unit}" if self.unit and self.unit != "1" else ""
        if self.value is None:
            return f"{self.name}: {self.note or 'unknown'}"
        if isinstance(self.limit, tuple):
            inside = self.limit[0] <= self.value <= self.limit[1]
            relation = "in" if inside else "outside"
            return f"{self.name} {self.value:.6g}{unit} {relation} [{self.limit[0]:.6g}, {self.limit[1]:.6g}]"
        if self.limit is None:
            return f"{self.name}: {self.note}"
        if self.signed:
            relation = f"{'within' if self.passed else 'beyond'} +-{self.limit:.6g}"
        else:
            relation = f"{'<=' if self.passed else '>'} {self.limit:.6g}"
        return f"{self.name} {self.value:.6g} {relation}{unit}" + (f" ({self.note})" if self.note else "")

    def labelled(self) -> str:
        """`describe()` saying what kind of check it is: `acceptance limit: Kg_x sigma ...`, `quality check failed:
        P07 ...`, `verify gyro scale x ...` (a verification check's name says it)."""
        if self.kind == ACCEPTANCE:
            return f"acceptance limit: {self.describe()}"
        if self.kind == QUALITY:
            return f"quality check failed: {self.note}"
        return self.describe()

    def to_json(self) -> dict[str, Any]:
        limit: Any = list(self.limit) if isinstance(self.limit, tuple) else self.limit
        return {"name": self.name, "kind": self.kind, "value": _finite_or_none(self.value), "limit": limit,
                "unit": self.unit, "passed": self.passed, "ratio": _finite_or_none(self.ratio), "text": self.describe()}


def _finite_or_none(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


@dataclass(frozen=True)
class Verdict:
    """PASS, FAIL or NOT CHECKED, with every check."""

    checks: list[Check] = field(default_factory=list)

    @property
    def outcome(self) -> str:
        """FAIL when a check failed, PASS when at least one ran and all passed, else NOT CHECKED."""
        if self.failed:
            return FAIL
        return PASS if self.checks else NOT_CHECKED

    @property
    def passed(self) -> bool:
        """PASS: at least one check ran and every one passed (NOT CHECKED is not passed)."""
        return self.outcome == PASS

    @property
    def failed(self) -> list[Check]:
        return [c for c in self.checks if not c.passed]

    @property
    def worst(self) -> Check | None:
        """The failed check furthest beyond its limit, else the passed one closest to it."""
        if not self.checks:
            return None
        return max(self.checks, key=lambda c: (not c.passed, c.ratio if math.isfinite(c.ratio) else math.inf))

    def headline(self) -> str:
        """`PASS (31 checks: 30 acceptance, 1 verification)` / `FAIL (acceptance: 2 of 30 failed: Kg_x sigma,
        lost samples; quality: 1 failed)` / `NOT CHECKED (no acceptance limits configured, no verification)`."""
        if self.outcome == NOT_CHECKED:
            return f"{NOT_CHECKED} (no check ran: no acceptance limits configured, no verification)"
        kinds = [k for k in _KIND_TITLE if any(c.kind == k for c in self.checks)]
        if self.outcome == PASS:
            n = len(self.checks)
            counts = ", ".join(f"{sum(c.kind == k for c in self.checks)} {_KIND_TITLE[k]}" for k in kinds)
            return f"{PASS} ({n} check{'s' if n != 1 else ''}: {counts})"
        parts = []
        for kind in kinds:
            failed = [c for c in self.failed if c.kind == kind]
            if not failed:
                continue
            total = sum(c.kind == kind for c in self.checks)
            head = f"{_KIND_TITLE[kind]}: {len(failed)}" + (f" of {total}" if kind != QUALITY else "") + " failed"
            if kind != QUALITY:         # a quality failure's text is long: the worst line and the report give it
                names = [c.name for c in failed]
                head += ": " + ", ".join(names[:6]) + (f", ... ({len(names) - 6} more)" if len(names) > 6 else "")
            parts.append(head)
        return f"{FAIL} ({'; '.join(parts)})"

    def to_json(self) -> dict[str, Any]:
        worst = self.worst
        return {"verdict": self.outcome.lower(), "passed": self.passed, "failed": bool(self.failed),
                "headline": self.headline(), "worst": worst.labelled() if worst else None,
                "checks": [c.to_json() for c in self.checks]}

    def to_section(self) -> VerdictSection:
        """The verdict as a result holds it (what `to_json` writes)."""
        return VerdictSection.from_dict(self.to_json(), "verdict")


def stored_outcome(verdict: dict[str, Any]) -> str:
    """The outcome of a verdict as a result file stores it (`Verdict.to_json`), by the rule above whatever the
    file says: an older file's `PASS (no acceptance limits configured)` with no check is NOT CHECKED."""
    checks = [c for c in verdict.get("checks", []) if isinstance(c, dict)]
    if any(c.get("passed") is not True for c in checks):
        return FAIL
    return PASS if checks else NOT_CHECKED


def stored_headline(verdict: dict[str, Any]) -> str:
    """The headline of a stored verdict; one whose words disagree with `stored_outcome` (an older file's)
    is told by the rule (`NOT CHECKED (no check ran)`)."""
    outcome = stored_outcome(verdict)
    headline = verdict.get("headline")
    if isinstance(headline, str) and headline.split(" (")[0] == outcome:
        return headline
    n = len([c for c in verdict.get("checks", []) if isinstance(c, dict)])
    return f"{outcome} ({n} check{'s' if n != 1 else ''})" if n else f"{NOT_CHECKED} (no check ran)"


def max_check(name: str, value: float | None, limit: float, unit: str, note: str = "", signed: bool = False,
              kind: str = ACCEPTANCE) -> Check:
    """|value| <= limit (an unknown or not finite value fails)."""
    if value is None or not math.isfinite(value):
        return Check(name, None, limit, unit, False, math.inf, note or "unknown", signed, kind)
    ratio = abs(value) / limit if limit > 0 else (0.0 if value == 0 else math.inf)
    return Check(name, value, limit, unit, abs(value) <= limit, ratio, note, signed, kind)


def _range_check(name: str, value: float, low: float, high: float, unit: str) -> Check:
    middle, half = (low + high) / 2, (high - low) / 2
    ratio = abs(value - middle) / half if half > 0 else (0.0 if value == middle else math.inf)
    return Check(name, value, (low, high), unit, low <= value <= high, ratio)


def coefficient_checks(result: CalibrationResult, limits: AcceptanceLimits) -> list[Check]:
    """The checks of the coefficients' limits (a limited coefficient the result lacks fails)."""
    checks = []
    for name in canonical_names():
        family = family_of(name)
        lim = limits.for_coefficient(name, family)
        if lim.min is None and lim.max_sigma is None and lim.max_change is None:
            continue
        unit = RESULT_UNITS[family][0]
        c = result.coefficients.get(name)
        if c is None:
            checks.append(Check(f"{name}", None, None, unit, False, math.inf, "not in the result"))
            continue
        if lim.min is not None and lim.max is not None:     # the configuration gives both or neither
            checks.append(_range_check(f"{name} value", c.value, lim.min, lim.max, unit))
        if lim.max_sigma is not None:
            checks.append(max_check(f"{name} sigma", c.sigma, lim.max_sigma, unit))
        if lim.max_change is not None:
            reference = lim.nominal if lim.nominal is not None else limits.reference.get(name)
            if reference is None:
                checks.append(Check(f"{name} change", None, lim.max_change, unit, False, math.inf,
                                    f"not in the reference {limits.reference_name}".rstrip()))
            else:
                source = "nominal" if lim.nominal is not None else f"reference {limits.reference_name}"
                checks.append(max_check(f"{name} change", c.value - reference, lim.max_change, unit,
                                         f"from {source} {reference:.10g}", signed=True))
    return checks


def max_residual_sigma(result: CalibrationResult) -> float | None:
    """The largest |residual| / sigma of any position or rotation in the result (None: none recorded)."""
    values = []
    for kind in ("positions", "rotations"):
        rows = result.residuals.get(kind, []) if isinstance(result.residuals, dict) else []
        for row in rows if isinstance(rows, list) else []:
            if not isinstance(row, dict):
                continue
            for key in ("acc_normalized", "gyro_normalized"):
                for v in row.get(key) or []:
                    if isinstance(v, (int, float)) and math.isfinite(v):
                        values.append(abs(float(v)))
    return max(values) if values else None


def judge(result: CalibrationResult, limits: AcceptanceLimits, *, lost_samples: int | None = None,
          quality_failures: Sequence[str] = (), extra: Sequence[Check] = ()) -> Verdict:
    """The verdict of `result`: its coefficient limits, lost samples, residuals, the run's quality failures
    and `extra` checks (the verification's)."""
    checks = coefficient_checks(result, limits)
    if limits.max_lost_samples is not None:
        checks.append(max_check("lost samples", None if lost_samples is None else float(lost_samples),
                                 float(limits.max_lost_samples), "samples",
                                 "" if lost_samples is not None else "not known"))
    if limits.max_residual_sigma is not None:
        checks.append(max_check("residual", max_residual_sigma(result), limits.max_residual_sigma, "sigma",
                                 "largest |residual| / sigma"))
    checks += list(extra)
    checks += [Check("quality", None, None, "", False, math.inf, text, kind=QUALITY) for text in quality_failures]
    return Verdict(checks)


__all__ = ["ACCEPTANCE", "FAIL", "NOT_CHECKED", "PASS", "QUALITY", "VERIFICATION", "Check", "Verdict",
           "coefficient_checks", "judge", "max_check", "max_residual_sigma", "stored_headline", "stored_outcome"]
