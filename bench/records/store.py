"""The records database: open it (SQLite by default, any SQLAlchemy URL), record runs and results, query them.

`open_records(url)` opens (and creates or migrates) the database; `Records.add_result`
records one result file's content, `Records.add_log` one run log's metadata; both are
idempotent (a result by the SHA-256 of its file, a run by its run id). The default
database is a SQLite file, `default_url()`: `$BENCH_DB` when set, else
`$XDG_DATA_HOME/turntable-bench/records.sqlite` (`~/.local/share/...` without XDG_DATA_HOME).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import os
from pathlib import Path
from typing import Any, Callable, Iterator, TypeVar

import sqlalchemy as sa

from bench import __version__
from bench.records import schema
from bench.records.errors import RecordsError
from bench.records.migrate import migrate
from bench.records.rows import (
    ORIGINS,
    Derivation,
    ResultRow,
    RunInfo,
    RunRow,
    coefficient_row,
    dict_or_none,
    finite,
    json_safe,
    now,
    utc,
    verdict_word,
)

#: environment variable naming the records database (a URL or a file path)
DB_ENV = "BENCH_DB"


def default_url() -> str:
    """`$BENCH_DB`, else the SQLite file under `$XDG_DATA_HOME` (`~/.local/share`)."""
    named = os.environ.get(DB_ENV, "").strip()
    if named:
        return named
    base = os.environ.get("XDG_DATA_HOME", "").strip() or str(Path.home() / ".local" / "share")
    return str(Path(base) / "turntable-bench" / "records.sqlite")


def database_url(name: str | None) -> str:
    """A SQLAlchemy URL from `--db` (a URL or a file path; None: `default_url()`)."""
    name = (name or "").strip() or default_url()
    if "://" in name:
        return name
    return f"sqlite:///{Path(name).expanduser().absolute()}"


class Records:
    """An open records database (`open_records`). Use as a context manager, or `close()`."""

    def __init__(self, engine: sa.Engine) -> None:
        self.engine = engine

    def close(self) -> None:
        self.engine.dispose()

    def __enter__(self) -> "Records":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- writing ---------------------------------------------------------------------------------

    def add_run(self, info: RunInfo) -> bool:
        """Record a run (or fill in what an earlier record of it lacked); True if anything was new."""
        return self._write(lambda conn: _upsert_run(conn, info)[1])

    def add_result(self, data: dict[str, Any], sha256: str, path: str | None, run: RunInfo,
                   derivation: Derivation | None = None) -> bool:
        """Record one result file's content (`CalibrationResult.to_json` form) of `run`, as `derivation` says it
        came to be (default: the run's own result); False if already held."""
        derivation = derivation or Derivation()
        table = schema.results

        def write(conn: sa.Connection) -> bool:
            if conn.execute(sa.select(table.c.id).where(table.c.sha256 == sha256)).first() is not None:
                _upsert_run(conn, run)
                return False
            run_pk, _ = _upsert_run(conn, run)
            verdict = dict_or_none(data.get("verdict"))
            mean_c = (dict_or_none(data.get("temperature")) or {}).get("mean_c")
            result_id = _insert(conn, sa.insert(table).values(
                run_pk=run_pk, path=path, sha256=sha256,
                software_version=run.software_version, imported_utc=now(),
                solved_utc=utc((dict_or_none(data.get("run")) or {}).get("solved_utc")) or run.finished_utc,
                verdict=verdict_word(verdict),
                verdict_json=json_safe(verdict), quality=json_safe(dict_or_none(data.get("quality"))),
                temperature_c=finite(mean_c), origin=derivation.origin, derivation=derivation.text[:400] or None,
                log_sha256=derivation.log_sha256,
            ))
            table_in = dict_or_none(data.get("coefficients")) or {}
            rows = [row for name, entry in table_in.items()
                    if (row := coefficient_row(result_id, name, entry)) is not None]
            if rows:
                conn.execute(sa.insert(schema.coefficients), rows)
            return True

        return self._write(write)

    def run_known(self, run_id: str) -> bool:
        """The run is recorded."""
        r = schema.runs
        with self._connect() as conn:
            return conn.execute(sa.select(r.c.id).where(r.c.run_id == run_id)).first() is not None

    def units_of_run(self, bench_run: str) -> list[tuple[str, str]]:
        """(record run id, serial) of every unit recorded of the run of several IMUs `bench_run`, by record."""
        r, u = schema.runs, schema.units
        query = (sa.select(r.c.run_id, u.c.serial).join(u, u.c.id == r.c.unit_id)
                 .where(r.c.bench_run == bench_run).order_by(r.c.run_id))
        with self._connect() as conn:
            return [(run_id, serial) for run_id, serial in conn.execute(query)]

    def unit_record(self, run_id: str, serial: str | None = None) -> str:
        """The record run id that `run_id` and `serial` (`--unit`) name: a record's run id as it is (its unit
        must be `serial` when given); a run of several IMUs by its run id, one unit of it by `serial`, or the only
        one recorded. RecordsError in one line otherwise (no such run; several units and no `serial`)."""
        units = self.units_of_run(run_id)
        if not units:
            r, u = schema.runs, schema.units
            with self._connect() as conn:
                found = conn.execute(sa.select(u.c.serial).join(r, r.c.unit_id == u.c.id)
                                     .where(r.c.run_id == run_id)).first()
            if found is None:
                raise RecordsError(f"no run {run_id!r} in the records")
            if serial is not None and found[0] != serial:
                raise RecordsError(f"run {run_id!r} is of unit {found[0]!r}, not {serial!r}")
            return run_id
        if serial is not None:
            for record, unit in units:
                if unit == serial:
                    return record
            raise RecordsError(f"run {run_id!r} has no unit {serial!r} recorded (its units: "
                               f"{', '.join(unit for _, unit in units)})")
        if len(units) > 1:
            raise RecordsError(f"run {run_id!r} calibrated {len(units)} units ({', '.join(u for _, u in units)}): "
                               f"name one with --unit SERIAL")
        return units[0][0]

    def has_result(self, run_id: str, software_version: str) -> bool:
        """A result of `run_id` solved by `software_version` is recorded (what a resumed archive re-solve skips)."""
        r, s = schema.runs, schema.results
        query = (sa.select(s.c.id).join(r, r.c.id == s.c.run_pk)
                 .where(r.c.run_id == run_id, s.c.software_version == software_version).limit(1))
        with self._connect() as conn:
            return conn.execute(query).first() is not None

    def solved_keys(self, software_version: str) -> set[tuple[str, str]]:
        """(run id, SHA-256 of the log solved) of every result `software_version` solved from a known log: what an
        archive re-solve skips, wherever the log lies now. A run's own result counts with its run's log."""
        r, s = schema.runs, schema.results
        # a run's own result, and one recorded before schema version 3 (keyed then on the run's log), count with
        # the run's log
        own = sa.or_(s.c.origin == "run", s.c.origin.is_(None))
        log_sha = sa.func.coalesce(s.c.log_sha256, sa.case((own, r.c.log_sha256), else_=None))
        query = (sa.select(r.c.run_id, log_sha).join(s, s.c.run_pk == r.c.id)
                 .where(s.c.software_version == software_version, log_sha.is_not(None)).distinct())
        with self._connect() as conn:
            return {(run_id, sha) for run_id, sha in conn.execute(query)}

    def promote(self, reference: str) -> ResultRow:
        """Make a result its run's record of truth: `reference` is its id (`bench db results`), or the path or
        SHA-256 of its file. RecordsError if no result matches."""
        s = schema.results
        if reference.isdigit() and len(reference) < 19:
            where = s.c.id == int(reference)
        elif len(reference) == 64 and all(c in "0123456789abcdef" for c in reference.lower()):
            where = s.c.sha256 == reference.lower()
        else:
            where = s.c.path == str(Path(reference).absolute())
        with self._begin() as conn:
            found = conn.execute(sa.select(s.c.id, s.c.run_pk).where(where)).first()
            if found is None:
                raise RecordsError(f"no recorded result {reference!r} (a result id from `bench db results RUN_ID`, "
                                   "or a recorded result file)")
            conn.execute(sa.update(s).where(s.c.id == found[0]).values(promoted_utc=now()))
        rows = self.results_of_run_pk(found[1])
        return next(row for row in rows if row.result_id == found[0])

    def results_of(self, run_id: str) -> list[ResultRow]:
        """Every result of the run, oldest first, the record of truth marked; RecordsError if no such run."""
        r = schema.runs
        with self._connect() as conn:
            found = conn.execute(sa.select(r.c.id).where(r.c.run_id == run_id)).first()
        if found is None:
            raise RecordsError(f"no run {run_id!r} in the records")
        return self.results_of_run_pk(found[0])

    def results_of_run_pk(self, run_pk: int) -> list[ResultRow]:
        r, s = schema.runs, schema.results
        truth = _truth_results(s.c.run_pk == run_pk).subquery()
        query = (sa.select(s.c.id, r.c.run_id, s.c.origin, s.c.derivation, s.c.software_version, s.c.solved_utc,
                           s.c.verdict, s.c.promoted_utc, s.c.path, truth.c.id.is_not(None))
                 .join(r, r.c.id == s.c.run_pk).outerjoin(truth, truth.c.id == s.c.id)
                 .where(s.c.run_pk == run_pk).order_by(s.c.id))
        with self._connect() as conn:
            return [ResultRow(*row) for row in conn.execute(query)]

    # -- reading ---------------------------------------------------------------------------------

    def list_runs(self, serial: str | None = None, since: dt.datetime | None = None) -> list[RunRow]:
        """Runs (newest first), of one serial and/or started (else finished) at or after `since`."""
        u, r, s = schema.units, schema.runs, schema.results
        counts = sa.select(s.c.run_pk, sa.func.count(s.c.id).label("n")).group_by(s.c.run_pk).subquery()
        newest = _truth_results().subquery()
        when = sa.func.coalesce(r.c.started_utc, r.c.finished_utc)
        query = (sa.select(r.c.run_id, u.c.model, u.c.serial, r.c.kind, r.c.started_utc, r.c.finished_utc,
                           r.c.outcome, r.c.operator, r.c.plan, sa.func.coalesce(counts.c.n, 0), s.c.verdict,
                           r.c.log_path, newest.c.id, s.c.origin, s.c.promoted_utc.is_not(None), r.c.log_complete)
                 .join(u, u.c.id == r.c.unit_id)
                 .outerjoin(counts, counts.c.run_pk == r.c.id)
                 .outerjoin(newest, newest.c.run_pk == r.c.id)
                 .outerjoin(s, s.c.id == newest.c.id)
                 .order_by(when.desc(), r.c.run_id.desc()))
        if serial is not None:
            query = query.where(u.c.serial == serial)
        if since is not None:
            query = query.where(when >= since)
        with self._connect() as conn:
            return [RunRow(*row) for row in conn.execute(query)]    # type: ignore[call-arg]  # the columns in order

    def unit_models(self, serial: str) -> list[str]:
        """The models recorded with this serial."""
        u = schema.units
        with self._connect() as conn:
            return [m for (m,) in conn.execute(sa.select(u.c.model).where(u.c.serial == serial).order_by(u.c.model))]

    def history_rows(self, serial: str, model: str | None = None, names: list[str] | None = None,
                     budgets: bool = True) -> tuple[list[tuple], list[tuple]]:
        """The record of truth of every calibration run of the unit (`_truth_results`), oldest first, as (result
        id, run_id, when, software_version, verdict, origin, promoted, mode), `when` being the run's start, else
        its end; and those results' coefficients
        (`names` only, if given) as (result id, name, value, sigma, unit, budget) by name (budget None
        unless `budgets`). Two queries: the run columns once per run, not once per coefficient."""
        u, r, s, c = schema.units, schema.runs, schema.results, schema.coefficients
        unit_ids = sa.select(u.c.id).where(u.c.serial == serial)
        if model is not None:
            unit_ids = unit_ids.where(u.c.model == model)
        run_ids = sa.select(r.c.id).where(r.c.unit_id.in_(unit_ids.scalar_subquery()), r.c.kind == "calibration")
        latest = _truth_results(s.c.run_pk.in_(run_ids.scalar_subquery())).subquery()
        when = sa.func.coalesce(r.c.started_utc, r.c.finished_utc)
        runs_query = (sa.select(s.c.id, r.c.run_id, when, s.c.software_version, s.c.verdict, s.c.origin,
                                s.c.promoted_utc.is_not(None), r.c.mode)
                      .select_from(latest).join(s, s.c.id == latest.c.id).join(r, r.c.id == s.c.run_pk)
                      .order_by(when, r.c.run_id))
        budget = c.c.budget if budgets else sa.null()
        values_query = (sa.select(c.c.result_id, c.c.name, c.c.value, c.c.sigma, c.c.unit, budget)
                        .where(c.c.result_id.in_(sa.select(latest.c.id).scalar_subquery()))
                        .order_by(c.c.name))     # each coefficient's rows together (the name index has that order)
        if names:
            values_query = values_query.where(c.c.name.in_(names))
        with self._connect() as conn:
            runs = [tuple(row) for row in conn.execute(runs_query)]
            result = conn.execute(values_query)
            if budgets:     # the budget column's JSON is decoded by SQLAlchemy's row processing
                return runs, list(result.fetchall())
            # numbers, text and NULLs need no processing: the driver's own tuples, in one call (300,000 rows: a
            # fifth of `bench db history`'s time went to building SQLAlchemy row objects)
            return runs, list(result.cursor.fetchall())

    # -- plumbing --------------------------------------------------------------------------------

    def _write(self, work: Callable[[sa.Connection], T]) -> T:
        """`work` in one transaction; run again when another process recorded the same unit, run or result
        between this one's check and its insert (a unique key's IntegrityError: PostgreSQL lets both check
        at once; SQLite's writers take turns, `_sqlite_begin`)."""
        for attempt in range(_WRITE_ATTEMPTS):
            try:
                with self._begin() as conn:
                    return work(conn)
            except RecordsError as exc:
                if not isinstance(exc.__cause__, sa.exc.IntegrityError) or attempt == _WRITE_ATTEMPTS - 1:
                    raise
        raise AssertionError("unreachable")

    def transaction(self) -> contextlib.AbstractContextManager[sa.Connection]:
        """A connection in a transaction (committed when the block ends well); database errors as RecordsError
        (for the modules beside this one: `bench.records.lab`)."""
        return self._begin()

    def connection(self) -> contextlib.AbstractContextManager[sa.Connection]:
        """A connection; database errors as RecordsError."""
        return self._connect()

    @contextlib.contextmanager
    def _begin(self) -> Iterator[sa.Connection]:
        """A connection in a transaction (committed when the block ends well); database errors as RecordsError."""
        with self._records_errors(), self.engine.begin() as conn:
            yield conn

    @contextlib.contextmanager
    def _connect(self) -> Iterator[sa.Connection]:
        """A connection; database errors as RecordsError."""
        with self._records_errors(), self.engine.connect() as conn:
            yield conn

    @contextlib.contextmanager
    def _records_errors(self) -> Iterator[None]:
        try:
            yield
        except sa.exc.SQLAlchemyError as exc:
            raise RecordsError(f"{_shown(self.engine)}: {_reason(exc)}") from exc


_WRITE_ATTEMPTS = 3
T = TypeVar("T")


def _insert(conn: sa.Connection, statement: sa.Insert) -> int:
    """Execute an INSERT of one row; its new primary key."""
    key = conn.execute(statement).inserted_primary_key
    assert key is not None
    return int(key[0])


def _truth_results(*where: sa.ColumnElement[bool]) -> sa.Select:
    """(run_pk, id) of each run's record of truth: the result a user promoted last; else the run's own result
    (`bench run` wrote it; the newest if several); else, for a run whose own result is not recorded (an archive
    of logs), the newest re-solve of its whole intact log (of the run's log itself when its hash is known; a
    result recorded before schema version 3 counts as one). A subset or a damaged log's solve is never one
    unless promoted: a run with only those has no record of truth."""
    s, r = schema.results, schema.runs
    same_log = sa.or_(s.c.log_sha256.is_(None), r.c.log_sha256.is_(None), s.c.log_sha256 == r.c.log_sha256)
    eligible = sa.or_(s.c.promoted_utc.is_not(None), s.c.origin == "run", s.c.origin.is_(None),
                      sa.and_(s.c.origin == "re-solve", same_log))
    rank = sa.func.row_number().over(partition_by=s.c.run_pk, order_by=(
        s.c.promoted_utc.is_(None), s.c.promoted_utc.desc(),         # promoted first, the latest promotion
        sa.case((s.c.origin == "run", 0), else_=1),                  # then the run's own
        sa.func.coalesce(s.c.solved_utc, s.c.imported_utc).desc(), s.c.id.desc())).label("rank")
    ranked = (sa.select(s.c.run_pk, s.c.id, rank).join(r, r.c.id == s.c.run_pk).where(eligible, *where)
              .subquery())
    return sa.select(ranked.c.run_pk, ranked.c.id).where(ranked.c.rank == 1)


def _unit_id(conn: sa.Connection, model: str, serial: str) -> int:
    u = schema.units
    found = conn.execute(sa.select(u.c.id).where(u.c.model == model, u.c.serial == serial)).first()
    if found is not None:
        return int(found[0])
    return _insert(conn, sa.insert(u).values(model=model, serial=serial))


_RUN_FIELDS = ("kind", "mode", "operator", "site", "table_url", "plan", "software_version", "started_utc",
               "finished_utc", "outcome", "bench_run")
_LOG_FIELDS = ("log_path", "log_sha256", "log_complete")


def _upsert_run(conn: sa.Connection, info: RunInfo) -> tuple[int, bool]:
    """The run's primary key; a known run gets the fields it lacked (a log's start time, a result's outcome)."""
    r = schema.runs
    found = conn.execute(sa.select(r).where(r.c.run_id == info.run_id)).mappings().first()
    values = {f: getattr(info, f) for f in _RUN_FIELDS}
    values["site"] = json_safe(values["site"])
    if found is None:
        values.update({f: getattr(info, f) for f in _LOG_FIELDS})
        unit_id = _unit_id(conn, info.model, info.serial)
        run_pk = _insert(conn, sa.insert(r).values(run_id=info.run_id, unit_id=unit_id, **values))
        link_equipment(conn, run_pk, info.equipment)
        return run_pk, True
    missing = {f: v for f, v in values.items() if v not in (None, "", {}) and found[f] in (None, "", {})}
    if info.kind == "noise" and found["kind"] != "noise":     # its noise result shows what the run was
        missing["kind"] = "noise"
    if _log_replaces(found, info):
        missing.update({f: getattr(info, f) for f in _LOG_FIELDS})
    if missing:
        conn.execute(sa.update(r).where(r.c.id == found["id"]).values(**missing))
    linked = link_equipment(conn, int(found["id"]), info.equipment)
    return int(found["id"]), bool(missing) or linked


def link_equipment(conn: sa.Connection, run_pk: int, used: tuple[tuple[str, str], ...]) -> bool:
    """Record that the run used the registered equipment `used` ((tag, serial) from its log's `lab` metadata);
    whether anything was new. An item is linked only when the register holds its tag with the serial the log
    recorded (a tag registered later for another item is not what the run used); the log keeps what the run
    recorded of the others."""
    if not used:
        return False
    e, re_ = schema.equipment, schema.run_equipment
    serials = dict(used)
    ids = {i for (i, tag, serial) in conn.execute(sa.select(e.c.id, e.c.tag, e.c.serial).where(
        e.c.tag.in_(list(serials)))) if serials[tag] in ("", serial)}
    known = {i for (i,) in conn.execute(sa.select(re_.c.equipment_id).where(re_.c.run_pk == run_pk))}
    new = sorted(ids - known)
    if new:
        conn.execute(sa.insert(re_), [{"run_pk": run_pk, "equipment_id": i} for i in new])
    return bool(new)


def _log_replaces(found: Any, info: RunInfo) -> bool:
    """The log `info` names becomes the run's log: the run has none; or its log was unfinished (no footer) and
    this one is finished, or is the same file grown (a run still recording, recorded again). A finished log is
    never replaced by another file (a copy, a cut copy)."""
    if info.log_path is None or info.log_sha256 is None:
        return False
    if found["log_path"] is None or found["log_sha256"] is None:
        return True
    if found["log_complete"] is not False or found["log_sha256"] == info.log_sha256:
        return False
    return info.log_complete is not False or found["log_path"] == info.log_path


def _shown(engine: sa.Engine) -> str:
    return engine.url.render_as_string(hide_password=True)


def _reason(exc: BaseException) -> str:
    orig = getattr(exc, "orig", None)
    text = str(orig or exc).strip().splitlines()[0] if str(orig or exc).strip() else type(exc).__name__
    if "database is locked" in text:
        return (f"the database is locked by another process (waited {SQLITE_BUSY_TIMEOUT_S:g} s): nothing was "
                f"written; try again when it is done")
    if "file is not a database" in text or "malformed" in text:
        return f"not a SQLite database, or a corrupt one ({text}): nothing was written"
    return text


def open_records(url: str | None = None, *, create: bool = True) -> Records:
    """Open the records database at `url` (`database_url` form: a URL or a file path; None: the default),
    creating a SQLite file's folder and bringing the schema up to date. `create=False` (a query): a SQLite
    file that is not there is a RecordsError, not a new empty database (a mistyped --db made one)."""
    url = database_url(url)
    try:
        parsed = sa.make_url(url)
    except sa.exc.ArgumentError as exc:
        raise RecordsError(f"--db {url!r}: not a database URL or file path") from exc
    if (not create and parsed.get_backend_name() == "sqlite" and parsed.database not in (None, "", ":memory:")
            and not Path(parsed.database).is_file()):
        raise RecordsError(f"{parsed.database}: no records database there (bench run, solve and check-table "
                           "create it; bench db import fills it)")
    if parsed.get_backend_name() == "sqlite" and parsed.database not in (None, "", ":memory:"):
        try:
            Path(parsed.database).parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RecordsError(f"{parsed.database}: cannot create its folder: {exc.strerror or exc}") from exc
    if parsed.get_backend_name() == "postgresql" and parsed.get_driver_name() in ("", "psycopg2"):
        parsed = parsed.set(drivername="postgresql+psycopg")     # psycopg 3: the driver the `postgres` extra installs
    engine = None
    try:
        engine = sa.create_engine(parsed)
        if engine.dialect.name == "sqlite":
            sa.event.listen(engine, "connect", _sqlite_pragmas)
            sa.event.listen(engine, "begin", _sqlite_begin)
        migrate(engine)
    except (sa.exc.SQLAlchemyError, ImportError, RecordsError) as exc:
        if engine is not None:
            engine.dispose()
        if isinstance(exc, RecordsError):
            raise
        raise RecordsError(f"{parsed.render_as_string(hide_password=True)}: {_reason(exc)}") from exc
    return Records(engine)


#: how long a SQLite writer waits for another process's transaction before it gives up with one line
SQLITE_BUSY_TIMEOUT_S = 30.0


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    # foreign keys are off by default in SQLite; a writer waits for another instead of failing at once. The
    # driver's own transaction handling is off: `_sqlite_begin` starts each transaction itself.
    dbapi_connection.isolation_level = None
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute(f"PRAGMA busy_timeout={int(SQLITE_BUSY_TIMEOUT_S * 1000)}")
    cursor.close()


def _sqlite_begin(conn: sa.Connection) -> None:
    """BEGIN IMMEDIATE: a transaction takes the write lock when it starts (waiting for it up to the busy
    timeout). With SQLite's default deferred BEGIN, two processes that both read and then write fail at once
    with "database is locked" (each holds a read lock the other's write must wait for, so SQLite does not wait:
    a deadlock); taking turns from the start, nothing is lost and nothing fails."""
    conn.exec_driver_sql("BEGIN IMMEDIATE")


SOFTWARE_VERSION = __version__

__all__ = ["DB_ENV", "ORIGINS", "Derivation", "RecordsError", "Records", "ResultRow", "RunInfo", "RunRow",
           "SOFTWARE_VERSION", "database_url",
           "default_url", "open_records", "utc"]
