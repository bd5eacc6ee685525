"""`bench cert`: a run's review and sign-off, and the audit trail (logic in `bench.records.lab`).

`bench cert review RUN --reviewer NAME` records that NAME reviewed the run's record of truth,
`bench cert sign RUN --signer NAME --role ROLE` that NAME signed it (only after it was reviewed),
`bench cert trail [RUN]` prints the append-only audit trail: who did what when,
`bench cert issue RUN --out DIR` writes the run's certificate, a PDF and a DCC XML (`bench.cert`),
`bench cert check FILE` checks a certificate file against the records.

Exit codes: 0 done (check: the certificate agrees with the records); 2 usage error, a run not recorded or without
a result, a sign before the review, a log that is not the run's, or the database cannot be opened; 4 (check) the
certificate disagrees with the records.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from bench.cli.common import ExitCode, fail
from bench.cli.db import DB_HELP

PROG = "bench cert"


UNIT_HELP = ("a run of several IMUs ([[imu]]): the unit (its serial), each unit being a record of its own "
             "(`<run-id>.<serial>`, as `bench db list` shows it); RUN alone is refused when it has several")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "cert",
        description="Review and sign-off of a recorded run, in the records database's append-only audit trail "
                    "(who did what when), and its certificate. A run is reviewed on its record of truth (`bench db "
                    "results RUN`) and signed only after that result was reviewed; `issue` writes its certificate "
                    "(PDF and DCC XML) from the records and the log, `check` compares a certificate file with them. "
                    "Exit codes: 0 done, 2 usage error, a run not recorded or without a result, a signature before "
                    "the review, a log that is not the run's, or the database cannot be opened; 4 a checked "
                    "certificate disagrees with the records.")
    parser.add_argument("--db", metavar="URL", help=DB_HELP)
    sub = parser.add_subparsers(dest="cert_command", metavar="ACTION")
    sub.required = True
    p = sub.add_parser("review", help="record that the run's result was reviewed")
    p.add_argument("run_id", metavar="RUN", help="the run (as `bench db list` shows it)")
    p.add_argument("--reviewer", required=True, metavar="NAME", help="who reviewed it")
    p.add_argument("--note", default="", help="a remark kept with the review")
    p.add_argument("--unit", metavar="SERIAL", help=UNIT_HELP)
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_review)
    p = sub.add_parser("sign", help="sign the reviewed result (the authorisation of its certificate)")
    p.add_argument("run_id", metavar="RUN", help="the run (as `bench db list` shows it)")
    p.add_argument("--signer", required=True, metavar="NAME", help="who signs")
    p.add_argument("--role", required=True, help="the signer's role (e.g. \"technical manager\")")
    p.add_argument("--note", default="", help="a remark kept with the signature")
    p.add_argument("--unit", metavar="SERIAL", help=UNIT_HELP)
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_sign)
    p = sub.add_parser("trail", help="the audit trail, oldest first: of one run, or all of it")
    p.add_argument("run_id", metavar="RUN", nargs="?", help="only this run's entries")
    p.add_argument("--unit", metavar="SERIAL", help=UNIT_HELP)
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_trail)
    p = sub.add_parser("issue", help="write the run's certificate: a PDF and a DCC XML (PTB Digital Calibration "
                                     "Certificate), from the records and the run's log")
    p.add_argument("run_id", metavar="RUN", help="the run (as `bench db list` shows it)")
    p.add_argument("--out", required=True, metavar="DIR", help="the folder to write them to (made if missing)")
    p.add_argument("--unit", metavar="SERIAL", help=UNIT_HELP)
    p.add_argument("--log", metavar="MCAP", help="the run's log, if not where the records say it is")
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_issue)
    p = sub.add_parser("check", help="check a certificate (PDF or DCC XML) against the records: numbers, hash, "
                                     "signatures; exit 4 when it disagrees")
    p.add_argument("file", metavar="FILE", help="the certificate's .pdf or .xml")
    p.add_argument("--log", metavar="MCAP", help="the run's log, if not where the records say it is")
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_check)


def _name(value: str) -> str | None:
    """`value` stripped; None if it is empty (the caller fails with one line)."""
    return value.strip() or None


def _act(args: argparse.Namespace, action) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.store import RecordsError, open_records

    try:
        with open_records(getattr(args, "db", None), create=False) as records:
            entry = action(records)
    except RecordsError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    print(_entry_line(entry))
    return ExitCode.OK


def cmd_review(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.lab import review

    reviewer = _name(args.reviewer)
    if reviewer is None:
        return fail(PROG, "--reviewer must name someone", ExitCode.USAGE)
    return _act(args, lambda records: review(records, records.unit_record(args.run_id, args.unit),
                                                            reviewer, args.note))


def cmd_sign(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.lab import sign

    signer, role = _name(args.signer), _name(args.role)
    if signer is None or role is None:
        return fail(PROG, "--signer and --role must not be empty", ExitCode.USAGE)
    return _act(args, lambda records: sign(records, records.unit_record(args.run_id, args.unit),
                                                          signer, role, args.note))


def _entry_line(entry) -> str:
    what = entry.action + (f" of run {entry.run_id}" if entry.run_id else "") + (
        f" result {entry.result_id}" if entry.result_id is not None else "") + (
        f" equipment {entry.equipment_tag}" if entry.equipment_tag else "")
    return (f"{entry.at_utc.isoformat(timespec='seconds')}Z  {what} by {entry.actor}"
            + (f" ({entry.role})" if entry.role else "") + (f": {entry.detail}" if entry.detail else ""))


def cmd_trail(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.lab import audit_trail
    from bench.records.store import RecordsError, open_records

    try:
        with open_records(getattr(args, "db", None), create=False) as records:
            if args.unit is not None and args.run_id is None:
                return fail(PROG, "--unit needs RUN", ExitCode.USAGE)
            entries = audit_trail(records, None if args.run_id is None else records.unit_record(args.run_id,
                                                                                                  args.unit))
    except RecordsError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    for entry in entries:
        print(_entry_line(entry))
    print(f"{len(entries)} entr{'y' if len(entries) == 1 else 'ies'}")
    return ExitCode.OK


def _file_stem(number: str) -> str:
    """The certificate number as a file name in --out (a number never names a path outside it)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", number).strip("._") or "certificate"


def cmd_issue(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy, fpdf2, xmlschema): imported when the command runs, not for its --help
    from bench.cert.content import load
    from bench.cert.dcc import to_xml, validate
    from bench.cert.errors import CertError
    from bench.cert.pdf import to_pdf
    from bench.records.store import RecordsError, open_records

    try:
        with open_records(getattr(args, "db", None), create=False) as records:
            certificate = load(records, records.unit_record(args.run_id, args.unit), args.log)
        xml = to_xml(certificate)
        invalid = validate(xml)
        if invalid:         # a bug: what the bench writes must be valid
            raise AssertionError(f"the DCC written is not valid: {invalid[0]}")
        pdf = to_pdf(certificate)
    except (RecordsError, CertError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    out = Path(args.out)
    stem = _file_stem(certificate.number)
    try:
        out.mkdir(parents=True, exist_ok=True)
        paths = (out / f"{stem}.pdf", out / f"{stem}.xml")
        for path, data in zip(paths, (pdf, xml)):
            partial = path.with_name(path.name + ".partial")
            partial.write_bytes(data)
            partial.replace(path)
    except OSError as exc:
        return fail(PROG, f"{out}: cannot write the certificate: {exc.strerror or exc}", ExitCode.USAGE)
    for item in certificate.equipment:
        if certificate.in_date(item) != "in date":
            print(f"{PROG}: warning: equipment {item.get('tag', '')} was {certificate.in_date(item)} "
                  f"(due {item.get('due_date', '')}); the certificate says so", flush=True)
    print(f"{certificate.title} {certificate.number}"
          + ("" if certificate.statement_of_conformity else f" ({certificate.why_not})"))
    print(f"pdf: {paths[0]}  dcc: {paths[1]}")
    return ExitCode.OK


def cmd_check(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy, xmlschema): imported when the command runs, not for its --help
    from bench.cert.check import MAX_LINES, check_file
    from bench.cert.errors import CertError
    from bench.records.store import RecordsError, open_records

    try:
        with open_records(getattr(args, "db", None), create=False) as records:
            report = check_file(records, args.file, args.log)
    except (RecordsError, CertError) as exc:
        return fail(PROG, f"{args.file}: {exc}", ExitCode.USAGE)
    if not report.problems:
        print(f"{args.file}: certificate {report.number} of run {report.run_id} agrees with the records "
              "(numbers, log SHA-256, signatures)")
        return ExitCode.OK
    for line in report.problems[:MAX_LINES]:
        print(f"{args.file}: {line}")
    more = len(report.problems) - MAX_LINES
    return fail(PROG, f"{args.file}: certificate {report.number} of run {report.run_id} DISAGREES with the records"
                      f" ({len(report.problems)} difference(s){f', {more} not shown' if more > 0 else ''})",
                ExitCode.QUALITY)


__all__ = ["register"]
