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

Version 4 adds the lab's side (issue 32): `equipment`, the register of the lab's equipment (turntable, thermal
chamber, reference instruments: kind, make, model, serial, the reference of its own calibration certificate and
its due date; retired, never deleted); `run_equipment`, which equipment a run used (from its log's `lab`
metadata); `audit`, the append-only trail of who did what when (equipment added and retired, a run's result
reviewed and signed): no row of it is ever updated or deleted, the code has no such statement and the
database refuses one (a trigger on SQLite and PostgreSQL, `AUDIT_TRIGGERS`).

Version 5 keeps a run of several IMUs (issue 31) as one record per unit: each unit's record has the run id
`<run-id>.<serial>` (the stem of its files) and `runs.bench_run`, the run of the bench it is one unit of (NULL: a
run of one IMU, or recorded before version 5), so a unit is found by its serial as any IMU is and the run's units
by their run.
"""

from __future__ import annotations

import sqlalchemy as sa

#: the schema version this software writes and reads
SCHEMA_VERSION = 5


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
        *bench_run_column(version),
        sa.Index("ix_runs_unit_started", "unit_id", "started_utc"),
        sa.Index("ix_runs_started", "started_utc"),
        *([bench_run_index()] if version >= 5 else []))
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
    if version >= 4:
        tables.update(lab_tables(metadata))
    return tables


#: what version 4 adds (`lab_tables`)
LAB_TABLES = ("equipment", "run_equipment", "audit")


def lab_tables(metadata: sa.MetaData) -> dict[str, sa.Table]:
    """The equipment register, the equipment of each run and the audit trail (version 4), added to `metadata`;
    the audit table carries its append-only triggers (created with it)."""
    tables = {}
    tables["equipment"] = sa.Table(
        "equipment", metadata,
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("tag", sa.String(64), nullable=False, unique=True),       # the lab's name for it: "TT-01"
        sa.Column("kind", sa.String(32), nullable=False),                   # turntable | chamber | gravity | ...
        sa.Column("make", sa.String(200), nullable=False),
        sa.Column("model", sa.String(200), nullable=False),
        sa.Column("serial", sa.String(200), nullable=False),
        sa.Column("certificate", sa.String(400), nullable=False),           # its own calibration certificate
        sa.Column("due_date", sa.Date, nullable=False),                     # its next calibration is due
        sa.Column("added_utc", sa.DateTime, nullable=False),
        sa.Column("retired_utc", sa.DateTime, nullable=True))
    tables["run_equipment"] = sa.Table(
        "run_equipment", metadata,
        sa.Column("run_pk", sa.Integer, sa.ForeignKey("runs.id"), primary_key=True),
        sa.Column("equipment_id", sa.Integer, sa.ForeignKey("equipment.id"), primary_key=True))
    audit = tables["audit"] = sa.Table(
        "audit", metadata,
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("at_utc", sa.DateTime, nullable=False),
        sa.Column("action", sa.String(32), nullable=False),      # equipment-add | equipment-retire | review | sign
        sa.Column("actor", sa.String(200), nullable=False),      # who
        sa.Column("role", sa.String(200), nullable=True),        # a signer's role
        sa.Column("run_pk", sa.Integer, sa.ForeignKey("runs.id"), nullable=True),
        sa.Column("result_id", sa.Integer, sa.ForeignKey("results.id"), nullable=True),   # the result reviewed
        sa.Column("equipment_id", sa.Integer, sa.ForeignKey("equipment.id"), nullable=True),
        sa.Column("detail", sa.Text, nullable=True),
        sa.Index("ix_audit_run", "run_pk", "id"))
    for ddl in AUDIT_TRIGGERS:
        sa.event.listen(audit, "after_create", ddl)
    return tables


_REFUSED = "the audit trail is append-only"
#: the database refuses an UPDATE or DELETE of the audit trail (the only SQL not from Core: Core has no triggers)
AUDIT_TRIGGERS = (
    *(sa.DDL(f"CREATE TRIGGER audit_no_{what.lower()} BEFORE {what} ON audit "
             f"BEGIN SELECT RAISE(ABORT, '{_REFUSED}'); END").execute_if(dialect="sqlite")
      for what in ("UPDATE", "DELETE")),
    sa.DDL("CREATE FUNCTION audit_append_only() RETURNS trigger LANGUAGE plpgsql AS "
           f"$$ BEGIN RAISE EXCEPTION '{_REFUSED}'; END $$").execute_if(dialect="postgresql"),
    sa.DDL("CREATE TRIGGER audit_append_only BEFORE UPDATE OR DELETE OR TRUNCATE ON audit "
           "FOR EACH STATEMENT EXECUTE FUNCTION audit_append_only()").execute_if(dialect="postgresql"),
)


def bench_run_column(version: int) -> list[sa.Column]:
    """`runs.bench_run` (version 5): the run of the bench a unit's record is one unit of; None: a run of one IMU."""
    return [sa.Column("bench_run", sa.String(200), nullable=True)] if version >= 5 else []


def bench_run_index() -> sa.Index:
    """The index on `runs.bench_run` (version 5): a run's units found by their run."""
    return sa.Index("ix_runs_bench_run", "bench_run")


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
equipment, run_equipment, audit = TABLES["equipment"], TABLES["run_equipment"], TABLES["audit"]

__all__ = ["AUDIT_TRIGGERS", "LAB_TABLES", "METADATA", "SCHEMA_VERSION", "TABLES", "audit", "coefficients", "define",
           "equipment", "lab_tables", "results", "run_equipment", "runs", "schema_version", "units"]
