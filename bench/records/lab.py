"""The lab's side of the records (schema version 4): the equipment register, a run's review and sign-off, and the
append-only audit trail of both.

Equipment is added (`add_equipment`) and retired (`retire_equipment`), never changed or deleted: a run recorded
with it keeps pointing at what it was. `check_equipment` is what `bench run` asks before anything moves: each
tag the configuration names is registered, not retired, and not past its due date. `review` and `sign` append
to the audit trail (`schema.audit`), the one record of who did what when: a run is reviewed on its record of
truth (`Records.results_of`), signed only after that result was reviewed, and neither is possible for a run that
is not recorded or has no result. The trail is never updated or deleted: this module has no such statement, and
the database refuses one (`schema.AUDIT_TRIGGERS`).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass

import sqlalchemy as sa

from bench.records import schema
from bench.records.errors import RecordsError
from bench.records.rows import now
from bench.records.store import Records

#: the kinds of equipment the register holds (a reference instrument is named by what it measures)
EQUIPMENT_KINDS = ("turntable", "chamber", "gravity", "temperature", "other")


@dataclass(frozen=True)
class Equipment:
    """One registered item of equipment (`schema.equipment`)."""

    tag: str
    kind: str
    make: str
    model: str
    serial: str
    certificate: str
    due_date: dt.date
    added_utc: dt.datetime | None = None
    retired_utc: dt.datetime | None = None

    def overdue(self, today: dt.date) -> bool:
        """Its calibration was due before `today` (on the due date itself it is still in date)."""
        return self.due_date < today

    def as_metadata(self) -> dict[str, str]:
        """What a run log records of it (`lab.equipment_json`): enough to name it without the database."""
        return {"tag": self.tag, "kind": self.kind, "make": self.make, "model": self.model, "serial": self.serial,
                "certificate": self.certificate, "due_date": self.due_date.isoformat()}


@dataclass(frozen=True)
class AuditEntry:
    """One line of the audit trail: who did what when (and to which run, result or equipment)."""

    entry_id: int
    at_utc: dt.datetime
    action: str
    actor: str
    role: str | None
    run_id: str | None
    result_id: int | None
    equipment_tag: str | None
    detail: str | None


def _equipment(row: sa.Row) -> Equipment:
    return Equipment(row.tag, row.kind, row.make, row.model, row.serial, row.certificate, row.due_date,
                     row.added_utc, row.retired_utc)


def _append(conn: sa.Connection, action: str, actor: str, *, role: str | None = None, run_pk: int | None = None,
            result_id: int | None = None, equipment_id: int | None = None, detail: str | None = None) -> None:
    """One line appended to the audit trail (the trail's only write)."""
    conn.execute(sa.insert(schema.audit).values(at_utc=now(), action=action, actor=actor[:200], role=role,
                                                run_pk=run_pk, result_id=result_id, equipment_id=equipment_id,
                                                detail=detail))


def add_equipment(records: Records, item: Equipment, actor: str) -> Equipment:
    """Register `item`; RecordsError if its tag is taken (retired equipment keeps its tag)."""
    if item.kind not in EQUIPMENT_KINDS:
        raise RecordsError(f"equipment kind {item.kind!r}: must be one of {', '.join(EQUIPMENT_KINDS)}")
    e = schema.equipment
    with records.transaction() as conn:
        if conn.execute(sa.select(e.c.id).where(e.c.tag == item.tag)).first() is not None:
            raise RecordsError(f"equipment {item.tag!r} is already registered (`bench db equipment list --all`)")
        values = {k: v for k, v in item.as_metadata().items() if k != "due_date"}
        key = conn.execute(sa.insert(e).values(**values, due_date=item.due_date, added_utc=now())).inserted_primary_key
        assert key is not None
        _append(conn, "equipment-add", actor, equipment_id=int(key[0]),
                detail=f"{item.kind} {item.make} {item.model} s/n {item.serial}, certificate {item.certificate}, "
                       f"due {item.due_date.isoformat()}")
    return find_equipment(records, [item.tag])[0]


def retire_equipment(records: Records, tag: str, actor: str, reason: str = "") -> Equipment:
    """Mark equipment retired (it stays in the register, and in the runs that used it); RecordsError if it is
    not registered or already retired."""
    e = schema.equipment
    with records.transaction() as conn:
        row = conn.execute(sa.select(e.c.id, e.c.retired_utc).where(e.c.tag == tag)).first()
        if row is None:
            raise RecordsError(f"no equipment {tag!r} in the register (`bench db equipment list`)")
        if row.retired_utc is not None:
            raise RecordsError(f"equipment {tag!r} was retired {row.retired_utc.isoformat(timespec='seconds')} UTC")
        conn.execute(sa.update(e).where(e.c.id == row.id).values(retired_utc=now()))
        _append(conn, "equipment-retire", actor, equipment_id=row.id, detail=reason or None)
    return find_equipment(records, [tag])[0]


def list_equipment(records: Records, include_retired: bool = False) -> list[Equipment]:
    """The register, by tag; retired equipment only when asked."""
    e = schema.equipment
    query = sa.select(e).order_by(e.c.tag)
    if not include_retired:
        query = query.where(e.c.retired_utc.is_(None))
    with records.connection() as conn:
        return [_equipment(row) for row in conn.execute(query)]


def find_equipment(records: Records, tags: list[str] | tuple[str, ...]) -> list[Equipment]:
    """The registered equipment of `tags`, in their order; RecordsError naming a tag the register lacks."""
    e = schema.equipment
    with records.connection() as conn:
        found = {row.tag: _equipment(row) for row in conn.execute(sa.select(e).where(e.c.tag.in_(list(tags))))}
    missing = [tag for tag in tags if tag not in found]
    if missing:
        raise RecordsError(f"equipment {', '.join(repr(t) for t in missing)} is not in the register "
                           "(`bench db equipment add`)")
    return [found[tag] for tag in tags]


def check_equipment(records: Records, tags: tuple[str, ...], today: dt.date) -> tuple[list[Equipment], list[str]]:
    """The equipment a run is to use, and what is wrong with it (one line each: retired, or past its due date);
    RecordsError if a tag is not registered."""
    items = find_equipment(records, tags)
    problems = []
    for item in items:
        if item.retired_utc is not None:
            problems.append(f"equipment {item.tag} ({item.kind}) was retired "
                            f"{item.retired_utc.date().isoformat()}")
        elif item.overdue(today):
            problems.append(f"equipment {item.tag} ({item.kind} {item.make} {item.model} s/n {item.serial}) is past "
                            f"its calibration due date {item.due_date.isoformat()} (certificate {item.certificate})")
    return items, problems


def run_equipment(records: Records, run_id: str) -> list[Equipment]:
    """The registered equipment the run used (as recorded from its log), by tag."""
    e, re_, r = schema.equipment, schema.run_equipment, schema.runs
    query = (sa.select(e).join(re_, re_.c.equipment_id == e.c.id).join(r, r.c.id == re_.c.run_pk)
             .where(r.c.run_id == run_id).order_by(e.c.tag))
    with records.connection() as conn:
        return [_equipment(row) for row in conn.execute(query)]


# -- review and sign-off ---------------------------------------------------------------------------

def _run_and_truth(records: Records, run_id: str) -> tuple[int, int]:
    """(run primary key, its record of truth's result id); RecordsError (one line) for a run that is not recorded
    or has no result to review."""
    rows = records.results_of(run_id)       # RecordsError: no such run
    truth = [row for row in rows if row.truth]
    if not truth:
        raise RecordsError(f"run {run_id!r} has no result to review"
                           + (" (only derived ones: `bench db promote RESULT_ID` makes one its record of truth)"
                              if rows else " (record its result file: `bench db import`)"))
    r = schema.runs
    with records.connection() as conn:
        run_pk = conn.execute(sa.select(r.c.id).where(r.c.run_id == run_id)).scalar_one()
    return int(run_pk), truth[0].result_id


def review(records: Records, run_id: str, reviewer: str, note: str = "") -> AuditEntry:
    """Record that `reviewer` reviewed the run's record of truth."""
    run_pk, result_id = _run_and_truth(records, run_id)
    with records.transaction() as conn:
        _append(conn, "review", reviewer, run_pk=run_pk, result_id=result_id, detail=note or None)
    return audit_trail(records, run_id)[-1]


def sign(records: Records, run_id: str, signer: str, role: str, note: str = "") -> AuditEntry:
    """Record that `signer` (as `role`) signed the run's record of truth; RecordsError unless that result was
    reviewed (a review of an earlier record of truth does not count)."""
    run_pk, result_id = _run_and_truth(records, run_id)
    a = schema.audit
    with records.transaction() as conn:
        reviewed = conn.execute(sa.select(a.c.id).where(a.c.run_pk == run_pk, a.c.action == "review",
                                                        a.c.result_id == result_id).limit(1)).first()
        if reviewed is None:
            raise RecordsError(f"run {run_id!r}: its result {result_id} is not reviewed: "
                               f"`bench cert review {run_id} --reviewer NAME` first")
        _append(conn, "sign", signer, role=role, run_pk=run_pk, result_id=result_id, detail=note or None)
    return audit_trail(records, run_id)[-1]


def audit_trail(records: Records, run_id: str | None = None) -> list[AuditEntry]:
    """The audit trail, oldest first: of one run, or (None) all of it."""
    a, r, e = schema.audit, schema.runs, schema.equipment
    query = (sa.select(a.c.id, a.c.at_utc, a.c.action, a.c.actor, a.c.role, r.c.run_id, a.c.result_id, e.c.tag,
                       a.c.detail)
             .outerjoin(r, r.c.id == a.c.run_pk).outerjoin(e, e.c.id == a.c.equipment_id).order_by(a.c.id))
    if run_id is not None:
        query = query.where(r.c.run_id == run_id)
    with records.connection() as conn:
        return [AuditEntry(*row) for row in conn.execute(query)]


# -- what a certificate states -----------------------------------------------------------------------

@dataclass(frozen=True)
class CertifiedCoefficient:
    """One coefficient of a run's record of truth: the estimate and its 1-sigma standard uncertainty."""

    name: str
    value: float
    sigma: float | None
    unit: str


@dataclass(frozen=True)
class RunRecord:
    """What the records hold of a run for its certificate: the run, its record of truth with its coefficients,
    the registered equipment it used and the audit trail of that result (`run_record`)."""

    run_id: str
    kind: str
    model: str
    serial: str
    mode: str
    operator: str
    plan: str
    table_url: str
    software_version: str
    started_utc: dt.datetime | None
    finished_utc: dt.datetime | None
    log_path: str | None
    log_sha256: str | None
    site: dict
    result_id: int
    result_software_version: str
    verdict: str | None
    verdict_json: dict | None
    quality: dict | None
    temperature_c: float | None
    coefficients: tuple[CertifiedCoefficient, ...]
    equipment: tuple[Equipment, ...]
    trail: tuple[AuditEntry, ...]

    def entries(self, action: str) -> list[AuditEntry]:
        """The trail's entries of `action` ("review", "sign") about this record of truth, oldest first."""
        return [e for e in self.trail if e.action == action and e.result_id == self.result_id]


def run_record(records: Records, run_id: str) -> RunRecord:
    """The run's record for a certificate; RecordsError (one line) for a run not recorded or without a result."""
    run_pk, result_id = _run_and_truth(records, run_id)
    r, u, s, c = schema.runs, schema.units, schema.results, schema.coefficients
    with records.connection() as conn:
        run = conn.execute(sa.select(r, u.c.model, u.c.serial).join(u, u.c.id == r.c.unit_id)
                           .where(r.c.id == run_pk)).one()
        result = conn.execute(sa.select(s).where(s.c.id == result_id)).one()
        coefficients = tuple(CertifiedCoefficient(row.name, row.value, row.sigma, row.unit) for row in
                             conn.execute(sa.select(c).where(c.c.result_id == result_id).order_by(c.c.name)))
    return RunRecord(run.run_id, run.kind, run.model, run.serial, run.mode, run.operator, run.plan, run.table_url,
                     run.software_version, run.started_utc, run.finished_utc, run.log_path, run.log_sha256,
                     dict(run.site or {}), result_id, result.software_version, result.verdict,
                     result.verdict_json, result.quality, result.temperature_c, coefficients,
                     tuple(run_equipment(records, run_id)), tuple(audit_trail(records, run_id)))


__all__ = ["EQUIPMENT_KINDS", "AuditEntry", "CertifiedCoefficient", "Equipment", "RunRecord", "add_equipment",
           "audit_trail", "check_equipment", "find_equipment", "list_equipment", "retire_equipment", "review",
           "run_equipment", "run_record", "sign"]
