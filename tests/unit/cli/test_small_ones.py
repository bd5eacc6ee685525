"""Issue 33, item 16: small things a new user trips over, each checked as the user meets it."""

from __future__ import annotations

import json

import pytest

from bench.files import OutputFileError, make_output_folder
from bench.log.mcap.records import MAGIC
from bench.log.reader import read_log
from bench.model.result import CalibrationResult, coefficient_table
from bench.model.run_section import ImuIdentity
from bench.report.compare import compare_results
from bench.thermal.export import export_thermal
from bench.thermal.model import ThermalModel, fit_thermal_model, point_from_result
from tests.helpers.run import cli


def test_apply_with_result_and_log_swapped_says_they_look_swapped(noisy_run, tmp_path):
    # it said "29639690 bytes, more than a result file holds" of the log given as the result
    rc, _, err = cli(["apply", str(noisy_run.log), str(noisy_run.result_path), "--out", str(tmp_path / "a.csv")])
    assert rc == 2 and err.count("\n") == 1
    assert "look swapped" in err and "bench apply RESULT LOG" in err
    assert not (tmp_path / "a.csv").exists()


def test_apply_of_a_log_that_is_not_mcap_is_not_called_swapped(tmp_path):
    result, log = tmp_path / "r.json", tmp_path / "l.mcap"
    result.write_bytes(MAGIC + b"\0" * 8)
    log.write_text("{}")
    rc, _, err = cli(["apply", str(log), str(result), "--out", str(tmp_path / "a.csv")])
    assert rc == 2 and "swapped" not in err


def test_export_says_what_it_wrote(noisy_run, tmp_path):
    out = tmp_path / "imu.h"
    rc, stdout, err = cli(["export", str(noisy_run.result_path), "--out", str(out)])
    assert rc == 0, err
    assert stdout == f"wrote {out} (C header, {out.stat().st_size} bytes)\n"
    rc, stdout, _ = cli(["export", str(noisy_run.result_path), "--out", "-", "--format", "json"])
    assert rc == 0 and json.loads(stdout)           # to stdout: the file alone, no line about it


def test_an_out_that_is_a_file_gets_a_clear_line(tmp_path):
    # it said "output folder FILE: File exists"
    file = tmp_path / "results"
    file.write_text("")
    rc, _, err = cli(["noise", "--sim", "--duration-h", "0.01", "--out", str(file)])
    assert rc == 2 and err.strip().endswith(f"--out {file}: it is a file, not a folder") and err.count("\n") == 1
    with pytest.raises(OutputFileError, match="it is a file, not a folder"):
        make_output_folder(file / "below")
    assert make_output_folder(tmp_path / "new" / "folder").is_dir()


def test_a_live_runs_result_records_when_it_started_and_a_comparison_shows_no_dash(noisy_run):
    # `bench solve --against` of the run's own result showed "started utc: - -> ..." and "finished utc: ... -> -"
    result = CalibrationResult.load(noisy_run.result_path)
    assert result.run.started_utc == read_log(noisy_run.log).metadata["run"]["started_utc"]
    resolved = CalibrationResult.load(noisy_run.result_path)
    resolved.run.finished_utc, resolved.run.started_utc = None, result.run.started_utc
    assert compare_results(resolved, result).run_changes == []
    older = CalibrationResult.load(noisy_run.result_path)
    older.run.started_utc = None                        # a result written before it recorded its start
    assert compare_results(resolved, older).run_changes == []
    moved = CalibrationResult.load(noisy_run.result_path)
    moved.run.started_utc = "2020-01-01T00:00:00Z"
    assert compare_results(resolved, moved).run_changes == [("started_utc", moved.run.started_utc,
                                                             result.run.started_utc)]


def test_the_thermal_c_header_names_the_imu_after_the_model_is_read_back(tmp_path):
    # the header said "imu_model: (not recorded)": the model file kept no identity of its calibrations
    points = []
    for t in (-20.0, 0.0, 25.0, 50.0):
        r = CalibrationResult(coefficient_table({"D0_x": 0.05 + 0.002 * (t - 25)}, {"D0_x": 0.001}))
        r.temperature = {"mean_c": t, "min_c": t, "max_c": t}
        r.run.imu = ImuIdentity("FOG-7", "SN 42")
        points.append(point_from_result(r, f"r{t:g}.json"))
    path = tmp_path / "thermal.json"
    fit_thermal_model(points).save(path)
    header = export_thermal(ThermalModel.load(path), "c")
    assert " * imu_model: FOG-7\n" in header and " * imu_serial: SN 42\n" in header
