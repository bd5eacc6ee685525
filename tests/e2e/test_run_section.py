"""One `RunInfo` type for a result's `run` section: `bench run`, `bench solve` and a thermal re-solve write it in
the order result files have always had, and every result's section reads back to the same dict."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.model.run_section import RunInfo
from tests.helpers.run import cli, only_file

#: The order of the section as each writer built it by hand before `RunInfo`.
LIVE = ["run_id", "mode", "operator", "software_version", "state", "log", "logs", "positions", "rotations",
        "started_utc", "finished_utc", "imu", "site", "quality_failures", "sim", "imu_link", "lost_samples"]
SOLVED = ["run_id", "mode", "operator", "software_version", "recorded_with", "state", "log", "logs", "positions",
          "rotations", "subset", "started_utc", "solved_utc", "solved_by", "imu", "site", "quality_failures",
          "imu_link", "lost_samples", "left_out", "damage", "notes"]
THERMAL_SOLVED = ["run_id", "mode", "operator", "software_version", "recorded_with", "state", "log", "logs",
                  "positions", "rotations", "solved_utc", "solved_by", "imu", "site", "quality_failures", "imu_link",
                  "lost_samples", "notes"]


def _run_section(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))["run"]


def test_bench_run_and_bench_solve_write_the_section_in_its_order(short_run, tmp_path):
    log = short_run.log
    live = _run_section(short_run.result)
    assert list(live) == LIVE
    assert live["log"] == log.name and live["logs"] == [log.name] and live["operator"] == "api"
    rc, _, stderr = cli(["solve", str(log), "--out", str(tmp_path), "--no-html", "--no-db"])
    assert rc in (0, 5), stderr
    solved = _run_section(only_file(tmp_path, "*.solved.result.json"))
    assert list(solved) == SOLVED
    assert solved["solved_by"] == "bench solve" and solved["subset"] is False and solved["operator"] == "api"
    for section in (live, solved):
        info = RunInfo.from_dict(section)
        assert info.to_dict() == section and list(info.to_dict()) == list(section) and info.extra == {}
        assert json.dumps(info.to_dict()) == json.dumps(section)


def test_a_thermal_re_solve_writes_the_section_in_its_order_with_the_blocks_entries(thermal_run_log, tmp_path):
    rc, _, stderr = cli(["solve", str(thermal_run_log), "--out", str(tmp_path), "--no-html", "--no-db"])
    assert rc in (0, 5), stderr
    head = _run_section(only_file(tmp_path, "*.solved.result.json"))
    block = _run_section(only_file(tmp_path, "*.solved.T1.result.json"))
    assert list(block) == THERMAL_SOLVED + ["temperature_block", "temperature_setpoint_c"]
    assert list(head)[:len(THERMAL_SOLVED)] == THERMAL_SOLVED and "thermal" in head
    live = _run_section(thermal_run_log.with_suffix(".result.json"))
    assert list(live)[:len(LIVE)] == LIVE
    for section in (head, block, live):     # the entries added after the run come back in `extra`, in order
        info = RunInfo.from_dict(section)
        assert json.dumps(info.to_dict()) == json.dumps(section)
    assert list(RunInfo.from_dict(block).extra) == ["temperature_block", "temperature_setpoint_c"]


def test_a_section_without_a_required_entry_is_refused():
    section = _minimal()
    assert RunInfo.from_dict(section).to_dict() == section
    del section["imu_link"]
    with pytest.raises(ValueError, match="lacks imu_link"):
        RunInfo.from_dict(section)


def _minimal() -> dict:
    return {"run_id": "r", "mode": "simulator", "operator": "", "software_version": "0", "state": "done",
            "log": "r.mcap", "logs": ["r.mcap"], "positions": "p", "rotations": "",
            "imu": {"model": "m", "serial": "s"}, "site": {}, "quality_failures": [], "imu_link": {},
            "lost_samples": {"total": 0}}
