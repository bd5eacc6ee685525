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
from tests.unit.table_check.test_table_check import _schedule_text


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


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_a_failing_database_keeps_the_files_and_is_a_non_zero_exit(recorded, tmp_path):
    """Records are sacred: a result the database did not take is exit 7 (NOT_RECORDED), the files kept."""
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    rc, stdout, stderr = cli(["solve", str(recorded.log), "--out", str(tmp_path / "out"), "--no-html",
                              "--db", str(blocker / "r.sqlite")])
    assert rc == 7, stderr
    assert "bench solve: warning: not recorded in the records database" in stderr
    assert "NOT recorded in the records database" in stderr.splitlines()[-1]
    assert only_file(tmp_path / "out", "*.result.json").stat().st_size > 0


@pytest.mark.slow
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


# -- issue 27: a run's record of truth is never replaced by what was derived from it ---------------------------

def _db_copy(recorded, tmp_path: Path) -> Path:
    """The fixture's database, copied: each test derives its own results from the one recorded run."""
    db = tmp_path / "records.sqlite"
    db.write_bytes(recorded.db.read_bytes())
    return db


def _list_line(db: Path, run_id: str) -> str:
    rc, stdout, stderr = cli(["db", "list", "--db", str(db)])
    assert rc == 0, stderr
    (line,) = [line for line in stdout.splitlines() if line.split()[1:2] == [run_id[:28]]]
    return line


@pytest.mark.slow
def test_what_if_solves_and_a_cut_copy_never_replace_the_runs_result(recorded, tmp_path):
    """Issue 27's reproduction: `bench solve LOG --positions none --out sub2` and `bench solve COPY_CUT.mcap` were
    recorded as results of the run: `db list` showed the run's `fail` and `db history --coefficient Kg_x` dropped
    it. Now both are derived results of the run; the run's own result stays its record of truth."""
    db = _db_copy(recorded, tmp_path)
    own = json.loads(recorded.result_path.read_text())
    run_id, serial = own["run"]["run_id"], own["run"]["imu"]["serial"]
    verdict = own["verdict"]["verdict"]                 # "pass", "fail" or "not checked"
    before = _list_line(db, run_id)
    assert before.endswith(" " + verdict)
    rc, _, stderr = cli(["solve", str(recorded.log), "--positions", "none", "--out", str(tmp_path / "sub2"),
                         "--no-html", "--quiet", "--db", str(db)])
    assert rc in (0, 4), stderr
    cut = tmp_path / "cut" / recorded.log.name
    cut.parent.mkdir()
    data = recorded.log.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])
    rc, _, stderr = cli(["solve", str(cut), "--out", str(tmp_path / "cut-out"), "--no-html", "--quiet",
                         "--db", str(db)])
    assert rc in (0, 4), stderr
    line = _list_line(db, run_id)
    assert line.endswith(" " + verdict) and line[:-len(verdict)].split()[-1] == "3", line   # 3 results, its verdict
    rc, stdout, stderr = cli(["db", "history", "--db", str(db), serial, "--coefficient", "Kg_x"])
    assert rc == 0, stderr
    assert run_id[:28] in stdout and "1 calibration(s)" in stdout
    with open_records(str(db)) as records:
        kg = next(c for c in unit_history(records, serial).coefficients if c.name == "Kg_x")
        assert [p.value for p in kg.points] == [own["coefficients"]["Kg_x"]["value"]]
        rows = records.results_of(run_id)
        (run,) = records.list_runs()
        assert run.log_path == str(recorded.log.absolute()) and run.log_complete   # the cut copy is not the log
    assert [(r.origin, r.truth) for r in rows] == [("run", True), ("subset", False), ("damaged", False)]
    rc, stdout, _ = cli(["db", "results", "--db", str(db), run_id])
    assert rc == 0 and "subset" in stdout and "damaged" in stdout

    # the user may promote one explicitly: it becomes the record, in the list and the history
    subset = rows[1]
    rc, stdout, stderr = cli(["db", "promote", "--db", str(db), str(subset.result_id)])
    assert rc == 0 and f"now the record of truth of run {run_id}" in stdout, stderr
    assert "(promoted)" in _list_line(db, run_id)
    with open_records(str(db)) as records:
        assert [r.truth for r in records.results_of(run_id)] == [False, True, False]
    rc, _, stderr = cli(["db", "promote", "--db", str(db), "999999"])
    assert rc == 2 and "no recorded result '999999'" in stderr


@pytest.mark.slow
def test_a_re_solve_by_this_version_is_derived_but_stands_in_without_the_runs_own_result(recorded, tmp_path):
    """A whole re-solve never replaces the run's own result; for a run whose own result is not recorded (an
    archive of logs) it is the record of truth."""
    db = tmp_path / "r.sqlite"
    rc, _, stderr = cli(["solve", str(recorded.log), "--out", str(tmp_path / "a"), "--no-html", "--quiet",
                         "--db", str(db)])
    assert rc in (0, 4), stderr
    run_id = json.loads(recorded.result_path.read_text())["run"]["run_id"]
    with open_records(str(db)) as records:
        assert [(r.origin, r.truth) for r in records.results_of(run_id)] == [("re-solve", True)]
    assert "(re-solve)" in _list_line(db, run_id)
    rc, _, stderr = cli(["db", "import", "--db", str(db), str(recorded.result_path)])
    assert rc == 0, stderr
    with open_records(str(db)) as records:
        assert [(r.origin, r.truth) for r in records.results_of(run_id)] == [("re-solve", False), ("run", True)]


@pytest.mark.slow
def test_a_log_still_being_written_is_recorded_as_unfinished_and_its_hash_follows_the_finished_file(recorded,
                                                                                                   tmp_path):
    """`bench db import runs/` while a run was recording recorded the unfinished log as the run's, with a SHA-256
    that is not the finished file's. Now a log without its MCAP footer is recorded as unfinished (`db list` says
    so) and its hash is replaced when the finished file is imported."""
    db = tmp_path / "r.sqlite"
    growing = tmp_path / "runs" / recorded.log.name
    growing.parent.mkdir()
    data = recorded.log.read_bytes()
    growing.write_bytes(data[: len(data) // 2])
    rc, _, stderr = cli(["db", "import", "--db", str(db), str(growing.parent)])
    assert rc == 0, stderr
    with open_records(str(db)) as records:
        (run,) = records.list_runs()
        assert run.log_complete is False
    assert "(log unfinished)" in _list_line(db, run.run_id)
    growing.write_bytes(data)       # the run finished
    rc, stdout, stderr = cli(["db", "import", "--db", str(db), str(growing.parent)])
    assert rc == 0 and "1 recorded" in stdout, stderr
    import sqlalchemy as sa

    from bench.records import schema
    with open_records(str(db)) as records:
        (run,) = records.list_runs()
        assert run.log_complete is True
        with records.engine.connect() as conn:
            (log_sha,) = conn.execute(sa.select(schema.runs.c.log_sha256)).one()
    assert log_sha == _sha(recorded.log)
    assert "(log unfinished)" not in _list_line(db, run.run_id)
