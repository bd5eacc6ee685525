"""Reports of a thermal model: `thermal.md` and the self-contained `thermal.html` (`bench thermal`), and a thermal
run's files: its per-temperature results and the model with its reports (`write_thermal_files`).

Both list every modelled coefficient's polynomial (degree chosen by the data) with its
1-sigma terms and the calibrations it was fitted to; for a simulated run also the
truth and the error in sigma. The HTML plots each coefficient against temperature: the
per-temperature calibrations with their +-1 sigma bars, the fitted polynomial, its
+-1 sigma band (shaded; extended 10 degC beyond the calibrated range, where it widens)
and, simulated, the truth (dashed). Values are drawn as the difference from the
model's value at the reference temperature, which the axis label gives.
"""

from __future__ import annotations

from html import escape
from pathlib import Path
from typing import Any

import numpy as np

from bench import __version__
from bench.files import write_output_text
from bench.model.families import FAMILY_INFO, family_of
from bench.report.html import CSS
from bench.report.markdown import md_text
from bench.report.plots import AXIS_COLORS, PLOT_RC, check_drawable, new_figure, plt, to_svg
from bench.thermal.fit import DEGREE_RULE
from bench.thermal.from_log import ThermalSolution
from bench.thermal.model import ThermalModel

#: how far beyond the calibrated range the plots draw the model, degC
PLOT_MARGIN_C = 10.0
READING = ("How to read the plots: each dot is one calibration at the IMU's mean temperature with its +-1 sigma "
           "bar; the line is the fitted polynomial (its degree chosen by the data) and the shaded band its +-1 sigma "
           "(how well the model is known at that temperature: it includes the error every calibration shares, such as "
           "the table's pointing errors, and widens outside the calibrated range). A dashed line is the simulated "
           "truth. Values are differences from the model's value at the reference temperature.")


def _f(x: float, digits: int = 6) -> str:
    return f"{x:.{digits}g}"


def _term_cells(model: ThermalModel, name: str) -> list[str]:
    fit = model.fits[name]
    cells = []
    for k in range(4):
        digits = 10 if k == 0 else 6       # c0 of a scale factor or a direction cosine needs its digits
        cells.append(f"{_f(fit.polynomial[k], digits)} +- {_f(fit.sigma[k], 2)}" if k <= fit.degree else "")
    return cells


def _truth_z(model: ThermalModel, name: str) -> str:
    """The largest |error| / sigma of the model's values at the calibrated temperatures and between them."""
    if model.truth_at(name, model.reference_c) is None:
        return "-"
    fit = model.fits[name]
    low, high = model.range_c
    temps = np.linspace(low, high, 15)
    z = [(fit.value(t) - model.truth_at(name, t)) / fit.sigma_at(t) for t in temps]
    return f"{max(z, key=abs):+.2f}"


def markdown_thermal(model: ThermalModel, title: str) -> str:
    low, high = model.range_c
    lines = [f"# {md_text(title)}", "",
             f"{len(model.points)} calibrations from {low:g} to {high:g} degC; polynomials in "
             f"(T - {model.reference_c:g} degC), T the IMU's temperature. turntable-bench {__version__}.", "",
             f"Degree rule: {DEGREE_RULE}.", "", "## Calibrations", "", "| calibration | IMU mean degC | min | max |",
             "|---|---:|---:|---:|"]
    for p in model.points:
        t = p.temperature
        lines.append(f"| {md_text(p.label)} | {p.temperature_c:.3f} | {_opt(t.get('min_c'))} | "
                     f"{_opt(t.get('max_c'))} |")
    sim = model.sim_truth is not None
    lines += ["", "## Coefficients", "", "| coefficient | unit | degree | c0 | c1 /degC | c2 /degC^2 | c3 /degC^3 | "
              "chi2/dof |" + (" truth: worst z |" if sim else ""),
              "|---|---|---:|---:|---:|---:|---:|---:|" + ("---:|" if sim else "")]
    for name, fit in model.fits.items():
        chi = f"{fit.chi2 / fit.dof:.2f}" if fit.dof else "-"
        lines.append(f"| {name} | {fit.unit} | {fit.degree} | " + " | ".join(_term_cells(model, name))
                     + f" | {chi} |" + (f" {_truth_z(model, name)} |" if sim else ""))
    if model.notes:
        lines += ["", "## Notes", ""] + [f"- {md_text(n)}" for n in model.notes]
    return "\n".join(lines) + "\n"


def _opt(x) -> str:
    return "-" if x is None else f"{float(x):.3f}"


def family_figure(model: ThermalModel, family: str) -> str | None:
    """The coefficients of one family against temperature (None when none is modelled)."""
    names = [n for n in model.fits if family_of(n) == family]
    if not names:
        return None
    low, high = model.range_c
    grid = np.linspace(low - PLOT_MARGIN_C, high + PLOT_MARGIN_C, 121)
    cols = 3
    rows = -(-len(names) // cols)
    with plt.rc_context(PLOT_RC):
        fig, axes = new_figure(rows, cols, 10.0, 2.4 * rows + 0.4, hgap_in=0.7, wgap_in=0.9, left_in=0.9,
                               bottom_in=0.5, top_in=0.45)
        for ax in axes.reshape(-1)[len(names):]:
            ax.set_visible(False)
        for k, (ax, name) in enumerate(zip(axes.reshape(-1), names)):
            fit = model.fits[name]
            base = float(fit.value(model.reference_c))
            value, band = fit.value(grid) - base, fit.sigma_at(grid)
            check_drawable(f"the values of {name}", value, band, fit.values - base, fit.sigmas)
            color = AXIS_COLORS[k % 3]
            ax.fill_between(grid, value - band, value + band, color=color, alpha=0.2, lw=0, label="+-1 sigma")
            ax.plot(grid, value, color=color, lw=1.2, label=f"fit, degree {fit.degree}")
            ax.errorbar(fit.temperatures_c, fit.values - base, yerr=fit.sigmas, fmt="o", ms=3, color="#333333",
                        capsize=2, lw=0.8, label="calibrations")
            if model.truth_at(name, model.reference_c) is not None:
                truth = np.array([model.truth_at(name, t) for t in grid], float) - base
                ax.plot(grid, truth, color="#000000", ls="--", lw=0.8, label="truth")
            ax.axvspan(low, high, color="#f2f2f2", lw=0, zorder=0)
            ax.set_title(name, fontsize=8)
            ax.set_xlabel("IMU temperature, degC")
            ax.set_ylabel(f"{fit.unit}\nminus {_f(base, 9)}", fontsize=7)
            if k == 0:
                ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.08), ncol=4, fontsize=6.5, frameon=False)
    return to_svg(fig)


def html_thermal(model: ThermalModel, title: str) -> str:
    low, high = model.range_c
    sim = model.sim_truth is not None
    head = ("<tr><th>coefficient</th><th>unit</th><th>degree</th><th>c0</th><th>c1 /degC</th><th>c2 /degC^2</th>"
            "<th>c3 /degC^3</th><th>chi2/dof</th>" + ("<th>truth: worst z</th>" if sim else "") + "</tr>")
    rows = []
    for name, fit in model.fits.items():
        chi = f"{fit.chi2 / fit.dof:.2f}" if fit.dof else "-"
        # the value over its sigma: side by side, four terms ran past the content column
        cells = "".join(f"<td class=num>{'<br>'.join(escape(part) for part in c.split(' ', 1))}</td>"
                        for c in _term_cells(model, name))
        rows.append(f"<tr><td>{name}</td><td>{escape(fit.unit)}</td><td class=num>{fit.degree}</td>{cells}"
                    f"<td class=num>{chi}</td>" + (f"<td class=num>{_truth_z(model, name)}</td>" if sim else "")
                    + "</tr>")
    points = "".join(f"<tr><td>{escape(p.label)}</td><td class=num>{p.temperature_c:.3f}</td></tr>"
                     for p in model.points)
    figures = []
    for family, info in FAMILY_INFO.items():
        svg = family_figure(model, family)
        if svg is not None:
            figures.append(f"<figure>{svg}<figcaption>{escape(info.title)} ({escape(info.result_unit)}) against "
                           "IMU temperature</figcaption></figure>")
    notes = "".join(f"<li>{escape(n)}</li>" for n in model.notes)
    return (f"<!DOCTYPE html>\n<html lang=en><head><meta charset=utf-8><title>{escape(title)}</title>"
            f"<style>{CSS}</style></head><body>\n<h1>{escape(title)}</h1>\n"
            f"<p>{len(model.points)} calibrations from {low:g} to {high:g} degC; polynomials in "
            f"(T - {model.reference_c:g} degC). Degree rule: {escape(DEGREE_RULE)}. turntable-bench "
            f"{escape(__version__)}.</p>\n<h2>Calibrations</h2>\n<table><tr><th>calibration</th><th>IMU mean degC</th>"
            f"</tr>{points}</table>\n<h2>Coefficients</h2>\n<table>{head}{''.join(rows)}</table>\n"
            + (f"<h2>Notes</h2><ul>{notes}</ul>\n" if notes else "")
            + f"<h2>Against temperature</h2>\n<p>{escape(READING)}</p>\n{''.join(figures)}\n</body></html>\n")


def write_thermal_reports(model: ThermalModel, out_dir: str | Path, stem: str = "thermal",
                          title: str = "", *, html: bool = True) -> list[Path]:
    """`<stem>.md` and (with `html`: its figures take seconds) `<stem>.html` in `out_dir` (`stem` is ours,
    never a name from a file)."""
    out = Path(out_dir)
    written = []
    title = title or "Thermal model"        # not the stem: it read "Thermal model: thermal"
    for suffix in (".md", ".html") if html else (".md",):
        text = markdown_thermal(model, title) if suffix == ".md" else html_thermal(model, title)
        path = out / f"{stem}{suffix}"
        write_output_text(path, text)        # renamed into place: never half a report
        written.append(path)
    return written


def write_thermal_files(solution: ThermalSolution, out_dir: Path, stem: str, run: dict[str, Any],
                        title: str, *, html: bool = True) -> tuple[list[Path], Path | None]:
    """`<stem>.T<k>.result.json` per temperature and `<stem>.thermal.json` (`.md`, and with `html` `.html`) with
    `run` in the model (`stem` is ours, never a name from a file). Returns (the result files, the model file or
    None)."""
    results = []
    for block in solution.blocks:
        path = out_dir / f"{stem}.T{block.temperature_index}.result.json"
        block.point.result.save(path)
        results.append(path)
    model = solution.model
    if model is None:
        return results, None
    model.run = {**run, "results": [p.name for p in results]}
    model_path = out_dir / f"{stem}.thermal.json"
    model.save(model_path)
    write_thermal_reports(model, out_dir, f"{stem}.thermal", title=title, html=html)
    return results, model_path


__all__ = ["READING", "family_figure", "html_thermal", "markdown_thermal", "write_thermal_files",
           "write_thermal_reports"]
