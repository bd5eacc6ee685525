"""Certificates (issue 32 items 4 and 6): `bench cert issue` writes a PDF with every ISO/IEC 17025 clause 7.8 item
that applies and a DCC XML valid against the shipped DCC 3.1.2 schema, both reproducible from the records and the
log; one that is not signed or did not pass says in its title that it is not a statement of conformity; `bench cert
check` finds a number, a hash or a signature changed in the file."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from bench.cert import dcc
from bench.cert.content import chamber_conditions, gather
from bench.cert.errors import CertError
from bench.cert.pdf import to_pdf, value_and_uncertainty
from bench.log.reader import read_log
from bench.records.store import open_records
from tests.helpers.lab import OVERDUE
from tests.helpers.run import cli, only_file


def _run_id(lab_run) -> str:
    return read_log(str(lab_run.log), messages=False).metadata["run"]["run_id"]


def _db(lab_run, folder: Path, *, signed: bool) -> tuple[Path, str]:
    """A copy of the lab run's database, reviewed and (when `signed`) signed."""
    db = folder / "records.sqlite"
    shutil.copy(lab_run.db, db)
    run_id = _run_id(lab_run)
    assert cli(["cert", "--db", str(db), "review", run_id, "--reviewer", "Bea Reviewer"])[0] == 0
    if signed:
        assert cli(["cert", "--db", str(db), "sign", run_id, "--signer", "Carl Signer", "--role",
                    "technical manager"])[0] == 0
    return db, run_id


def _issue(db: Path, run_id: str, out: Path) -> tuple[Path, Path, str]:
    rc, stdout, stderr = cli(["cert", "--db", str(db), "issue", run_id, "--out", str(out)])
    assert rc == 0, stderr
    return only_file(out, "*.pdf"), only_file(out, "*.xml"), stdout


def _pdf_text(pdf: Path) -> str:
    if shutil.which("pdftotext") is None:
        pytest.skip("pdftotext (poppler-utils) is not installed")
    return subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True, text=True,
                          check=True).stdout


@pytest.fixture(scope="module")
def signed(lab_run, tmp_path_factory):
    folder = tmp_path_factory.mktemp("signed")
    db, run_id = _db(lab_run, folder, signed=True)
    pdf, xml, stdout = _issue(db, run_id, folder / "certificates")
    return dataclasses.make_dataclass("Signed", ["db", "run_id", "pdf", "xml", "stdout", "folder"])(
        db, run_id, pdf, xml, stdout, folder)


def test_a_signed_passing_run_gives_a_pdf_with_every_required_item_and_a_valid_dcc(signed, lab_run):
    text = _pdf_text(signed.pdf)
    sha = __import__("hashlib").sha256(lab_run.log.read_bytes()).hexdigest()
    year = signed.run_id[:4]
    number = f"CAL-{year}-{signed.run_id}"
    pages = text.count("\f") or 1
    required = {
        "title (7.8.2.1 a)": "Calibration Certificate\n",
        "lab name (b)": "Example Calibration Lab", "lab address (b)": "1 Bench Street (CN)",
        "lab contact": "lab@example.com",
        "location of the calibration (c)": "at the laboratory",
        "unique identification (d)": number, "clear end (d)": "End of certificate",
        "customer (e)": "ACME Navigation", "method (f)": "optimal-24 + optimal-5s6r",
        "item (g)": "gyro pack 4711", "IMU model and serial (g)": "T-0001",
        "date of receipt (h)": "Date of receipt", "date of calibration (i)": " UTC to ",
        "date of issue (j)": "Date of issue",
        "results relate only to the item (l)": "The results relate only to the item calibrated",
        "results with units (m)": "counts/s per deg/s", "gyro bias unit (m)": "deg/h",
        "authorised by, with role (o)": "Carl Signer (technical manager)", "reviewer": "Bea Reviewer",
        "expanded uncertainty U with k (7.8.4.1 a)": "coverage factor k = 2",
        "decision rule (7.8.6)": "Decision rule: Simple acceptance", "verdict": "PASS",
        "an acceptance check": "Kg_x sigma",
        "traceability: equipment, certificate, due date (7.8.4.1 c)": "NIM-TT-01",
        "overdue reference marked": "OVERDUE at calibration", "its due date": OVERDUE,
        "IMU temperature (7.8.4.1 b)": "IMU temperature", "chamber (b)": "Chamber",
        "site latitude (b)": "30.27 deg", "gravity (b)": "m/s^2 (WGS84 normal gravity",
        "software version": "turntable-bench 0.1.0", "log SHA-256": sha,
    }
    missing = [what for what, words in required.items() if words not in text]
    assert not missing, missing
    assert "not a statement of conformity" not in text
    # every page: the lab, the number, "Page i of n"
    for i in range(1, pages + 1):
        assert f"Page {i} of {pages}" in text
    assert text.count(f"Certificate {number}") >= 2 * pages
    # each coefficient's U in the PDF is k sigma of the record of truth (two significant digits)
    with open_records(str(signed.db)) as records:
        from bench.records.lab import run_record
        record = run_record(records, signed.run_id)
    assert len(record.coefficients) == 30
    kg_x = next(c for c in record.coefficients if c.name == "Kg_x")
    value, u = value_and_uncertainty(kg_x.value, 2 * kg_x.sigma)
    assert any(line.split()[:1] == ["Kg_x"] and value in line and u in line for line in text.splitlines())

    xml = signed.xml.read_bytes()
    assert dcc.validate(xml) == []
    root = ET.fromstring(xml)
    reals = {r.findtext(f"{{{dcc.SI}}}label"): r for r in root.iter(f"{{{dcc.SI}}}real")}
    assert float(reals["Kg_x"].findtext(f"{{{dcc.SI}}}expandedUnc/{{{dcc.SI}}}coverageFactor")) == 2.0
    assert set(reals) >= {c.name for c in record.coefficients} | {"imu_temperature", "latitude", "gravity"}
    assert "pass" == root.findtext(f".//{{{dcc.DCC}}}conformity")
    assert root.findtext(f".//{{{dcc.DCC}}}countryCodeISO3166_1") == "CN"
    assert sha in xml.decode()


def test_the_same_records_and_log_give_the_same_bytes(signed, tmp_path):
    pdf, xml, _ = _issue(signed.db, signed.run_id, tmp_path / "again")
    assert pdf.read_bytes() == signed.pdf.read_bytes() and xml.read_bytes() == signed.xml.read_bytes()


def test_an_unsigned_or_failed_run_is_not_a_statement_of_conformity(lab_run, tmp_path):
    db, run_id = _db(lab_run, tmp_path, signed=False)
    pdf, xml, stdout = _issue(db, run_id, tmp_path / "out")
    assert "not a statement of conformity" in stdout and "not signed" in stdout
    text = _pdf_text(pdf)
    assert "Calibration Certificate - not a statement of conformity" in text and "NOT SIGNED" in text
    assert dcc.validate(xml.read_bytes()) == []
    # a signed run whose verdict failed: the same title, with the reason
    with open_records(str(db)) as records:
        from bench.records.lab import run_record
        record = run_record(records, run_id)
    failed = dataclasses.replace(record, verdict="fail", trail=tuple(
        dataclasses.replace(e, action="sign", role="technical manager") if e.action == "review" else e
        for e in record.trail))
    certificate = gather(failed, {"name": "Lab"}, record.log_sha256 or "", "x.mcap")
    assert certificate.why_not == "verdict fail" and certificate.title.endswith("not a statement of conformity")
    passed = gather(dataclasses.replace(failed, verdict="pass"), {}, record.log_sha256 or "", "x.mcap")
    assert passed.statement_of_conformity and passed.title == "Calibration Certificate"
    # reviewed and signed by the same person: allowed, and the certificate says so
    review = next(e for e in record.trail if e.action == "review")
    both = dataclasses.replace(record, verdict="pass", trail=(review, dataclasses.replace(
        review, action="sign", role="technical manager")))
    pdf = tmp_path / "same.pdf"
    pdf.write_bytes(to_pdf(gather(both, {"name": "Lab"}, record.log_sha256 or "", "x.mcap")))
    assert "Bea Reviewer, " in _pdf_text(pdf) and "(the same person as the signer)" in _pdf_text(pdf)
    with pytest.raises(CertError, match="table-check run: only a calibration"):
        gather(dataclasses.replace(record, kind="table-check"), {}, record.log_sha256 or "", "x.mcap")


def test_the_chamber_is_stated_from_its_recorded_states():
    assert chamber_conditions([]) == "no thermal chamber in this run (ambient)"
    assert chamber_conditions([20.0, float("nan"), 40.0]) == (
        "thermal chamber air 20.00 to 40.00 degC (mean 30.00 degC, 2 recorded states)")


def test_check_finds_a_changed_number_hash_or_signature(signed, tmp_path):
    base = ["cert", "--db", str(signed.db), "check"]
    for path in (signed.pdf, signed.xml):
        rc, out, err = cli([*base, str(path)])
        assert rc == 0 and "agrees with the records" in out, err
    xml = signed.xml.read_text(encoding="utf-8")
    root = ET.fromstring(xml)
    kg_y = next(r for r in root.iter(f"{{{dcc.SI}}}real") if r.findtext(f"{{{dcc.SI}}}label") == "Kg_y")
    value = kg_y.findtext(f"{{{dcc.SI}}}value")
    sha = next(line for line in xml.splitlines() if "SHA-256" in line)
    for before, after, words in (
            (f"<si:value>{value}</si:value>", f"<si:value>{float(value) * 1.000001!r}</si:value>", "Kg_y: "),
            (sha, sha.replace(sha.split()[-1][:8], "00000000"), "SHA-256"),
            ("Carl Signer", "Mallory", "'Mallory' in the file, 'Carl Signer' in the records")):
        assert xml.count(before) == 1
        tampered = tmp_path / "tampered.xml"
        tampered.write_text(xml.replace(before, after), encoding="utf-8")
        rc, out, err = cli([*base, str(tampered)])
        assert rc == 4 and words in out and "DISAGREES" in err and err.count("\n") == 1, (out, err)
    data = bytearray(signed.pdf.read_bytes())
    data[len(data) // 2] ^= 0x01
    tampered = tmp_path / "tampered.pdf"
    tampered.write_bytes(bytes(data))
    rc, out, err = cli([*base, str(tampered)])
    assert rc == 4 and "the PDF differs" in out
    # not a certificate, or the wrong log: one line, exit 2
    (tmp_path / "junk.xml").write_text("<a/>", encoding="utf-8")
    rc, _, err = cli([*base, str(tmp_path / "junk.xml")])
    assert rc == 2 and err.count("\n") == 1 and "not a DCC" in err


def test_issue_refuses_a_log_that_is_not_the_runs(signed, cli_run_log, tmp_path):
    rc, _, err = cli(["cert", "--db", str(signed.db), "issue", signed.run_id, "--out", str(tmp_path / "c"),
                      "--log", str(cli_run_log)])
    assert rc == 2 and err.count("\n") == 1 and "is not the one the records hold" in err
    assert not (tmp_path / "c").exists()


def test_a_certificate_number_never_names_a_path_outside_out():
    from bench.cli.cert import _file_stem

    assert _file_stem("../../etc/passwd") == "etc_passwd"
    assert _file_stem("CAL 2026/07:x") == "CAL_2026_07_x" and _file_stem("..") == "certificate"


def test_value_and_uncertainty_are_rounded_to_the_same_place():
    assert value_and_uncertainty(36012.50000277, 0.004634) == ("36012.5000", "0.0046")
    assert value_and_uncertainty(-7.9994984e-05, 2.96e-06) == ("-0.0000800", "0.0000030")
    assert value_and_uncertainty(40021.0003, 204.4) == ("40020", "200")
    assert value_and_uncertainty(1.5, None) == ("1.5", "not estimated")
