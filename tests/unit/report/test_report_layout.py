"""What a reader sees in the reports (issue 33, item 11): the noise report's code and legends, the thermal report's
title and coefficient table, tick labels that do not overprint, and why chi2 against the sample noise alone is large.

The figures are checked on matplotlib's own renderer: the window extents of the legend, the axes, their titles
and the tick labels as drawn. The HTML table's width is estimated from its text (monospace digits, the report's
CSS font sizes), not rendered.
"""

from __future__ import annotations

import re
from html.parser import HTMLParser

import numpy as np
import pytest

from bench.model.result import CalibrationResult, coefficient_table
from bench.report import plots
from bench.report.facts import SAMPLE_NOISE_NOTE
from bench.report.html import html_report
from bench.report.markdown import markdown_report
from bench.report.noise import _lines, html_noise_report, markdown_noise_report
from bench.report.thermal import html_thermal, markdown_thermal, write_thermal_reports
from bench.thermal.model import fit_thermal_model, point_from_result
from tests.helpers.run import cli


@pytest.fixture(scope="module")
def noise_result(tmp_path_factory):
    from bench.model.noise_result import NoiseResult

    out = tmp_path_factory.mktemp("noise")
    rc, _, err = cli(["noise", "--sim", "--duration-h", "0.05", "--rate-hz", "100", "--seed", "2", "--out", str(out)])
    assert rc == 0, err
    return NoiseResult.load(out / "sim-0.05h-100hz-seed2.noise.json")


def _drawn(monkeypatch, draw, *args):
    """The matplotlib figure a report function draws, with its renderer after drawing (to_svg intercepted)."""
    seen = []

    def keep(fig):
        fig.canvas.draw()
        seen.append((fig, fig.canvas.get_renderer()))
        return "<svg></svg>"

    monkeypatch.setattr(plots, "to_svg", keep)
    draw(*args)
    assert len(seen) == 1
    return seen[0]


def _overlap(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


# -- the noise report --------------------------------------------------------------------------------------------

def test_the_noise_html_shows_the_configuration_line_as_code_not_backticks(noise_result):
    html = html_noise_report(noise_result, "Noise")
    text = re.sub(r"<svg.*?</svg>", "", html, flags=re.S)
    assert "`" not in text
    assert "<code>[imu] noise = &quot;FILE&quot;</code> in a bench configuration feeds these" in text
    assert '`[imu] noise = "FILE"` in a bench configuration' in markdown_noise_report(noise_result, "Noise")


def test_the_allan_legend_covers_no_panel(noise_result):
    import matplotlib.pyplot as plt

    fig = plots.allan_axes_figure(_lines(noise_result))
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        panels = [ax for ax in fig.axes if ax.get_visible()]
        assert len(panels) == 6 and all(ax.get_legend() is None for ax in panels)
        [legend] = fig.legends
        box = legend.get_window_extent(renderer)
        for ax in panels:
            assert not _overlap(box, ax.get_window_extent(renderer)), ax.get_title()
            assert not _overlap(box, ax.title.get_window_extent(renderer)), ax.get_title()
        labels = [t.get_text() for t in legend.get_texts()]
        assert labels[:2] == ["ADEV", plots.ALLAN_MODEL_LABEL]
        assert {"-1/2: ARW", "-1/2: VRW", "0: bias instability (x0.664)"} <= set(labels)
        assert len(labels) == len(set(labels))
    finally:
        plt.close(fig)


# -- tick labels -------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("n", [6, 24, 64, 96, 300])
def test_tick_labels_of_many_rotations_do_not_overprint(monkeypatch, n):
    rng = np.random.default_rng(n)
    rows = [{"label": f"R{i + 1:02d}", "gyro_normalized": list(rng.normal(size=3))} for i in range(n)]
    fig, renderer = _drawn(monkeypatch, plots.residual_figure, [], rows, 4.0)
    [ax] = fig.axes
    written = [t for t in ax.get_xticklabels() if t.get_text()]
    boxes = [t.get_window_extent(renderer) for t in written]
    assert all(a.x1 <= b.x0 for a, b in zip(boxes, boxes[1:])), "tick labels overlap"
    assert written[0].get_fontsize() >= 5.5
    step = n // len(written)
    assert [t.get_text() for t in written] == [r["label"] for r in rows][::step]
    assert step == 1 or n > 64          # up to 64 every label is written
    assert len(ax.get_xticks()) == n    # a tick per rotation either way


# -- the thermal report ------------------------------------------------------------------------------------------

TEMPS = (-30.0, -10.0, 10.0, 25.0, 40.0, 60.0)
#: cubic in (T - 25): large terms at tiny sigmas, so every coefficient is fitted to degree 3
CUBIC = {"Kg_x": (36012.51229, 0.360168, 0.00402342, -1.23e-5), "Eg_Xx": (0.9999997403, -2.43e-9, 4.3e-11, 1.2e-13),
         "D0_x": (0.05222789123, 0.00193, 1.76e-5, -6.06e-7), "Ka_y": (39978.49121, -0.599217, 0.0100314, 2.2e-5)}
SIGMAS = {"Kg_x": 0.011, "Eg_Xx": 4.5e-12, "D0_x": 1e-6, "Ka_y": 0.018}


def _cubic_model():
    points = []
    for t in TEMPS:
        values = {k: sum(c * (t - 25.0) ** p for p, c in enumerate(cs)) for k, cs in CUBIC.items()}
        r = CalibrationResult(coefficient_table(values, SIGMAS))
        r.temperature = {"mean_c": t, "min_c": t - 0.1, "max_c": t + 0.1}
        points.append(point_from_result(r, f"r{t:g}.json"))
    model = fit_thermal_model(points)
    assert {fit.degree for fit in model.fits.values()} == {3}
    return model


class _Cells(HTMLParser):
    """The text lines of each cell of each row of the tables."""

    def __init__(self) -> None:
        super().__init__()
        self.rows: list[list[list[str]]] = []
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        if tag == "tr":
            self.rows.append([])
        elif tag in ("td", "th"):
            self._cell = [""]
            self.rows[-1].append(self._cell)
        elif tag == "br" and self._cell is not None:
            self._cell.append("")

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell[-1] += data


#: The report's CSS: tables at .9em, cells padded .5em each side; a digit of the monospace font 0.6 em.
TABLE_EM, PAD_EM, GLYPH_EM = 0.9, 1.0, 0.6


def _table_width_em(html: str) -> float:
    """The coefficient table's narrowest width: each column as wide as its widest unbreakable run of text."""
    table = re.search(r"<h2>Coefficients</h2>\s*<table>(.*?)</table>", html, re.S).group(1)
    parser = _Cells()
    parser.feed(table)
    widths: dict[int, int] = {}
    for row in parser.rows:
        for k, cell in enumerate(row):
            runs = [len(line) for line in cell]             # numbers do not wrap (white-space: nowrap)
            if k < 2 or k > 6:                               # names, units and headers wrap at spaces
                runs = [len(word) for line in cell for word in line.split()]
            widths[k] = max(widths.get(k, 0), *runs)
    return sum(TABLE_EM * (GLYPH_EM * chars + PAD_EM) for chars in widths.values())


def test_the_thermal_coefficient_table_fits_a_narrow_content_column():
    html = html_thermal(_cubic_model(), "Thermal model")
    # a 1024-pixel window at 16 px per em, the body's 1em padding each side: 62 em of content
    assert _table_width_em(html) < 62.0
    assert re.search(r"<td class=num>36012\.5\d+<br>\+- 0\.0\d+</td>", html)   # the value over its sigma


def test_the_thermal_title_is_said_once(tmp_path):
    model = _cubic_model()
    md_path, html_path = write_thermal_reports(model, tmp_path)
    assert md_path.read_text().startswith("# Thermal model\n")
    assert "<h1>Thermal model</h1>" in html_path.read_text() and "thermal</h1>" not in html_path.read_text()
    html = html_thermal(model, "Thermal model 20261127T201638Z-632a39")
    assert "<h1>Thermal model 20261127T201638Z-632a39</h1>" in html
    assert markdown_thermal(model, "Thermal model X").startswith("# Thermal model X\n")


# -- chi2 against the sample noise alone -------------------------------------------------------------------------

def test_both_reports_say_why_chi2_against_the_sample_noise_alone_is_large(noisy_run):
    result = CalibrationResult.load(noisy_run.result_path)
    md = markdown_report(result, title="r")
    lines = md.splitlines()
    alone = [i for i, line in enumerate(lines) if "against the sample noise alone" in line and "chi2/dof per" in line]
    assert alone and lines[alone[-1] + 1] == f"- {SAMPLE_NOISE_NOTE}"
    assert "budget's predicted scatter" in lines[alone[-1] + 2]
    html = html_report(result, title="r")
    assert f"<li>{SAMPLE_NOISE_NOTE.replace(chr(39), '&#x27;')}</li>" in html
