"""Reports of a noise result: `<name>.noise.md` and the self-contained `<name>.noise.html` (log-log plots).

Both list, per channel, the fitted terms with their 1-sigma and the tau region each was
read from (and, for simulated data, the configured value and the error in sigma); the
HTML adds the Allan deviation of every channel with its +-1 sigma interval and the
fitted lines (thin over all taus, thick over the fit region). Text from a log (run id,
notes) is escaped as in the calibration reports.
"""

from __future__ import annotations

from html import escape
from pathlib import Path
from typing import Any

import numpy as np

from bench import __version__
from bench.files import write_output_text
from bench.log.names import output_path
from bench.model.noise_result import NoiseResult
from bench.noise.fit import FLICKER_FACTOR
from bench.report.html import CSS
from bench.report.markdown import md_text
from bench.report.plots import allan_figure

#: The plot in one paragraph (README "Characterising noise" says the same).
READING = ("How to read the plot: the Allan deviation is the scatter of the channel's mean over a cluster time "
           "tau. A slope of -1 is quantisation, -1/2 white noise on the rate (angle random walk for a gyro, "
           "velocity random walk for an accelerometer; its value at tau = 1 s is the ARW/VRW), 0 the bias "
           "instability floor (its minimum / 0.664), +1/2 rate random walk (a bias that wanders without bound). "
           "Error bars are the +-1 sigma chi-square intervals from the equivalent degrees of freedom; the solid "
           "line is the fitted curve (all terms, the correlated bias included, fitted together with the points' "
           "covariance) with its +-1 sigma band over the taus it was fitted on, dotted beyond them; each dashed "
           "line is one fitted term, drawn thick over the taus where it is the largest part of the fitted curve. "
           "A term marked upper bound: "
           "a rate random walk the record cannot tell from zero (its 2-sigma bound), or a bias instability whose "
           "fitted curve still falls at the longest tau.")
_ORDER = ("quantisation", "arw", "vrw", "bias_instability", "rrw")
_LABELS = {"quantisation": "quantisation", "arw": "angle random walk", "vrw": "velocity random walk",
           "bias_instability": "bias instability", "rrw": "rate random walk"}


def _f(x: Any, digits: int = 4) -> str:
    return "-" if x is None else f"{x:.{digits}g}"


def _rows(result: NoiseResult) -> list[tuple[str, str, dict, dict | None]]:
    """(channel, term, term dict, truth dict or None) in display order."""
    truth = (result.sim_truth or {}).get("channels", {})
    rows = []
    for name, ch in result.channels.items():
        for term in _ORDER:
            if term in ch.get("terms", {}):
                rows.append((name, term, ch["terms"][term], truth.get(name)))
    return rows


def not_resolved_lines(result: NoiseResult) -> list[str]:
    """One line per term the record does not resolve: "gyro_x quantisation: not given: why"."""
    return [f"{name} {_LABELS.get(term, term)}: not given: {why}" for name, ch in result.channels.items()
            for term, why in (ch.get("terms_not_resolved") or {}).items()]


def _truth_cells(term: str, t: dict, truth: dict | None) -> tuple[str, str]:
    if truth is None or truth.get(term) is None or not truth.get(term):
        return "-", "-"
    true = float(truth[term])
    if term == "rrw" and t.get("upper_bound"):       # not resolved: a bound, not an estimate
        return _f(true), "below the bound" if true <= t["value"] else "ABOVE the bound"
    z = (t["value"] - true) / t["sigma"] if t.get("sigma") else None
    return _f(true), "-" if z is None else f"{z:+.2f}"


def _region(t: dict) -> str:
    lo, hi = t["region_tau_s"]
    return f"{lo:g}" if lo == hi else f"{lo:g}..{hi:g}"


#: How the summary's bias stabilities reach a solve: (before, the configuration line, after).
_FEEDS = ("(", '[imu] noise = "FILE"', " in a bench configuration feeds these to the solve)")


def _summary_lines(result: NoiseResult) -> list[str]:
    return [f"gyro bias stability (largest of x, y, z): {_f(result.gyro_bias_stability_dph)} deg/h",
            f"accelerometer bias stability (largest of x, y, z): {_f(result.acc_bias_stability_ug)} ug"]


def _source_text(result: NoiseResult) -> str:
    s = result.source
    if s.get("kind") == "sim":
        return (f"simulated IMU alone, seed {s.get('seed')}, {result.duration_s / 3600:.3g} h at "
                f"{result.rate_hz:g} Hz")
    return f"log {s.get('log', '?')} (run {s.get('run_id', '?')}), scales from {s.get('scales', '?')}"


def markdown_noise_report(result: NoiseResult, title: str) -> str:
    sim = result.sim_truth is not None
    lines = [f"# {md_text(title)}", "", f"- data: {md_text(_source_text(result))}",
             f"- samples per channel: {result.n_samples} ({result.duration_s:.1f} s at {result.rate_hz:g} Hz), "
             f"{result.points_per_octave} point(s) per octave", ""]
    lines += ["## Noise terms (1 sigma)", ""]
    head = ["channel", "term", "value", "1 sigma", "unit", "fit region tau, s"] + (["configured", "error/sigma"]
                                                                                     if sim else [])
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, term, t, truth in _rows(result):
        cells = [name, _LABELS[term] + (" (upper bound)" if t.get("upper_bound") else ""), _f(t["value"]),
                 _f(t["sigma"], 2), md_text(t["unit"]), _region(t)]
        if sim:
            cells += list(_truth_cells(term, t, truth))
        lines.append("| " + " | ".join(cells) + " |")
    unresolved = not_resolved_lines(result)
    if unresolved:
        lines += ["", "Terms the record does not resolve (not reported as numbers):", ""]
        lines += [f"- {md_text(line)}" for line in unresolved]
    lines += ["", "## Summary", ""] + [f"- {line}" for line in _summary_lines(result)]
    lines += [f"- {_FEEDS[0]}`{_FEEDS[1]}`{_FEEDS[2]}", ""]
    if result.sim_truth is not None:
        lines += [f"Configured bias instability is what the flat-region rule should read from the simulated IMU's "
                  f"theoretical curve (min ADEV / {FLICKER_FACTOR:.3f}); its Gauss-Markov bias of 1-sigma s alone "
                  f"would read {result.sim_truth.get('gm_to_allan_bi', 0.0):.3f} s.", ""]
    lines += ["## Allan deviation", ""]
    for name, ch in result.channels.items():
        lines += [f"### {name} ({md_text(ch['unit'])})", "", "| tau, s | ADEV | -1 sigma | +1 sigma | edf |",
                  "|---|---|---|---|---|"]
        for row in zip(ch["tau_s"], ch["adev"], ch["adev_low"], ch["adev_high"], ch["edf"]):
            lines.append("| " + " | ".join(_f(v, 5) for v in row) + " |")
        lines.append("")
    lines += [READING, ""]
    if result.notes:
        lines += ["## Notes", ""] + [f"- {md_text(n)}" for n in result.notes] + [""]
    return "\n".join(lines)


def _e(x: Any) -> str:
    return escape(str(x), quote=True)


def _lines(result: NoiseResult) -> list[tuple[str, dict, dict[str, np.ndarray]]]:
    """Each channel with its term lines at its taus (the same formulas as `bench.noise.fit.ChannelFit.line`)."""
    out = []
    for name, ch in result.channels.items():
        tau = np.asarray(ch["tau_s"], float)
        lines = {}
        for term, t in ch.get("terms", {}).items():
            gyro = name.startswith("gyro")
            if term == "quantisation":
                lines[term] = np.sqrt(3.0) * t["value"] / tau
            elif term in ("arw", "vrw"):
                lines[term] = t["value"] * (60.0 if gyro else 1.0) / np.sqrt(tau)
            elif term == "bias_instability":
                lines[term] = np.full(tau.shape, t["value"] * FLICKER_FACTOR)
            elif term == "rrw":
                lines[term] = t["value"] / 60.0 * np.sqrt(tau / 3.0)
        out.append((name, ch, lines))
    return out


def html_noise_report(result: NoiseResult, title: str) -> str:
    sim = result.sim_truth is not None
    head = ["channel", "term", "value", "1 sigma", "unit", "fit region tau, s"] + (["configured", "error/sigma"]
                                                                                     if sim else [])
    rows = []
    for name, term, t, truth in _rows(result):
        cells = [name, _LABELS[term] + (" (upper bound)" if t.get("upper_bound") else ""), _f(t["value"]),
                 _f(t["sigma"], 2), t["unit"], _region(t)]
        if sim:
            cells += list(_truth_cells(term, t, truth))
        rows.append("<tr>" + "".join(f"<td>{_e(c)}</td>" for c in cells) + "</tr>")
    try:
        figure = f"<figure>\n{allan_figure(_lines(result))}\n<figcaption>{_e(READING)}</figcaption>\n</figure>"
    except (ValueError, OverflowError, FloatingPointError) as exc:
        figure = f'<p class="fail">The Allan deviation figure is not drawn: {_e(exc)}.</p>'
    notes = "".join(f"<li>{_e(n)}</li>" for n in result.notes)
    unresolved = "".join(f"<li>{_e(line)}</li>" for line in not_resolved_lines(result))
    return "\n".join([
        "<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
        f'<meta name="generator" content="turntable-bench {_e(__version__)}">', f"<title>{_e(title)}</title>",
        f"<style>{CSS}</style>", "</head>", "<body>", f"<h1>{_e(title)}</h1>",
        f"<p>data: {_e(_source_text(result))}; {result.n_samples} samples per channel ({result.duration_s:.1f} s at "
        f"{result.rate_hz:g} Hz), {result.points_per_octave} point(s) per octave</p>",
        "<h2>Noise terms (1 sigma)</h2>", "<table>", "<thead><tr>" + "".join(f"<th>{_e(h)}</th>" for h in head)
        + "</tr></thead>", "<tbody>", *rows, "</tbody>", "</table>",
        f"<p>Terms the record does not resolve (not reported as numbers):</p><ul>{unresolved}</ul>" if unresolved
        else "",
        "<ul>" + "".join(f"<li>{_e(line)}</li>" for line in _summary_lines(result))
        + f"<li>{_e(_FEEDS[0])}<code>{_e(_FEEDS[1])}</code>{_e(_FEEDS[2])}</li></ul>",
        "<h2>Allan deviation</h2>", figure,
        f"<h2>Notes</h2><ul>{notes}</ul>" if notes else "", "</body>", "</html>", ""])


def write_noise_outputs(result: NoiseResult, out_dir: str | Path, name: str) -> tuple[Path, Path, Path]:
    """Write `<name>.noise.json`, `.noise.md` and `.noise.html` into `out_dir` (never a path out of it)."""
    out_dir = Path(out_dir)
    json_path, md_path, html_path = (output_path(out_dir, f"{name}.noise.{ext}") for ext in ("json", "md", "html"))
    title = f"Noise characterisation {name}"
    result.save(json_path)
    write_output_text(md_path, markdown_noise_report(result, title))     # renamed into place: never half a report
    write_output_text(html_path, html_noise_report(result, title))
    return json_path, md_path, html_path


__all__ = ["READING", "html_noise_report", "markdown_noise_report", "not_resolved_lines", "write_noise_outputs"]
