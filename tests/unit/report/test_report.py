"""Reports (issue 5, item 3): Markdown and the self-contained HTML report.

One short simulated run (noise on, black box on; 2 s dwells, 50 Hz IMU) through the CLI gives a real result
and log: the session's `noisy_run` (tests/unit/conftest.py), read only. "Must show": the HTML report is
self-contained (no external URL) and contains every coefficient.
"""

from __future__ import annotations

import copy
import json
import math
import re
import time
from html.parser import HTMLParser
from types import SimpleNamespace

import numpy as np
import pytest

from bench.errors import InputError
from bench.log.reader import read_log
from bench.model.families import canonical_names
from bench.model.quality_section import Outlier
from bench.model.result import CalibrationResult
from bench.model.run_section import RunInfo
from bench.report.compare import compare_results
from bench.report.html import html_report, log_damage, log_series
from bench.report.markdown import markdown_report, write_reports
from bench.report.plots import envelope, inline_svg

#: Elements without an end tag in HTML.
VOID = {"area", "base", "br", "col", "embed", "hr", "img", "input", "link", "meta", "source", "track", "wbr"}
@pytest.fixture(scope="module")
def run(noisy_run):
    """The session's noisy run (tests/unit/conftest.py: noise on, a 20" black box, a log chunk every 5 s of
    simulated time) and the reports `bench run` wrote for it; read only."""
    return SimpleNamespace(out=noisy_run.out, log_path=noisy_run.log, log=read_log(noisy_run.log),
                           result=CalibrationResult.load(noisy_run.result_path),
                           md=noisy_run.report_md.read_text(encoding="utf-8"),
                           html=noisy_run.report_html.read_text(encoding="utf-8"))


class StrictWalk(HTMLParser):
    """Walks a whole document: every end tag must close the innermost open element."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.counts: dict[str, int] = {}
        self.ids: list[str] = []
        self.refs: list[tuple[str, str, str]] = []   # (tag, attribute, value)
        self.doctype = None
        self.rows: dict[str, list[str]] = {}         # tr id -> its cell texts
        self._row: str | None = None
        self._cell: list[str] | None = None

    def handle_decl(self, decl):
        self.doctype = decl

    def _attrs(self, tag, attrs):
        self.counts[tag] = self.counts.get(tag, 0) + 1
        for name, value in attrs:
            if name == "id":
                self.ids.append(value)
            if name in ("href", "src", "xlink:href", "action", "data", "poster", "srcset", "style"):
                self.refs.append((tag, name, value or ""))

    def handle_starttag(self, tag, attrs):
        self._attrs(tag, attrs)
        if tag == "tr":
            self._row = dict(attrs).get("id")
            if self._row:
                self.rows[self._row] = []
        if tag == "td" and self._row:
            self._cell = []
        if tag not in VOID:
            self.stack.append(tag)

    def handle_startendtag(self, tag, attrs):
        self._attrs(tag, attrs)

    def handle_endtag(self, tag):
        if tag in VOID:
            return
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> at line {self.getpos()[0]} closes {self.stack[-1:] or 'nothing'}")
            return
        self.stack.pop()
        if tag == "td" and self._cell is not None:
            self.rows[self._row].append("".join(self._cell).strip())
            self._cell = None
        if tag == "tr":
            self._row = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def walk(html: str) -> StrictWalk:
    parser = StrictWalk()
    parser.feed(html)
    parser.close()
    return parser


def assert_self_contained(html: str) -> None:
    """Nothing in the page points outside it: no URL scheme, no script/link/img/iframe, local references only."""
    assert not re.search(r"(?i)\b(?:https?|ftp|file):", html), re.search(r"(?i)\b(?:https?|ftp|file):.{0,60}", html)
    assert not re.search(r"(?i)<(script|link|img|iframe|object|embed|base|audio|video|source)\b", html)
    assert "@import" not in html
    for m in re.finditer(r"url\(([^)]*)\)", html):
        assert m.group(1).startswith("#"), m.group(0)
    for tag, name, value in walk(html).refs:
        if name in ("href", "xlink:href"):
            assert value.startswith("#"), (tag, name, value)
        elif name != "style":
            raise AssertionError(f"<{tag} {name}={value!r}> loads something")


def assert_well_formed(html: str) -> StrictWalk:
    w = walk(html)
    assert w.doctype and w.doctype.lower() == "doctype html"
    assert not w.errors, w.errors[:5]
    assert w.stack == [], w.stack
    for tag in ("html", "head", "body", "title"):
        assert w.counts.get(tag) == 1, tag
    duplicates = sorted({i for i in w.ids if w.ids.count(i) > 1})
    assert not duplicates, duplicates[:5]
    ids = set(w.ids)
    local = [v[1:] for _, name, v in w.refs if name == "href"] + re.findall(r"url\(#([^)]+)\)", html)
    missing = sorted({r for r in local if r not in ids})
    assert not missing, missing[:5]
    return w


# -- the run's own reports ------------------------------------------------------------------

def test_run_writes_a_self_contained_html_report_with_every_coefficient(run):
    html = run.html
    assert_self_contained(html)
    w = assert_well_formed(html)
    assert list(run.result.coefficients) == canonical_names()
    for name, c in run.result.coefficients.items():
        cells = w.rows[f"coef-{name}"]
        assert cells[0] == name
        assert math.isclose(float(cells[1]), c.value, rel_tol=1e-9, abs_tol=1e-12), (name, cells)
        assert math.isclose(float(cells[2]), c.sigma, rel_tol=1e-2), (name, cells)
        assert cells[3] == c.unit
        truth = run.result.sim_truth[name].value
        assert math.isclose(float(cells[4]), truth, rel_tol=1e-9, abs_tol=1e-12)
        assert math.isclose(float(cells[5]), (c.value - truth) / c.sigma, rel_tol=1e-2, abs_tol=1e-3)
    # truth z, residuals, mean per dwell, time series, table angles
    assert w.counts.get("svg") == 5 == html.count("<svg ")
    assert all(len(svg) > 2000 for svg in re.findall(r"<svg .*?</svg>", html, re.S))
    for heading in ("Run", "Quality checks", "Coefficients", "Quality", "Residuals", "IMU outputs and table angles"):
        assert f"<h2>{heading}</h2>" in html
    assert run.result.run.run_id in html
    assert "The log is damaged" not in html          # the live run read its own log before closing it


def test_markdown_report_lists_every_coefficient(run):
    for name, c in run.result.coefficients.items():
        row = next(line for line in run.md.splitlines() if line.startswith(f"| {name} |"))
        assert math.isclose(float(row.split("|")[2]), c.value, rel_tol=1e-9, abs_tol=1e-12)
    assert "## Residuals" in run.md and "## Comparison" not in run.md


def test_plots_cover_the_log(run):
    series = log_series(run.log)
    steps = [s for s in json.loads(run.log.metadata["plan"]["steps_json"]) if s["kind"] == "dwell"]
    assert series.dwell_labels == sorted(s["unit"] for s in steps)
    assert len(series.spans) == len(steps) + len(run.result.residuals["rotations"])
    assert len(series.sample_t_s) > 10000 and series.acc_rate.shape == (len(series.sample_t_s), 3)
    # A dwell at rest: the accelerometers' means are ~ +-1 g (40000 counts/s per g) or 0 per axis.
    assert np.all(np.abs(series.acc_mean).max(axis=1) > 30000)
    assert len(series.state_t_s) == len(run.log.read_table_states()) and not series.notes


@pytest.mark.slow
def test_report_time_for_the_short_log(run, tmp_path):
    started = time.perf_counter()
    md, html = write_reports(run.result, tmp_path, "timed", log=run.log)
    elapsed = time.perf_counter() - started
    print(f"\nreports for a log of {len(run.log.read_can_frames().ids)} CAN frames: {elapsed:.2f} s, "
          f"HTML {html.stat().st_size / 1e3:.0f} kB")
    assert md.name == "timed.report.md" and html.name == "timed.report.html"
    assert_self_contained(html.read_text(encoding="utf-8"))


# -- outliers -----------------------------------------------------------------------------------

def _with_outliers(result: CalibrationResult) -> CalibrationResult:
    """P04's acc_y residual at 7.5 sigma (normalized value only) and R02's gyro_z listed by the solver only."""
    edited = copy.deepcopy(result)
    edited.residuals["positions"][3]["acc_normalized"][1] = 7.5
    edited.quality.outliers = [Outlier(step="rotation", index=1, sensor="gyro_z", normalized=-6.25)]
    return edited


def test_markdown_flags_outliers(run):
    edited = _with_outliers(run.result)
    md = markdown_report(edited, title="t")
    p04 = edited.residuals["positions"][3]["label"]
    r02 = edited.residuals["rotations"][1]["label"]
    flagged = [line for line in md.splitlines() if line.startswith("|") and "**OUTLIER**" in line]
    assert len(flagged) == 2, flagged
    assert flagged[0].startswith(f"| **{p04}** |") and "acc_y 7.5 sigma" in flagged[0]
    assert flagged[1].startswith(f"| **{r02}** |") and "gyro_z -6.25 sigma" in flagged[1]
    # the real run's tables flag exactly what its solver listed
    listed = {(o.step, o.index) for o in run.result.quality.outliers or []}
    assert sum(line.startswith("|") and "**OUTLIER**" in line for line in run.md.splitlines()) == len(listed)


def test_html_highlights_outliers(run):
    edited = _with_outliers(run.result)
    html = html_report(edited)
    assert_self_contained(html)
    assert_well_formed(html)
    rows = re.findall(r'<tr class="outlier">(.*?)</tr>', html, re.S)
    labels = [re.search(r"<td>([^<]*)</td>", r).group(1) for r in rows]
    assert labels == [edited.residuals["positions"][3]["label"], edited.residuals["rotations"][1]["label"]]
    assert "OUTLIER acc_y 7.5 sigma" in rows[0] and "OUTLIER gyro_z -6.25 sigma" in rows[1]
    # x, y and z one above the other (the tables were too wide for a page): no comma lists in residual cells
    assert re.search(r'<td class="num">[^<,]+<br>[^<,]+<br>[^<,]+</td>', rows[0]), rows[0]
    # without a log: truth and residual plots only
    assert html.count("<svg ") == 2 and "IMU outputs" not in html


# -- comparison with an earlier result ---------------------------------------------------------

def _moved(result: CalibrationResult) -> CalibrationResult:
    """An 'earlier' result: Kg_x 5 combined sigmas lower, D0_y 1 higher, Eg_Xy missing."""
    old = copy.deepcopy(result)
    for name, z in (("Kg_x", 5.0), ("D0_y", -1.0)):
        c = old.coefficients[name]
        old.coefficients[name] = type(c)(c.value - z * math.sqrt(2.0) * c.sigma, c.sigma, c.unit)
    del old.coefficients["Eg_Xy"]
    old.run = RunInfo.from_dict({**old.run.to_dict(), "run_id": "OLD-RUN", "positions": "traditional-12"})
    return old


def test_comparison_in_sigma(run):
    old = _moved(run.result)
    comparison = compare_results(run.result, old)
    by_name = {c.name: c for c in comparison.changes}
    assert list(by_name) == canonical_names()
    assert by_name["Kg_x"].z == pytest.approx(5.0, rel=1e-9)
    assert by_name["D0_y"].z == pytest.approx(-1.0, rel=1e-9)
    assert by_name["Ka_z"].z == 0.0
    assert by_name["Eg_Xy"].old is None and by_name["Eg_Xy"].z is None
    assert [c.name for c in comparison.flagged] == ["Kg_x"]
    assert ("run_id", "OLD-RUN", run.result.run.run_id) in comparison.run_changes
    assert "only in this result: Eg_Xy" in comparison.notes


def test_reports_against_an_earlier_result(run, tmp_path):
    old_path = tmp_path / "old.result.json"
    _moved(run.result).save(old_path)
    md_path, html_path = write_reports(run.result, tmp_path, "cmp", against=CalibrationResult.load(old_path))
    md = md_path.read_text(encoding="utf-8")
    assert "## Comparison with OLD-RUN" in md
    assert "**1 coefficient(s) changed by more than 3 sigma**: Kg_x (5 sigma)" in md
    changed = [line for line in md.split("## Comparison")[1].splitlines() if "**CHANGED**" in line]
    assert len(changed) == 1 and changed[0].startswith("| Kg_x |") and "| 5 |" in changed[0]
    d0 = next(line for line in md.split("## Comparison")[1].splitlines() if line.startswith("| D0_y |"))
    assert "| -1 |" in d0 and "CHANGED" not in d0
    assert "- positions: traditional-12 -> optimal-24" in md

    html = html_path.read_text(encoding="utf-8")
    assert_self_contained(html)
    w = assert_well_formed(html)
    assert w.rows["change-Kg_x"][5] == "5" and w.rows["change-Kg_x"][6] == "CHANGED"
    assert w.rows["change-D0_y"][5] == "-1" and w.rows["change-D0_y"][6] == ""
    assert w.rows["change-Eg_Xy"][1] == "-"
    assert re.search(r'<tr id="change-Kg_x" class="changed">', html)
    assert html.count("<svg ") == 3   # truth, residuals, change in sigma


# -- free text from a log, a configuration or a result file ------------------------------------

def test_markdown_escapes_free_text_as_the_html_report_does(run, tmp_path):
    """Many viewers render Markdown as HTML: an operator named <script> must not become a script there."""
    hostile = copy.deepcopy(run.result)
    hostile.run = RunInfo.from_dict({**hostile.run.to_dict(), "operator": "<script>alert(1)</script>",
                                     "mode": "simulator\n# forged heading",
                                     "imu": {"model": "<b>IMU</b>", "serial": "[x](javascript:alert(1)) | y"}})
    hostile.residuals["positions"][0]["label"] = "<img src=x onerror=alert(1)>"
    old = _moved(run.result)
    old.run = RunInfo.from_dict({**old.run.to_dict(), "positions": "<i>old</i>"})
    md = markdown_report(hostile, problems=["P02: <iframe src=x>"], failures=["**PASSED** _really_"],
                         title="report <script>", against=old, against_label="<u>old</u>.result.json")
    for raw in ("<script", "<b>", "<img", "<iframe", "<i>", "<u>", "[x](javascript", "\n# forged"):
        assert raw not in md, raw
    assert "- **operator**: &lt;script&gt;alert(1)&lt;/script&gt;" in md
    assert "- **mode**: simulator # forged heading" in md
    assert "- **IMU**: &lt;b&gt;IMU&lt;/b&gt; \\[x\\](javascript:alert(1)) \\| y" in md
    assert "- P02: &lt;iframe src=x&gt;" in md and "- \\*\\*PASSED\\*\\* \\_really\\_" in md
    assert "| &lt;img src=x onerror=alert(1)&gt; |" in md
    assert "## Comparison with &lt;u&gt;old&lt;/u&gt;.result.json" in md
    assert "- positions: &lt;i&gt;old&lt;/i&gt; -> " in md
    assert md.startswith("# report &lt;script&gt;\n")
    # the same in the HTML report, which always escaped it
    html = html_report(hostile)
    assert "<script" not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    # an output name that is not a safe file name is refused before anything is written
    with pytest.raises(InputError):
        write_reports(hostile, tmp_path, "../escape")
    assert list(tmp_path.iterdir()) == []


# -- logs that are not pristine -------------------------------------------------------------

@pytest.mark.slow
def test_damaged_log_without_its_dbc_is_reported(run, tmp_path):
    data = run.log_path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    log = read_log(cut)
    assert not log.scan().complete
    assert log.chunks >= 20 and log.unchecked_chunks >= 10, \
        (f"test setup: the cut keeps many whole chunks, /imu/samples ones among them: {log.chunks} chunks, "
         f"{log.unchecked_chunks} of /imu/samples")
    log.attachments.clear()   # as if the DBC attachment were lost too: plots fall back to /imu/samples
    html = html_report(run.result, log=log)
    assert_self_contained(html)
    assert_well_formed(html)
    assert "The log is damaged; what was lost:" in html
    lost = re.search(r"what was lost:</p><ul>(.*?)</ul>", html, re.S).group(1)
    assert lost.count("<li>") == len(log.scan().damage)
    assert "plots use the recorded /imu/samples topic" in html and html.count("<svg ") == 5
    # The live run reads its own log before closing it: a missing summary is expected there, nothing else is.
    no_summary = [d.describe() for d in log.scan().lost if d.kind == "no_summary"]
    assert no_summary and log_damage(log, still_open=True) == [d for d in log.scan().damage if d not in no_summary]
    assert log_damage(log) == log.scan().damage


def test_log_without_its_dbc_plots_the_decoded_topic(run):
    log = read_log(run.log_path)
    log.attachments.clear()
    series = log_series(log)
    assert series.notes and "/imu/samples" in series.notes[0]
    assert len(series.sample_t_s) == len(log.read_imu_records()) > 0
    reference = log_series(run.log)
    assert series.dwell_labels == reference.dwell_labels
    np.testing.assert_allclose(series.acc_mean, reference.acc_mean)
    np.testing.assert_allclose(series.gyro_std, reference.gyro_std)


def test_minimal_result_renders(run):
    bare = CalibrationResult({k: run.result.coefficients[k] for k in ("Ka_x", "K0_x")})
    html = html_report(bare, failures=["something & <odd>"])
    assert_self_contained(html)
    w = assert_well_formed(html)
    assert set(w.rows) == {"coef-Ka_x", "coef-K0_x"} and "<svg" not in html
    assert "something &amp; &lt;odd&gt;" in html
    assert "Quality check **failed**" in markdown_report(bare, failures=["x"])


def test_both_reports_name_every_log_of_a_resumed_run_and_the_site_in_words(run):
    """The HTML report said `local_g None`; the Markdown one named only the resumed run's last log."""
    result = CalibrationResult({k: run.result.coefficients[k] for k in ("Ka_x", "K0_x")},
                               run=RunInfo.from_dict({"run_id": "r1", "log": "r1-b.mcap",
                                                      "logs": ["r1-a.mcap", "r1-b.mcap"],
                                                      "site": {"latitude_deg": 30.27, "height_m": 12.5,
                                                               "local_g": None}}, complete=False))
    md, html = markdown_report(result), html_report(result)
    assert "- **logs**: r1-a.mcap, r1-b.mcap" in md
    assert "- **site**: latitude 30.27 deg, height 12.5 m" in md
    assert "latitude 30.27 deg, height 12.5 m" in html and "r1-a.mcap, r1-b.mcap" in html
    assert "None" not in md and "None" not in html


# -- plot helpers ---------------------------------------------------------------------------

def test_envelope_keeps_spikes_within_the_point_budget():
    t = np.arange(100_003, dtype=float)
    y = np.sin(t / 5000.0)
    y[54321], y[777] = 50.0, -40.0
    y[90000:91000] = np.nan
    tt, yy = envelope(t, y, 1000)
    assert len(tt) <= 1000 and np.all(np.diff(tt) >= 0)
    assert 50.0 in yy and -40.0 in yy and tt[yy == 50.0][0] == 54321
    assert np.isnan(yy).any()
    small_t, small_y = envelope(t[:500], y[:500], 1000)
    assert np.array_equal(small_y, y[:500])


def test_inline_svg_prefixes_ids_and_drops_namespace_urls():
    text = ('<?xml version="1.0"?>\n<!DOCTYPE svg PUBLIC "-//W3C//DTD SVG 1.1//EN" "http://www.w3.org/x.dtd">\n'
            '<svg xmlns:xlink="http://www.w3.org/1999/xlink" width="1pt" xmlns="http://www.w3.org/2000/svg">'
            '<defs><style type="text/css">*{stroke-linecap: butt}</style></defs>'
            '<defs><path id="m1" d="M 0 0"/><clipPath id="p2"><rect/></clipPath></defs>'
            '<use xlink:href="#m1"/><g clip-path="url(#p2)" id="figure_1"/></svg>')
    out = inline_svg(text, "f7-")
    assert out.startswith("<svg ") and "http" not in out and "<style" not in out
    assert 'id="f7-m1"' in out and 'href="#f7-m1"' in out and "url(#f7-p2)" in out and 'id="f7-figure_1"' in out
    with pytest.raises(ValueError):
        inline_svg("<html></html>", "x")


def test_a_report_whose_writing_fails_leaves_no_half_file(run, tmp_path, monkeypatch):
    """Issue 34, item 3: outputs are written under a temporary name and renamed into place; a report that cannot
    be made (here the HTML) leaves neither a half file nor the temporary one."""
    from bench.report import markdown as markdown_module

    def broken(*args, **kwargs):
        return "<html>" * 1000 + "\ud800"        # fails while the file is written (cannot be encoded)

    monkeypatch.setattr(markdown_module, "html_report", broken)
    with pytest.raises(UnicodeEncodeError):
        write_reports(run.result, tmp_path, "half")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["half.report.md"]
