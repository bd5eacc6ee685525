"""`bench cert`: a run's review and sign-off, and the audit trail (logic in `bench.records.lab`).

`bench cert review RUN --reviewer NAME` records that NAME reviewed the run's record of truth,
`bench cert sign RUN --signer NAME --role ROLE` that NAME signed it (only after it was reviewed),
`bench cert trail [RUN]` prints the append-only audit trail: who did what when.

Exit codes: 0 done; 2 usage error, a run not recorded or without a result, a sign before the review, or the
database cannot be opened.
"""

from __future__ import annotations

import argparse

from bench.cli.common import ExitCode, fail
from bench.cli.db import DB_HELP

PROG = "bench cert"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "cert",
        description="Review and sign-off of a recorded run, in the records database's append-only audit trail "
                    "(who did what when). A run is reviewed on its record of truth (`bench db results RUN`) and "
                    "signed only after that result was reviewed. Exit codes: 0 done, 2 usage error, a run not "
                    "recorded or without a result, a signature before the review, or the database cannot be opened.")
    parser.add_argument("--db", metavar="URL", help=DB_HELP)
    sub = parser.add_subparsers(dest="cert_command", metavar="ACTION")
    sub.required = True
    p = sub.add_parser("review", help="record that the run's result was reviewed")
    p.add_argument("run_id", metavar="RUN", help="the run (as `bench db list` shows it)")
    p.add_argument("--reviewer", required=True, metavar="NAME", help="who reviewed it")
    p.add_argument("--note", default="", help="a remark kept with the review")
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_review)
    p = sub.add_parser("sign", help="sign the reviewed result (the authorisation of its certificate)")
    p.add_argument("run_id", metavar="RUN", help="the run (as `bench db list` shows it)")
    p.add_argument("--signer", required=True, metavar="NAME", help="who signs")
    p.add_argument("--role", required=True, help="the signer's role (e.g. \"technical manager\")")
    p.add_argument("--note", default="", help="a remark kept with the signature")
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_sign)
    p = sub.add_parser("trail", help="the audit trail, oldest first: of one run, or all of it")
    p.add_argument("run_id", metavar="RUN", nargs="?", help="only this run's entries")
    p.add_argument("--db", metavar="URL", help=DB_HELP, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_trail)


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
    return _act(args, lambda records: review(records, args.run_id, reviewer, args.note))


def cmd_sign(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.lab import sign

    signer, role = _name(args.signer), _name(args.role)
    if signer is None or role is None:
        return fail(PROG, "--signer and --role must not be empty", ExitCode.USAGE)
    return _act(args, lambda records: sign(records, args.run_id, signer, role, args.note))


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
            if args.run_id is not None and not records.run_known(args.run_id):
                return fail(PROG, f"no run {args.run_id!r} in the records", ExitCode.USAGE)
            entries = audit_trail(records, args.run_id)
    except RecordsError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    for entry in entries:
        print(_entry_line(entry))
    print(f"{len(entries)} entr{'y' if len(entries) == 1 else 'ies'}")
    return ExitCode.OK


__all__ = ["register"]
