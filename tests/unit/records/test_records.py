"""The records database (bench.records, `bench db`): schema and migrations on SQLite and on a real PostgreSQL
server, idempotent import of real result files, list, a unit's history (changes in sigma, drift per year)."""

from __future__ import annotations

import datetime as dt
import json
import math
import re
from pathlib import Path

import pytest
import sqlalchemy as sa

from bench.cli.main import main
from bench.records import schema
from bench.records.history import unit_history
from bench.records.migrate import SchemaError, current_version, migrate
from bench.records.store import RecordsError, database_url, default_url, open_records
from tests.helpers.postgres import create_database, postgres_server
from tests.helpers.records import drifted_imu, write_result

T0 = dt.datetime(2022, 3, 1, 8, 0, 0)
DRIFT_DPH_PER_YEAR = 0.5


def _schema_of(engine: sa.Engine) -> dict[str, tuple]:
    """Per table: columns, indexes, unique constraints, primary key (PostgreSQL reflects a unique constraint as an
    index too: those are left out of the indexes)."""
    inspector = sa.inspect(engine)
    return {t: ({c["name"] for c in inspector.get_columns(t)},
                {tuple(i["column_names"]) for i in inspector.get_indexes(t) if not i.get("duplicates_constraint")},
                {tuple(u["column_names"]) for u in inspector.get_unique_constraints(t)},
                tuple(inspector.get_pk_constraint(t)["constrained_columns"]))
            for t in inspector.get_table_names()}


def _expected_schema() -> dict[str, tuple]:
    return {name: ({c.name for c in table.columns}, {tuple(c.name for c in i.columns) for i in table.indexes},
                   {tuple(c.name for c in u.columns) for u in table.constraints if isinstance(u, sa.UniqueConstraint)},
                   tuple(c.name for c in table.primary_key.columns))
            for name, table in schema.TABLES.items()}


def check_migrations(url: str) -> None:
    """From empty to version 1, data in, then to the latest: the data kept, the schema the latest definition's."""
    engine = sa.create_engine(url)
    try:
        assert migrate(engine, target=1) == (0, 1)
        with engine.begin() as conn:
            assert current_version(conn) == 1
            v1 = schema.define(sa.MetaData(), 1)
            unit = conn.execute(sa.insert(v1["units"]).values(model="M", serial="S1")).inserted_primary_key[0]
            run = conn.execute(sa.insert(v1["runs"]).values(
                run_id="r1", unit_id=unit, kind="calibration", mode="hardware", operator="ann", table_url="",
                plan="", software_version="0.0.9", outcome="done", started_utc=T0)).inserted_primary_key[0]
            result = conn.execute(sa.insert(v1["results"]).values(
                run_pk=run, sha256="0" * 64, software_version="0.0.9", imported_utc=T0)).inserted_primary_key[0]
            conn.execute(sa.insert(v1["coefficients"]).values(result_id=result, name="Kg_x", value=1.5, sigma=0.1,
                                                              unit="u"))
        assert "budget" not in _schema_of(engine)["coefficients"][0]
        assert migrate(engine) == (1, schema.SCHEMA_VERSION)
        assert _schema_of(engine) == _expected_schema()
        with engine.connect() as conn:
            row = conn.execute(sa.select(schema.coefficients)).mappings().one()
            assert (row["name"], row["value"], row["sigma"], row["budget"]) == ("Kg_x", 1.5, 0.1, None)
            versions = [v for (v,) in conn.execute(sa.select(schema.schema_version.c.version).order_by(
                schema.schema_version.c.version))]
            assert versions == list(range(1, schema.SCHEMA_VERSION + 1))
        assert migrate(engine) == (schema.SCHEMA_VERSION, schema.SCHEMA_VERSION)      # nothing left to do
        with engine.begin() as conn:                                                  # a newer database is refused
            conn.execute(sa.insert(schema.schema_version).values(version=schema.SCHEMA_VERSION + 1, applied_utc=T0,
                                                                 software_version="9.9"))
        with pytest.raises(SchemaError, match="newer than this software"):
            migrate(engine)
    finally:
        engine.dispose()


def test_migrations_on_sqlite(tmp_path):
    check_migrations(f"sqlite:///{tmp_path / 'r.sqlite'}")


def test_a_version_4_database_migrates_to_one_record_per_unit(tmp_path):
    """Version 5 (a run of several IMUs, one record per unit): a version-4 database keeps its runs, each a run of
    one IMU (`bench_run` NULL), and takes a unit's record of a run of several."""
    from bench.records.store import RunInfo

    url = f"sqlite:///{tmp_path / 'v4.sqlite'}"
    engine = sa.create_engine(url)
    try:
        assert migrate(engine, target=4) == (0, 4)
        with engine.begin() as conn:
            v4 = schema.define(sa.MetaData(), 4)
            assert "bench_run" not in {c.name for c in v4["runs"].columns}
            unit = conn.execute(sa.insert(v4["units"]).values(model="M", serial="S1")).inserted_primary_key[0]
            conn.execute(sa.insert(v4["runs"]).values(
                run_id="r1", unit_id=unit, kind="calibration", mode="hardware", operator="ann", table_url="",
                plan="", software_version="0.0.9", outcome="done", started_utc=T0, log_complete=True))
    finally:
        engine.dispose()
    with open_records(url) as records:
        with records.connection() as conn:
            assert current_version(conn) == schema.SCHEMA_VERSION == 5
            assert conn.execute(sa.select(schema.runs.c.run_id, schema.runs.c.bench_run)).all() == [("r1", None)]
        assert _schema_of(records.engine) == _expected_schema()
        assert records.unit_record("r1") == "r1" and records.units_of_run("r1") == []
        for serial in ("A", "B"):
            records.add_run(RunInfo(run_id=f"r2.{serial}", model="M", serial=serial, bench_run="r2"))
        assert records.units_of_run("r2") == [("r2.A", "A"), ("r2.B", "B")]
        assert records.unit_record("r2", "B") == "r2.B" and records.unit_record("r2.B") == "r2.B"
        for args, words in ((("r2",), "calibrated 2 units (A, B): name one with --unit SERIAL"),
                            (("r2", "C"), "has no unit 'C'"), (("r1", "A"), "is of unit 'S1', not 'A'"),
                            (("r9",), "no run 'r9'")):
            with pytest.raises(RecordsError, match=re.escape(words)):
                records.unit_record(*args)


def test_a_database_of_something_else_is_refused(tmp_path):
    engine = sa.create_engine(f"sqlite:///{tmp_path / 'other.sqlite'}")
    sa.Table("runs", sa.MetaData(), sa.Column("x", sa.Integer)).create(engine)
    engine.dispose()
    with pytest.raises(RecordsError, match="not a turntable-bench records database"):
        open_records(str(tmp_path / "other.sqlite"))


def test_default_database_path(monkeypatch, tmp_path):
    monkeypatch.delenv("BENCH_DB")
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert default_url() == str(tmp_path / "xdg" / "turntable-bench" / "records.sqlite")
    monkeypatch.delenv("XDG_DATA_HOME")
    assert default_url() == str(Path.home() / ".local" / "share" / "turntable-bench" / "records.sqlite")
    monkeypatch.setenv("BENCH_DB", "postgresql://lab@db.example/records")
    assert database_url(None) == "postgresql://lab@db.example/records"
    assert database_url("rel/r.sqlite") == f"sqlite:///{Path('rel/r.sqlite').absolute()}"


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> Path:
    """Real result files: unit A calibrated 5 times over 4 years with D0_x drifting; unit B twice."""
    folder = tmp_path_factory.mktemp("archive")
    for k in range(5):
        years = k * 1.0
        write_result(folder / "a", "A-1", T0 + dt.timedelta(days=365.25 * years), seed=10 + k,
                     imu=drifted_imu(years, DRIFT_DPH_PER_YEAR))
    for k in range(2):
        write_result(folder / "b", "B-2", T0 + dt.timedelta(days=200 * k), seed=20 + k)
    return folder


def test_import_is_idempotent_and_list_filters(archive, tmp_path, capsys):
    db = str(tmp_path / "r.sqlite")
    assert main(["db", "--db", db, "import", str(archive)]) == 0
    assert "7 recorded, 0 already known, 0 failed" in capsys.readouterr().out
    assert main(["db", "import", "--db", db, str(archive)]) == 0
    assert "0 recorded, 7 already known, 0 failed" in capsys.readouterr().out
    with open_records(db) as records:
        assert len(records.list_runs()) == 7
        assert [r.serial for r in records.list_runs(serial="B-2")] == ["B-2", "B-2"]
        since = records.list_runs(since=T0 + dt.timedelta(days=365 * 2))
        assert {r.serial for r in since} == {"A-1"} and len(since) == 3
        first = records.list_runs(serial="A-1")[-1]
        assert (first.run_id, first.results, first.outcome, first.operator) == (
            "20220301T080000Z-a-1-10", 1, "done", "tester")
    assert main(["db", "list", "--db", db, "--serial", "A-1", "--since", "2024-06-01"]) == 0
    out = capsys.readouterr().out
    assert "2 run(s)" in out and "A-1" in out and "B-2" not in out
    assert main(["db", "list", "--db", db, "--since", "yesterday"]) == 2
    assert "--since 'yesterday': not a date" in capsys.readouterr().err


def test_history_finds_the_drift_and_the_changes(archive, tmp_path, capsys):
    db = str(tmp_path / "r.sqlite")
    assert main(["db", "import", "--db", db, "--quiet", str(archive)]) == 0
    with open_records(db) as records:
        history = unit_history(records, "A-1")
    assert len(history.runs) == 5 and len(history.coefficients) == 30
    d0 = next(c for c in history.coefficients if c.name == "D0_x")
    drift, sigma = d0.drift_per_year()
    assert sigma is not None and sigma > 0
    assert abs(drift - DRIFT_DPH_PER_YEAR) < 4 * sigma, (drift, sigma)
    # each year moved D0_x by 0.5 deg/h, many times its combined sigma; a coefficient that did not drift did not
    changes = d0.changes_sigma()
    expected = [DRIFT_DPH_PER_YEAR / math.hypot(a.sigma, b.sigma) for a, b in zip(d0.points, d0.points[1:])]
    assert all(abs(z - e) < 4 for z, e in zip(changes, expected)) and min(changes) > 5
    kg = next(c for c in history.coefficients if c.name == "Kg_x")
    assert max(abs(z) for z in kg.changes_sigma()) < 4
    kg_drift, kg_sigma = kg.drift_per_year()
    assert abs(kg_drift) < 4 * kg_sigma

    out_dir = tmp_path / "hist"
    assert main(["db", "history", "--db", db, "A-1", "--coefficient", "D0_x", "Kg_x", "--out", str(out_dir)]) == 0
    out = capsys.readouterr().out
    assert "unit simulated FOG IMU / A-1: 5 calibration(s)" in out and "D0_x [deg/h]  drift:" in out
    assert "Ka_x" not in out
    saved = json.loads((out_dir / "A-1.history.json").read_text())
    assert list(saved["coefficients"]) == ["D0_x", "Kg_x"]
    assert saved["coefficients"]["D0_x"]["drift_per_year"]["value"] == pytest.approx(drift)
    assert (out_dir / "A-1.history.png").read_bytes()[:4] == b"\x89PNG"
    assert len((out_dir / "A-1.history.csv").read_text().splitlines()) == 1 + 2 * 5
    assert main(["db", "history", "--db", db, "NOPE"]) == 2
    assert "no unit with serial 'NOPE'" in capsys.readouterr().err


def _reference_table(history) -> list[str]:
    """The history table built one value at a time: the oracle of the column-wise table (its digits, drift line
    and marks from the same rules)."""
    from bench.records.history import _marks, drift_text

    def g(x):
        return "-" if x is None else f"{x:.6g}"
    lines = [f"unit {history.model} / {history.serial}: {len(history.runs)} calibration(s)"]
    for c in history.coefficients:
        digits = c.digits()
        width = max(14, digits + 7)
        lines += ["", f"{c.name} [{c.unit}]  {drift_text(c)}",
                  f"  {'when (UTC)':20} {'run':28} {'value':>{width}} {'sigma':>11} {'change':>9}"]
        previous = None
        for p, k in zip(c.points, c.index.tolist()):
            z = None
            if previous is not None and None not in (previous.sigma, p.sigma) and (previous.sigma or p.sigma):
                z = (p.value - previous.value) / math.hypot(previous.sigma, p.sigma)
            when = p.when.replace(microsecond=0).isoformat() + "Z"
            marks = _marks(history.calibrations[k])
            lines.append(f"  {when:20} {p.run_id[:28]:28} {p.value:>{width}.{digits}g} {g(p.sigma):>11} "
                         f"{'' if z is None else f'{z:+.2f} sig':>9}" + ("  " + ", ".join(marks) if marks else ""))
            previous = p
    return lines


def test_the_history_table_holds_every_value_unknown_sigmas_and_gaps_included(archive, tmp_path, capsys):
    """The table is built column-wise (10,000 calibrations of 30 coefficients print in well under a second): it
    must still say what the value-by-value table says, for a sigma that is unknown and a coefficient that one
    calibration lacks."""
    folder = tmp_path / "odd"
    folder.mkdir()
    paths = sorted((archive / "a").glob("*.result.json"))
    for k, path in enumerate(paths):
        data = json.loads(path.read_text())
        if k == 1:
            data["coefficients"]["Kg_x"]["sigma"] = float("nan")      # unknown: no change on either side of it
        if k == 2:
            del data["coefficients"]["Ka_y"]                           # this calibration has no Ka_y
        (folder / path.name).write_text(json.dumps(data))
    db = str(tmp_path / "r.sqlite")
    assert main(["db", "import", "--db", db, "--quiet", str(folder)]) == 0
    with open_records(db) as records:
        history = unit_history(records, "A-1")
        lean = unit_history(records, "A-1", budgets=False)
        two = unit_history(records, "A-1", ["Kg_x", "Ka_y"])
    kg = next(c for c in history.coefficients if c.name == "Kg_x")
    assert [p.sigma is None for p in kg.points] == [False, True, False, False, False]
    assert kg.changes_sigma()[:2] == [None, None] and None not in kg.changes_sigma()[2:]
    ka_y = next(c for c in history.coefficients if c.name == "Ka_y")
    assert len(ka_y.points) == 4 and paths[2].name.split(".")[0] not in [p.run_id for p in ka_y.points]
    assert all(p.budget is None for c in lean.coefficients for p in c.points)
    capsys.readouterr()
    assert main(["db", "history", "--db", db, "A-1"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed == _reference_table(history) and len(printed) == 1 + 30 * 3 + 30 * 5 - 1
    assert main(["db", "history", "--db", db, "A-1", "--coefficient", "Kg_x", "Ka_y"]) == 0
    assert capsys.readouterr().out.splitlines() == _reference_table(two)


def test_a_resolve_is_a_derived_result_and_history_takes_it_once_promoted(archive, tmp_path):
    """A re-solve by another version is recorded with the run but never replaces the run's own result (issue 27)
    unless a user promotes it."""
    from bench.records.ingest import import_paths

    path = sorted((archive / "b").glob("*.result.json"))[0]
    data = json.loads(path.read_text())
    data["run"]["software_version"] = "9.0"
    data["run"]["solved_by"] = "bench solve"
    data["run"]["solved_utc"] = "2030-01-01T00:00:00Z"      # re-solved long after the run
    data["coefficients"]["Kg_x"]["value"] += 1.0
    data["coefficients"]["Kg_x"]["budget"] = {"noise": 0.1, "table": 0.05}    # what a result with a budget adds
    resolved = tmp_path / "resolved" / path.name
    resolved.parent.mkdir()
    resolved.write_text(json.dumps(data))
    with open_records(str(tmp_path / "r.sqlite")) as records:
        import_paths(records, [resolved])                   # the newer result imported first: newest by solve time
        import_paths(records, [archive / "b"])
        rows = records.list_runs(serial="B-2")
        assert sorted(r.results for r in rows) == [1, 2]
        assert records.has_result(data["run"]["run_id"], "9.0")
        assert not records.has_result(data["run"]["run_id"], "8.0")
        kg = next(c for c in unit_history(records, "B-2").coefficients if c.name == "Kg_x")
        own = next(p for p in kg.points if p.run_id == data["run"]["run_id"])
        assert own.value == data["coefficients"]["Kg_x"]["value"] - 1.0 and own.software_version != "9.0"
        records.promote(str(resolved))
        kg = next(c for c in unit_history(records, "B-2").coefficients if c.name == "Kg_x")
        assert len(kg.points) == 2
        newest = next(p for p in kg.points if p.run_id == data["run"]["run_id"])
        assert newest.value == data["coefficients"]["Kg_x"]["value"] and newest.software_version == "9.0"
        # everything the result file says of the coefficient beyond value, sigma and unit (the budget, its k)
        assert newest.budget is not None and newest.budget["budget"] == {"noise": 0.1, "table": 0.05}
        assert set(newest.budget) == set(data["coefficients"]["Kg_x"]) - {"value", "sigma", "unit"}


def test_unreadable_files_are_reported_and_the_rest_recorded(archive, tmp_path, capsys):
    folder = tmp_path / "mixed"
    folder.mkdir()
    good = sorted((archive / "b").glob("*.result.json"))[0]
    (folder / good.name).write_bytes(good.read_bytes())
    (folder / "bad.result.json").write_text("{ not json")
    (folder / "other.result.json").write_text('{"format": "something-else"}')
    (folder / "broken.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 50)
    db = str(tmp_path / "r.sqlite")
    assert main(["db", "import", "--db", db, str(folder)]) == 4
    captured = capsys.readouterr()
    assert "1 recorded, 0 already known, 3 failed" in captured.out
    assert "bad.result.json: " in captured.err and "not JSON" in captured.err
    assert "other.result.json: not a turntable-bench/result" in captured.err
    assert "broken.mcap: " in captured.err
    assert main(["db", "import", "--db", db, str(folder / "missing")]) == 2


def test_record_outputs_warns_and_says_whether_it_recorded(tmp_path, capsys, archive):
    import argparse

    from bench.cli.db import record_outputs

    blocker = tmp_path / "file"
    blocker.write_text("")
    result = sorted((archive / "b").glob("*.result.json"))[0]
    assert not record_outputs(argparse.Namespace(db=str(blocker / "r.sqlite"), no_db=False), "bench solve", [result])
    assert "bench solve: warning: not recorded in the records database" in capsys.readouterr().err
    assert record_outputs(argparse.Namespace(db=str(tmp_path / "r.sqlite"), no_db=True), "bench solve", [result])
    assert not (tmp_path / "r.sqlite").exists()
    assert record_outputs(argparse.Namespace(db=str(tmp_path / "r.sqlite"), no_db=False), "bench solve", [result])
    with open_records(str(tmp_path / "r.sqlite")) as records:
        assert len(records.list_runs()) == 1


@pytest.fixture(scope="module")
def postgres():
    with postgres_server() as url:
        yield url


def test_migrations_on_postgresql(postgres):
    check_migrations(create_database(postgres, "migrations"))


def test_import_and_history_on_postgresql(postgres, archive, capsys):
    url = create_database(postgres, "records").replace("postgresql+psycopg", "postgresql")   # as a user writes it
    assert main(["db", "import", "--db", url, "--quiet", str(archive)]) == 0
    assert main(["db", "import", "--db", url, "--quiet", str(archive)]) == 0
    assert "0 recorded, 7 already known" in capsys.readouterr().out
    with open_records(url) as records:
        d0 = next(c for c in unit_history(records, "A-1").coefficients if c.name == "D0_x")
        drift, sigma = d0.drift_per_year()
        assert abs(drift - DRIFT_DPH_PER_YEAR) < 4 * sigma
        assert len(records.list_runs(serial="B-2")) == 2
        # without budgets (the printed table) the driver's own rows are read: the same values, types and units
        plain, full = (unit_history(records, "A-1", budgets=budgets) for budgets in (False, True))
        assert [(c.name, c.unit, c.values.tolist(), c.sigmas.tolist()) for c in plain.coefficients] == \
            [(c.name, c.unit, c.values.tolist(), c.sigmas.tolist()) for c in full.coefficients]
    assert main(["db", "history", "--db", url, "A-1"]) == 0 and "D0_x" in capsys.readouterr().out


def test_a_query_on_a_database_that_is_not_there_says_so_and_creates_nothing(tmp_path, capsys):
    """`bench db list --db /mistyped/path.sqlite` made the folder and an empty database and listed 0 runs."""
    missing = tmp_path / "nowhere" / "records.sqlite"
    assert main(["db", "list", "--db", str(missing)]) == 2
    assert main(["db", "history", "--db", str(missing), "A-1"]) == 2
    assert "no records database there" in capsys.readouterr().err
    assert not (tmp_path / "nowhere").exists()


@pytest.mark.slow
def test_two_processes_importing_into_one_postgresql_database_lose_nothing(postgres, archive, tmp_path):
    """On PostgreSQL both processes may check for a run or result at once; the one whose insert then meets the
    other's unique key runs its transaction again (it finds the row: already known) instead of ending the import
    with `duplicate key value violates unique constraint`. A new database's schema is created by one of them
    (an advisory lock), the other waits."""
    import subprocess
    import sys

    from tests.helpers.run import REPO
    from tests.unit.records.test_records_import import _variants

    good = sorted((archive / "b").glob("*.result.json"))[0].read_text()
    _variants(good, tmp_path / "a", "A", 20)
    _variants(good, tmp_path / "b", "B", 20)
    _variants(good, tmp_path / "shared", "S", 60)
    url = create_database(postgres, "concurrent")      # empty: both processes open it, one creates the schema
    procs = [subprocess.Popen([sys.executable, "-m", "bench.cli", "db", "import", "--db", url, "--quiet",
                               str(tmp_path / "shared"), str(tmp_path / folder)], cwd=REPO,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for folder in ("a", "b")]
    outputs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outputs
    with open_records(url) as records:
        assert len(records.list_runs()) == 100
        with records.engine.connect() as conn:
            assert conn.execute(sa.select(sa.func.count()).select_from(schema.results)).scalar() == 100


def test_nan_in_a_result_files_json_sections_is_recorded_on_postgresql(postgres, archive, tmp_path, capsys):
    """PostgreSQL's JSON refuses NaN: a result file from another tool with NaN in its verdict, quality, site or a
    coefficient's budget ended the whole import as a database error; it is recorded, the NaN as null."""
    path = sorted((archive / "b").glob("*.result.json"))[0]
    data = json.loads(path.read_text())
    data["quality"] = {"reduced_chi2": float("nan"), "nested": [float("inf")]}
    data["run"]["site"]["local_g"] = float("nan")
    data["coefficients"]["Kg_x"]["budget"] = {"noise": float("nan")}
    (tmp_path / "nan.result.json").write_text(json.dumps(data))
    url = create_database(postgres, "nan")
    assert main(["db", "import", "--db", url, str(tmp_path / "nan.result.json")]) == 0, capsys.readouterr().err
    with open_records(url) as records:
        with records.engine.connect() as conn:
            assert conn.execute(sa.select(schema.results.c.quality)).scalar() == {"reduced_chi2": None,
                                                                                   "nested": [None]}
