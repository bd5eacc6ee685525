"""Reports of a calibration result: Markdown (`<run-id>.report.md`) and, via `bench.report.html`, HTML.

Shared here by both formats: outlier detection over the residual tables and the
comparison with an earlier result (`compare_results`: per coefficient old, new, change
and change in sigma = (new - old) / sqrt(s_new^2 + s_old^2)). `write_reports` writes both
files; `bench run` and `bench solve` call it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.model.result import CalibrationResult

#: |change| / sigma above which a coefficient counts as changed in a comparison.
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


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


# -- outliers -------------------------------------------------------------------------------

def outlier_threshold(result: CalibrationResult) -> float:
    value = result.quality.get("outlier_sigma", 4.0)
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
    for o in result.quality.get("outliers", []):
        if isinstance(o, dict) and o.get("step") == kind and o.get("index") == row.get("index"):
            found.setdefault(str(o.get("sensor")), float(o["normalized"]) if _finite(o.get("normalized")) else math.nan)
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
    from bench.model.families import canonical_names

    def sig(c):
        return c.sigma if c is not None and _finite(c.sigma) else None

    changes = []
    for name in canonical_names():
        a, b = old.coefficients.get(name), new.coefficients.get(name)
        if a is None and b is None:
            continue
        changes.append(CoefficientChange(name, (b or a).unit, a.value if a else None, b.value if b else None,
                                         sig(a), sig(b)))
    run_changes = [(k, old.run.get(k), new.run.get(k)) for k in COMPARED_RUN_FIELDS
                   if old.run.get(k) != new.run.get(k)]
    notes = []
    for key in ("accelerometers", "gyros", "gyro_bias"):
        qa, qb = old.quality.get(key) or {}, new.quality.get(key) or {}
        if qa.get("chi2_per_dof") != qb.get("chi2_per_dof") and (qa or qb):
            notes.append(f"{key} chi2/dof per axis: {_list(qa.get('chi2_per_dof'))} -> {_list(qb.get('chi2_per_dof'))}")
    na, nb = len(old.quality.get("outliers", [])), len(new.quality.get("outliers", []))
    if na != nb:
        notes.append(f"residual outliers: {na} -> {nb}")
    missing = [c.name for c in changes if c.new is None]
    added = [c.name for c in changes if c.old is None]
    if missing:
        notes.append(f"only in the earlier result: {', '.join(missing)}")
    if added:
        notes.append(f"only in this result: {', '.join(added)}")
    return Comparison(label or str(old.run.get("run_id") or "earlier result"), changes, threshold, run_changes, notes)


def _list(values) -> str:
    return "-" if not values else ", ".join(fmt(v, 3) for v in values)


# -- Markdown -------------------------------------------------------------------------------

def markdown_report(result: CalibrationResult, *, problems: list[str] = (), failures: list[str] = (),
                    imu_link: dict[str, Any] | None = None, title: str = "Calibration report",
                    against: CalibrationResult | None = None, against_label: str | None = None) -> str:
    """Run metadata, verdict, coefficients (with the truth for a simulated run), quality, residuals
    with outliers flagged, and the comparison with `against` (an earlier result) when given."""
    run = result.run
    lines = [f"# {title}", ""]
    for key in ("run_id", "mode", "operator", "started_utc", "finished_utc", "state", "software_version",
                "positions", "rotations", "log"):
        if run.get(key) not in (None, ""):
            lines.append(f"- **{key.replace('_', ' ')}**: {run[key]}")
    lines.append("")
    lines.append("## Verdict")
    lines.append("")
    if failures:
        lines.append("Quality check **failed**:")
        lines += [f"- {f}" for f in failures]
    else:
        lines.append("Quality checks passed.")
    lines.append("")
    truth = result.sim_truth
    lines.append("## Coefficients")
    lines.append("")
    if truth:
        lines.append("| name | value | 1-sigma | unit | true | error / sigma |")
        lines.append("|---|---|---|---|---|---|")
    else:
        lines.append("| name | value | 1-sigma | unit |")
        lines.append("|---|---|---|---|")
    for name, c in result.coefficients.items():
        row = f"| {name} | {fmt(c.value, 10)} | {fmt(c.sigma, 3)} | {c.unit} |"
        if truth:
            t = truth.get(name)
            row += f" {fmt(t.value if t else None, 10)} | {fmt(truth_z(c, t), 3)} |"
        lines.append(row)
    lines.append("")
    lines.append("## Quality")
    lines.append("")
    flags = result.quality.get("flags", [])
    lines += [f"- {f}" for f in flags] or ["- no solver flags"]
    for key in ("accelerometers", "gyros", "gyro_bias"):
        q = result.quality.get(key)
        if q:
            lines.append(f"- {key}: chi2/dof per axis {_list(q.get('chi2_per_dof', []))}")
    outliers = result.quality.get("outliers", [])
    lines.append(f"- outliers beyond {result.quality.get('outlier_sigma', 4)} sigma: {len(outliers)}")
    for o in outliers:
        lines.append(f"  - {o['step']} {o['index']} {o['sensor']}: {fmt(o['normalized'], 3)} sigma")
    if problems:
        lines.append("")
        lines.append("Steps left out or degraded:")
        lines += [f"- {p}" for p in problems]
    if imu_link:
        lines.append("")
        lines.append("IMU link: " + ", ".join(f"{k} {v}" for k, v in imu_link.items()))
    lines.append("")
    lines += _markdown_residuals(result)
    if against is not None:
        lines += _markdown_comparison(compare_results(result, against, label=against_label))
    return "\n".join(lines) + "\n"


def truth_z(c, t) -> float | None:
    """(value - true) / sigma, None when either is unknown."""
    if t is None or not _finite(c.sigma) or c.sigma <= 0:
        return None
    return (c.value - t.value) / c.sigma


def _markdown_residuals(result: CalibrationResult) -> list[str]:
    lines = ["## Residuals", ""]
    threshold = outlier_threshold(result)
    positions = result.residuals.get("positions", [])
    rotations = result.residuals.get("rotations", [])
    if positions or rotations:
        lines.append(f"Outliers (|residual| / sigma > {threshold:g}, or listed by the solver) are marked "
                     "**OUTLIER**.")
        lines.append("")
    if positions:
        lines.append("| position | angles deg | acc counts/s (x, y, z) | gyro deg/h (x, y, z) | max abs r/sigma "
                     "| flag |")
        lines.append("|---|---|---|---|---|---|")
        for row in positions:
            acc = ", ".join(fmt(v, 3) for v in row.get("acc_counts_per_s", []))
            gyro = ", ".join(fmt(v, 3) for v in row.get("gyro_dph", []))
            flag = row_outliers(result, "position", row)
            label = f"**{row['label']}**" if flag else row["label"]
            lines.append(f"| {label} | {row['angles_deg']} | {acc} | {gyro} | {fmt(max_normalized(row), 3)} | "
                         f"{'**OUTLIER** ' + outlier_text(flag) if flag else ''} |")
        lines.append("")
    if rotations:
        lines.append("| rotation | start deg | turn | gyro arcsec (x, y, z) | max abs r/sigma | flag |")
        lines.append("|---|---|---|---|---|---|")
        for row in rotations:
            arcsec = ", ".join(fmt(v, 3) for v in row.get("gyro_arcsec", []))
            flag = row_outliers(result, "rotation", row)
            label = f"**{row['label']}**" if flag else row["label"]
            lines.append(f"| {label} | {row['start_deg']} | {row['frame']} {row['direction']} "
                         f"x{row['revolutions']} | {arcsec} | {fmt(max_normalized(row), 3)} | "
                         f"{'**OUTLIER** ' + outlier_text(flag) if flag else ''} |")
        lines.append("")
    return lines


def _markdown_comparison(comparison: Comparison) -> list[str]:
    flagged = comparison.flagged
    lines = [f"## Comparison with {comparison.label}", ""]
    if flagged:
        lines.append(f"**{len(flagged)} coefficient(s) changed by more than {comparison.threshold:g} sigma**: "
                     + ", ".join(f"{c.name} ({fmt(c.z, 3)} sigma)" for c in flagged))
    else:
        lines.append(f"No coefficient changed by more than {comparison.threshold:g} sigma.")
    lines.append("")
    lines.append("change / sigma = (new - old) / sqrt(sigma_new^2 + sigma_old^2)")
    lines.append("")
    if comparison.run_changes:
        lines += [f"- {k.replace('_', ' ')}: {old if old not in (None, '') else '-'} -> "
                  f"{new if new not in (None, '') else '-'}" for k, old, new in comparison.run_changes]
    lines += [f"- {n}" for n in comparison.notes]
    if comparison.run_changes or comparison.notes:
        lines.append("")
    lines.append("| name | old | new | change | unit | change / sigma | flag |")
    lines.append("|---|---|---|---|---|---|---|")
    for c in comparison.changes:
        big = c.z is not None and abs(c.z) > comparison.threshold
        lines.append(f"| {c.name} | {fmt(c.old, 10)} | {fmt(c.new, 10)} | {fmt(c.change, 3)} | {c.unit} | "
                     f"{fmt(c.z, 3)} | {'**CHANGED**' if big else ''} |")
    lines.append("")
    return lines


# -- both files -------------------------------------------------------------------------------

def write_reports(result: CalibrationResult, out_dir: str | Path, run_id: str, *, log=None, layout=None,
                  problems: list[str] = (), failures: list[str] = (), imu_link: dict[str, Any] | None = None,
                  against: CalibrationResult | None = None, against_label: str | None = None,
                  title: str | None = None, log_still_open: bool = False) -> tuple[Path, Path]:
    """Write `<run-id>.report.md` and the self-contained `<run-id>.report.html` into `out_dir`.

    `log` (a `bench.log.reader.RunLog`) adds the time-series plots to the HTML report;
    `layout` (an `ImuLayout`) decodes its CAN frames (default: the DBC attached to the
    log). `log_still_open`: the log is the live run's, not closed yet (its missing
    summary is not damage). `against` is an earlier result to compare with.
    Returns (md_path, html_path).
    """
    from bench.report.html import html_report

    out_dir = Path(out_dir)
    title = title or f"Calibration report {run_id}"
    md_path, html_path = out_dir / f"{run_id}.report.md", out_dir / f"{run_id}.report.html"
    md_path.write_text(markdown_report(result, problems=problems, failures=failures, imu_link=imu_link, title=title,
                                       against=against, against_label=against_label), encoding="utf-8")
    html_path.write_text(html_report(result, log=log, layout=layout, problems=problems, failures=failures,
                                     imu_link=imu_link, against=against, against_label=against_label, title=title,
                                     log_still_open=log_still_open),
                         encoding="utf-8")
    return md_path, html_path
