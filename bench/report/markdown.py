"""Reports of a calibration result: Markdown (`<run-id>.report.md`) and, via `bench.report.html`, HTML.

What both formats share (outliers, the comparison with an earlier result) is in
`bench.report.compare`. `write_reports` writes both files; `bench run` and `bench solve`
call it.

Text taken from a log, a configuration or a result file (operator, IMU model and serial,
unit labels, problems, notes, ...) goes into the Markdown through `md_text`: many viewers
render Markdown as HTML, so it is escaped as the HTML report escapes it, and Markdown's
own markup (links, emphasis, table bars, a leading heading or list mark) is escaped too.
"""

from __future__ import annotations

import re
from html import escape
from pathlib import Path
from typing import Any, Sequence

from bench.files import write_output_text
from bench.log.names import output_path
from bench.model.quality_section import FIT_NAMES
from bench.model.result import CalibrationResult
from bench.model.verdict_section import VerdictSection
from bench.report.compare import (
    Comparison,
    compare_results,
    fmt,
    fmt_list,
    max_normalized,
    outlier_text,
    outlier_threshold,
    row_outliers,
    truth_z,
)
from bench.report.facts import (
    SAMPLE_NOISE_NOTE,
    budget_notes,
    budget_table,
    consistency_lines,
    lost_samples_note,
    quality_findings,
    run_facts,
    verdict_view,
)
from bench.report.html import html_report
from bench.report.significance import COEFFICIENT_HEADER, FAMILY_HEADER, significance_table

_CONTROL = re.compile(r"[\x00-\x1f\x7f]+")
_MARKUP = re.compile(r"([\\`*\[\]|])")
_EMPHASIS_UNDERSCORE = re.compile(r"(?<![A-Za-z0-9])_|_(?![A-Za-z0-9])")


def md_text(value: object) -> str:
    """`value` as inert Markdown text on one line: HTML escaped (`<`, `>`, `&`), control characters
    as spaces, Markdown markup backslash-escaped (backslash, backquote, `*`, `[`, `]`, `|`, an
    underscore that could start or end emphasis, a leading `#`, `-` or `+`)."""
    text = escape(_CONTROL.sub(" ", str(value)), quote=False)
    text = _EMPHASIS_UNDERSCORE.sub(r"\\_", _MARKUP.sub(r"\\\1", text))
    return "\\" + text if text[:1] in ("#", "-", "+") else text


# -- Markdown -------------------------------------------------------------------------------

def markdown_report(result: CalibrationResult, *, problems: Sequence[str] = (), failures: Sequence[str] = (),
                    imu_link: dict[str, Any] | None = None, title: str = "Calibration report",
                    against: CalibrationResult | None = None, against_label: str | None = None) -> str:
    """Run metadata, verdict, coefficients (with the truth for a simulated run), quality, residuals
    with outliers flagged, and the comparison with `against` (an earlier result) when given."""
    run = result.run
    lines = [f"# {md_text(title)}", ""]
    lines += _markdown_verdict(result.verdict)
    lines += [f"- **{label}**: {md_text(text)}" for label, text in run_facts(run)]
    lines.append("")
    lines.append("## Quality checks")
    lines.append("")
    if failures:
        lines.append("Quality check **failed**:")
        lines += [f"- {md_text(f)}" for f in quality_findings(result.verdict, list(failures))]
    else:
        lines.append("No quality check failed (they can fail a result, not pass it: the verdict above says "
                     "whether it was checked)." if result.verdict is not None else "No quality check failed.")
    note = lost_samples_note(run)
    if note:
        lines += ["", f"Note: {md_text(note)}."]
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
    lines += _markdown_budget(result)
    lines += _markdown_significance(result)
    lines.append("## Quality")
    lines.append("")
    quality = result.quality
    lines += [f"- {f}" for f in quality.flags or []] or ["- no solver flags"]
    budget_lines = consistency_lines(result)
    noise_alone = False     # a chi2/dof against the sample noise alone is written
    for key in FIT_NAMES:
        fit = quality.fit(key)
        if fit is not None and fit.to_dict():
            versus = " against the sample noise alone" if budget_lines is not None else ""
            noise_alone = True
            lines.append(f"- {key}: chi2/dof per axis{versus} {fmt_list(fit.chi2_per_dof or [])}")
    lines += [f"- {SAMPLE_NOISE_NOTE}"] if budget_lines and noise_alone else []
    lines += [f"- {md_text(line)}" for line in budget_lines or []]
    outliers = quality.outliers or []
    sigma = quality.outlier_sigma if quality.outlier_sigma is not None else 4
    lines.append(f"- outliers beyond {sigma} sigma: {len(outliers)}")
    for o in outliers:
        lines.append(f"  - {md_text(o.step)} {md_text(o.index)} {md_text(o.sensor)}: "
                     f"{fmt(o.normalized, 3)} sigma")
    if problems:
        lines.append("")
        lines.append("Steps left out or degraded:")
        lines += [f"- {md_text(p)}" for p in problems]
    if imu_link:
        lines.append("")
        lines.append("IMU link: " + md_text(", ".join(f"{k} {v}" for k, v in imu_link.items())))
    lines.append("")
    lines += _markdown_residuals(result)
    if against is not None:
        lines += _markdown_comparison(compare_results(result, against, label=against_label))
    return "\n".join(lines) + "\n"


def _markdown_budget(result: CalibrationResult) -> list[str]:
    lines = ["## Uncertainty budget", ""]
    lines += [md_text(n) for n in budget_notes(result)]
    titles, rows, names = budget_table(result)
    if titles:
        lines += ["", "| name | " + " | ".join(titles) + " |", "|---" * (len(titles) + 1) + "|"]
        lines += [f"| {name} | " + " | ".join(fmt(v, 3) for v in row) + " |" for name, row in zip(names, rows)]
    lines.append("")
    return lines


def _markdown_significance(result: CalibrationResult) -> list[str]:
    table = significance_table(result)
    if table is None:
        return []
    lines = ["## Extended model: significance", "", md_text(table.note), ""]
    for header, rows in ((COEFFICIENT_HEADER, table.coefficients), (FAMILY_HEADER, table.families)):
        if rows:
            lines += ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
            lines += ["| " + " | ".join(row) + " |" for row in rows]     # names, numbers and units of our own
            lines.append("")
    if table.left_out:
        lines += ["Families not in the model:", ""] + [f"- {md_text(line)}" for line in table.left_out] + [""]
    return lines


def _markdown_verdict(verdict: VerdictSection | None) -> list[str]:
    """The verdict, first in the report: headline, worst check, every check with its kind."""
    view = verdict_view(verdict)
    if view is None:
        return []
    lines = [f"**Verdict: {md_text(view.headline)}**", ""]
    if view.worst:
        lines += [f"Worst check: {md_text(view.worst)}", ""]
    if view.checks:
        lines += ["| kind | check | result |", "|---|---|---|"]
        lines += [f"| {kind} | {md_text(text)} | {'pass' if passed else '**FAIL**'} |"
                  for kind, text, passed in view.checks]
        lines.append("")
    return lines


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
            label = f"**{md_text(row['label'])}**" if flag else md_text(row["label"])
            lines.append(f"| {label} | {row['angles_deg']} | {acc} | {gyro} | {fmt(max_normalized(row), 3)} | "
                         f"{'**OUTLIER** ' + outlier_text(flag) if flag else ''} |")
        lines.append("")
    if rotations:
        lines.append("| rotation | start deg | turn | gyro arcsec (x, y, z) | max abs r/sigma | flag |")
        lines.append("|---|---|---|---|---|---|")
        for row in rotations:
            arcsec = ", ".join(fmt(v, 3) for v in row.get("gyro_arcsec", []))
            flag = row_outliers(result, "rotation", row)
            label = f"**{md_text(row['label'])}**" if flag else md_text(row["label"])
            lines.append(f"| {label} | {row['start_deg']} | {row['frame']} {row['direction']} "
                         f"x{row['revolutions']} | {arcsec} | {fmt(max_normalized(row), 3)} | "
                         f"{'**OUTLIER** ' + outlier_text(flag) if flag else ''} |")
        lines.append("")
    return lines


def _markdown_comparison(comparison: Comparison) -> list[str]:
    flagged = comparison.flagged
    lines = [f"## Comparison with {md_text(comparison.label)}", ""]
    if flagged:
        lines.append(f"**{len(flagged)} coefficient(s) changed by more than {comparison.threshold:g} sigma**: "
                     + ", ".join(f"{c.name} ({fmt(c.z, 3)} sigma)" for c in flagged))
    else:
        lines.append(f"No coefficient changed by more than {comparison.threshold:g} sigma.")
    lines.append("")
    lines.append("change / sigma = (new - old) / sqrt(sigma_new^2 + sigma_old^2)")
    lines.append("")
    if comparison.run_changes:
        lines += [f"- {k.replace('_', ' ')}: {md_text(old) if old not in (None, '') else '-'} -> "
                  f"{md_text(new) if new not in (None, '') else '-'}" for k, old, new in comparison.run_changes]
    lines += [f"- {md_text(n)}" for n in comparison.notes]
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
                  problems: Sequence[str] = (), failures: Sequence[str] = (), imu_link: dict[str, Any] | None = None,
                  against: CalibrationResult | None = None, against_label: str | None = None,
                  title: str | None = None, log_still_open: bool = False) -> tuple[Path, Path]:
    """Write `<run-id>.report.md` and the self-contained `<run-id>.report.html` into `out_dir`.

    `log` (a `bench.log.reader.RunLog`) adds the time-series plots to the HTML report;
    `layout` (an `ImuLayout`) decodes its CAN frames (default: the DBC attached to the
    log). `log_still_open`: the log is the live run's, not closed yet (its missing
    summary is not damage). `against` is an earlier result to compare with.
    Returns (md_path, html_path).
    """

    out_dir = Path(out_dir)
    title = title or f"Calibration report {run_id}"
    # never a path out of out_dir, whatever the run id
    md_path, html_path = output_path(out_dir, f"{run_id}.report.md"), output_path(out_dir, f"{run_id}.report.html")
    # each written under a temporary name and renamed: an interrupted write leaves no half report
    write_output_text(md_path, markdown_report(result, problems=problems, failures=failures, imu_link=imu_link,
                                               title=title, against=against, against_label=against_label))
    write_output_text(html_path, html_report(result, log=log, layout=layout, problems=problems, failures=failures,
                                             imu_link=imu_link, against=against, against_label=against_label,
                                             title=title, log_still_open=log_still_open))
    return md_path, html_path
