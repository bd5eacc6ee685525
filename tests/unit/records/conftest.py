"""The records' shared recording: one short simulated run of a lab (tests/unit/records/test_lab.py and
test_certificate.py read it; a test that writes copies the database first)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from tests.helpers.lab import IN_DATE, OVERDUE, PASSING_ACCEPTANCE, add_equipment_cli, lab_section
from tests.helpers.run import cli, config_text, only_file


@pytest.fixture(scope="session")
def lab_run(tmp_path_factory) -> SimpleNamespace:
    """One short simulated `bench run` with an in-date turntable and an overdue temperature reference, a customer
    and an item on the command line and acceptance limits it passes (verdict PASS), recorded into its own
    database (`db`; copy it to write)."""
    folder = tmp_path_factory.mktemp("lab-run")
    db = folder / "records.sqlite"
    assert add_equipment_cli(db, "TT-01", "turntable", IN_DATE)[0] == 0
    assert add_equipment_cli(db, "REF-T", "temperature", OVERDUE)[0] == 0
    config = folder / "bench.toml"
    config.write_text(config_text(dwell_s=1.0) + lab_section(["TT-01", "REF-T"]) + PASSING_ACCEPTANCE,
                      encoding="utf-8")
    rc, stdout, stderr = cli(["run", "--config", str(config), "--out", str(folder / "out"), "--quiet",
                              "--db", str(db), "--customer", "ACME Navigation", "--item", "gyro pack 4711"])
    assert rc == 0, stderr
    return SimpleNamespace(folder=folder, db=db, config=config, stderr=stderr, log=only_file(folder / "out", "*.mcap"))
