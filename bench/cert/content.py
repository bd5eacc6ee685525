"""What a calibration certificate states (ISO/IEC 17025 clause 7.8), gathered from the records database and the
run's log alone: `gather(records, run_id)` -> `Certificate`, which `bench.cert.pdf` and `bench.cert.dcc` render.

The records give the run, its record of truth (coefficients, sigma, verdict, the budget's coverage factor), the
equipment it used and the audit trail (review, signature); the log gives the lab, the customer and the item
(its `lab` metadata record), and its bytes are checked against the SHA-256 the records hold. Nothing depends on
the clock of the machine that issues it: the date of issue is the signature's, so the same records and log give
the same certificate.
"""

from __future__ import annotations

import datetime as dt
import json
import math
from dataclasses import dataclass
from pathlib import Path

from bench.cert.errors import CertError
from bench.log.reader import LogError, read_log
from bench.model.earth import Site
from bench.model.families import RESULT_UNITS, TITLES, canonical_names, family_of
from bench.records.ingest import sha256_of
from bench.records.lab import AuditEntry, Equipment, RunRecord, run_record
from bench.records.store import Records

#: the decision rule of the verdict (bench.acceptance.verdict): stated on every certificate with a verdict
DECISION_RULE = ("Simple acceptance (ILAC-G8:09/2019, clause 4.2.1, binary statement without guard band): a check "
                 "passes when its measured value lies within its limit; the expanded uncertainty is reported but not "
                 "deducted from the limits. The verdict is PASS when at least one check ran and every check passed.")
#: a coefficient's expanded uncertainty is U = k sigma with the budget's k; the probability assumes a normal law
COVERAGE_PROBABILITY = 0.95
#: the families in the order a certificate lists them
FAMILY_ORDER = ("Kg", "D0", "Eg", "Ka", "K0", "Ea")
#: a result unit -> its D-SI form (https://ptb.de/si) for the SI value (the result unit's factor to SI applied)
DSI_UNITS = {"Kg": r"\one\radian\tothe{-1}", "D0": r"\radian\second\tothe{-1}", "Eg": r"\one",
             "Ka": r"\second\metre\tothe{-1}", "K0": r"\metre\second\tothe{-2}", "Ea": r"\one"}


@dataclass(frozen=True)
class Row:
    """One certified coefficient: the estimate, its expanded uncertainty U = k sigma, in the result unit."""

    name: str
    title: str
    value: float
    expanded: float | None
    k: float
    unit: str
    si_factor: float         # result unit -> SI
    dsi_unit: str


@dataclass(frozen=True)
class Certificate:
    """Everything a certificate states, in the words and numbers both renderings use."""

    number: str
    statement_of_conformity: bool     # a signed run with a PASS verdict
    why_not: str                      # why it is not one ("" when it is)
    lab_name: str
    lab_address: str
    accreditation_id: str
    country: str                      # ISO 3166-1 alpha-2, "" when not configured
    lab_email: str
    customer: str
    item: str
    record: RunRecord
    rows: tuple[Row, ...]
    k: float
    issued_utc: dt.datetime
    site: Site
    gravity_source: str
    imu_temperature_c: float | None
    chamber: str
    log_sha256: str
    log_name: str
    signature: AuditEntry | None
    review: AuditEntry | None
    equipment: tuple[dict[str, str], ...]     # as the log recorded each item at the run's start

    @property
    def title(self) -> str:
        return ("Calibration Certificate" if self.statement_of_conformity else
                "Calibration Certificate - not a statement of conformity")

    @property
    def verdict(self) -> str:
        return (self.record.verdict or "not judged").upper()

    @property
    def calibrated_utc(self) -> tuple[dt.datetime | None, dt.datetime | None]:
        return self.record.started_utc, self.record.finished_utc

    def checks(self) -> list[dict]:
        return [c for c in (self.record.verdict_json or {}).get("checks", []) if isinstance(c, dict)]

    def in_date(self, item: dict[str, str]) -> str:
        """An item's calibration status on the day of the calibration."""
        day = (self.record.started_utc or self.record.finished_utc or self.issued_utc).date()
        try:
            due = dt.date.fromisoformat(item.get("due_date", ""))
        except ValueError:
            return "due date unknown"
        return "in date" if due >= day else "OVERDUE at calibration"


def _number(pattern: str, run_id: str, serial: str, year: int) -> str:
    pattern = pattern or "{run_id}"
    return pattern.format(year=year, run_id=run_id, serial=serial)


def _rows(record: RunRecord, k: float) -> tuple[Row, ...]:
    order = {family: i for i, family in enumerate(FAMILY_ORDER)}
    canonical = set(canonical_names())
    rows = []
    for c in sorted(record.coefficients, key=lambda c: (order.get(family_of(c.name), 99), c.name)):
        family = family_of(c.name)
        expanded = k * c.sigma if c.sigma is not None and math.isfinite(c.sigma) else None
        if c.name in canonical:
            rows.append(Row(c.name, TITLES[family], c.value, expanded, k, c.unit, RESULT_UNITS[family][1],
                            DSI_UNITS[family]))
        else:       # not one of the model's coefficients: as recorded, in its own unit (no SI form known)
            rows.append(Row(c.name, "other", c.value, expanded, k, c.unit, 1.0, c.unit))
    return tuple(rows)


def _equipment_of_log(lab: dict[str, str], registered: tuple[Equipment, ...]) -> tuple[dict[str, str], ...]:
    try:
        items = json.loads(lab.get("equipment_json") or "[]")
    except ValueError:
        items = []
    items = [i for i in items if isinstance(i, dict)] if isinstance(items, list) else []
    if not items:       # a log from before the register: what the records linked
        items = [e.as_metadata() for e in registered]
    return tuple({key: str(value) for key, value in item.items()} for item in items)


def chamber_conditions(temperatures_c: list[float]) -> str:
    """The chamber's air temperature over the run, as its recorded states give it (none: no chamber was used)."""
    finite = [t for t in temperatures_c if math.isfinite(t)]
    if not finite:
        return "no thermal chamber in this run (ambient)"
    return (f"thermal chamber air {min(finite):.2f} to {max(finite):.2f} degC "
            f"(mean {sum(finite) / len(finite):.2f} degC, {len(finite)} recorded states)")


def gather(record: RunRecord, lab: dict[str, str], log_sha256: str, log_name: str,
           chamber: str = "no thermal chamber in this run (ambient)") -> Certificate:
    """The certificate of `record` (the run's record of truth), with the lab identity of its log's `lab`
    metadata, for the log whose bytes hash to `log_sha256`; CertError if that is not the log the records hold."""
    if record.log_sha256 and record.log_sha256 != log_sha256:
        raise CertError(f"the log {log_name} (SHA-256 {log_sha256[:12]}...) is not the one the records hold for "
                        f"run {record.run_id} ({record.log_sha256[:12]}...)")
    if record.kind != "calibration":
        raise CertError(f"run {record.run_id} is a {record.kind} run: only a calibration gets a certificate")
    signatures, reviews = record.entries("sign"), record.entries("review")
    signature = signatures[-1] if signatures else None
    review = reviews[-1] if reviews else None
    issued = signature.at_utc if signature else (record.finished_utc or record.started_utc)
    if issued is None:
        raise CertError(f"run {record.run_id}: the records hold neither a signature nor the run's times")
    passed = record.verdict == "pass"
    why_not = "; ".join(w for w in ("" if signature else "not signed",
                                    "" if passed else f"verdict {record.verdict or 'not judged'}") if w)
    uncertainty = (record.quality or {}).get("uncertainty") or {}
    k = float(uncertainty.get("k", 2.0))
    site = Site(float(record.site.get("latitude_deg", 0.0)), float(record.site.get("height_m") or 0.0),
                record.site.get("local_g"))
    gravity_source = ("measured local gravity (configured [site] local_g)" if site.local_g is not None else
                      "WGS84 normal gravity at the site's latitude and height")
    return Certificate(
        number=_number(lab.get("certificate_number_pattern", ""), record.run_id, record.serial, issued.year),
        statement_of_conformity=not why_not, why_not=why_not,
        lab_name=lab.get("name") or "(laboratory not named: [lab] name)", lab_address=lab.get("address", ""),
        accreditation_id=lab.get("accreditation_id", ""), country=lab.get("country", ""),
        lab_email=lab.get("email", ""), customer=lab.get("customer") or "(not named)",
        item=lab.get("item") or f"{record.model} s/n {record.serial}", record=record, rows=_rows(record, k), k=k,
        issued_utc=issued, site=site, gravity_source=gravity_source, imu_temperature_c=record.temperature_c,
        chamber=chamber,
        log_sha256=log_sha256, log_name=log_name, signature=signature, review=review,
        equipment=_equipment_of_log(lab, record.equipment))


def load(records: Records, run_id: str, log: str | Path | None = None) -> Certificate:
    """`gather` for a recorded run: its record from `records`, its log from `log` (default: where the records say
    it is). CertError for a log that cannot be read or is not the run's; RecordsError for a run not certifiable."""
    record = run_record(records, run_id)
    path = Path(log) if log is not None else (Path(record.log_path) if record.log_path else None)
    if path is None:
        raise CertError(f"run {run_id}: the records name no log; give it with --log")
    try:
        run_log = read_log(str(path))
        digest = sha256_of(path)
    except (LogError, OSError) as exc:
        raise CertError(f"{path}: cannot read the run's log: {exc}") from exc
    lab = run_log.metadata.get("lab") or {}
    chamber = chamber_conditions([s.temperature_c for s in run_log.chamber_states])
    return gather(record, dict(lab), digest, path.name, chamber)


__all__ = ["COVERAGE_PROBABILITY", "DECISION_RULE", "Certificate", "Row", "chamber_conditions", "gather", "load"]
