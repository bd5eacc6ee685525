"""Acceptance limits and the verdict (issue 16, item 3).

Each kind of limit is checked on its own (`bench.acceptance.verdict.judge`), a bad limit is
refused by the configuration reader with one `file:line: key: message` line, and `bench run`
on the simulator carries the verdict into the result, the reports and its exit code (4 on
fail), with a four-line summary even with `--quiet`. Issue 27: three outcomes (PASS only when
a check ran), each check named with its kind, and the reports say the same as the summary.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import pytest

from bench.acceptance.limits import AcceptanceLimits, CoefficientLimits
from bench.acceptance.verdict import FAIL, NOT_CHECKED, PASS, judge, stored_headline, stored_outcome
from bench.config.load import ConfigError, load_config, parse_config
from bench.model.imu import default_sim_imu
from bench.model.result import CalibrationResult, coefficient_table
from bench.model.verdict_section import VerdictSection
from bench.report.html import html_report
from bench.report.markdown import markdown_report
from tests.helpers.run import cli, config_text, load_json, only_file
from tests.helpers.shared import share

TRUTH = default_sim_imu().to_canonical()       # Kg_x 36012.5, D0_x 0.052 deg/h, K0_x 1.2e-4 g, ...


def _result(sigma: float = 1e-3, **changes: float) -> CalibrationResult:
    values = {**TRUTH, **changes}
    result = CalibrationResult(coefficient_table(values, {n: sigma for n in values}))
    result.residuals = {"positions": [{"index": 0, "acc_normalized": [0.5, -2.5, 1.0], "gyro_normalized": [0.1]}],
                        "rotations": [{"index": 0, "gyro_normalized": [-1.5, None, 0.2]}]}
    return result


def _checks(verdict) -> dict[str, bool]:
    return {c.name: c.passed for c in verdict.checks}


# -- each kind of limit ------------------------------------------------------------------------------

def test_a_value_range_per_family_and_per_coefficient():
    limits = AcceptanceLimits(families={"Kg": CoefficientLimits(min=36000.0, max=36020.0)},
                              coefficients={"Kg_z": CoefficientLimits(min=36020.0, max=36030.0)})
    verdict = judge(_result(), limits)
    assert _checks(verdict) == {"Kg_x value": True, "Kg_y value": False, "Kg_z value": True}    # Kg_y 35987.2
    assert not verdict.passed and verdict.worst.name == "Kg_y value"
    assert verdict.worst.describe() == "Kg_y value 35987.2 counts/s per deg/s outside [36000, 36020]"
    assert verdict.worst.ratio == pytest.approx((36010.0 - 35987.2) / 10.0)


def test_a_maximum_uncertainty_and_an_unknown_one_fails():
    limits = AcceptanceLimits(families={"D0": CoefficientLimits(max_sigma=0.002)})
    assert judge(_result(sigma=0.001), limits).passed
    verdict = judge(_result(sigma=0.003), limits)
    assert _checks(verdict) == {"D0_x sigma": False, "D0_y sigma": False, "D0_z sigma": False}
    assert verdict.worst.describe() == "D0_x sigma 0.003 > 0.002 deg/h"
    unknown = judge(_result(sigma=math.nan), limits)
    assert not unknown.passed and unknown.checks[0].describe() == "D0_x sigma: unknown"


def test_a_maximum_change_from_a_nominal_or_from_a_reference_result():
    assert TRUTH["K0_x"] == pytest.approx(1.2e-4)
    near = AcceptanceLimits(coefficients={"K0_x": CoefficientLimits(max_change=1e-4, nominal=1e-4)})
    far = AcceptanceLimits(coefficients={"K0_x": CoefficientLimits(max_change=1e-4, nominal=0.0)})
    assert judge(_result(), near).passed
    verdict = judge(_result(), far)
    assert not verdict.passed and verdict.worst.describe() == "K0_x change 0.00012 beyond +-0.0001 g (from nominal 0)"
    reference = AcceptanceLimits(families={"Ka": CoefficientLimits(max_change=1.0)},
                                 reference={**TRUTH, "Ka_y": TRUTH["Ka_y"] + 2.0}, reference_name="old.result.json")
    verdict = judge(_result(), reference)
    assert _checks(verdict) == {"Ka_x change": True, "Ka_y change": False, "Ka_z change": True}
    assert verdict.worst.describe() == ("Ka_y change -2 beyond +-1 counts/s per g "
                                        "(from reference old.result.json 39980.5)")


def test_lost_samples_residuals_and_the_runs_quality_failures():
    limits = AcceptanceLimits(max_lost_samples=3, max_residual_sigma=2.0)
    verdict = judge(_result(), limits, lost_samples=4, quality_failures=["P07: left out: not run"])
    assert _checks(verdict) == {"lost samples": False, "residual": False, "quality": False}
    assert [c.value for c in verdict.checks[:2]] == [4.0, 2.5]          # the largest |residual| / sigma
    assert judge(_result(), AcceptanceLimits(max_lost_samples=4, max_residual_sigma=2.5), lost_samples=4).passed
    assert "P07: left out" in verdict.checks[2].describe()


def test_a_limited_coefficient_missing_from_the_result_fails():
    result = _result()
    del result.coefficients["Eg_Yx"]
    verdict = judge(result, AcceptanceLimits(coefficients={"Eg_Yx": CoefficientLimits(min=-1e-3, max=1e-3)}))
    assert not verdict.passed and verdict.checks[0].describe() == "Eg_Yx: not in the result"


def test_no_check_is_not_checked_and_a_quality_failure_alone_fails_as_quality():
    """Issue 27: PASS only when a check ran; the quality checks can fail a result but never pass it."""
    unchecked = judge(_result(), AcceptanceLimits())
    assert unchecked.outcome == NOT_CHECKED and not unchecked.passed and not unchecked.failed
    assert unchecked.headline().startswith("NOT CHECKED (no check ran")
    assert unchecked.to_json()["verdict"] == "not checked" and unchecked.to_json()["passed"] is False
    quality = judge(_result(), AcceptanceLimits(), quality_failures=["P07: left out: not run"])
    assert quality.outcome == FAIL and quality.headline() == "FAIL (quality: 1 failed)"
    assert quality.worst is not None and quality.worst.labelled() == "quality check failed: P07: left out: not run"
    both = judge(_result(), AcceptanceLimits(max_lost_samples=0), lost_samples=2, quality_failures=["P07: left out"])
    assert both.headline() == "FAIL (acceptance: 1 of 1 failed: lost samples; quality: 1 failed)"
    passed = judge(_result(), AcceptanceLimits(max_lost_samples=0), lost_samples=0)
    assert passed.outcome == PASS and passed.headline() == "PASS (1 check: 1 acceptance)"
    assert passed.to_json()["verdict"] == "pass" and passed.to_json()["checks"][0]["kind"] == "acceptance"


def test_an_older_result_files_pass_without_checks_reads_as_not_checked(tmp_path):
    """A result written before issue 27 (`PASS (no acceptance limits configured)`, no check) still loads, and the
    reports and the TUI tell it by today's rule."""
    old = {"passed": True, "verdict": "pass", "headline": "PASS (no acceptance limits configured)", "worst": None,
           "checks": []}
    result = _result()
    result.verdict, result.residuals = VerdictSection.from_dict(old), {}
    path = tmp_path / "old.result.json"
    result.save(path)
    loaded = CalibrationResult.load(path)
    assert loaded.verdict.to_dict() == old                          # kept as stored
    assert stored_outcome(old) == NOT_CHECKED and stored_headline(old) == "NOT CHECKED (no check ran)"
    assert "**Verdict: NOT CHECKED (no check ran)**" in markdown_report(loaded)
    html = html_report(loaded)
    assert '<span class="notchecked">NOT CHECKED</span>' in html and 'class="pass"' not in html
    failed = {**old, "passed": False, "headline": "FAIL (1 of 1 checks: quality)",
              "checks": [{"name": "quality", "passed": False, "text": "quality: P07 left out"}]}
    assert stored_outcome(failed) == FAIL and stored_headline(failed) == failed["headline"]
    result.verdict = VerdictSection.from_dict(failed)
    assert "| quality | quality: P07 left out | **FAIL** |" in markdown_report(result)


# -- the configuration ------------------------------------------------------------------------------

GOOD = """
[acceptance]
max_lost_samples = 0
max_residual_sigma = 6.0
[acceptance.Kg]
min = 35000
max = 37000
max_sigma = 0.1
[acceptance.D0]
max_change = 0.5
nominal = 0.0
[acceptance.Ea_Yx]
min = -0.002
max = 0.002
"""


def _config(tmp_path: Path, extra: str) -> Path:
    path = tmp_path / "bench.toml"
    path.write_text(config_text() + extra, encoding="utf-8")
    return path


def test_the_acceptance_section_is_read(tmp_path):
    config = load_config(_config(tmp_path, GOOD))
    a = config.acceptance
    assert (a.max_lost_samples, a.max_residual_sigma) == (0, 6.0)
    assert a.families["Kg"] == CoefficientLimits(min=35000.0, max=37000.0, max_sigma=0.1)
    assert a.for_coefficient("Ea_Yx", "Ea") == CoefficientLimits(min=-0.002, max=0.002)
    assert parse_config(config_text()).acceptance == AcceptanceLimits()


def test_a_reference_result_is_read_when_the_configuration_is(tmp_path):
    old = tmp_path / "old.result.json"
    CalibrationResult(coefficient_table(TRUTH)).save(old)
    config = load_config(_config(tmp_path, '[acceptance]\nreference = "old.result.json"\n[acceptance.Kg]\n'
                                           "max_change = 1.0\n"))
    assert config.acceptance.reference == pytest.approx(TRUTH) and config.acceptance.reference_name == old.name


BAD = [
    ("[acceptance.Kg]\nmin = 36000\n", "acceptance.Kg.min: a range needs both min and max"),
    ("[acceptance.Kg]\nmin = 36000\nmax = 35000\n", "acceptance.Kg.max: must be above min (36000), got 35000"),
    ("[acceptance.D0_x]\nmax_sigma = 0\n", "acceptance.D0_x.max_sigma: must be > 0 deg/h, got 0"),
    ("[acceptance.K0]\nmax_sigma = 5\n", "acceptance.K0.max_sigma: must be <= 2 g, got 5"),
    ("[acceptance.Eg]\nmin = -2\nmax = 1\n", "acceptance.Eg.min: must be >= -1, got -2"),
    ("[acceptance.Kg]\nmax_sigma = \"big\"\n",
     "acceptance.Kg.max_sigma: must be a finite number, got the string 'big'"),
    ("[acceptance.Ka_y]\nmax_change = 1.0\n",
     "acceptance.Ka_y.max_change: needs a nominal value or an [acceptance] reference result file"),
    ("[acceptance.Kg]\nmaximum = 1\n", "acceptance.Kg.maximum: unknown key"),
    ("[acceptance]\nKx_q = 1\n", "acceptance.Kx_q: unknown key"),
    ("[acceptance]\nmax_lost_samples = -1\n", "acceptance.max_lost_samples: must be >= 0, got -1"),
    ("[acceptance]\nmax_lost_samples = 1.5\n", "acceptance.max_lost_samples: must be a whole number"),
    ("[acceptance]\nmax_residual_sigma = 0\n", "acceptance.max_residual_sigma: must be > 0 sigma, got 0"),
    ("[acceptance]\nreference = \"missing.result.json\"\n", "acceptance.reference: no such result file"),
    ("[acceptance]\nreference = \"bench.toml\"\n", "acceptance.reference: "),
]


@pytest.mark.parametrize("extra, message", BAD, ids=[m.split(":")[0] + f"-{i}" for i, (_, m) in enumerate(BAD)])
def test_a_bad_limit_is_refused_with_file_line_and_key(tmp_path, extra, message):
    path = _config(tmp_path, extra)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    text = str(info.value)
    key = message.split(":")[0]
    line = next(i for i, ln in enumerate(path.read_text().splitlines(), 1)
                if ln.startswith(key.rsplit(".", 1)[-1]) or ln.startswith(f"[{key}]"))
    assert text.startswith(f"{path}:{line}: {message}"), text
    rc, stdout, stderr = cli(["run", "--config", str(path), "--out", str(tmp_path / "out"), "--quiet"])
    assert rc == 2 and stdout == "" and stderr.strip().splitlines() == [f"bench run: {text}"]
    assert not (tmp_path / "out").exists()


# -- bench run: verdict, summary, exit code ------------------------------------------------------

PASSING = """
[acceptance]
max_lost_samples = 0
max_residual_sigma = 1000.0
[acceptance.Kg]
min = 35900
max = 36100
max_sigma = 0.1
[acceptance.K0]
max_change = 0.01
nominal = 0.0
"""
#: the short noise-free plan's uncertainties are ~1e-3 counts/s per deg/s on Kg: 1e-6 fails all three
FAILING = PASSING.replace("max_sigma = 0.1", "max_sigma = 1e-6")


@pytest.fixture(scope="module")
def judged_run(tmp_path_factory):
    """`judged_run(limits)`: `bench run` of the short test plan with `limits`, recorded once per module for the
    tests that only read it (exit code, stdout, stderr, its output folder and records database). Write nothing
    into its folder: a test's own outputs go to its `tmp_path`."""
    recorded: dict[str, SimpleNamespace] = {}

    def judged(limits: str) -> SimpleNamespace:
        if limits not in recorded:
            folder = tmp_path_factory.mktemp("judged")
            out, db = folder / "out", folder / "records.sqlite"
            rc, stdout, stderr = cli(["run", "--config", str(_config(folder, limits)), "--out", str(out), "--quiet",
                                      "--db", str(db)])
            recorded[limits] = SimpleNamespace(rc=rc, stdout=stdout, stderr=stderr, out=out, db=share(folder) / db.name)
        return recorded[limits]

    return judged


@pytest.mark.slow
@pytest.mark.parametrize("limits, code", [(PASSING, 0), (FAILING, 4)], ids=["pass", "fail"])
def test_bench_run_judges_the_result_and_says_so_in_its_closing_lines(judged_run, limits, code):
    run = judged_run(limits)
    rc, stdout, stderr, out, db = run.rc, run.stdout, run.stderr, run.out, run.db
    assert rc == code, stderr
    result_path, report_path = only_file(out, "*.result.json"), only_file(out, "*.report.md")
    lines = stdout.splitlines()
    assert len(lines) == 4, stdout
    result = load_json(result_path)
    verdict = result["verdict"]
    assert list(result)[:3] == ["format", "version", "verdict"]
    checks = {c["name"]: c for c in verdict["checks"]}
    assert set(checks) == {"Kg_x value", "Kg_y value", "Kg_z value", "Kg_x sigma", "Kg_y sigma", "Kg_z sigma",
                           "K0_x change", "K0_y change", "K0_z change", "lost samples", "residual"}
    assert {c["kind"] for c in verdict["checks"]} == {"acceptance"}
    html = only_file(out, "*.report.html").read_text(encoding="utf-8")
    if code == 0:
        assert verdict["passed"] is True and verdict["verdict"] == "pass" and stderr == ""
        assert lines[0] == "verdict: PASS (11 checks: 11 acceptance)"
        assert html.count('class="pass"') == 1 and '<span class="pass">PASS</span>' in html
    else:
        assert verdict["passed"] is False and verdict["verdict"] == "fail"
        assert lines[0] == "verdict: FAIL (acceptance: 3 of 11 failed: Kg_x sigma, Kg_y sigma, Kg_z sigma)"
        assert [c["name"] for c in verdict["checks"] if not c["passed"]] == ["Kg_x sigma", "Kg_y sigma", "Kg_z sigma"]
        assert stderr.startswith("bench run: verdict FAIL: acceptance limit: Kg_x sigma ")
        assert len(stderr.splitlines()) == 1
        assert checks["Kg_x sigma"]["limit"] == 1e-6 and checks["Kg_x sigma"]["value"] > 1e-6
        # issue 27: one verdict, one colour: no green "quality checks passed" under the red FAIL
        assert '<span class="fail">FAIL</span>' in html and 'class="pass"' not in html
        assert "passed" not in html.split("<h2>Quality checks</h2>", 1)[1].split("<h2>", 1)[0]
    worst = max(verdict["checks"], key=lambda c: (not c["passed"], c["ratio"]))
    assert lines[1] == f"worst:   acceptance limit: {worst['text']}" and verdict["worst"] == lines[1][9:]
    assert lines[2].startswith(f"result:  {result_path}  report: {report_path}, ")
    assert lines[3] == f"records: {db.absolute()}" and db.is_file()
    report = report_path.read_text(encoding="utf-8")
    first_section = report.split("\n## ", 1)[0]
    assert f"**Verdict: {lines[0].removeprefix('verdict: ')}**" in first_section
    assert html.index("<h2>Verdict: ") < html.index("<h2>Run</h2>")
    assert "Quality checks passed" not in report + html
    assert CalibrationResult.load(result_path).verdict.to_dict() == verdict      # read back
    assert json.loads(result_path.read_text())["coefficients"]["Kg_x"]["unit"] == "counts/s per deg/s"


@pytest.mark.slow
def test_bench_solve_judges_a_log_by_its_recorded_acceptance_limits(judged_run, tmp_path):
    """The failing run of `test_bench_run_judges_the_result_and_says_so_in_its_closing_lines` (the module's, read
    only), re-solved into `tmp_path`."""
    out = judged_run(FAILING).out
    assert judged_run(FAILING).rc == 4
    run_verdict = load_json(only_file(out, "*.result.json"))["verdict"]
    rc, stdout, stderr = cli(["solve", str(only_file(out, "*.mcap")), "--out", str(tmp_path / "solved"),
                              "--no-html"])
    assert rc == 4 and "verdict: FAIL (acceptance: 3 of 11 failed: Kg_x sigma, Kg_y sigma, Kg_z sigma)" in stdout
    assert stderr.startswith("bench solve: verdict FAIL: acceptance limit: Kg_x sigma ")
    solved = load_json(only_file(tmp_path / "solved", "*.result.json"))["verdict"]
    assert [(c["name"], c["passed"]) for c in solved["checks"]] == [(c["name"], c["passed"])
                                                                   for c in run_verdict["checks"]]
