"""Table-check outputs: figures like the paper's 2 and 3, a Markdown and a self-contained HTML report, JSON.

Files written next to each other for run `<run-id>`: `<run-id>.table-check.json`
(format "turntable-bench/table-check"), `.table-check.md`, `.table-check.html` (plots
inline) and the two figures as standalone SVG (`.table-check-curves.svg`,
`.table-check-map.svg`) that the Markdown report links.
"""

from __future__ import annotations

import io
import json
from html import escape
from pathlib import Path

import numpy as np

from bench.log.names import output_path
from bench.model.units import ARCSEC
from bench.report.html import CSS
from bench.report.markdown import md_text
from bench.report.plots import NO_SVG_METADATA, PLOT_RC, inline_svg, new_figure, plt
from bench.table_check.from_log import TableCheckAnalysis

UG = 1e-6   # micro-g in units of g


def _svg_text(fig) -> str:
    """Standalone SVG document of a figure; closes it."""
    buf = io.StringIO()
    try:
        with plt.rc_context(PLOT_RC):
            fig.savefig(buf, format="svg", metadata=NO_SVG_METADATA)
    finally:
        plt.close(fig)
    return buf.getvalue()


def _centred(analysis: TableCheckAnalysis) -> np.ndarray:
    """Measured horizontal outputs minus the fitted offsets, micro-g (K, 2)."""
    est = analysis.estimate
    return (est.horizontal_g - est.offsets_g) / UG


def curves_figure(analysis: TableCheckAnalysis) -> str:
    """Paper figure 2: x and y accelerometer output over the inner angle, one curve per outer angle."""
    est = analysis.estimate
    y = _centred(analysis)
    outer = np.round(est.angles_deg[:, 0] % 360.0, 6)
    inner = est.angles_deg[:, 2] % 360.0
    levels = np.unique(outer)
    colors = plt.get_cmap("viridis")(np.linspace(0.0, 1.0, max(len(levels), 2)))
    with plt.rc_context(PLOT_RC):
        fig, axes = new_figure(1, 2, 10.0, 3.8, right_in=1.3, wgap_in=0.8)
        for k, (ax, name) in enumerate(zip(axes[0], ("x", "y"))):
            for level, color in zip(levels, colors):
                sel = np.flatnonzero(outer == level)
                sel = sel[np.argsort(inner[sel])]
                ax.plot(inner[sel], y[sel, k], "-o", ms=2.5, lw=0.8, color=color, label=f"{level:g}")
            ax.set_xlabel("inner angle, deg")
            ax.set_ylabel(f"{name} accelerometer - offset, ug")
            ax.set_title(f"{name} accelerometer (middle 0), one curve per outer angle")
        axes[0, 1].legend(title="outer, deg", loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=6,
                          ncol=1 if len(levels) <= 18 else 2, frameon=False)
    return _svg_text(fig)


def map_figure(analysis: TableCheckAnalysis) -> str:
    """Paper figure 3: the outer x inner map of both horizontal outputs (empty cells: not measured)."""
    est = analysis.estimate
    y = _centred(analysis)
    outer = np.round(est.angles_deg[:, 0] % 360.0, 6)
    inner = np.round(est.angles_deg[:, 2] % 360.0, 6)
    o_levels, i_levels = np.unique(outer), np.unique(inner)
    grid = np.full((2, len(o_levels), len(i_levels)), np.nan)
    oi, ii = np.searchsorted(o_levels, outer), np.searchsorted(i_levels, inner)
    for k in range(2):
        grid[k, oi, ii] = y[:, k]
    with plt.rc_context(PLOT_RC):
        fig, axes = new_figure(1, 2, 10.0, 4.4, right_in=0.6, wgap_in=1.3, bottom_in=0.6)
        for k, (ax, name) in enumerate(zip(axes[0], ("x", "y"))):
            lim = np.nanmax(np.abs(grid[k])) or 1.0
            img = ax.imshow(grid[k], origin="lower", aspect="auto", cmap="RdBu_r", vmin=-lim, vmax=lim,
                            extent=_extent(i_levels) + _extent(o_levels))
            ax.grid(False)
            ax.set_xlabel("inner angle, deg")
            ax.set_ylabel("outer angle, deg")
            ax.set_title(f"{name} accelerometer - offset, ug ({len(est.angles_deg)} positions)")
            fig.colorbar(img, ax=ax, fraction=0.06, pad=0.02)
    return _svg_text(fig)


def _extent(levels: np.ndarray) -> tuple[float, float]:
    if len(levels) < 2:
        return float(levels[0]) - 0.5, float(levels[0]) + 0.5
    step = float(np.min(np.diff(levels)))
    return float(levels[0]) - step / 2, float(levels[-1]) + step / 2


def _fmt(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}f}"


def summary_rows(analysis: TableCheckAnalysis) -> list[list[str]]:
    """Rows: combination, formula, estimate, 1-sigma (arcsec) [, truth, difference/sigma, within 3 sigma]."""
    est = analysis.estimate
    comparison = analysis.comparison()
    rows = []
    for k, c in enumerate(est.combinations):
        row = [c.key, c.formula, _fmt(est.values_arcsec[k]), _fmt(est.sigma_arcsec[k])]
        if comparison is not None:
            r = comparison[k]
            row += [_fmt(r["truth_arcsec"]), f"{r['z']:+.2f}", "yes" if r["within_3_sigma"] else "NO"]
        rows.append(row)
    return rows


def _header(analysis: TableCheckAnalysis) -> list[str]:
    head = ["combination", "angles", "estimate, arcsec", "1-sigma, arcsec"]
    if analysis.black_box_rad is not None:
        head += ["truth, arcsec", "(est - truth) / sigma", "within 3 sigma"]
    return head


def _facts(analysis: TableCheckAnalysis) -> list[tuple[str, str]]:
    est = analysis.estimate
    obs = est.observability
    noise_rad, conversion_rad = est.sigma_noise_rad, est.sigma_conversion_rad   # set by `estimate`
    facts = [("log", Path(analysis.log_path).name), ("mode", analysis.mode or "unknown"),
             *([("operator", analysis.operator)] if analysis.operator else []),
             ("positions", f"{len(analysis.labels)} (dwell {analysis.dwell_s:g} s)"),
             ("residual RMS", f"{est.residual_rms_g / UG:.3f} ug ({est.residual_rms_g / ARCSEC:.3f} arcsec of tilt)"),
             ("reduced chi-square", f"{est.reduced_chi2:.3f} (sigmas scaled by {est.sigma_scale:.3f})"),
             ("offsets (bias + vertical misalignment)",
              f"x {est.offsets_g[0] / UG:.3f} +- {est.offsets_sigma_g[0] / UG:.3f} ug, "
              f"y {est.offsets_g[1] / UG:.3f} +- {est.offsets_sigma_g[1] / UG:.3f} ug"),
             ("1-sigma", "noise (the dwells' standard errors) "
              + (f"and conversion ({est.relative_scale_uncertainty:g} x each tilt vector's length: "
                 + ", ".join(f"{c.key} {n / ARCSEC:.3f} + {v / ARCSEC:.3f}" for c, n, v in
                             zip(est.combinations, noise_rad, conversion_rad))
                 + " arcsec) in quadrature"
                 if est.relative_scale_uncertainty and noise_rad is not None and conversion_rad is not None
                 else "only")),
             ("accelerometer scale", f"{analysis.conversion.source}: "
              + ", ".join(f"{s:.1f}" for s in analysis.conversion.scale_counts_per_g) + " counts/s per g")]
    if obs is not None:
        facts.append(("observability", f"rank {obs.rank} of 9 after removing the two offsets; singular values "
                      + ", ".join(f"{s:.3g}" for s in obs.singular_values)))
    return facts


def _explanation() -> list[str]:
    return ["The middle frame is at 0, so body X and Y are horizontal. The horizontal accelerometers see only "
            "four combinations of the nine black-box angles (the gammas, zero offsets about the frames' own "
            "axes, enter at second order):",
            "level_alpha, level_beta: the outer axis's tilt from the local vertical (the table's levelness);",
            "inner_alpha, inner_beta: the inner axis's tilt against the outer axis at middle 0 (middle and inner "
            "black boxes together). These four do not fix the nine angles (a calibration moves the middle frame), "
            "but a large combination means at least one of its angles is at least half as large."]


def markdown_report(analysis: TableCheckAnalysis, curves_name: str, map_name: str) -> str:
    est = analysis.estimate
    lines = [f"# Table check {md_text(analysis.run_id)}", ""]
    lines += [f"- {k}: {md_text(v)}" for k, v in _facts(analysis)]
    lines += ["", "## Observable combinations of the black-box angles", ""]
    head = _header(analysis)
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in summary_rows(analysis)]
    lines += [""] + [f"{t}" if i == 0 else f"- {t}" for i, t in enumerate(_explanation())]
    lines += ["", "| combination | meaning |", "|---|---|"]
    lines += [f"| {c.key} | {c.description} |" for c in est.combinations]
    if analysis.black_box_rad is not None:
        verdict = "all within 3 sigma" if analysis.sim_within_3_sigma else "NOT all within 3 sigma"
        lines += ["", f"Simulated table: {verdict} of the truth (the exact projection of the simulated black box)."]
    if analysis.problems or analysis.notes:
        lines += ["", "## Problems and notes", ""] + [f"- {md_text(p)}" for p in analysis.problems + analysis.notes]
    lines += ["", "## Figures", "", f"![horizontal accelerometers over the inner angle]({curves_name})", "",
              f"![outer x inner map]({map_name})", ""]
    return "\n".join(lines)


def html_report(analysis: TableCheckAnalysis, curves_svg: str, map_svg: str) -> str:
    est = analysis.estimate
    e = escape
    parts = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
             f"<title>Table check {e(analysis.run_id)}</title>", f"<style>{CSS}</style>", "</head>", "<body>",
             f"<h1>Table check {e(analysis.run_id)}</h1>", "<table><tbody>"]
    parts += [f"<tr><th>{e(k)}</th><td>{e(v)}</td></tr>" for k, v in _facts(analysis)]
    parts += ["</tbody></table>", "<h2>Observable combinations of the black-box angles</h2>", "<table>",
              "<thead><tr>" + "".join(f"<th>{e(h)}</th>" for h in _header(analysis)) + "</tr></thead><tbody>"]
    for row in summary_rows(analysis):
        css = ' class="outlier"' if row[-1] == "NO" else ""
        parts.append(f"<tr{css}>" + "".join(f'<td class="num">{e(c)}</td>' if i >= 2 else f"<td>{e(c)}</td>"
                                             for i, c in enumerate(row)) + "</tr>")
    parts += ["</tbody></table>", "<p>" + e(_explanation()[0]) + "</p>", "<ul>"]
    parts += [f"<li>{e(t)}</li>" for t in _explanation()[1:]] + ["</ul>", "<table><tbody>"]
    parts += [f"<tr><th>{e(c.key)}</th><td>{e(c.description)}</td></tr>" for c in est.combinations]
    parts.append("</tbody></table>")
    if analysis.black_box_rad is not None:
        ok = analysis.sim_within_3_sigma
        parts.append(f'<p class="{"pass" if ok else "fail"}">Simulated table: '
                     f'{"all within" if ok else "NOT all within"} 3 sigma of the truth.</p>')
    if analysis.problems or analysis.notes:
        parts += ["<h2>Problems and notes</h2>", "<ul>"]
        parts += [f"<li>{e(p)}</li>" for p in analysis.problems + analysis.notes] + ["</ul>"]
    parts += ["<h2>Figures</h2>",
              f"<figure>{inline_svg(curves_svg, 'tc-curves-')}<figcaption>Horizontal accelerometers over the inner "
              "angle, one curve per outer angle (paper figure 2)</figcaption></figure>",
              f"<figure>{inline_svg(map_svg, 'tc-map-')}<figcaption>Outer x inner map of the horizontal "
              "accelerometers (paper figure 3)</figcaption></figure>", "</body>", "</html>", ""]
    return "\n".join(parts)


def write_outputs(analysis: TableCheckAnalysis, out_dir: str | Path) -> dict[str, Path]:
    """Write JSON, Markdown, HTML and the two SVG figures; returns their paths by kind."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"{analysis.run_id}.table-check"
    # the run id comes from a log: a name that is not a safe file name never becomes a path
    paths = {kind: output_path(out, f"{stem}{suffix}") for kind, suffix in
             (("json", ".json"), ("markdown", ".md"), ("html", ".html"), ("curves", "-curves.svg"),
              ("map", "-map.svg"))}
    curves, grid = curves_figure(analysis), map_figure(analysis)
    paths["curves"].write_text(curves, encoding="utf-8")
    paths["map"].write_text(grid, encoding="utf-8")
    paths["json"].write_text(json.dumps(analysis.to_json(), indent=2) + "\n", encoding="utf-8")
    paths["markdown"].write_text(markdown_report(analysis, paths["curves"].name, paths["map"].name),
                                 encoding="utf-8")
    paths["html"].write_text(html_report(analysis, curves, grid), encoding="utf-8")
    return paths


__all__ = ["curves_figure", "html_report", "map_figure", "markdown_report", "summary_rows", "write_outputs"]
