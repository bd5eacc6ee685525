"""The Markdown report of a calibration result (`<run-id>.report.md`)."""

from __future__ import annotations

import math
from typing import Any

from bench.result import CalibrationResult


def _fmt(x: float | None, digits: int = 8) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{digits}g}"


def markdown_report(result: CalibrationResult, *, problems: list[str] = (), failures: list[str] = (),
                    imu_link: dict[str, Any] | None = None, title: str = "Calibration report") -> str:
    """Run metadata, the coefficient table (with the truth for a simulated run), quality and residuals."""
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
        row = f"| {name} | {_fmt(c.value, 10)} | {_fmt(c.sigma, 3)} | {c.unit} |"
        if truth:
            t = truth.get(name)
            z = (c.value - t.value) / c.sigma if t and c.sigma and math.isfinite(c.sigma) and c.sigma > 0 else None
            row += f" {_fmt(t.value if t else None, 10)} | {_fmt(z, 3)} |"
        lines.append(row)
    lines.append("")
    lines.append("## Quality")
    lines.append("")
    flags = result.quality.get("flags", [])
    lines += [f"- {f}" for f in flags] or ["- no solver flags"]
    for key in ("accelerometers", "gyros", "gyro_bias"):
        q = result.quality.get(key)
        if q:
            chi2 = ", ".join(_fmt(v, 3) for v in q.get("chi2_per_dof", []))
            lines.append(f"- {key}: chi2/dof per axis {chi2}")
    outliers = result.quality.get("outliers", [])
    lines.append(f"- outliers beyond {result.quality.get('outlier_sigma', 4)} sigma: {len(outliers)}")
    for o in outliers:
        lines.append(f"  - {o['step']} {o['index']} {o['sensor']}: {_fmt(o['normalized'], 3)} sigma")
    if problems:
        lines.append("")
        lines.append("Steps left out or degraded:")
        lines += [f"- {p}" for p in problems]
    if imu_link:
        lines.append("")
        lines.append("IMU link: " + ", ".join(f"{k} {v}" for k, v in imu_link.items()))
    lines.append("")
    lines.append("## Residuals")
    lines.append("")
    positions = result.residuals.get("positions", [])
    if positions:
        lines.append("| position | angles deg | acc counts/s (x, y, z) | gyro deg/h (x, y, z) |")
        lines.append("|---|---|---|---|")
        for row in positions:
            acc = ", ".join(_fmt(v, 3) for v in row.get("acc_counts_per_s", []))
            gyro = ", ".join(_fmt(v, 3) for v in row.get("gyro_dph", []))
            lines.append(f"| {row['label']} | {row['angles_deg']} | {acc} | {gyro} |")
        lines.append("")
    rotations = result.residuals.get("rotations", [])
    if rotations:
        lines.append("| rotation | start deg | turn | gyro arcsec (x, y, z) |")
        lines.append("|---|---|---|---|")
        for row in rotations:
            arcsec = ", ".join(_fmt(v, 3) for v in row.get("gyro_arcsec", []))
            lines.append(f"| {row['label']} | {row['start_deg']} | {row['frame']} {row['direction']} "
                         f"x{row['revolutions']} | {arcsec} |")
        lines.append("")
    return "\n".join(lines) + "\n"
