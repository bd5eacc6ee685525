"""The lab's side of the records (issue 32 items 1-3): the equipment register (`bench db equipment`), a run's
equipment, lab, customer and item in its log and the records (`bench run`, refused with overdue equipment when
configured), review and sign-off (`bench cert`) in an append-only audit trail the database enforces."""

from __future__ import annotations

import json
import shutil

import pytest
import sqlalchemy as sa

from bench.config.load import ConfigError, parse_config
from bench.log.reader import read_log
from bench.records import schema
from bench.records.lab import Equipment, add_equipment, audit_trail, run_equipment
from bench.records.store import RecordsError, open_records
from tests.helpers.lab import IN_DATE, OVERDUE, TODAY
from tests.helpers.lab import add_equipment_cli as _add
from tests.helpers.lab import lab_section as _lab
from tests.helpers.postgres import create_database, postgres_server
from tests.helpers.run import cli, config_text


def _refuse_update_and_delete(url: str) -> None:
    """The audit trail's rows cannot be changed nor removed: the database refuses both."""
    with open_records(url) as records:
        add_equipment(records, Equipment("TT-9", "turntable", "Acme", "T", "1", "C-1", TODAY), "ann")
        for statement in (sa.update(schema.audit).values(actor="mallory"), sa.delete(schema.audit)):
            with pytest.raises(RecordsError, match="append-only"):
                with records.transaction() as conn:
                    conn.execute(statement)
        trail = audit_trail(records)
    assert [(e.action, e.actor, e.equipment_tag) for e in trail] == [("equipment-add", "ann", "TT-9")]


def test_the_audit_trail_refuses_update_and_delete_on_sqlite(tmp_path):
    _refuse_update_and_delete(str(tmp_path / "r.sqlite"))


def test_the_audit_trail_refuses_update_and_delete_on_postgresql():
    with postgres_server() as server:
        _refuse_update_and_delete(create_database(server, "audit"))


def test_equipment_register_add_list_retire(tmp_path):
    db = tmp_path / "r.sqlite"
    assert _add(db, "TT-01", "turntable", IN_DATE)[0] == 0
    rc, out, _ = _add(db, "CH-01", "chamber", OVERDUE)
    assert rc == 0 and "already past its due date" in out
    rc, _, err = _add(db, "TT-01", "turntable", IN_DATE)
    assert rc == 2 and err.count("\n") == 1 and "already registered" in err
    rc, _, err = _add(db, "X-1", "turntable", "next year")
    assert rc == 2 and "--due 'next year': not a date" in err
    rc, _, err = _add(db, "X-1", "voltmeter", IN_DATE)
    assert rc == 2 and err.count("\n") == 1 and "must be one of turntable, chamber, gravity" in err
    rc, out, _ = cli(["db", "--db", str(db), "equipment", "list"])
    assert rc == 0
    lines = {line.split()[0]: line for line in out.splitlines()[1:-1]}
    assert "OVERDUE" in lines["CH-01"] and "in date" in lines["TT-01"] and "NIM-TT-01" in lines["TT-01"]
    assert out.splitlines()[-1] == "2 item(s), 1 past the due date"
    rc, _, _ = cli(["db", "--db", str(db), "equipment", "retire", "CH-01", "--reason", "sold", "--by", "bob"])
    assert rc == 0
    rc, _, err = cli(["db", "--db", str(db), "equipment", "retire", "CH-01"])
    assert rc == 2 and "was retired" in err
    assert "CH-01" not in cli(["db", "--db", str(db), "equipment", "list"])[1]
    assert "retired" in cli(["db", "--db", str(db), "equipment", "list", "--all"])[1]
    rc, out, _ = cli(["cert", "--db", str(db), "trail"])
    assert [line.split()[1:3] for line in out.splitlines()[:-1]] == [
        ["equipment-add", "equipment"], ["equipment-add", "equipment"], ["equipment-retire", "equipment"]]
    assert "by bob: sold" in out


def test_the_lab_section_is_checked_with_file_line_and_key():
    base = config_text()
    config = parse_config(base + _lab(["TT-01", "CH-01"], refuse=True))
    assert config.lab.equipment == ("TT-01", "CH-01") and config.lab.refuse_overdue_equipment
    assert config.lab.name == "Example Calibration Lab"
    for bad, words in ((_lab(["TT-01", "TT-01"]), "listed twice"),
                       ("\n[lab]\ncertificate_number_pattern = \"CAL-{customer}\"\n", "unknown field '{customer}'"),
                       ("\n[lab]\nequipment = \"TT-01\"\n", "must be a list"),
                       ("\n[lab]\ncountry = \"China\"\n", "ISO 3166-1 alpha-2"),
                       ("\n[lab]\nowner = 1\n", "unknown key")):
        with pytest.raises(ConfigError, match="lab") as caught:
            parse_config(base + bad, source="bench.toml")
        assert words in str(caught.value) and str(caught.value).startswith("bench.toml:")


def test_a_run_records_its_lab_customer_item_and_equipment(lab_run):
    assert "warning: equipment REF-T (temperature Acme temperature-9 s/n S-REF-T) is past its calibration due " \
           f"date {OVERDUE}" in lab_run.stderr
    lab = read_log(str(lab_run.log), messages=False).metadata["lab"]
    assert lab["name"] == "Example Calibration Lab" and lab["address"] == "1 Bench Street"
    assert lab["customer"] == "ACME Navigation" and lab["item"] == "gyro pack 4711"    # the command line wins
    assert lab["certificate_number_pattern"] == "CAL-{year}-{run_id}"
    equipment = json.loads(lab["equipment_json"])
    assert [(e["tag"], e["certificate"], e["due_date"]) for e in equipment] == [
        ("TT-01", "NIM-TT-01", IN_DATE), ("REF-T", "NIM-REF-T", OVERDUE)]
    run_id = read_log(str(lab_run.log), messages=False).metadata["run"]["run_id"]
    with open_records(str(lab_run.db)) as records:
        assert [e.tag for e in run_equipment(records, run_id)] == ["REF-T", "TT-01"]
    rc, out, _ = cli(["db", "--db", str(lab_run.db), "equipment", "list", "--run", run_id])
    assert rc == 0 and [line.split()[0] for line in out.splitlines()[1:-1]] == ["REF-T", "TT-01"]


def test_overdue_or_unknown_equipment_refuses_the_run_when_configured(lab_run, tmp_path):
    db = tmp_path / "records.sqlite"
    shutil.copy(lab_run.db, db)
    for equipment, refuse, words in ((["TT-01", "REF-T"], True, "REF-T (temperature"),
                                     (["TT-01", "NOPE"], False, "'NOPE' is not in the register")):
        config = tmp_path / "bench.toml"
        config.write_text(config_text(dwell_s=1.0) + _lab(equipment, refuse), encoding="utf-8")
        rc, _, stderr = cli(["run", "--config", str(config), "--out", str(tmp_path / "out"), "--quiet",
                             "--db", str(db)])
        assert rc == 2 and stderr.count("\n") == 1 and words in stderr and "nothing moved" in stderr, stderr
        assert not (tmp_path / "out").exists()
    config.write_text(config_text(dwell_s=1.0) + _lab(["TT-01"], refuse=True), encoding="utf-8")
    rc, _, stderr = cli(["run", "--config", str(config), "--out", str(tmp_path / "out"), "--quiet", "--no-db"])
    assert rc == 2 and "cannot be checked: --no-db" in stderr


def test_review_then_sign_in_the_audit_trail(lab_run, tmp_path):
    db = tmp_path / "records.sqlite"
    shutil.copy(lab_run.db, db)
    run_id = read_log(str(lab_run.log), messages=False).metadata["run"]["run_id"]
    base = ["cert", "--db", str(db)]
    rc, _, err = cli([*base, "sign", run_id, "--signer", "carol", "--role", "technical manager"])
    assert rc == 2 and err.count("\n") == 1 and "is not reviewed" in err
    rc, out, _ = cli([*base, "review", run_id, "--reviewer", "bob", "--note", "residuals fine"])
    assert rc == 0 and f"review of run {run_id}" in out and "by bob: residuals fine" in out
    rc, out, _ = cli([*base, "sign", run_id, "--signer", "carol", "--role", "technical manager"])
    assert rc == 0 and "by carol (technical manager)" in out
    rc, out, _ = cli([*base, "trail", run_id])
    assert [line.split()[1] for line in out.splitlines()[:-1]] == ["review", "sign"]
    with open_records(str(db)) as records:
        truth = next(r.result_id for r in records.results_of(run_id) if r.truth)
        assert {e.result_id for e in audit_trail(records, run_id)} == {truth}
    for argv, words in (([*base, "review", "no-such-run", "--reviewer", "bob"], "no run 'no-such-run'"),
                        ([*base, "sign", run_id, "--signer", " ", "--role", "x"], "must not be empty")):
        rc, _, err = cli(argv)
        assert rc == 2 and err.count("\n") == 1 and words in err


def test_a_run_without_a_result_is_not_reviewed(cli_run_log, tmp_path):
    log = tmp_path / cli_run_log.name
    shutil.copy(cli_run_log, log)                   # the run's log alone: recorded, but no result
    db = tmp_path / "records.sqlite"
    assert cli(["db", "--db", str(db), "import", str(log), "--quiet"])[0] == 0
    run_id = read_log(str(log), messages=False).metadata["run"]["run_id"]
    rc, _, err = cli(["cert", "--db", str(db), "review", run_id, "--reviewer", "bob"])
    assert rc == 2 and err.count("\n") == 1 and "has no result to review" in err


def test_a_run_is_linked_only_to_the_registered_equipment_its_log_names(tmp_path):
    from bench.records.ingest import equipment_used
    from bench.records.store import RunInfo

    lab = {"equipment_json": json.dumps([{"tag": "TT-01", "serial": "S-TT-01"}, {"tag": "CH-01", "serial": "old"},
                                         {"tag": "REF-T"}, {"tag": "NOPE", "serial": "1"}, "junk", {"serial": "2"}])}
    used = equipment_used(lab)
    assert used == (("TT-01", "S-TT-01"), ("CH-01", "old"), ("REF-T", ""), ("NOPE", "1"))
    assert equipment_used({"equipment_json": "{not json"}) == () == equipment_used({"equipment_json": '{"a": 1}'})
    with open_records(str(tmp_path / "r.sqlite")) as records:
        for tag, kind in (("TT-01", "turntable"), ("CH-01", "chamber"), ("REF-T", "temperature")):
            add_equipment(records, Equipment(tag, kind, "Acme", "M", f"S-{tag}", "C", TODAY), "ann")
        records.add_run(RunInfo("r1", "M", "S1", equipment=used))
        # CH-01 is registered for another serial than the run's log recorded: not what the run used
        assert [e.tag for e in run_equipment(records, "r1")] == ["REF-T", "TT-01"]
        assert not records.add_run(RunInfo("r1", "M", "S1", equipment=used))      # nothing new the second time


def test_the_tui_refuses_overdue_equipment_as_bench_run_does(lab_run, tmp_path, monkeypatch):
    monkeypatch.setenv("BENCH_DB", str(tmp_path / "records.sqlite"))     # the TUI checks the default database
    shutil.copy(lab_run.db, tmp_path / "records.sqlite")
    config = tmp_path / "bench.toml"
    config.write_text(config_text(dwell_s=1.0) + _lab(["TT-01", "REF-T"], refuse=True), encoding="utf-8")
    rc, _, stderr = cli(["tui", "--config", str(config), "--out", str(tmp_path / "out")])
    assert rc == 2 and stderr.count("\n") == 1 and "REF-T (temperature" in stderr and "nothing moved" in stderr
