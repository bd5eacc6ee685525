"""One way to finish a run (`bench.finish.finish`): the live run and a re-solve of its log finish it alike; what
differs is the target's (names, the run section's provenance, how a file is kept)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.finish.calibration import load_subset_schedule
from bench.finish.finish import finish
from bench.finish.recorded import SolveInputError, load_recorded
from bench.jobs.resolve import ResolveTarget, output_stem

pytestmark = pytest.mark.slow          # the shared recorded runs take a few seconds each to record

#: The run section's entries a re-solve says otherwise than the live run (who solved it, when, from what).
PROVENANCE = {"finished_utc", "solved_utc", "solved_by", "recorded_with", "software_version", "subset",
              "started_utc", "left_out", "damage", "notes", "imu_link", "sim"}


def _json(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def test_a_resolve_finishes_the_log_as_the_live_run_did(short_run, tmp_path):
    recorded = load_recorded([str(short_run.log)])
    finished = finish(recorded, ResolveTarget(tmp_path, output_stem(recorded), html=False))
    live, solved = _json(short_run.result), _json(finished.result_path)
    assert finished.result_path == tmp_path / f"{recorded.run_id}.solved.result.json"
    assert finished.report_path == tmp_path / f"{recorded.run_id}.solved.report.md"
    assert finished.html_report_path is None
    for section in ("coefficients", "residuals", "quality", "sim_truth", "verdict", "temperature"):
        assert solved[section] == live[section], section
    differing = {key for key in live["run"].keys() | solved["run"].keys()
                 if live["run"].get(key) != solved["run"].get(key)}
    assert differing <= PROVENANCE, differing - PROVENANCE
    assert solved["run"]["solved_by"] == "bench solve" and "finished_utc" not in solved["run"]
    assert "finished_utc" in live["run"] and "solved_by" not in live["run"]
    # the re-solve's report says which logs it was solved from; the live run's log holds its own result
    assert "## Logs" in finished.report_path.read_text(encoding="utf-8")
    assert finished.verdict is not None and finished.verdict.to_json() == live["verdict"]


def test_a_subset_is_named_by_its_schedules_and_said_to_be_one(short_run, tmp_path):
    recorded = load_recorded([str(short_run.log)])
    positions = load_subset_schedule("traditional-12", "positions")
    rotations = load_subset_schedule("none", "rotations")
    stem = output_stem(recorded, positions, rotations)
    assert stem == f"{recorded.run_id}.traditional-12+none"
    finished = finish(recorded, ResolveTarget(tmp_path, stem, html=False), positions=positions, rotations=rotations)
    solved = _json(finished.result_path)
    assert finished.result_path.name == f"{stem}.result.json"
    assert solved["run"]["subset"] is True and solved["run"]["rotations"] == ""
    assert finished.resolved is not None and not finished.resolved.solution.extraction.rotations


def test_a_thermal_log_is_finished_whole(thermal_run_log, tmp_path):
    recorded = load_recorded([str(thermal_run_log)])
    positions = load_subset_schedule("traditional-12", "positions")
    with pytest.raises(SolveInputError, match="finished whole"):
        finish(recorded, ResolveTarget(tmp_path, output_stem(recorded, positions), html=False), positions=positions)
    assert not list(tmp_path.iterdir())              # refused before anything is written
