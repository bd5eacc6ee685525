"""`bench cert check`: a certificate file against the records database (and the run's log).

Both forms are issued reproducibly from the records and the log, so the check issues the certificate again and
compares. A DCC XML is first validated against the schema, then compared element by element: each number, hash,
name or signature that differs is one line naming where it is (the coefficient, for a result). A PDF is found by
its /Subject (the certificate's number and run) and compared byte for byte: its text is not parsed, so a
difference is reported as such, not located.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from bench.cert import dcc
from bench.cert.content import load
from bench.cert.errors import CertError
from bench.cert.pdf import SUBJECT_PREFIX, to_pdf
from bench.records.store import Records

_SUBJECT = re.compile(rb"/Subject \(" + re.escape(SUBJECT_PREFIX.encode()) + rb" (.+?) run ([^()\s]+)\)")
#: at most this many differences are listed
MAX_LINES = 20
#: a certificate file larger than this is not read (the bench's are tens of kB)
MAX_CERTIFICATE_BYTES = 16 << 20


@dataclass(frozen=True)
class CheckReport:
    """What `check_file` found: the run and certificate it names, and what disagrees (empty: it is genuine)."""

    run_id: str
    number: str
    problems: list[str]


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _where(path: list[ET.Element]) -> str:
    """A readable place: the element names, with the label of the quantity they are in (e.g. `Kg_x`)."""
    names = [_local(e.tag) for e in path]
    label = next((lab.text for e in reversed(path) if (lab := e.find(f"{{{dcc.SI}}}label")) is not None), None)
    short = "/".join(names[-3:])
    return f"{label}: {short}" if label else short


def _differences(issued: ET.Element, given: ET.Element) -> list[str]:
    out: list[str] = []

    def walk(a: ET.Element, b: ET.Element, path: list[ET.Element]) -> None:
        here = [*path, b]
        if a.tag != b.tag:
            out.append(f"{_where(here)}: element {_local(b.tag)} where the records give {_local(a.tag)}")
            return
        if (a.text or "").strip() != (b.text or "").strip():
            out.append(f"{_where(here)}: {(b.text or '').strip()!r} in the file, "
                       f"{(a.text or '').strip()!r} in the records")
        if a.attrib != b.attrib:
            out.append(f"{_where(here)}: attributes {b.attrib} in the file, {a.attrib} in the records")
        ca, cb = list(a), list(b)
        for x, y in zip(ca, cb):
            walk(x, y, here)
        if len(ca) != len(cb):
            out.append(f"{_where(here)}: {len(cb)} elements in the file, {len(ca)} in the records")

    walk(issued, given, [])
    return out


def _identification(root: ET.Element, name: str) -> str | None:
    for ident in root.iter(f"{{{dcc.DCC}}}identification"):
        label = ident.find(f"{{{dcc.DCC}}}name/{{{dcc.DCC}}}content")
        if label is not None and label.text == name:
            value = ident.find(f"{{{dcc.DCC}}}value")
            return value.text if value is not None else None
    return None


def check_xml(records: Records, data: bytes, log: str | Path | None = None) -> CheckReport:
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise CertError(f"not XML: {exc}") from exc
    if root.tag != f"{{{dcc.DCC}}}digitalCalibrationCertificate":
        raise CertError(f"not a DCC: the root element is {root.tag}")
    run_id = _identification(root, dcc.RUN_ID)
    if not run_id:
        raise CertError("the DCC names no run (no identification 'run id'): not issued by the bench")
    number = root.findtext(f".//{{{dcc.DCC}}}uniqueIdentifier") or ""
    problems = [f"not valid against the DCC {dcc.SCHEMA_VERSION} schema: {line}" for line in dcc.validate(data)]
    certificate = load(records, run_id, log)
    problems += _differences(ET.fromstring(dcc.to_xml(certificate)), root)
    return CheckReport(run_id, number, problems)


def check_pdf(records: Records, data: bytes, log: str | Path | None = None) -> CheckReport:
    found = _SUBJECT.search(data)
    if found is None:
        raise CertError("not a certificate the bench issued (no /Subject naming its run)")
    number, run_id = found.group(1).decode("latin-1"), found.group(2).decode("latin-1")
    certificate = load(records, run_id, log)
    problems = []
    if certificate.number != number:
        problems.append(f"certificate number {number!r} in the file, {certificate.number!r} in the records")
    if to_pdf(certificate) != data:
        problems.append("the PDF differs from the certificate the records and the log give (its text, a number, "
                        "a hash or a signature was changed, or the records changed since it was issued)")
    return CheckReport(run_id, number, problems)


def check_file(records: Records, path: str | Path, log: str | Path | None = None) -> CheckReport:
    """Check a certificate file (PDF or DCC XML, by its first bytes); CertError if it is neither or names a run
    the records cannot certify."""
    try:
        with open(path, "rb") as file:
            data = file.read(MAX_CERTIFICATE_BYTES + 1)
    except OSError as exc:
        raise CertError(str(exc.strerror or exc)) from exc
    if len(data) > MAX_CERTIFICATE_BYTES:
        raise CertError(f"larger than {MAX_CERTIFICATE_BYTES >> 20} MiB: not a certificate the bench issued")
    if data.startswith(b"%PDF-"):
        return check_pdf(records, data, log)
    return check_xml(records, data, log)


__all__ = ["MAX_CERTIFICATE_BYTES", "MAX_LINES", "CheckReport", "check_file", "check_pdf", "check_xml"]
