"""`bench db equipment add|list|retire`: the lab's equipment register (logic in `bench.records.lab`); and
`run_lab_record`, the check `bench run` makes of the configured equipment before anything moves.

Exit codes: 0 done; 2 usage error, a tag taken or unknown, or the database cannot be opened.
"""

from __future__ import annotations

import argparse
import datetime as dt
import getpass
import sys
from typing import TYPE_CHECKING

from bench.cli.common import ExitCode, fail

if TYPE_CHECKING:
    from bench.config.load import BenchConfig

PROG = "bench db equipment"


def register_equipment(sub: argparse._SubParsersAction, db_option: dict) -> None:
    """`bench db equipment ACTION` under `bench db` (`db_option`: the --db argument's keywords)."""
    parser = sub.add_parser("equipment", help="the lab's equipment register: add, list, retire",
                            description="The equipment the lab calibrates with (turntable, thermal chamber, "
                                        "reference instruments), each with its own calibration certificate and due "
                                        "date. A configuration's [lab] equipment names them by tag; `bench run` "
                                        "warns about (or refuses) equipment past its due date. Equipment is never "
                                        "deleted: it is retired. Every change is in the audit trail "
                                        "(`bench cert trail`).")
    parser.add_argument("--db", metavar="URL", **db_option, default=argparse.SUPPRESS)
    actions = parser.add_subparsers(dest="equipment_command", metavar="ACTION")
    actions.required = True
    p = actions.add_parser("add", help="register equipment")
    p.add_argument("tag", metavar="TAG", help="the lab's name for it, as [lab] equipment names it (e.g. TT-01)")
    # (the kinds are checked by bench.records.lab, EQUIPMENT_KINDS: SQLAlchemy is not imported for --help)
    p.add_argument("--kind", required=True,
                   help="turntable, chamber, gravity or temperature (a reference instrument for it), or other")
    p.add_argument("--make", required=True, help="manufacturer")
    p.add_argument("--model", required=True, help="model name")
    p.add_argument("--serial", required=True, help="serial number")
    p.add_argument("--certificate", required=True, help="its own calibration certificate (number, issuer)")
    p.add_argument("--due", required=True, metavar="YYYY-MM-DD", help="its next calibration is due on this date")
    p.add_argument("--by", metavar="NAME", help="who registers it (the audit trail; default: the login name)")
    p.add_argument("--db", metavar="URL", **db_option, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_add)
    p = actions.add_parser("list", help="list the register, with what is past its due date")
    p.add_argument("--all", action="store_true", help="retired equipment too")
    p.add_argument("--run", metavar="RUN_ID", help="only the equipment this run used (as recorded from its log)")
    p.add_argument("--db", metavar="URL", **db_option, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_list)
    p = actions.add_parser("retire", help="retire equipment (it stays in the register and in its runs)")
    p.add_argument("tag", metavar="TAG", help="the equipment's tag (`bench db equipment list`)")
    p.add_argument("--reason", default="", help="why (the audit trail)")
    p.add_argument("--by", metavar="NAME", help="who retires it (default: the login name)")
    p.add_argument("--db", metavar="URL", **db_option, default=argparse.SUPPRESS)
    p.set_defaults(func=cmd_retire)


def _today() -> dt.date:
    return dt.datetime.now(dt.UTC).date()


def _who(args: argparse.Namespace) -> str:
    if args.by:
        return str(args.by)
    try:
        return getpass.getuser()
    except (KeyError, OSError):      # no login name (a container's uid without a passwd entry)
        return "unknown"


def _line(item, today: dt.date) -> str:
    state = ("retired " + item.retired_utc.date().isoformat() if item.retired_utc is not None
             else "OVERDUE" if item.overdue(today) else "in date")
    return (f"{item.tag:12} {item.kind:11} {item.make[:16]:16} {item.model[:16]:16} {item.serial[:14]:14} "
            f"{item.due_date.isoformat():10} {state:16} {item.certificate}")


def cmd_add(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.lab import Equipment, add_equipment
    from bench.records.store import RecordsError, open_records

    try:
        due = dt.date.fromisoformat(args.due)
    except ValueError:
        return fail(PROG, f"--due {args.due!r}: not a date (YYYY-MM-DD)", ExitCode.USAGE)
    fields = {"tag": args.tag, "make": args.make, "model": args.model, "serial": args.serial,
              "certificate": args.certificate}
    for name, value in fields.items():
        if not value.strip():
            return fail(PROG, f"--{name} must not be empty" if name != "tag" else "TAG must not be empty",
                        ExitCode.USAGE)
    try:
        with open_records(getattr(args, "db", None)) as records:
            item = add_equipment(records, Equipment(kind=args.kind, due_date=due,
                                                    **{k: v.strip() for k, v in fields.items()}), _who(args))
    except RecordsError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    print(f"registered {item.tag}: {item.kind} {item.make} {item.model} s/n {item.serial}, certificate "
          f"{item.certificate}, due {item.due_date.isoformat()}"
          + (" (already past its due date)" if item.overdue(_today()) else ""))
    return ExitCode.OK


def cmd_list(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.lab import list_equipment, run_equipment
    from bench.records.store import RecordsError, open_records

    try:
        with open_records(getattr(args, "db", None), create=False) as records:
            if args.run is not None:
                if not records.run_known(args.run):
                    return fail(PROG, f"no run {args.run!r} in the records", ExitCode.USAGE)
                items = run_equipment(records, args.run)
            else:
                items = list_equipment(records, include_retired=args.all)
    except RecordsError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    today = _today()
    print(f"{'tag':12} {'kind':11} {'make':16} {'model':16} {'serial':14} {'due':10} {'state':16} certificate")
    for item in items:
        print(_line(item, today))
    overdue = sum(1 for item in items if item.retired_utc is None and item.overdue(today))
    print(f"{len(items)} item(s)" + (f", {overdue} past the due date" if overdue else ""))
    return ExitCode.OK


def cmd_retire(args: argparse.Namespace) -> ExitCode:
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.lab import retire_equipment
    from bench.records.store import RecordsError, open_records

    try:
        with open_records(getattr(args, "db", None), create=False) as records:
            item = retire_equipment(records, args.tag, _who(args), args.reason)
    except RecordsError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    print(f"retired {item.tag} ({item.kind} {item.make} {item.model} s/n {item.serial})")
    return ExitCode.OK


# -- bench run's check -----------------------------------------------------------------------------

def run_lab_record(args: argparse.Namespace, config: BenchConfig, prog: str) -> dict[str, str] | ExitCode:
    """The run log's `lab` record (`bench.run.runner.lab_record`: the configured lab, --customer and --item, the
    equipment as the register describes it), or the exit code of a run refused before anything moved: equipment
    the register does not hold; with `[lab] refuse_overdue_equipment`, equipment past its due date or retired,
    or a register that cannot be read. Without that key those are warnings."""
    # heavy (SQLAlchemy; the runner's numpy and drivers): imported when the command runs, not for its --help
    from bench.run.runner import lab_record

    customer, item = getattr(args, "customer", None) or "", getattr(args, "item", None) or ""
    tags = config.lab.equipment
    if not tags:
        return lab_record(config, customer=customer, item=item)
    refuse = config.lab.refuse_overdue_equipment

    def unchecked(reason: str) -> dict[str, str] | ExitCode:
        if refuse:
            return fail(prog, f"the equipment's due dates cannot be checked: {reason} ([lab] "
                              "refuse_overdue_equipment = true: nothing moved)", ExitCode.USAGE)
        print(f"{prog}: warning: the equipment's due dates are not checked: {reason}", file=sys.stderr)
        return lab_record(config, customer=customer, item=item)

    if getattr(args, "no_db", False):
        return unchecked("--no-db (the register is in the records database)")
    # heavy (SQLAlchemy): imported when the command runs, not for its --help
    from bench.records.lab import check_equipment
    from bench.records.store import RecordsError, open_records

    try:
        with open_records(getattr(args, "db", None)) as records:
            items, problems = check_equipment(records, tags, _today())
    except RecordsError as exc:
        if "not in the register" in str(exc):
            return fail(prog, f"[lab] equipment: {exc}; nothing moved", ExitCode.USAGE)
        return unchecked(str(exc))
    if problems and refuse:
        return fail(prog, f"{problems[0]}" + (f" (and {len(problems) - 1} more)" if len(problems) > 1 else "")
                    + ": [lab] refuse_overdue_equipment = true, nothing moved", ExitCode.USAGE)
    for problem in problems:
        print(f"{prog}: warning: {problem}", file=sys.stderr)
    return lab_record(config, [e.as_metadata() for e in items], customer=customer, item=item)


__all__ = ["register_equipment", "run_lab_record"]
