"""A log records its run kind (`run.kind`) and `bench.log.run_kind` reads it back; a log written before the field
existed (the field taken out of a real log) gets the kind the commands gave it before: a static noise recording
from its recorded configuration, a thermal run from its temperature blocks, else a calibration."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from bench.config.load import parse_config
from bench.finish.recorded import load_recorded, static_noise_plan
from bench.log.reader import read_log
from bench.log.run_info import is_manual_log, layout_and_config_from_log
from bench.log.run_kind import RunKind, kind_of_config, recorded_run_kind, run_kind
from bench.plan.compiler import compile_plan
from bench.run.devices import SIMULATOR
from bench.run.runner import BenchRun, compile_from_config
from bench.verify.plan import verification_config, verification_plan
from schedules import resolve_schedule
from tests.helpers.mcap_surgery import rewrite
from tests.helpers.run import api_run, cli, config_text

SHORT = dict(positions="traditional-12", rotations="traditional-3s6r", dwell_s=1.0)

VERIFICATION_SCHEDULE = """format = "turntable-bench/schedule"
version = 1
name = "verify-tiny"
kind = "verification"
description = "two tilts and one turn"

[[position]]
angles_deg = [0, 45, 0]

[[position]]
angles_deg = [0, 135, 90]

[[rotation]]
start_deg = [0, 0, 0]
frame = "outer"
direction = "ccw"
revolutions = 1
rate_dps = 30.0
"""

TABLE_CHECK_SCHEDULE = """format = "turntable-bench/schedule"
version = 1
name = "table-check-tiny"
kind = "table-check"
description = "four positions"

[[position]]
angles_deg = [0, 0, 0]

[[position]]
angles_deg = [90, 0, 45]

[[position]]
angles_deg = [180, 0, 135]

[[position]]
angles_deg = [270, 0, 225]
"""


def _without_kind(log: Path, dst: Path) -> Path:
    """`log` as a version before the field wrote it: the same records, no `run.kind`."""
    def drop(name: str, data: dict) -> dict:
        return {k: v for k, v in data.items() if not (name == "run" and k == "kind")}

    rewrite(log, dst, metadata=drop)
    assert "kind" not in read_log(str(dst)).metadata["run"]
    return dst


def _config(tmp_path: Path, text: str):
    path = tmp_path / "bench.toml"
    path.write_text(text, encoding="utf-8")
    return parse_config(text, source=str(path), base_dir=tmp_path)


def _record_unsolved(config, plan, out: Path) -> Path:
    """Run `plan` on the simulator and close its log without solving (as `bench verify`/`check-table` do)."""
    with BenchRun(config, plan, devices=SIMULATOR, out_dir=out) as run:
        run.open()
        run.run()
        assert run.sequencer is not None and run.sequencer.error is None, run.sequencer.error
        extraction, error = run.finish_observations()
        assert error is None and extraction is not None
    return run.log_path


def _as_before(log: Path) -> RunKind:
    """The kind of `log` as `bench solve` tells it: from its record, or for a log without one from the
    configuration rebuilt from it and its events."""
    return run_kind(read_log(str(log)), layout_and_config_from_log(read_log(str(log))).config)


@pytest.fixture(scope="module")
def calibration_log(short_run) -> Path:
    """The session's short calibration run (read only: the tests write their rewritten copies to `tmp_path`)."""
    return short_run.log


def test_a_calibration_run_records_its_kind_and_an_older_log_reads_as_before(calibration_log, tmp_path):
    log = read_log(str(calibration_log))
    assert log.metadata["run"]["kind"] == "calibration"
    assert recorded_run_kind(log.metadata) is run_kind(log) is RunKind.CALIBRATION
    older = _without_kind(calibration_log, tmp_path / calibration_log.name)
    assert _as_before(older) is RunKind.CALIBRATION
    recorded = load_recorded([str(older)])
    assert recorded.kind is RunKind.CALIBRATION and static_noise_plan(recorded) is None
    assert load_recorded([str(calibration_log)]).kind is RunKind.CALIBRATION


def test_a_thermal_run_records_its_kind_and_an_older_log_reads_as_before(thermal_run_log, tmp_path):
    log = read_log(str(thermal_run_log))
    assert log.metadata["run"]["kind"] == "thermal" and run_kind(log) is RunKind.THERMAL
    older = _without_kind(thermal_run_log, tmp_path / thermal_run_log.name)
    assert _as_before(older) is RunKind.THERMAL          # from its temperature blocks ("T1-P01")
    assert run_kind(read_log(str(older))) is RunKind.THERMAL
    recorded = load_recorded([str(older)])
    assert recorded.kind is RunKind.THERMAL and recorded.first_log_of_kind(RunKind.THERMAL) is not None


def test_a_static_noise_run_records_its_kind_and_an_older_log_reads_as_before(tmp_path):
    text = config_text(positions="static-noise", rotations="", dwell_s=10.0, rate_hz=100.0)
    with api_run(text, tmp_path / "runs") as (run, outcome):
        assert outcome.error is None and run.kind is RunKind.STATIC_NOISE
    log = outcome.log_path
    assert read_log(str(log)).metadata["run"]["kind"] == "static-noise"
    older = _without_kind(log, tmp_path / log.name)
    assert _as_before(older) is RunKind.STATIC_NOISE      # from its recorded configuration's schedule
    assert run_kind(read_log(str(older))) is RunKind.CALIBRATION   # (without the configuration: not told)
    for path in (log, older):
        assert static_noise_plan(load_recorded([str(path)])) == "static-noise"
        rc, _, stderr = cli(["solve", str(path), "--out", str(tmp_path / "solved"), "--no-db"])
        assert rc == 2 and f"{path} is a static noise recording (plan positions 'static-noise'" in stderr


def test_a_verification_run_records_its_kind_and_an_older_log_reads_as_a_calibration(tmp_path):
    (tmp_path / "verify-tiny.toml").write_text(VERIFICATION_SCHEDULE, encoding="utf-8")
    config = verification_config(_config(tmp_path, config_text(**SHORT).replace(
        "[plan]\n", '[plan]\nverification = "verify-tiny.toml"\n')))
    assert kind_of_config(config) is RunKind.VERIFICATION
    log = _record_unsolved(config, verification_plan(config), tmp_path / "runs")
    assert read_log(str(log)).metadata["run"]["kind"] == "verification"
    assert run_kind(read_log(str(log))) is RunKind.VERIFICATION
    assert _as_before(_without_kind(log, tmp_path / log.name)) is RunKind.CALIBRATION


def test_a_table_check_run_records_its_kind_and_an_older_log_reads_as_a_calibration(tmp_path):
    (tmp_path / "table-check-tiny.toml").write_text(TABLE_CHECK_SCHEDULE, encoding="utf-8")
    base = _config(tmp_path, config_text(**SHORT))
    schedule = resolve_schedule(str(tmp_path / "table-check-tiny.toml"))
    config = dataclasses.replace(base, plan=dataclasses.replace(base.plan, positions=schedule, rotations=None))
    assert kind_of_config(config) is RunKind.TABLE_CHECK
    plan = compile_plan(schedule, None, config.plan, limits=config.table.limits, order=config.plan.order)
    log = _record_unsolved(config, plan, tmp_path / "runs")
    assert run_kind(read_log(str(log))) is RunKind.TABLE_CHECK
    assert _as_before(_without_kind(log, tmp_path / log.name)) is RunKind.CALIBRATION


def test_a_log_of_manual_moves_records_its_kind(tmp_path):
    config = _config(tmp_path, config_text(**SHORT))
    with BenchRun(config, compile_from_config(config), devices=SIMULATOR, out_dir=tmp_path / "runs") as run:
        run.open(record=False)
        recorder = run.open_manual_log()
        recorder.close()
    (path,) = (tmp_path / "runs").glob("*-manual.mcap")
    log = read_log(str(path))
    assert run_kind(log) is RunKind.MANUAL and is_manual_log(log)


@pytest.mark.parametrize("raw", [None, "", "calibrations", 3, ["thermal"]])
def test_a_missing_or_unknown_recorded_kind_is_told_as_before(raw):
    assert recorded_run_kind({"run": {"kind": raw}}) is None
    assert recorded_run_kind({"run": "not a table"}) is None and recorded_run_kind({}) is None


def test_every_kind_a_run_records_has_its_finish():
    """`bench.finish.finish` dispatches on the run's kind, for the live run and a re-solve alike: every kind a plan
    gives has an entry (manual moves are no run: `open_manual_log`)."""
    from bench.finish.finish import FINISHERS, finish_calibration, finish_noise, finish_thermal

    assert set(FINISHERS) == set(RunKind) - {RunKind.MANUAL}
    assert FINISHERS[RunKind.THERMAL] is finish_thermal
    assert FINISHERS[RunKind.STATIC_NOISE] is finish_noise
    assert FINISHERS[RunKind.CALIBRATION] is finish_calibration
