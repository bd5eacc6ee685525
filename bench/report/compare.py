"""What the Markdown and HTML reports share: number formats, outliers, truth z, and comparing two results.

`compare_results(new, old)`: per coefficient old, new, change and change in sigma =
(new - old) / sqrt(s_new^2 + s_old^2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, TypeGuard

from bench.model.families import canonical_names
from bench.model.quality_section import FIT_NAMES
from bench.model.result import CalibrationResult

CHANGE_SIGMA = 3.0
#: Run fields a comparison lists when they differ.
COMPARED_RUN_FIELDS = ("run_id", "mode", "started_utc", "finished_utc", "software_version", "positions", "rotations",
                       "state", "log")


def fmt(x: float | None, digits: int = 8) -> str:
    """A number for a report cell; '-' for unknown (None, NaN, inf)."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{digits}g}"


_fmt = fmt


def _finite(x: Any) -> TypeGuard[float]:
    return isinstance(x, (int, float)) and math.isfinite(x)


# -- outliers -------------------------------------------------------------------------------

def fmt_list(values) -> str:
    """Numbers as `a, b, c` with 3 significant digits, `-` for none."""
    return "-" if not values else ", ".join(fmt(v, 3) for v in values)


def outlier_threshold(result: CalibrationResult) -> float:
    value = result.quality.outlier_sigma
    return float(value) if _finite(value) and value > 0 else 4.0


def row_outliers(result: CalibrationResult, kind: str, row: dict) -> list[tuple[str, float]]:
    """(sensor, residual/sigma) of a residual row's outliers; `kind` is 'position' or 'rotation'.

    Beyond the result's outlier threshold, or listed in `quality.outliers` (a result
    file may come from elsewhere: both sources count).
    """
    threshold = outlier_threshold(result)
    found: dict[str, float] = {}
    for key, sensor in (("acc_normalized", "acc"), ("gyro_normalized", "gyro")):
        for axis, v in zip("xyz", row.get(key) or []):
            if _finite(v) and abs(v) > threshold:
                found[f"{sensor}_{axis}"] = float(v)
    for o in result.quality.outliers or []:
        if o.step == kind and o.index == row.get("index"):
            found.setdefault(str(o.sensor), float(o.normalized) if _finite(o.normalized) else math.nan)
    return sorted(found.items())


def max_normalized(row: dict) -> float | None:
    values = [abs(v) for key in ("acc_normalized", "gyro_normalized") for v in (row.get(key) or []) if _finite(v)]
    return max(values) if values else None


def outlier_text(outliers: list[tuple[str, float]]) -> str:
    return ", ".join(f"{sensor} {fmt(v, 3)} sigma" for sensor, v in outliers)


# -- comparison with an earlier result -----------------------------------------------------

@dataclass(frozen=True)
class CoefficientChange:
    """One coefficient in two results; None where a result lacks it."""

    name: str
    unit: str
    old: float | None
    new: float | None
    old_sigma: float | None
    new_sigma: float | None

    @property
    def change(self) -> float | None:
        return None if self.old is None or self.new is None else self.new - self.old

    @property
    def sigma(self) -> float | None:
        """sqrt(s_new^2 + s_old^2); an unknown sigma counts as 0, both unknown gives None."""
        known = [s for s in (self.old_sigma, self.new_sigma) if _finite(s)]
        combined = math.sqrt(sum(s * s for s in known)) if known else 0.0
        return combined if combined > 0 else None

    @property
    def z(self) -> float | None:
        """The change in units of the combined sigma."""
        change, sigma = self.change, self.sigma
        return None if change is None or sigma is None else change / sigma


@dataclass
class Comparison:
    """A result against an earlier one (`against`)."""

    label: str                                   # what the earlier result is (its run id or file name)
    changes: list[CoefficientChange]
    threshold: float = CHANGE_SIGMA
    run_changes: list[tuple[str, Any, Any]] = field(default_factory=list)   # (field, old, new)
    notes: list[str] = field(default_factory=list)

    @property
    def flagged(self) -> list[CoefficientChange]:
        """Coefficients that moved by more than `threshold` sigma."""
        return [c for c in self.changes if c.z is not None and abs(c.z) > self.threshold]


def compare_results(new: CalibrationResult, old: CalibrationResult, threshold: float = CHANGE_SIGMA,
                    label: str | None = None) -> Comparison:
    """Per coefficient (canonical order, the union of both results) old, new, change and change in sigma."""

    def sig(c):
        return c.sigma if c is not None and _finite(c.sigma) else None

    changes = []
    for name in canonical_names():
        a, b = old.coefficients.get(name), new.coefficients.get(name)
        shown = b or a
        if shown is None:   # in neither result
            continue
        changes.append(CoefficientChange(name, shown.unit, a.value if a else None, b.value if b else None,
                                         sig(a), sig(b)))
    # a field one result does not record is no change (a re-solve records no finish; older results no start)
    run_changes = [(k, a, b) for k in COMPARED_RUN_FIELDS
                   if (a := getattr(old.run, k)) not in (None, "") and (b := getattr(new.run, k)) not in (None, "")
                   and a != b]
    notes = []
    for key in FIT_NAMES:
        qa, qb = old.quality.fit(key), new.quality.fit(key)
        chi2_a, chi2_b = (None if q is None else q.chi2_per_dof for q in (qa, qb))
        if chi2_a != chi2_b and (qa or qb):
            notes.append(f"{key} chi2/dof per axis: {fmt_list(chi2_a)} -> {fmt_list(chi2_b)}")
    na, nb = len(old.quality.outliers or []), len(new.quality.outliers or [])
    if na != nb:
        notes.append(f"residual outliers: {na} -> {nb}")
    missing = [c.name for c in changes if c.new is None]
    added = [c.name for c in changes if c.old is None]
    if missing:
        notes.append(f"only in the earlier result: {', '.join(missing)}")
    if added:
        notes.append(f"only in this result: {', '.join(added)}")
    return Comparison(label or str(old.run.run_id or "earlier result"), changes, threshold, run_changes, notes)


def truth_z(c, t) -> float | None:
    """(value - true) / sigma, None when either is unknown."""
    if t is None or not _finite(c.sigma) or c.sigma <= 0:
        return None
    return (c.value - t.value) / c.sigma
