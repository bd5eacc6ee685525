"""The typed sections of a calibration result (issue 28 item 3): `run` (`RunInfo`, with `ImuIdentity`, `ImuLink`
and `LostSamples`), `quality` (`QualitySection`, with `FitQuality` and `Outlier`) and `verdict` (`VerdictSection`,
with `CheckRecord`). A real result file reads back to the same bytes; an older file's shape (entries missing, in
another order, entries this software does not know) loads and writes back as it was; a malformed section is
refused in one line naming the file, the section and the entry."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from bench.acceptance.limits import AcceptanceLimits, CoefficientLimits
from bench.acceptance.verdict import judge
from bench.model.closed_form import exact_observations
from bench.model.earth import Site
from bench.model.imu import default_sim_imu
from bench.model.quality_section import FitQuality, Outlier, QualitySection
from bench.model.result import CalibrationResult, ResultFormatError, coefficient_table
from bench.model.run_section import ImuIdentity, ImuLink, LostSamples, RunInfo
from bench.model.verdict_section import CheckRecord, VerdictSection
from bench.solve.calibrate import solve
from drivers.imu.receiver import TimeBase
from drivers.imu.samples import ImuStats
from schedules import load_builtin
from tests.helpers.run import only_file

#: every section type with where a result file has one of it (a list: each item is one)
WHERE = {RunInfo: ("run",), ImuIdentity: ("run", "imu"), ImuLink: ("run", "imu_link"),
         LostSamples: ("run", "lost_samples"), QualitySection: ("quality",), FitQuality: ("quality", "gyros"),
         Outlier: ("quality", "outliers"), VerdictSection: ("verdict",), CheckRecord: ("verdict", "checks")}


def _entries(data: dict, path: tuple[str, ...]) -> list:
    """The entries at `path` (none when the file has none there)."""
    for key in path:
        if key not in data:
            return []
        data = data[key]
    return data if isinstance(data, list) else [data]


def _round_trips(text: str, complete: bool = True) -> None:
    """Every section of the result file `text` reads back to the same JSON, and the file to the same bytes
    (`complete`: its run section has every entry the bench writes)."""
    data = json.loads(text)
    for cls, path in WHERE.items():
        for entry in _entries(data, path):
            section = (RunInfo.from_dict(entry, complete=complete) if cls is RunInfo
                       else cls.from_dict(entry, ".".join(path)))
            assert json.dumps(section.to_dict()) == json.dumps(entry), (cls.__name__, path)
    assert CalibrationResult.loads(text, "r.json").dumps() + "\n" == text


# -- result files the bench wrote ----------------------------------------------------------------------------------

@pytest.mark.slow
def test_a_bench_run_result_reads_back_to_the_same_bytes_with_typed_sections(short_run):
    text = short_run.result.read_text(encoding="utf-8")
    _round_trips(text)
    result = CalibrationResult.load(short_run.result)
    run = result.run
    assert run.run_id == short_run.log.stem and run.logs == [short_run.log.name] and run.finished_utc
    assert isinstance(run.imu, ImuIdentity) and run.imu.serial
    assert isinstance(run.imu_link, ImuLink) and run.imu_link.frames and run.imu_link.samples
    assert isinstance(run.lost_samples, LostSamples) and run.lost_samples.total == 0
    assert run.extra == {}
    quality = result.quality
    assert quality.outlier_sigma == 4.0 and isinstance(quality.gyros, FitQuality) and quality.gyros.dof
    assert quality.gyro_bias is not None and quality.gyro_bias.dof is None and quality.gyro_bias.sigma_scaled
    assert quality.uncertainty is not None and quality.uncertainty["k"] == 2.0
    assert isinstance(result.verdict, VerdictSection) and result.verdict.verdict == "not checked"
    assert result.verdict.worst is None and result.verdict.checks == []
    assert json.loads(text)["verdict"]["worst"] is None          # a null the file has is written back


@pytest.mark.slow
def test_a_thermal_runs_results_read_back_to_the_same_bytes_with_the_entries_added_after_the_run(thermal_run_log):
    folder = thermal_run_log.parent
    head = only_file(folder, f"{thermal_run_log.stem}.result.json")
    for path in [head, *sorted(folder.glob("*.T*.result.json"))]:
        _round_trips(path.read_text(encoding="utf-8"))
    run = CalibrationResult.load(head).run
    assert list(run.extra) == ["temperature_block", "temperature_setpoint_c", "thermal"]
    assert run.extra["thermal"]["this_block"] in (1, 2)


def test_a_verdict_is_held_as_written_nulls_ranges_and_unknowns_included():
    truth = default_sim_imu().to_canonical()
    result = CalibrationResult(coefficient_table({k: v for k, v in truth.items() if k != "Eg_Xy"},
                                                 {k: 1e-3 for k in truth}))
    limits = AcceptanceLimits(families={"Kg": CoefficientLimits(min=35900.0, max=36100.0, max_sigma=0.1),
                                        "Eg": CoefficientLimits(max_sigma=1.0)}, max_lost_samples=0)
    verdict = judge(result, limits, lost_samples=None, quality_failures=["P07: left out"])
    section = verdict.to_section()
    assert json.dumps(section.to_dict()) == json.dumps(verdict.to_json())
    by_name = {c.name: c for c in section.checks or []}
    assert by_name["Kg_x value"].limit == [35900.0, 36100.0] and by_name["Kg_x value"].passed
    assert by_name["lost samples"].value is None and by_name["lost samples"].ratio is None
    assert by_name["Eg_Xy"].passed is False and by_name["quality"].kind == "quality"
    result.verdict = section
    assert CalibrationResult.loads(result.dumps()).verdict == section


# -- older files ---------------------------------------------------------------------------------------------------

#: a verdict as the first version wrote it: another order, no `failed`, checks without a kind
OLD_VERDICT = {"passed": False, "verdict": "fail", "headline": "FAIL (1 of 1 checks: quality)", "worst": None,
               "checks": [{"name": "quality", "value": None, "limit": None, "unit": "", "passed": False,
                           "ratio": None, "text": "quality: P07 left out"}]}
#: a run section before the link statistics, the lost samples and the quality failures, with an entry of its own
OLD_RUN = {"run_id": "r1", "mode": "simulator", "operator": "", "seed": 7, "software_version": "0.1.0",
           "state": "done", "log": "r1.mcap", "positions": "optimal-24", "rotations": "optimal-5s6r",
           "finished_utc": "2026-11-22T10:00:00Z", "imu": {"model": "m", "serial": "s"},
           "site": {"latitude_deg": 30.27, "height_m": 0.0}}
#: the quality of a result before version 2: no budget, fits without sigma_scaled
OLD_QUALITY = {"flags": [], "accelerometers": {"chi2_per_dof": [1.1, None, 0.9], "dof": 18, "weighted": True},
               "outliers": [{"step": "position", "index": 3, "sensor": "acc_y", "normalized": 7.5}]}


def _old_file() -> str:
    """A version 1 file (the sections' order in the file is today's: the file writes them so)."""
    coefficients = CalibrationResult(coefficient_table({"Kg_x": 36000.0}, {"Kg_x": 0.01})).to_json()["coefficients"]
    return json.dumps({"format": "turntable-bench/result", "version": 1, "verdict": OLD_VERDICT,
                       "coefficients": coefficients, "residuals": {}, "quality": OLD_QUALITY, "run": OLD_RUN}, indent=2)


def test_an_older_files_sections_load_with_their_missing_entries_none_and_write_back_as_they_were():
    text = _old_file()
    result = CalibrationResult.loads(text, "old.json")
    assert result.dumps() == text.replace('"version": 1', '"version": 2')    # as saving an older file always did
    run = result.run
    assert run.imu_link is None and run.lost_samples is None and run.quality_failures is None and run.logs is None
    assert run.extra == {"seed": 7} and run.link_dict() is None
    assert result.quality.uncertainty is None and result.quality.outlier_sigma is None
    assert result.quality.accelerometers is not None and result.quality.accelerometers.sigma_scaled is None
    assert result.quality.outliers == [Outlier(step="position", index=3, sensor="acc_y", normalized=7.5)]
    assert result.verdict is not None and result.verdict.failed is None and result.verdict.checks
    assert result.verdict.checks[0].kind is None
    assert list(result.verdict.to_dict()) == list(OLD_VERDICT)      # the file's order, not today's


def test_entries_set_after_a_read_follow_the_files_entries():
    result = CalibrationResult.loads(_old_file())
    result.run.extra["verification"] = {"file": "v.json"}
    result.run.lost_samples = LostSamples(total=0, in_windows={}, outside_windows=0)
    section = result.to_json()["run"]
    assert list(section) == [*OLD_RUN, "lost_samples", "verification"]
    assert section["lost_samples"] == {"total": 0, "in_windows": {}, "outside_windows": 0}


def test_sections_built_in_code_write_the_benchs_order_without_the_entries_not_set():
    link = ImuLink.from_dict({**ImuStats(frames=3).as_dict()})
    info = RunInfo(run_id="r", mode="hardware", operator="", software_version="1", state="done", log="r.mcap",
                   logs=["r.mcap"], positions="p", rotations="", imu=ImuIdentity("m", "s"), site={},
                   quality_failures=[], imu_link=link, lost_samples=LostSamples(total=0), solved_by="bench solve")
    section = info.to_dict()
    assert list(section) == ["run_id", "mode", "operator", "software_version", "state", "log", "logs", "positions",
                             "rotations", "solved_by", "imu", "site", "quality_failures", "imu_link", "lost_samples"]
    assert section["imu_link"] == ImuStats(frames=3).as_dict() and section["lost_samples"] == {"total": 0}
    assert RunInfo.from_dict(section).to_dict() == section
    q = QualitySection(flags=["f"], gyro_bias=FitQuality(chi2_per_dof=[1.0, None, 2.0], sigma_scaled=[False] * 3))
    assert q.to_dict() == {"flags": ["f"], "gyro_bias": {"chi2_per_dof": [1.0, None, 2.0],
                                                        "sigma_scaled": [False, False, False]}}


def test_the_link_section_has_every_counter_of_the_link_statistics_and_the_time_base_in_their_order():
    base = TimeBase(lambda: 0.0)
    base.offset_s, base.lag_min_s, base.lag_max_s = 1.5, 0.001, 0.002
    written = {**ImuStats().as_dict(), **base.as_dict()}
    link = ImuLink.from_dict(written)
    assert link.extra == {} and link.can_time_offset_s == 1.5 and link.frames == 0
    assert [f.name for f in dataclasses.fields(ImuLink) if f.name not in ("extra", "keys")] == list(written)
    assert json.dumps(dataclasses.replace(link, keys=None).to_dict()) == json.dumps(written)


def test_a_calibration_given_its_run_section_as_entries_keeps_their_order():
    """`bench thermal --sim` writes each temperature's result with a partial run section in its own order."""
    imu = default_sim_imu()
    angles = np.array([p.angles_deg for p in load_builtin("traditional-12").positions])
    positions, rotations = exact_observations(angles, list(load_builtin("traditional-3s6r").rotations), imu,
                                              Site(30.27))
    run = {"mode": "simulator (in memory, soaked)", "seed": 3, "temperature_setpoint_c": 25.0,
           "imu": {"model": "m", "serial": "s"}}
    result = solve(positions, rotations, Site(30.27)).to_result(run, sim_truth=imu)
    assert result.run.imu == ImuIdentity("m", "s") and result.run.extra == {"seed": 3, "temperature_setpoint_c": 25.0}
    assert json.dumps(result.to_json()["run"]) == json.dumps(run)
    quality = result.to_json()["quality"]
    assert list(quality) == ["flags", "outlier_sigma", "accelerometers", "gyros", "gyro_bias", "outliers",
                             "uncertainty"]
    assert list(quality["accelerometers"]) == ["chi2_per_dof", "dof", "weighted", "sigma_scaled"]
    assert list(quality["gyro_bias"]) == ["chi2_per_dof", "sigma_scaled"]
    _round_trips(result.dumps() + "\n", complete=False)


# -- malformed sections --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("section, change, message", [
    ("run", lambda d: d["run"]["imu"].update(serial=5), "run.imu.serial must be a string"),
    ("run", lambda d: d["run"]["imu_link"].update(frames="many"), "run.imu_link.frames must be a whole number"),
    ("run", lambda d: d["run"]["imu_link"].update(can_lag_max_s=True), "run.imu_link.can_lag_max_s must be a finite"),
    ("run", lambda d: d["run"]["lost_samples"].update(in_windows={"P01": 1.5}),
     "run.lost_samples.in_windows.P01 must be a whole number"),
    ("run", lambda d: d["run"].update(lost_samples=[]), "run.lost_samples must be an object"),
    ("run", lambda d: d["run"].update(logs="r.mcap"), "run.logs must be a list"),
    ("run", lambda d: d["run"].update(quality_failures=[1]), r"run.quality_failures\[0\] must be a string"),
    ("run", lambda d: d.update(run="r1"), "run must be an object"),
    ("quality", lambda d: d["quality"]["outliers"].append({"index": "one"}),
     r"quality.outliers\[1\].index must be a whole number"),
    ("quality", lambda d: d["quality"]["accelerometers"].update(chi2_per_dof=["x"]),
     r"quality.accelerometers.chi2_per_dof\[0\] must be a finite number"),
    ("quality", lambda d: d["quality"].update(outlier_sigma="4"), "quality.outlier_sigma must be a finite number"),
    ("verdict", lambda d: d["verdict"]["checks"][0].update(passed="no"),
     r"verdict.checks\[0\].passed must be true or false"),
    ("verdict", lambda d: d["verdict"]["checks"][0].update(limit=[1, 2, 3]), r"verdict.checks\[0\].limit must be"),
    ("verdict", lambda d: d.update(verdict=["fail"]), "verdict must be an object"),
])
def test_a_malformed_section_is_refused_naming_the_file_the_section_and_the_entry(section, change, message):
    data = json.loads(_old_file())
    data["run"] |= {"imu_link": {"frames": 10}, "lost_samples": {"total": 0, "in_windows": {}}}
    CalibrationResult.from_json(data, "r.json")                  # sound before the change
    change(data)
    with pytest.raises(ResultFormatError, match=f"^r.json: {message}"):
        CalibrationResult.from_json(data, "r.json")


def test_a_section_from_code_without_a_required_entry_is_refused_and_a_result_files_is_not():
    section = {**OLD_RUN}
    with pytest.raises(ResultFormatError, match="the run section lacks logs, quality_failures, imu_link, lost_samples"):
        RunInfo.from_dict(section)
    assert RunInfo.from_dict(section, complete=False).to_dict() == section


def test_sections_given_as_their_entries_are_read_as_a_files_would_be():
    """A script builds a result with plain dicts (as the kalibr export's test does): the sections are typed."""
    result = CalibrationResult({}, run={"run_id": "r-1", "imu": {"model": "FOG-1", "serial": "S-1"}},
                               quality={}, verdict=None)
    assert isinstance(result.run, RunInfo) and result.run.imu is not None and result.run.imu.serial == "S-1"
    assert isinstance(result.quality, QualitySection)
    with pytest.raises(ResultFormatError, match=r"run\.imu"):
        CalibrationResult({}, run={"imu": "not a table"})
