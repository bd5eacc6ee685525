"""The self-contained HTML report (`<run-id>.report.html`): one file, CSS inline, plots as inline SVG.

Nothing in the page is fetched: no scripts, no style sheets, no images by URL, no
namespace URLs either (see `bench.report.plots`). Sections: run metadata, verdict, the
coefficient table (value, 1-sigma, unit; truth and error/sigma for a simulated run),
quality, residuals per position and per rotation with outliers highlighted, plots from
the run log when given (mean output per dwell, accelerometer and gyro time series,
table angles), and the comparison with an earlier result when given.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from html import escape
from typing import Any, Collection

import numpy as np

from bench import __version__
from bench.acceptance.verdict import FAIL, NOT_CHECKED, PASS
from bench.log.events import TurnRecord, finished_observation_steps
from bench.model.quality_section import FIT_NAMES
from bench.model.result import CalibrationResult
from bench.report.compare import (
    Comparison,
    compare_results,
    fmt,
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
from bench.report.significance import COEFFICIENT_HEADER, FAMILY_HEADER, significance_table
from drivers.errors import DeviceError
from drivers.imu import ImuLayout, spec_of

CSS = """
body { font-family: system-ui, -apple-system, 'Segoe UI', Roboto, sans-serif; margin: 1.5em auto; max-width: 72em;
       padding: 0 1em; color: #1a1a1a; line-height: 1.4; }
h1 { font-size: 1.6em; border-bottom: 2px solid #444; padding-bottom: .2em; }
h2 { font-size: 1.25em; margin-top: 1.8em; border-bottom: 1px solid #bbb; }
table { border-collapse: collapse; margin: .6em 0; font-size: .9em; }
th, td { border: 1px solid #ccc; padding: .2em .5em; text-align: left; vertical-align: top; }
th { background: #f0f0f0; }
td.num { text-align: right; font-family: ui-monospace, 'DejaVu Sans Mono', monospace; white-space: nowrap; }
tr.outlier td, tr.changed td { background: #fde2e2; }
.flag { color: #b00000; font-weight: bold; }
.pass { color: #17692b; font-weight: bold; }
.fail { color: #b00000; font-weight: bold; }
.notchecked { color: #6b5200; font-weight: bold; }
figure { margin: 1em 0; }
figure svg { max-width: 100%; height: auto; }
figcaption { font-size: .85em; color: #555; }
.note { color: #555; font-size: .9em; }
"""


# -- what the log contributes ------------------------------------------------------------------

@dataclass
class LogSeries:
    """The log's data for the plots, times relative to the run's first record."""

    t0_s: float
    spans: list[tuple[float, float, str]] = field(default_factory=list)   # (start, end, "dwell"|"turn")
    dwell_labels: list[str] = field(default_factory=list)
    acc_mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    acc_std: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    gyro_mean: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    gyro_std: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    sample_t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    acc_rate: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))    # counts/s
    gyro_rate: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))   # counts/s
    state_t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    angles_deg: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    notes: list[str] = field(default_factory=list)


def log_layout(log):
    """The IMU frame layout a log was recorded with: its attached DBC and its configuration's [imu] signals.

    Raises ValueError (or `ImuConfigError`) when the log does not say.
    """

    imu_meta = log.metadata.get("imu", {})
    toml = log.metadata.get("config", {}).get("toml")
    if toml is None:
        raise ValueError("the log has no configuration metadata")
    imu = tomllib.loads(toml).get("imu", {})
    spec = spec_of(imu)
    dbc = log.attachments.get(imu_meta.get("dbc", ""))
    if dbc is None:
        raise ValueError(f"the log has no attachment with its DBC file {imu_meta.get('dbc')!r}")
    return ImuLayout.from_dbc_string(dbc[1].decode("utf-8", "replace"), spec, source=imu_meta.get("dbc"))


def _log_samples(log, layout, rate_hz: float, notes: list[str]):
    """(receive times, counters, acc counts/s, gyro counts/s) from the raw CAN frames, else the decoded topic."""

    try:
        block, _ = log.imu_samples(layout if layout is not None else log_layout(log), rate_hz)
        return block.receive_time_s, block.counter, block.acc_rate, block.gyro_rate
    except (DeviceError, ValueError, tomllib.TOMLDecodeError) as exc:
        notes.append(f"raw CAN frames not decoded ({exc}); plots use the recorded /imu/samples topic")
    records = log.read_imu_records()
    return records.receive_time_s, records.counter, records.acc_counts * rate_hz, records.gyro_counts * rate_hz


def log_series(log, layout=None) -> LogSeries:
    """Everything the plots need from a `RunLog` (decoding its CAN frames with `layout` or its own DBC)."""

    notes: list[str] = []
    try:
        rate_hz = float(log.metadata.get("imu", {}).get("rate_hz", "nan"))
    except ValueError:
        rate_hz = math.nan
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        return LogSeries(0.0, notes=["the log does not say the IMU rate: no IMU plots"])
    t, counter, acc, gyro = _log_samples(log, layout, rate_hz, notes)
    states = log.read_table_states()
    starts = [x[0] for x in (t, states.time_s) if len(x)] + ([log.events[0].time_s] if log.events else [])
    t0 = float(np.nanmin(starts)) if starts else 0.0
    series = LogSeries(t0, sample_t_s=t - t0, acc_rate=acc, gyro_rate=gyro, state_t_s=states.time_s - t0,
                       angles_deg=states.angles_deg, notes=notes)
    labels, means, stds = [], [], []
    for unit, (started, finished) in sorted(finished_observation_steps(log.events).items()):
        kind = "turn" if isinstance(finished.record, TurnRecord) else "dwell"
        counters = finished.window
        assert counters is not None                  # a finished observation step has one
        if started is not None:
            series.spans.append((started.time_s - t0, finished.time_s - t0, kind))
        if kind != "dwell":
            continue
        lo, hi = np.searchsorted(counter, [counters.first, counters.last + 1])
        if hi - lo < 2:
            notes.append(f"{unit}: fewer than 2 samples in its window, not plotted")
            continue
        window = np.hstack([acc[lo:hi], gyro[lo:hi]])
        labels.append(unit)
        means.append(window.mean(axis=0))
        stds.append(window.std(axis=0, ddof=1))
    if labels:
        m, s = np.array(means), np.array(stds)
        series.dwell_labels = labels
        series.acc_mean, series.gyro_mean, series.acc_std, series.gyro_std = m[:, :3], m[:, 3:], s[:, :3], s[:, 3:]
    return series


# -- HTML pieces ---------------------------------------------------------------------------

def _e(x: Any) -> str:
    return escape(str(x), quote=True)


def _table(header: list[str], rows: list[tuple[list[str], str]], numeric: Collection[int] = frozenset(),
           row_ids: list[str] | None = None) -> str:
    """`rows`: (already escaped cells, css class). Columns in `numeric` are right-aligned."""
    out = ["<table>", "<thead><tr>" + "".join(f"<th>{_e(h)}</th>" for h in header) + "</tr></thead>", "<tbody>"]
    for k, (cells, css) in enumerate(rows):
        attrs = (f' id="{_e(row_ids[k])}"' if row_ids else "") + (f' class="{css}"' if css else "")
        out.append(f"<tr{attrs}>" + "".join(f'<td class="num">{c}</td>' if i in numeric else f"<td>{c}</td>"
                                            for i, c in enumerate(cells)) + "</tr>")
    out += ["</tbody>", "</table>"]
    return "\n".join(out)


def _figure(svg: str | None, caption: str) -> str:
    if svg is None:
        return ""
    return f'<figure>\n{svg}\n<figcaption>{_e(caption)}</figcaption>\n</figure>'


def _plot(what: str, caption: str, draw, *args) -> str:
    """The figure `draw(*args)` with its caption; where it cannot be drawn from the data (a log from
    outside may hold anything, e.g. angles of 1e308: `plots.PlotError`, or what matplotlib raises on
    such data), a note in its place that says which figure is missing and why."""
    try:
        svg = draw(*args)
    except (ValueError, OverflowError, FloatingPointError) as exc:   # PlotError is a ValueError
        return f'<p class="fail">The figure of {_e(what)} is not drawn: {_e(exc)}.</p>'
    return _figure(svg, caption)


def log_damage(log, still_open: bool = False) -> list[str]:
    """What the log lost; a log still being written (`still_open`) lacks its summary by design."""
    scan = log.scan()
    expected = {d.describe() for d in scan.lost if d.kind == "no_summary"} if still_open else set()
    return [d for d in scan.damage if d not in expected]


def _metadata(result: CalibrationResult, log, imu_link, log_still_open: bool) -> str:
    run = result.run
    rows = [([_e(label), _e(text)], "") for label, text in run_facts(run)]
    if imu_link:
        rows.append(([_e("IMU link"), _e(", ".join(f"{k} {v}" for k, v in imu_link.items()))], ""))
    if log is not None:
        plan = log.metadata.get("plan", {})
        if plan.get("estimated_total_s"):
            rows.append(([_e("plan estimate"), _e(f"{plan['estimated_total_s']} s, order {plan.get('order', '-')}")],
                         ""))
        cfg = log.metadata.get("config", {})
        if cfg.get("path"):
            rows.append(([_e("configuration"), _e(cfg["path"])], ""))
        rows.append(([_e("log file"), _e(f"{log.path}: {log.scan().can_frame_count} CAN frames, "
                                            f"{len(log.read_table_states())} table states, {len(log.events)} events, "
                                            f"{log.chunks} chunks")], ""))
    damage = log_damage(log, log_still_open) if log is not None else []
    html = ["<h2>Run</h2>", _table(["field", "value"], rows)]
    if damage:
        html.append('<p class="fail">The log is damaged; what was lost:</p><ul>'
                    + "".join(f"<li>{_e(d)}</li>" for d in damage) + "</ul>")
    return "\n".join(html)


#: the CSS class of each outcome: green only for a PASS
_OUTCOME_CLASS = {PASS: "pass", FAIL: "fail", NOT_CHECKED: "notchecked"}


def _acceptance(verdict) -> str:
    """The verdict, first in the report: PASS, FAIL or NOT CHECKED, headline, worst check, every check."""
    view = verdict_view(verdict)
    if view is None:
        return ""
    html = [f'<h2>Verdict: <span class="{_OUTCOME_CLASS[view.outcome]}">{_e(view.outcome)}</span></h2>',
            f"<p>{_e(view.headline)}</p>"]
    if view.worst:
        html.append(f"<p>Worst check: {_e(view.worst)}</p>")
    if view.checks:
        html.append(_table(["kind", "check", "result"], [
            ([_e(kind), _e(text), "pass" if passed else "FAIL"], "" if passed else "fail")
            for kind, text, passed in view.checks]))
    return "\n".join(html)


def _verdict(verdict, failures, problems, note: str | None = None) -> str:
    """The run's quality checks (each failure is a failed check of the verdict, unless a limit judges it), and
    `note` (`lost_samples_note`)."""
    html = ["<h2>Quality checks</h2>"]
    if failures:
        html.append('<p class="fail">Quality check failed:</p><ul>'
                    + "".join(f"<li>{_e(f)}</li>" for f in quality_findings(verdict, failures)) + "</ul>")
    else:
        html.append("<p>No quality check failed (they can fail a result, not pass it: the verdict above says whether "
                    "it was checked).</p>" if verdict is not None else "<p>No quality check failed.</p>")
    if note:
        html.append(f"<p>Note: {_e(note)}.</p>")
    if problems:
        html.append("<p>Steps left out or degraded:</p><ul>" + "".join(f"<li>{_e(p)}</li>" for p in problems)
                    + "</ul>")
    return "\n".join(html)


def _coefficients(result: CalibrationResult) -> str:
    from bench.report import plots  # matplotlib: loaded only when a report draws

    truth = result.sim_truth
    header = ["name", "value", "1-sigma", "unit"] + (["true", "error / sigma"] if truth else [])
    rows, ids, names, zs = [], [], [], []
    for name, c in result.coefficients.items():
        cells = [_e(name), _e(fmt(c.value, 10)), _e(fmt(c.sigma, 3)), _e(c.unit)]
        css = ""
        if truth:
            t = truth.get(name)
            z = truth_z(c, t)
            cells += [_e(fmt(t.value if t else None, 10)), _e(fmt(z, 3))]
            names.append(name)
            zs.append(z)
            css = "outlier" if z is not None and abs(z) > 3 else ""
        rows.append((cells, css))
        ids.append(f"coef-{name}")
    numeric = {1, 2} | ({4, 5} if truth else set())
    html = ["<h2>Coefficients</h2>", _table(header, rows, numeric, ids)]
    if truth and names:
        html.append(_plot("the errors against the simulated truth",
                          "Simulated run: each coefficient's error against the simulator's true value, in units "
                          "of its 1-sigma (red beyond 3 sigma).",
                          plots.sigma_bars_figure, names, zs, 3.0, "error / sigma against the simulated truth"))
    return "\n".join(html)


def _budget(result: CalibrationResult) -> str:
    html = ["<h2>Uncertainty budget</h2>"]
    for note in budget_notes(result):
        css = "flag" if note.startswith(("WARNING", "Residuals")) else "note"
        html.append(f'<p class="{css}">{_e(note)}</p>')
    titles, rows, names = budget_table(result)
    if titles:
        html.append(_table(["name"] + titles, [([_e(n)] + [_e(fmt(v, 3)) for v in row], "")
                                               for n, row in zip(names, rows)], set(range(1, len(titles) + 1))))
    significance = significance_table(result)
    if significance is not None:
        html += ["<h2>Extended model: significance</h2>", f'<p class="note">{_e(significance.note)}</p>']
        for header, table_rows, numeric in ((COEFFICIENT_HEADER, significance.coefficients, {2, 3, 4, 6}),
                                            (FAMILY_HEADER, significance.families, {1, 2, 3})):
            if table_rows:
                html.append(_table(header, [([_e(c) for c in row], "") for row in table_rows], numeric))
        html += [f'<p class="note">{_e(line)}</p>' for line in significance.left_out]
    return "\n".join(html)


def _quality(result: CalibrationResult) -> str:
    q = result.quality
    items = [_e(f) for f in q.flags or []] or ["no solver flags"]
    budget_lines = consistency_lines(result)
    noise_alone = False     # a chi2/dof against the sample noise alone is written
    for key in FIT_NAMES:
        fit = q.fit(key)
        if fit is not None and fit.to_dict():
            chi2 = ", ".join(fmt(v, 3) for v in fit.chi2_per_dof or [])
            extra = f", dof {fit.dof}" if fit.dof is not None else ""
            versus = " against the sample noise alone" if budget_lines is not None else ""
            noise_alone = True
            items.append(f"{_e(key)}: chi2/dof per axis{versus} {_e(chi2)}{_e(extra)}")
    items += [_e(SAMPLE_NOISE_NOTE)] if budget_lines and noise_alone else []
    items += [_e(line) for line in budget_lines or []]
    outliers = q.outliers or []
    items.append(f"outliers beyond {_e(q.outlier_sigma if q.outlier_sigma is not None else 4)} sigma: {len(outliers)}")
    items += [f'<span class="flag">{_e(o.step)} {_e(o.index)} {_e(o.sensor)}: '
              f'{_e(fmt(o.normalized, 3))} sigma</span>' for o in outliers]
    return "<h2>Quality</h2>\n<ul>" + "".join(f"<li>{i}</li>" for i in items) + "</ul>"


def _vector(values) -> str:
    return _e(", ".join(fmt(v, 3) for v in values or []))


def _stacked(values) -> str:
    """x, y and z one above the other: the residual tables' eight columns then fit a page."""
    return "<br>".join(_e(fmt(v, 3)) for v in values or []) or "-"


def _residuals(result: CalibrationResult) -> str:
    from bench.report import plots  # matplotlib: loaded only when a report draws

    threshold = outlier_threshold(result)
    positions = result.residuals.get("positions", [])
    rotations = result.residuals.get("rotations", [])
    html = ["<h2>Residuals</h2>",
            f'<p class="note">Rows with a residual beyond {threshold:g} sigma (or listed by the solver) are '
            'highlighted and flagged OUTLIER.</p>']
    if positions:
        rows = []
        for row in positions:
            flag = row_outliers(result, "position", row)
            rows.append(([_e(row["label"]), _vector(row.get("angles_deg")), _stacked(row.get("acc_counts_per_s")),
                          _stacked(row.get("acc_normalized")), _stacked(row.get("gyro_dph")),
                          _stacked(row.get("gyro_normalized")), _e(fmt(max_normalized(row), 3)),
                          f'<span class="flag">OUTLIER {_e(outlier_text(flag))}</span>' if flag else ""],
                         "outlier" if flag else ""))
        html.append("<h3>Positions</h3>")
        html.append(_table(["position", "angles deg", "acc counts/s (x, y, z)", "acc r/sigma",
                            "gyro deg/h (x, y, z)", "gyro r/sigma", "max |r|/sigma", "flag"], rows, {2, 3, 4, 5, 6}))
    if rotations:
        rows = []
        for row in rotations:
            flag = row_outliers(result, "rotation", row)
            rows.append(([_e(row["label"]), _vector(row.get("start_deg")),
                          _e(f"{row.get('frame')} {row.get('direction')} x{row.get('revolutions')}"),
                          _stacked(row.get("gyro_arcsec")), _stacked(row.get("gyro_normalized")),
                          _e(fmt(max_normalized(row), 3)),
                          f'<span class="flag">OUTLIER {_e(outlier_text(flag))}</span>' if flag else ""],
                         "outlier" if flag else ""))
        html.append("<h3>Rotations</h3>")
        html.append(_table(["rotation", "start deg", "turn", "gyro arcsec (x, y, z)", "gyro r/sigma",
                            "max |r|/sigma", "flag"], rows, {3, 4, 5}))
    html.append(_plot("the normalized residuals",
                      "Normalized residuals per position and per rotation; circled points are outliers.",
                      plots.residual_figure, positions, rotations, threshold))
    return "\n".join(html)


def _log_plots(series: LogSeries) -> str:
    from bench.report import plots  # matplotlib: loaded only when a report draws

    html = ["<h2>IMU outputs and table angles</h2>"]
    html += [f'<p class="note">{_e(n)}</p>' for n in series.notes]
    if series.dwell_labels:
        html.append(_plot("the mean output per dwell",
                          "Accelerometer and gyro output per dwell step: mean over the dwell window, "
                          "error bars +-1 standard deviation of its samples.",
                          plots.step_means_figure, series.dwell_labels, series.acc_mean, series.acc_std,
                          series.gyro_mean, series.gyro_std))
    if len(series.sample_t_s):
        html.append(_plot("the IMU outputs over the run",
                          f"Accelerometer and gyro outputs over the run ({len(series.sample_t_s)} samples, drawn as "
                          f"a min/max envelope of at most {plots.MAX_POINTS} points per channel).",
                          plots.timeseries_figure, series.sample_t_s, series.acc_rate, series.gyro_rate, series.spans))
    else:
        html.append('<p class="note">No IMU samples in the log.</p>')
    if len(series.state_t_s):
        html.append(_plot("the table angles",
                          f"Table frame angles as the controller reported them ({len(series.state_t_s)} states).",
                          plots.angles_figure, series.state_t_s, series.angles_deg, series.spans))
    else:
        html.append('<p class="note">No table states in the log.</p>')
    return "\n".join(html)


def _comparison(comparison: Comparison) -> str:
    from bench.report import plots  # matplotlib: loaded only when a report draws

    flagged = comparison.flagged
    html = [f"<h2>Comparison with {_e(comparison.label)}</h2>"]
    if flagged:
        html.append(f'<p class="fail">{len(flagged)} coefficient(s) changed by more than {comparison.threshold:g} '
                    "sigma: " + _e(", ".join(f"{c.name} ({fmt(c.z, 3)} sigma)" for c in flagged)) + "</p>")
    else:
        html.append(f'<p class="pass">No coefficient changed by more than {comparison.threshold:g} sigma.</p>')
    html.append('<p class="note">change / sigma = (new - old) / sqrt(sigma_new<sup>2</sup> + '
                "sigma_old<sup>2</sup>)</p>")
    items = [f"{_e(k.replace('_', ' '))}: {_e(old if old not in (None, '') else '-')} &rarr; "
             f"{_e(new if new not in (None, '') else '-')}" for k, old, new in comparison.run_changes]
    items += [_e(n) for n in comparison.notes]
    if items:
        html.append("<ul>" + "".join(f"<li>{i}</li>" for i in items) + "</ul>")
    rows, ids = [], []
    for c in comparison.changes:
        big = c.z is not None and abs(c.z) > comparison.threshold
        rows.append(([_e(c.name), _e(fmt(c.old, 10)), _e(fmt(c.new, 10)), _e(fmt(c.change, 3)), _e(c.unit),
                      _e(fmt(c.z, 3)), '<span class="flag">CHANGED</span>' if big else ""], "changed" if big else ""))
        ids.append(f"change-{c.name}")
    html.append(_table(["name", "old", "new", "change", "unit", "change / sigma", "flag"], rows, {1, 2, 3, 5}, ids))
    names = [c.name for c in comparison.changes]
    if names:
        html.append(_plot("the changes in sigma",
                          "Each coefficient's change in units of the combined sigma (red beyond the threshold).",
                          plots.sigma_bars_figure, names, [c.z for c in comparison.changes], comparison.threshold,
                          f"change against {comparison.label}, in sigma"))
    return "\n".join(html)


def html_report(result: CalibrationResult, *, log=None, layout=None, problems=(), failures=(),
                imu_link: dict[str, Any] | None = None, against: CalibrationResult | None = None,
                against_label: str | None = None, title: str = "Calibration report",
                log_still_open: bool = False) -> str:
    """The whole report as one self-contained HTML document (see the module docstring).

    `log` is a `bench.log.reader.RunLog` (plots of the IMU outputs and table angles);
    `layout` the `ImuLayout` to decode its CAN frames with (default: the DBC attached
    to the log); `against` an earlier `CalibrationResult` to compare with. `log_still_open`:
    the log is the live run's, read before it was closed (its missing summary is not damage).
    """
    parts = [_acceptance(result.verdict), _metadata(result, log, imu_link, log_still_open),
             _verdict(result.verdict, list(failures), list(problems), lost_samples_note(result.run)),
             _coefficients(result), _budget(result), _quality(result), _residuals(result)]
    if log is not None:
        parts.append(_log_plots(log_series(log, layout)))
    if against is not None:
        parts.append(_comparison(compare_results(result, against, label=against_label)))
    return "\n".join([
        "<!DOCTYPE html>",
        '<html lang="en">',
        "<head>",
        '<meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f'<meta name="generator" content="turntable-bench {_e(__version__)}">',
        f"<title>{_e(title)}</title>",
        f"<style>{CSS}</style>",
        "</head>",
        "<body>",
        f"<h1>{_e(title)}</h1>",
        *parts,
        "</body>",
        "</html>",
        "",
    ])
