"""`bench run`, `bench solve` and `bench check-table` record what they write into the records database
(issue 20): after the files, skipped with --no-db, and a database that fails only warns."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from bench import __version__
from bench.records.history import unit_history
from bench.records.store import open_records
from tests.helpers.run import cli, config_text, only_file
from tests.test_table_check import _schedule_text


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """One short simulated `bench run` recorded into its own database."""
    folder = tmp_path_factory.mktemp("hooked")
    config = folder / "bench.toml"
    config.write_text(config_text(noise="true", seed=4, dwell_s=2.0, rate_hz=50.0), encoding="utf-8")
    db = folder / "records.sqlite"
    rc, stdout, stderr = cli(["run", "--config", str(config), "--out", str(folder / "out"), "--quiet",
                              "--operator", "ann", "--db", str(db)])
    assert rc == 0, stderr
    assert "warning" not in stderr
    out = folder / "out"
    return SimpleNamespace(folder=folder, config=config, db=db, out=out, log=only_file(out, "*.mcap"),
                           result_path=only_file(out, "*.result.json"))


def test_bench_run_records_its_run_log_and_result(recorded):
    result = json.loads(recorded.result_path.read_text())
    with open_records(str(recorded.db)) as records:
        (run,) = records.list_runs()
        assert (run.run_id, run.serial, run.operator, run.outcome, run.results) == (
            result["run"]["run_id"], result["run"]["imu"]["serial"], "ann", "done", 1)
        assert run.started_utc is not None and run.log_path == str(recorded.log.absolute())
        assert records.has_result(run.run_id, __version__)
        history = unit_history(records, run.serial)
        kg = next(c for c in history.coefficients if c.name == "Kg_x")
        assert [p.value for p in kg.points] == [result["coefficients"]["Kg_x"]["value"]]
        import sqlalchemy as sa

        from bench.records import schema
        with records.engine.connect() as conn:
            log_sha, table_url = conn.execute(sa.select(schema.runs.c.log_sha256, schema.runs.c.table_url)).one()
            (result_sha,) = conn.execute(sa.select(schema.results.c.sha256)).one()
    assert log_sha == _sha(recorded.log) and table_url == "sim"
    assert result_sha == _sha(recorded.result_path)


def test_bench_solve_records_a_resolve_and_no_db_skips(recorded, tmp_path):
    rc, _, stderr = cli(["solve", str(recorded.log), "--out", str(tmp_path / "a"), "--no-html", "--quiet",
                         "--db", str(tmp_path / "r.sqlite")])
    assert rc == 0, stderr
    with open_records(str(tmp_path / "r.sqlite")) as records:
        (run,) = records.list_runs()
        assert run.results == 1 and run.started_utc is not None and run.log_path == str(recorded.log.absolute())
    rc, _, stderr = cli(["solve", str(recorded.log), "--out", str(tmp_path / "b"), "--no-html", "--quiet",
                         "--no-db", "--db", str(tmp_path / "skipped.sqlite")])
    assert rc == 0, stderr
    assert not (tmp_path / "skipped.sqlite").exists()


def test_a_failing_database_warns_and_keeps_the_files(recorded, tmp_path):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    rc, stdout, stderr = cli(["solve", str(recorded.log), "--out", str(tmp_path / "out"), "--no-html",
                              "--db", str(blocker / "r.sqlite")])
    assert rc == 0
    assert "bench solve: warning: not recorded in the records database" in stderr
    assert only_file(tmp_path / "out", "*.result.json").stat().st_size > 0


def test_bench_check_table_records_its_check(tmp_path):
    schedule = tmp_path / "table-check-16.toml"
    schedule.write_text(_schedule_text((0, 90, 180, 270), (45, 135, 225, 315)), encoding="utf-8")
    config = tmp_path / "bench.toml"
    config.write_text(config_text(black_box_arcsec=20.0, seed=3, noise="true"), encoding="utf-8")
    db = tmp_path / "r.sqlite"
    rc, _, stderr = cli(["check-table", "--config", str(config), "--schedule", str(schedule), "--dwell-s", "2",
                         "--out", str(tmp_path / "out"), "--quiet", "--db", str(db)])
    assert rc in (0, 5), stderr
    check = json.loads(only_file(tmp_path / "out", "*.table-check.json").read_text())
    with open_records(str(db)) as records:
        (run,) = records.list_runs()
        assert (run.kind, run.run_id, run.results) == ("table-check", check["run"]["run_id"], 1)
        assert unit_history(records, run.serial).coefficients == []      # a table check is not the IMU's calibration
