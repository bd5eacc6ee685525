"""`bench db import` takes every file the bench writes or says in one line why it cannot (issue 27), and hostile
result files are one line each while the folder import goes on (issue 34)."""

from __future__ import annotations

import datetime as dt
import json
import os
from pathlib import Path

import pytest

from bench.records import schema
from bench.records.store import open_records
from tests.helpers.crafted import rewrite_log
from tests.helpers.records import write_result
from tests.helpers.run import cli, config_text
from tests.helpers.static_log import write_static_log

T0 = dt.datetime(2024, 5, 1, 9, 0, 0)


@pytest.fixture(scope="module")
def good_result(tmp_path_factory) -> Path:
    return write_result(tmp_path_factory.mktemp("good"), "H-1", T0, seed=3)


def _hostile_texts(good: str) -> dict[str, str]:
    """Result files as a hostile or broken tool might write them (each from the good file's text)."""
    data = json.loads(good)
    value = repr(data["coefficients"]["Kg_x"]["value"])
    run_id = data["run"]["run_id"]
    finished = data["run"]["finished_utc"]
    deep = "[" * 100 + "]" * 100
    deeper = "[" * 100_000 + "]" * 100_000
    return {
        "huge-int.result.json": good.replace(value, "1" + "0" * 400, 1),            # 10**400
        "digits.result.json": good.replace(value, "7" * 5000, 1),                  # beyond Python's int parsing
        "infinite.result.json": good.replace(value, "1e999", 1),
        "deep.result.json": good.replace('"site": {', f'"extra": {deep}, "site": {{', 1),
        "deeper.result.json": good.replace('"site": {', f'"extra": {deeper}, "site": {{', 1),
        "early.result.json": good.replace(finished, "0001-01-01T00:00:00+05:00", 1),
        "late.result.json": good.replace(finished, "9999-12-31T23:00:00-05:00", 1),
        "long-id.result.json": good.replace(run_id, "r" * 100_000),
        "id-object.result.json": good.replace(f'"{run_id}"', '{"a": 1}', 1),
        "name.result.json": good.replace('"Kg_x"', '"' + "K" * 500 + '"', 1),
    }


def test_hostile_result_files_are_one_line_each_and_the_folder_import_goes_on(good_result, tmp_path):
    """9 of 22 such files gave tracebacks and the first of them ended the folder's import."""
    folder = tmp_path / "in"
    folder.mkdir()
    good = good_result.read_text()
    bad = _hostile_texts(good)
    for name, text in bad.items():
        (folder / name).write_text(text)
    (folder / "z-good.result.json").write_text(good)         # sorted after every bad one
    big = folder / "big.result.json"
    with open(big, "wb") as f:                                # 17 MiB, sparse: refused by its size, never read
        f.truncate(17 << 20)
    db = tmp_path / "r.sqlite"
    rc, stdout, stderr = cli(["db", "import", "--db", str(db), str(folder)])
    assert rc == 4
    assert f"1 recorded, 0 already known, {len(bad) + 1} failed" in stdout, stdout
    lines = stderr.splitlines()
    assert len(lines) == len(bad) + 1 and "Traceback" not in stderr, stderr
    for name in [*bad, big.name]:
        (line,) = [line for line in lines if f"/{name}: " in line]
        assert line.count(name) == 1, line                   # the path once
    reasons = {name: next(line for line in lines if f"/{name}: " in line).split(f"{name}: ", 1)[1]
               for name in [*bad, big.name]}
    assert "beyond a float's range" in reasons["huge-int.result.json"]
    assert "an integer of more than 4300 digits" in reasons["digits.result.json"]
    assert "infinite" in reasons["infinite.result.json"]
    assert "nested more than 64" in reasons["deep.result.json"]
    assert "nested too deeply" in reasons["deeper.result.json"]
    assert "outside the years 1..9999" in reasons["early.result.json"]
    assert "outside the years 1..9999" in reasons["late.result.json"]
    assert "run.run_id is 100000 characters" in reasons["long-id.result.json"]
    assert "run.run_id is not text" in reasons["id-object.result.json"]
    assert "more than 32" in reasons["name.result.json"]
    assert "more than a result file holds" in reasons["big.result.json"]
    with open_records(str(db)) as records:
        (run,) = records.list_runs()
        assert run.serial == "H-1" and run.results == 1


def test_non_regular_files_are_one_line_and_never_read(tmp_path):
    """/dev/zero raised MemoryError; a FIFO blocked `bench db import` forever."""
    fifo = tmp_path / "pipe.result.json"
    os.mkfifo(fifo)
    fifo_log = tmp_path / "pipe.mcap"
    os.mkfifo(fifo_log)
    rc, stdout, stderr = cli(["db", "import", "--db", str(tmp_path / "r.sqlite"), "/dev/zero", str(fifo),
                              str(fifo_log)])
    assert rc == 4 and "0 recorded, 0 already known, 3 failed" in stdout
    assert stderr.count("not a regular file") == 3, stderr


def test_a_log_that_starts_before_year_1_in_utc_is_recorded_with_its_start_unknown(tmp_path):
    """`run.started_utc = 0001-01-01T00:00:00+05:00` crashed `bench db import` (OverflowError)."""
    log = write_static_log(tmp_path / "static.mcap", 5.0, 50.0)
    (tmp_path / "in").mkdir()
    crafted = rewrite_log(log, tmp_path / "in" / "early.mcap", metadata={"run": {
        "run_id": "early-run", "mode": "simulator", "started_utc": "0001-01-01T00:00:00+05:00"}})
    db = tmp_path / "r.sqlite"
    rc, stdout, stderr = cli(["db", "import", "--db", str(db), str(crafted)])
    assert rc == 0 and "1 recorded" in stdout, stderr
    with open_records(str(db)) as records:
        (run,) = records.list_runs()
        assert (run.run_id, run.started_utc, run.log_complete) == ("early-run", None, True)


@pytest.mark.slow
def test_a_noise_result_of_a_run_is_recorded_and_a_simulated_imus_is_named(tmp_path):
    """A static-noise run's `<run-id>.noise.json` was ignored without a word (the run told the user to import it
    later); the noise of the simulated IMU alone belongs to no run and says so."""
    folder = tmp_path / "runs"
    folder.mkdir()
    log = write_static_log(folder / "20260101T000000Z-noise-run.mcap", 60.0, 100.0)
    rc, _, stderr = cli(["noise", str(log), "--out", str(folder), "--quiet"])
    assert rc == 0, stderr
    rc, _, stderr = cli(["noise", "--sim", "--duration-h", "0.01", "--rate-hz", "100", "--out",
                         str(tmp_path / "sim"), "--quiet"])
    assert rc == 0, stderr
    (sim_noise,) = (tmp_path / "sim").glob("*.noise.json")
    db = tmp_path / "r.sqlite"
    rc, stdout, stderr = cli(["db", "import", "--db", str(db), str(folder), str(sim_noise)])
    assert rc == 0, stderr
    assert "2 recorded, 0 already known, 0 failed, 1 with nothing to record" in stdout
    assert f"not recorded {sim_noise}: the noise of a simulated IMU alone" in stdout
    import sqlalchemy as sa

    with open_records(str(db)) as records:
        (run,) = records.list_runs()
        assert (run.run_id, run.kind, run.results) == (log.stem, "noise", 1)
        with records.engine.connect() as conn:
            names = {n for (n,) in conn.execute(sa.select(schema.coefficients.c.name))}
    assert "gyro_x.arw" in names and "acc_z.vrw" in names
    rc, stdout, _ = cli(["db", "import", "--db", str(db), str(folder)])
    assert rc == 0 and "0 recorded, 2 already known" in stdout


@pytest.mark.slow
def test_thermal_sim_results_say_in_one_line_why_they_are_not_recorded(tmp_path):
    """`bench thermal sim` results were refused as "the result names no run", the path printed twice."""
    config = tmp_path / "bench.toml"
    config.write_text(config_text(positions="traditional-12", rotations="traditional-3s6r", dwell_s=1.0))
    rc, _, stderr = cli(["thermal", "sim", "--temperatures-c", "20", "30", "--config", str(config), "--out",
                         str(tmp_path / "sim"), "--quiet"])
    assert rc == 0, stderr
    model = tmp_path / "sim" / "thermal.json"
    rc, stdout, stderr = cli(["db", "import", "--db", str(tmp_path / "r.sqlite"), str(tmp_path / "sim"), str(model)])
    assert rc == 0 and stderr == "", stderr
    assert "0 recorded, 0 already known, 0 failed, 3 with nothing to record" in stdout
    lines = [line for line in stdout.splitlines() if line.startswith("not recorded ")]
    assert len(lines) == 3 and all(line.count(str(tmp_path)) == 1 for line in lines)
    assert sum("an in-memory simulation (`bench thermal sim`)" in line for line in lines) == 2
    assert any("thermal.json: a thermal model" in line for line in lines)


def test_a_database_from_a_newer_schema_is_one_line_and_nothing_is_written(good_result, tmp_path):
    db = tmp_path / "r.sqlite"
    rc, _, stderr = cli(["db", "import", "--db", str(db), str(good_result)])
    assert rc == 0, stderr
    import sqlalchemy as sa

    engine = sa.create_engine(f"sqlite:///{db}")
    with engine.begin() as conn:
        conn.execute(sa.insert(schema.schema_version).values(version=schema.SCHEMA_VERSION + 1, applied_utc=T0,
                                                             software_version="99.0"))
    engine.dispose()
    before = db.read_bytes()
    other = write_result(tmp_path / "other", "H-2", T0, seed=4)
    for argv in (["db", "import", "--db", str(db), str(other)], ["db", "list", "--db", str(db)],
                 ["db", "history", "--db", str(db), "H-1"]):
        rc, _, stderr = cli(argv)
        assert rc != 0, argv
        assert "newer than this software's" in stderr and "Traceback" not in stderr, (argv, stderr)
    assert db.read_bytes() == before


def test_history_marks_failed_simulated_and_stand_in_results_shows_the_changes_and_no_drift_from_minutes(
        tmp_path):
    """Issue 27: `bench db history` printed `36012.5` on every row, listed failed and simulated runs unmarked, and
    stated a drift per year from 30 minutes of runs."""
    folder = tmp_path / "runs"
    values = (36012.51, 36012.54, 36012.58)
    for k, value in enumerate(values):
        path = write_result(folder, "M-1", T0 + dt.timedelta(minutes=10 * k), seed=30 + k)
        data = json.loads(path.read_text())
        data["coefficients"]["Kg_x"]["value"] = value
        data["verdict"] = {"verdict": "fail" if k == 1 else "pass", "passed": k != 1}
        if k == 2:      # only a whole re-solve of this run is recorded: it stands in, marked
            data["run"]["solved_by"] = "bench solve"
        path.write_text(json.dumps(data))
    db = tmp_path / "r.sqlite"
    rc, _, stderr = cli(["db", "import", "--db", str(db), "--quiet", str(folder)])
    assert rc == 0, stderr
    rc, stdout, stderr = cli(["db", "history", "--db", str(db), "M-1", "--coefficient", "Kg_x", "--out",
                              str(tmp_path / "hist")])
    assert rc == 0, stderr
    rows = [line for line in stdout.splitlines() if line.startswith("  2024-")]
    assert [float(row.split()[2]) for row in rows] == list(values), rows
    assert rows[0].endswith("  simulated") and rows[1].endswith("  FAILED, simulated")
    assert rows[2].endswith("  simulated, re-solve (its own result not recorded)")
    assert ("drift: not stated: the calibrations span 20 min, a drift per year needs at least 30 days" in stdout)
    saved = json.loads((tmp_path / "hist" / "M-1.history.json").read_text())["coefficients"]["Kg_x"]
    assert saved["drift_per_year"] is None and "span 20 min" in saved["drift_note"]
    assert saved["calibrations"][1]["marks"] == ["FAILED", "simulated"]


def _variants(good: str, folder: Path, prefix: str, n: int) -> None:
    """`n` result files of distinct runs (the good file's run id and serial renamed)."""
    data = json.loads(good)
    run_id, serial = data["run"]["run_id"], data["run"]["imu"]["serial"]
    folder.mkdir(parents=True)
    for k in range(n):
        text = good.replace(run_id, f"{prefix}-{k:03d}").replace(f'"{serial}"', f'"{prefix}-S{k % 3}"')
        (folder / f"{prefix}-{k:03d}.result.json").write_text(text)


@pytest.mark.slow
def test_two_processes_importing_into_one_database_at_once_lose_nothing(good_result, tmp_path):
    """Each process's transaction takes SQLite's write lock when it begins (BEGIN IMMEDIATE). Before, the driver
    began a transaction only at the first INSERT, after the checks: both processes found a run (or the schema)
    missing and one died with `UNIQUE constraint failed: runs.run_id` (or `schema_version.version`), exit 2, the
    rest of its files not recorded (2 of 3 tries)."""
    import subprocess
    import sys

    from tests.helpers.run import REPO

    good = good_result.read_text()
    _variants(good, tmp_path / "a", "A", 40)
    _variants(good, tmp_path / "b", "B", 40)
    _variants(good, tmp_path / "shared", "S", 100)         # both import these, first: each recorded once
    db = tmp_path / "r.sqlite"
    procs = [subprocess.Popen([sys.executable, "-m", "bench.cli", "db", "import", "--db", str(db), "--quiet",
                               str(tmp_path / "shared"), str(tmp_path / folder)], cwd=REPO,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for folder in ("a", "b")]
    outputs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outputs
    recorded = [int(out.split("\n")[-2].split()[0]) for out, _ in outputs]
    known = [int(out.split("\n")[-2].split()[2]) for out, _ in outputs]
    assert sum(recorded) == 180 and sum(known) == 100, outputs
    import sqlalchemy as sa

    with open_records(str(db)) as records:
        assert len(records.list_runs()) == 180
        with records.engine.connect() as conn:
            assert conn.exec_driver_sql("PRAGMA integrity_check").scalar() == "ok"
            assert conn.execute(sa.select(sa.func.count()).select_from(schema.results)).scalar() == 180
            assert conn.execute(sa.select(sa.func.count()).select_from(schema.units)).scalar() == 9


def test_a_locked_or_corrupt_database_is_one_line_and_nothing_is_written(good_result, tmp_path, monkeypatch):
    import sqlite3

    from bench.records import store

    db = tmp_path / "r.sqlite"
    rc, _, stderr = cli(["db", "import", "--db", str(db), str(good_result)])
    assert rc == 0, stderr
    other = write_result(tmp_path / "other", "L-2", T0, seed=5)
    monkeypatch.setattr(store, "SQLITE_BUSY_TIMEOUT_S", 0.2)
    holder = sqlite3.connect(db, isolation_level=None)
    try:
        holder.execute("BEGIN EXCLUSIVE")               # another process in the middle of a write
        before = db.read_bytes()
        rc, stdout, stderr = cli(["db", "import", "--db", str(db), str(other)])
        assert rc == 2 and len(stderr.splitlines()) == 1, stderr
        assert "the database is locked by another process (waited 0.2 s): nothing was written" in stderr
        assert db.read_bytes() == before
    finally:
        holder.close()

    corrupt = tmp_path / "corrupt.sqlite"
    corrupt.write_bytes(b"this is no database\n" * 400)
    before = corrupt.read_bytes()
    for argv in (["db", "import", "--db", str(corrupt), str(other)], ["db", "list", "--db", str(corrupt)],
                 ["db", "history", "--db", str(corrupt), "L-2"]):
        rc, _, stderr = cli(argv)
        assert rc == 2 and len(stderr.splitlines()) == 1 and "not a SQLite database, or a corrupt one" in stderr, \
            (argv, stderr)
    assert corrupt.read_bytes() == before
