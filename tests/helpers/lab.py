"""The lab's side of the records in tests (issue 32): registering equipment through the CLI and a `[lab]` section."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

from tests.helpers.run import cli

TODAY = dt.datetime.now(dt.UTC).date()
IN_DATE = (TODAY + dt.timedelta(days=365)).isoformat()
OVERDUE = (TODAY - dt.timedelta(days=1)).isoformat()
#: limits that the short simulated plan passes: its verdict is PASS (a certificate can state conformity)
PASSING_ACCEPTANCE = "\n[acceptance]\nmax_lost_samples = 0\n[acceptance.Kg]\nmax_sigma = 0.01\n"


def add_equipment_cli(db: Path, tag: str, kind: str, due: str, *extra: str) -> tuple[int, str, str]:
    """`bench db equipment add TAG` into `db`: make Acme, model `<kind>-9`, serial `S-<tag>`, certificate
    `NIM-<tag>`, due `due`."""
    return cli(["db", "--db", str(db), "equipment", "add", tag, "--kind", kind, "--make", "Acme", "--model",
                f"{kind}-9", "--serial", f"S-{tag}", "--certificate", f"NIM-{tag}", "--due", due, "--by", "ann",
                *extra])


def lab_section(equipment: list[str], refuse: bool = False) -> str:
    """A `[lab]` section naming `equipment` (register tags)."""
    return ("\n[lab]\nname = \"Example Calibration Lab\"\naddress = \"1 Bench Street\"\ncountry = \"CN\"\n"
            "email = \"lab@example.com\"\n"
            "certificate_number_pattern = \"CAL-{year}-{run_id}\"\ncustomer = \"configured customer\"\n"
            f"equipment = {json.dumps(equipment)}\nrefuse_overdue_equipment = {str(refuse).lower()}\n")
