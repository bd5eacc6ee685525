"""Versioned schema: the `schema_version` table and the migrations that bring a database up to date.

A migration is a Python function over one connection, written with SQLAlchemy Core (no
hand-written SQL), run inside one transaction with the row that records it: on
PostgreSQL (transactional DDL) a failed migration leaves the database as it was. An
empty database is brought to the latest version by running every migration from 1,
the same path an old database takes, so that path is always tested.

Why not Alembic: its migrations live in a script folder with an env.py that a wheel
would have to ship and the command would have to point at; ours are a handful of
functions over a few tables, and the one operation Core lacks (ALTER TABLE ADD COLUMN)
is one line compiled from a `Column` by the connection's dialect.
"""

from __future__ import annotations

import datetime as dt
from typing import Callable

import sqlalchemy as sa
from sqlalchemy.schema import CreateColumn

from bench import __version__
from bench.records import schema
from bench.records.errors import SchemaError


def _v1(conn: sa.Connection) -> None:
    """Units, runs, results, coefficients (value, sigma, unit)."""
    metadata = sa.MetaData()
    schema.define(metadata, 1)
    metadata.create_all(conn)


def _v2(conn: sa.Connection) -> None:
    """`coefficients.budget` (JSON): the uncertainty budget's components as the result file carries them."""
    add_column(conn, "coefficients", sa.Column("budget", sa.JSON, nullable=True))


def _v3(conn: sa.Connection) -> None:
    """A run's record of truth apart from derived results: `results.origin`, `.derivation`, `.log_sha256`,
    `.promoted_utc`; `runs.log_complete` (see `bench.records.schema`). Rows recorded before keep NULL origin."""
    for table in ("runs", "results"):
        for column in schema.version_columns(3, table):
            add_column(conn, table, column)


def _v4(conn: sa.Connection) -> None:
    """The equipment register, each run's equipment and the append-only audit trail (`schema.lab_tables`)."""
    metadata = sa.MetaData()
    tables = schema.define(metadata, 4)
    metadata.create_all(conn, tables=[tables[name] for name in schema.LAB_TABLES])


def _v5(conn: sa.Connection) -> None:
    """A run of several IMUs, one record per unit: `runs.bench_run` and its index (see `bench.records.schema`).
    Runs recorded before keep NULL (each a run of one IMU as recorded)."""
    for column in schema.bench_run_column(5):
        add_column(conn, "runs", column)
    index = schema.bench_run_index()
    sa.Table("runs", sa.MetaData(), sa.Column("bench_run", sa.String(200)), index)     # an index needs its table
    index.create(conn)


#: PostgreSQL's advisory lock key migrations hold (SQLite's writers take turns: `BEGIN IMMEDIATE`)
_MIGRATION_LOCK = 0x7462_7265_636F  # "tbreco"


#: version -> the migration that brings the version before it to it
MIGRATIONS: dict[int, Callable[[sa.Connection], None]] = {1: _v1, 2: _v2, 3: _v3, 4: _v4, 5: _v5}


def add_column(conn: sa.Connection, table: str, column: sa.Column) -> None:
    """ALTER TABLE `table` ADD COLUMN `column`, the column's DDL compiled by the connection's dialect."""
    sa.Table(table, sa.MetaData(), column)      # a column compiles only inside a table
    quote = conn.dialect.identifier_preparer.quote
    column_ddl = CreateColumn(column).compile(dialect=conn.dialect)
    conn.execute(sa.DDL(f"ALTER TABLE {quote(table)} ADD COLUMN {column_ddl}"))


def current_version(conn: sa.Connection) -> int:
    """The database's schema version: 0 for an empty database."""
    inspector = sa.inspect(conn)
    if not inspector.has_table("schema_version"):
        foreign = [t for t in inspector.get_table_names() if t in schema.TABLES]
        if foreign:
            raise SchemaError(f"the database has tables {', '.join(sorted(foreign))} but no schema_version: "
                              f"not a turntable-bench records database")
        return 0
    table = schema.schema_version
    return int(conn.execute(sa.select(sa.func.coalesce(sa.func.max(table.c.version), 0))).scalar_one())


def migrate(engine: sa.Engine, target: int = schema.SCHEMA_VERSION) -> tuple[int, int]:
    """Bring the database to `target`; returns (version before, version after)."""
    with engine.begin() as conn:
        if conn.dialect.name == "postgresql":   # two processes opening a new database: one migrates, one waits
            conn.execute(sa.select(sa.func.pg_advisory_xact_lock(_MIGRATION_LOCK)))
        before = current_version(conn)
        if before > schema.SCHEMA_VERSION:
            raise SchemaError(f"the database has schema version {before}, newer than this software's "
                              f"{schema.SCHEMA_VERSION}: update turntable-bench")
        for version in range(before + 1, target + 1):
            MIGRATIONS[version](conn)
            conn.execute(sa.insert(schema.schema_version).values(
                version=version, applied_utc=dt.datetime.now(dt.UTC).replace(tzinfo=None),
                software_version=__version__))
    return before, max(before, target)


__all__ = ["MIGRATIONS", "SchemaError", "add_column", "current_version", "migrate"]
