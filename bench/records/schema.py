"""The records database's tables (SQLAlchemy Core), by schema version.

One definition, `define(metadata, version)`, builds the tables as they are at a schema
version: the migrations (`bench.records.migrate`) create version 1 from it and add what
later versions add, and the queries use `TABLES` (the latest). A test migrates an empty
database from version 0 and compares it with the latest definition, on SQLite and on
PostgreSQL, so the two cannot drift apart.

- `units`: one IMU, by (model, serial);
- `runs`: one calibration run (its run id, unique), of one unit: the log it was recorded
  to (path and SHA-256 of its content), operator, site, table, plan, software version,
  start and end, outcome (the run's final state);
- `results`: one result file (unique by the SHA-256 of its content), of one run: a run
  re-solved by a newer software version has several; the verdict and the quality;
- `coefficients`: one solved coefficient of one result: value, 1-sigma, unit, and from
  version 2 `budget` (JSON): what else the result file says of it (the uncertainty
  budget's components as the result file carries them), so a budget lands without a
  schema change.

Version 3 separates a run's record of truth from what was derived from it: `results.origin`
("run": the result `bench run` wrote; "re-solve": `bench solve` of the whole, intact log;
"subset", "damaged": what-if solves and solves of damaged logs; NULL: recorded before version
3), `results.derivation` (one line: how it was derived), `results.log_sha256` (the log it was
solved from), `results.promoted_utc` (a user made it the run's record of truth, `bench db
promote`), and `runs.log_complete` (False: the log had no MCAP footer when recorded, a run
still recording or cut off; its hash is replaced when the finished file is recorded).
"""

from __future__ import annotations

import sqlalchemy as sa

#: the schema version this software writes and reads
SCHEMA_VERSION = 3


def define(metadata: sa.MetaData, version: int = SCHEMA_VERSION) -> dict[str, sa.Table]:
    """The tables as they are at `version` (1..SCHEMA_VERSION), added to `metadata`."""
    if not 1 <= version <= SCHEMA_VERSION:
        raise ValueError(f"no schema version {version}")
    tables = {}
    tables["schema_version"] = sa.Table(
        "schema_version", metadata,
        sa.Column("version", sa.Integer, primary_key=True, autoincrement=False),
        sa.Column("applied_utc", sa.DateTime, nullable=False),
        sa.Column("software_version", sa.String(64), nullable=False))
    tables["units"] = sa.Table(
        "units", metadata,
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("model", sa.String(200), nullable=False),
        sa.Column("serial", sa.String(200), nullable=False),
        sa.UniqueConstraint("model", "serial", name="uq_units_model_serial"),
        sa.Index("ix_units_serial", "serial"))
    tables["runs"] = sa.Table(
        "runs", metadata,
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("run_id", sa.String(200), nullable=False, unique=True),
        sa.Column("unit_id", sa.Integer, sa.ForeignKey("units.id"), nullable=False),
        sa.Column("kind", sa.String(32), nullable=False),           # calibration | table-check
        sa.Column("mode", sa.String(32), nullable=False),           # simulator | hardware | ""
        sa.Column("log_path", sa.Text, nullable=True),
        sa.Column("log_sha256", sa.String(64), nullable=True),
        sa.Column("operator", sa.String(200), nullable=False),
        sa.Column("site", sa.JSON, nullable=True),                  # latitude_deg, height_m, local_g
        sa.Column("table_url", sa.Text, nullable=False),
        sa.Column("plan", sa.String(400), nullable=False),          # positions + rotations schedule names
        sa.Column("software_version", sa.String(64), nullable=False),
        sa.Column("started_utc", sa.DateTime, nullable=True),
        sa.Column("finished_utc", sa.DateTime, nullable=True),
        sa.Column("outcome", sa.String(32), nullable=False),        # the run's final state: done, aborted, ...
        *version_columns(version, "runs"),
        sa.Index("ix_runs_unit_started", "unit_id", "started_utc"),
        sa.Index("ix_runs_started", "started_utc"))
    tables["results"] = sa.Table(
        "results", metadata,
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("run_pk", sa.Integer, sa.ForeignKey("runs.id"), nullable=False),
        sa.Column("path", sa.Text, nullable=True),
        sa.Column("sha256", sa.String(64), nullable=False, unique=True),
        sa.Column("software_version", sa.String(64), nullable=False),
        sa.Column("solved_utc", sa.DateTime, nullable=True),
        sa.Column("imported_utc", sa.DateTime, nullable=False),
        sa.Column("verdict", sa.String(16), nullable=True),         # pass | fail | None (not judged)
        sa.Column("verdict_json", sa.JSON, nullable=True),
        sa.Column("quality", sa.JSON, nullable=True),
        sa.Column("temperature_c", sa.Float, nullable=True),        # the IMU's mean temperature over the run
        *version_columns(version, "results"),
        sa.Index("ix_results_run", "run_pk", "id"),
        sa.Index("ix_results_software", "run_pk", "software_version"))
    columns: list[sa.schema.SchemaItem] = [
        sa.Column("result_id", sa.Integer, sa.ForeignKey("results.id", ondelete="CASCADE"), primary_key=True),
        sa.Column("name", sa.String(32), primary_key=True),
        sa.Column("value", sa.Float, nullable=False),
        sa.Column("sigma", sa.Float, nullable=True),                # None: unknown (NaN in the result file)
        sa.Column("unit", sa.String(64), nullable=False),
    ]
    if version >= 2:
        columns.append(sa.Column("budget", sa.JSON, nullable=True))
    tables["coefficients"] = sa.Table("coefficients", metadata, *columns,
                                      sa.Index("ix_coefficients_name", "name", "result_id"))
    return tables


def version_columns(version: int, table: str, since: int = 3) -> list[sa.Column]:
    """The columns version 3 added to `table` (the migration adds the same, `since` is the version they came
    with): nothing before it."""
    if version < since:
        return []
    if table == "runs":
        return [sa.Column("log_complete", sa.Boolean, nullable=True)]     # None: not known (before version 3)
    return [sa.Column("origin", sa.String(16), nullable=True),       # run | re-solve | subset | damaged | None
            sa.Column("derivation", sa.String(400), nullable=True),  # how it was derived, one line
            sa.Column("log_sha256", sa.String(64), nullable=True),   # the log it was solved from
            sa.Column("promoted_utc", sa.DateTime, nullable=True)]   # made the run's record of truth by a user


METADATA = sa.MetaData()
TABLES = define(METADATA)
units, runs, results, coefficients = TABLES["units"], TABLES["runs"], TABLES["results"], TABLES["coefficients"]
schema_version = TABLES["schema_version"]

__all__ = ["METADATA", "SCHEMA_VERSION", "TABLES", "coefficients", "define", "results", "runs", "schema_version",
           "units"]
