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
    with pytest.raises(OutputFileError) as below:      # a file in the way of a folder below it: named
        make_output_folder(file / "below")
    assert str(below.value) == f"--out {file / 'below'}: {file} is a file, not a folder"
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


def test_the_python_tutorials_sigma_of_kg_x_is_the_one_bench_run_gives(tmp_path, monkeypatch, capsys):
    # the example printed sigma(Kg_x) = 1.8 (a budget told nothing of the table) where `bench run --sim` gives 0.016
    import re
    from pathlib import Path

    page = (Path(__file__).resolve().parents[3] / "docs" / "tutorials" / "python.md").read_text(encoding="utf-8")
    first_block = re.search(r"```python\n(.*?)```", page, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    exec(compile(first_block, "python.md", "exec"), {})
    line = next(s for s in capsys.readouterr().out.splitlines() if s.startswith("Kg_x"))
    value, sigma, true = (float(x) for x in re.fullmatch(r"Kg_x\s+(\S+) \+- (\S+) .*\(true (\S+)\)", line).groups())
    assert sigma < 0.05 and abs(value - true) < 3 * sigma


def test_db_list_shows_a_long_model_name_whole(noisy_run, tmp_path):
    # the model column was cut at 20 characters
    long_model = "Northrop Grumman LN-200C FOG IMU rev 4"
    document = json.loads(noisy_run.result_path.read_text(encoding="utf-8"))
    document["run"]["imu"] = {"model": long_model, "serial": "SN-0042"}
    path = tmp_path / "in" / noisy_run.result_path.name
    path.parent.mkdir()
    path.write_text(json.dumps(document), encoding="utf-8")
    db = str(tmp_path / "records.sqlite")
    rc, _, err = cli(["db", "import", "--db", db, "--quiet", str(path)])
    assert rc == 0, err
    rc, out, err = cli(["db", "list", "--db", db])
    assert rc == 0, err
    header, row = out.splitlines()[:2]
    assert f" {long_model} SN-0042 " in row
    assert header.index("serial") == row.index("SN-0042")          # the columns still line up


def test_a_line_of_thousands_of_characters_is_bounded(capsys):
    # a damaged log's error and an archive's progress item ran to ~2,000 characters on one line
    from bench.cli.edge import ERROR_LINE_MAX, LINE_MAX, ExitCode, bounded_line, fail
    from bench.cli.progress import CountProgress

    cause = "; ".join(f"chunk {k} at byte {k * 4096}: bad CRC" for k in range(80))
    assert len(cause) > 2000
    fail("bench solve", f"damaged.mcap: {cause}", ExitCode.USAGE)
    line = capsys.readouterr().err
    assert line.count("\n") == 1 and len(line) <= ERROR_LINE_MAX + 40
    assert line.startswith("bench solve: damaged.mcap: chunk 0 at byte 0") and line.rstrip().endswith("bad CRC")
    assert "characters left out" in line
    progress = CountProgress(2, live=False)
    progress.item(f"FAILED x.mcap: {cause}", problem=True)
    progress.note(f"warning: {cause}")
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and all(len(s) <= LINE_MAX + 40 for s in err)
    assert bounded_line("short\nmessage") == "short message"
