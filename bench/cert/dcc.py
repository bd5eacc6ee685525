"""A certificate as a PTB Digital Calibration Certificate (DCC 3.1.2, https://ptb.de/dcc, with D-SI 2.1.0 quantities):
`to_xml(certificate)` -> bytes, the same for the same certificate; `validate(xml)` checks it against the schema
shipped in `schemas/` (no network: the D-SI schema the DCC schema imports by URL is taken from there too).

Each coefficient is a `si:real` in SI units (its value in the result unit times the unit's factor to SI, the
unit in D-SI notation), with its expanded uncertainty, coverage factor and coverage probability. The run id,
the result id and the log's SHA-256 are identifications and metadata, so `bench cert check` can find the run.
"""

from __future__ import annotations

import datetime as dt
import xml.etree.ElementTree as ET
from pathlib import Path

from bench import __version__
from bench.cert.content import COVERAGE_PROBABILITY, DECISION_RULE, Certificate
from bench.cert.errors import CertError

DCC = "https://ptb.de/dcc"
SI = "https://ptb.de/si"
SCHEMA_VERSION = "3.1.2"
SCHEMAS = Path(__file__).parent / "schemas"
DCC_XSD = SCHEMAS / "dcc-3.1.2.xsd"
SI_XSD = SCHEMAS / "SI_Format-2.1.0.xsd"
#: the identification names `bench cert check` reads back
RUN_ID, RESULT_ID = "run id", "result id"
#: no `[lab] country`: ISO 3166-1's user-assigned code for "unknown"
UNKNOWN_COUNTRY = "ZZ"

ET.register_namespace("dcc", DCC)
ET.register_namespace("si", SI)


def _d(parent: ET.Element, tag: str, text: str | None = None) -> ET.Element:
    element = ET.SubElement(parent, f"{{{DCC}}}{tag}")
    if text is not None:
        element.text = text
    return element


def _text(parent: ET.Element, tag: str, text: str) -> ET.Element:
    """A `dcc:textType` element: one English `dcc:content`."""
    element = _d(parent, tag)
    _d(element, "content", text).set("lang", "en")
    return element


def _number(value: float) -> str:
    return repr(float(value))


def _real(parent: ET.Element, label: str, value: float, unit: str, expanded: float | None = None,
          k: float | None = None) -> None:
    real = ET.SubElement(parent, f"{{{SI}}}real")
    ET.SubElement(real, f"{{{SI}}}label").text = label
    ET.SubElement(real, f"{{{SI}}}value").text = _number(value)
    ET.SubElement(real, f"{{{SI}}}unit").text = unit
    if expanded is not None and k is not None:
        unc = ET.SubElement(real, f"{{{SI}}}expandedUnc")
        ET.SubElement(unc, f"{{{SI}}}uncertainty").text = _number(expanded)
        ET.SubElement(unc, f"{{{SI}}}coverageFactor").text = _number(k)
        ET.SubElement(unc, f"{{{SI}}}coverageProbability").text = _number(COVERAGE_PROBABILITY)
        ET.SubElement(unc, f"{{{SI}}}distribution").text = "normal"


def _identification(parent: ET.Element, issuer: str, value: str, name: str) -> None:
    ident = _d(parent, "identification")
    _d(ident, "issuer", issuer)
    _d(ident, "value", value)
    _text(ident, "name", name)


def _contact(parent: ET.Element, tag: str, name: str, address: str, email: str = "") -> None:
    contact = _d(parent, tag)
    _text(contact, "name", name)
    _d(contact, "eMail", email)         # required by the schema, even when not known (a customer's)
    location = _d(contact, "location")
    _text(location, "further", address or "(no address recorded)")


def _date(when: dt.datetime | None, fallback: dt.datetime) -> str:
    return (when or fallback).date().isoformat()


def _administrative(root: ET.Element, c: Certificate) -> None:
    admin = _d(root, "administrativeData")
    software = _d(_d(admin, "dccSoftware"), "software")
    _text(software, "name", "turntable-bench")
    _d(software, "release", __version__)
    _d(software, "type", "application")

    core = _d(admin, "coreData")
    _d(core, "countryCodeISO3166_1", c.country or UNKNOWN_COUNTRY)
    _d(core, "usedLangCodeISO639_1", "en")
    _d(core, "mandatoryLangCodeISO639_1", "en")
    _d(core, "uniqueIdentifier", c.number)
    idents = _d(core, "identifications")
    _identification(idents, "calibrationLaboratory", c.record.run_id, RUN_ID)
    _identification(idents, "calibrationLaboratory", str(c.record.result_id), RESULT_ID)
    started, finished = c.calibrated_utc
    _d(core, "beginPerformanceDate", _date(started, c.issued_utc))
    _d(core, "endPerformanceDate", _date(finished, c.issued_utc))
    _d(core, "performanceLocation", "laboratory")

    item = _d(_d(admin, "items"), "item")
    _text(item, "name", c.item)
    _text(_d(item, "manufacturer"), "name", "(not recorded)")
    _d(item, "model", c.record.model)
    idents = _d(item, "identifications")
    _identification(idents, "manufacturer", c.record.serial, "serial number")
    _identification(idents, "customer", c.item, "the customer's identification")

    lab = _d(admin, "calibrationLaboratory")
    if c.accreditation_id:
        _d(lab, "calibrationLaboratoryCode", c.accreditation_id)
    _contact(lab, "contact", c.lab_name, c.lab_address, c.lab_email)

    persons = _d(admin, "respPersons")
    for entry, main in ((c.signature, True), (c.review, False)):
        if entry is None:
            continue
        person = _d(persons, "respPerson")
        _text(_d(person, "person"), "name", entry.actor)
        _text(person, "description",
              f"{'signed' if main else 'reviewed'} {entry.at_utc.isoformat(timespec='seconds')}Z")
        _d(person, "role", entry.role or "reviewer")
        _d(person, "mainSigner", "true" if main else "false")
    if c.signature is None and c.review is None:
        person = _d(persons, "respPerson")
        _text(_d(person, "person"), "name", c.record.operator or "(operator not recorded)")
        _d(person, "role", "operator; the certificate is not authorised (not signed)")

    _contact(admin, "customer", c.customer, "")

    statements = _d(admin, "statements")
    _text(_d(statements, "statement"), "declaration", c.title)
    statement = _d(statements, "statement")
    _text(statement, "declaration", DECISION_RULE if c.statement_of_conformity else
          f"Not a statement of conformity ({c.why_not}). Decision rule of the verdict: {DECISION_RULE}")
    if c.record.verdict in ("pass", "fail"):
        _d(statement, "conformity", c.record.verdict)
    statement = _d(statements, "statement")
    _d(statement, "traceable", "true")
    _text(statement, "declaration", "Traceability through the equipment listed in the measurement results, each "
                                    "with its own calibration certificate and due date.")
    statement = _d(statements, "statement")
    _text(statement, "declaration", "The results relate only to the item calibrated.")


def _equipment(parent: ET.Element, c: Certificate) -> None:
    if not c.equipment:
        return
    listing = _d(parent, "measuringEquipments")
    for item in c.equipment:
        equipment = _d(listing, "measuringEquipment")
        _text(equipment, "name", f"{item.get('tag', '')}: {item.get('kind', '')}")
        _text(equipment, "description",
              f"calibration certificate {item.get('certificate', '')}, due {item.get('due_date', '')}, "
              f"{c.in_date(item)}")
        _text(_d(equipment, "manufacturer"), "name", item.get("make", "") or "(not recorded)")
        _d(equipment, "model", item.get("model", ""))
        _identification(_d(equipment, "identifications"), "manufacturer", item.get("serial", ""), "serial number")


def _condition(parent: ET.Element, name: str, label: str, value: float | None, unit: str, text: str) -> None:
    condition = _d(parent, "influenceCondition")
    _text(condition, "name", name)
    data = _d(condition, "data")
    if value is None:
        _text(data, "text", text)
    else:
        _real(_d(data, "quantity"), label, value, unit)


def _results(root: ET.Element, c: Certificate) -> None:
    result = _d(_d(root, "measurementResults"), "measurementResult")
    _text(result, "name", "IMU calibration coefficients")
    method = _d(_d(result, "usedMethods"), "usedMethod")
    _text(method, "name", f"multi-position and rate-turn calibration on a three-axis turntable: {c.record.plan}")
    software = _d(_d(result, "usedSoftware"), "software")
    _text(software, "name", "turntable-bench (the run and its solve)")
    _d(software, "release", c.record.result_software_version)
    _equipment(result, c)
    conditions = _d(result, "influenceConditions")
    _condition(conditions, "IMU temperature (mean over the run)", "imu_temperature", c.imu_temperature_c,
               r"\degreeCelsius", "not recorded")
    _condition(conditions, "thermal chamber", "chamber", None, "", c.chamber)
    _condition(conditions, "site latitude", "latitude", c.site.latitude_deg, r"\degree", "")
    _condition(conditions, f"gravity: {c.gravity_source}", "gravity", c.site.gravity, r"\metre\second\tothe{-2}", "")
    results = _d(result, "results")
    for row in c.rows:
        entry = _d(results, "result")
        _text(entry, "name", f"{row.name} ({row.title}; result unit {row.unit})")
        expanded = row.expanded * row.si_factor if row.expanded is not None else None
        _real(_d(_d(entry, "data"), "quantity"), row.name, row.value * row.si_factor, row.dsi_unit, expanded, row.k)
    metadata = _d(result, "measurementMetaData")
    _text(_d(metadata, "metaData"), "declaration", f"run log {c.log_name}, SHA-256 {c.log_sha256}")
    _text(_d(metadata, "metaData"), "declaration", f"verdict {c.verdict}")


def to_xml(c: Certificate) -> bytes:
    """The certificate as DCC XML (UTF-8), byte for byte the same for the same certificate."""
    root = ET.Element(f"{{{DCC}}}digitalCalibrationCertificate", {"schemaVersion": SCHEMA_VERSION})
    _administrative(root, c)
    _results(root, c)
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"


_SCHEMA = None


def schema():
    """The DCC 3.1.2 schema (xmlschema), built once from the shipped files; CertError without xmlschema."""
    global _SCHEMA
    if _SCHEMA is None:
        try:
            # optional (the `cert` extra), and slow to import: only when a DCC is validated
            import xmlschema
        except ImportError as exc:
            raise CertError("validating a DCC needs xmlschema: pip install 'turntable-bench[cert]'") from exc
        _SCHEMA = xmlschema.XMLSchema(str(DCC_XSD), locations=[(SI, str(SI_XSD))], allow="local")
    return _SCHEMA


def validate(xml: bytes) -> list[str]:
    """What makes `xml` invalid against the DCC schema, one line each (empty: valid)."""
    # optional (the `cert` extra): only when a DCC is validated (schema() has said so if it is missing)
    import xmlschema

    try:
        root = ET.fromstring(xml)
    except ET.ParseError as exc:
        return [f"not XML: {exc}"]
    out = []
    for error in schema().iter_errors(root):
        if isinstance(error, xmlschema.XMLSchemaValidationError):
            out.append(f"{error.path}: {error.reason}")
        else:
            out.append(str(error))
    return out


__all__ = ["DCC", "RESULT_ID", "RUN_ID", "SI", "schema", "to_xml", "validate"]
