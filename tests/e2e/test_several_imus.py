"""Several IMUs in one simulated run (issue 31): three units on two faces and two buses, each solved in its own
body axes from its own topics; `bench solve` reproduces every unit's result bit for bit."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from bench.log.events import RunListener, StepStarted
from bench.log.reader import read_log
from tests.helpers.run import cli, only_file

UNITS = (("A1", "bus-a", 0, '"z-up"'), ("A2", "bus-a", 16, '"x-up"'), ("B1", "bus-b", 0, '"y-down"'))


def several_config(units=UNITS, black_box_arcsec: float = 20.0) -> str:
    entries = "".join(
        f'[[imu]]\ninterface = "virtual"\nchannel = "{bus}"\nrate_hz = 200.0\nid_offset = {offset}\n'
        f'mounting = {mounting}\nidentity = {{ model = "sim", serial = "{serial}" }}\n\n'
        for serial, bus, offset, mounting in units)
    return f"""format = "turntable-bench/config"
version = 1
[site]
latitude_deg = 30.0
[table]
url = "sim"
dialect = "scpi"

{entries}[plan]
positions = "traditional-12"
rotations = "traditional-3s6r"
dwell_s = 2.0
settle_s = 1.0
turn_rate_dps = 20.0
revolutions = 1
[sim]
seed = 3
black_box_arcsec = {black_box_arcsec}
noise = true
"""


@pytest.fixture(scope="module")
def several_run(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("several")
    config = folder / "several.toml"
    config.write_text(several_config(), encoding="utf-8")
    rc, out, err = cli(["run", "--config", str(config), "--out", str(folder / "run"), "--db",
                        str(folder / "records.sqlite"), "--quiet"])
    assert rc == 0, err
    assert "unit A2: verdict" in out and "unit B1: verdict" in out
    return only_file(folder / "run", "*.mcap")


def unit_result(log: Path, serial: str, solved: bool = False) -> dict:
    name = f"{log.stem}.{serial}{'.solved' if solved else ''}.result.json"
    return json.loads((log.parent / name).read_text(encoding="utf-8"))


def test_each_unit_recovers_its_own_truth_within_its_uncertainty(several_run):
    truths, within = [], 0
    for serial, *_ in UNITS:
        result = unit_result(several_run, serial)
        assert result["run"]["imu"] == {"model": "sim", "serial": serial}
        coefficients, truth = result["coefficients"], result["sim_truth"]["coefficients"]
        truths.append(tuple(truth[name]["value"] for name in sorted(truth)))
        for name, entry in coefficients.items():
            error = abs(entry["value"] - truth[name]["value"])
            assert error <= 2.0 * entry["expanded"], f"{serial} {name}: error {error:.3g}, U {entry['expanded']:.3g}"
            within += error <= entry["expanded"]
    assert within >= 0.85 * 30 * len(UNITS)            # k = 2: about 95 % within U
    assert len(set(truths)) == len(UNITS)               # every unit its own truth


def test_each_unit_is_on_its_own_topics_with_its_identity_and_mounting(several_run):
    log = read_log(several_run)
    topics = set(log.message_counts)
    assert {"/can/raw", "/imu/samples", "/imu/A2/can/raw", "/imu/A2/samples", "/imu/B1/can/raw",
            "/imu/B1/samples"} <= topics
    assert not any(topic.startswith("/imu/A1/") for topic in topics)     # the reference unit: a single IMU's topics
    units = json.loads(log.metadata["units"]["units_json"])
    assert [(u["serial"], u["bus"], u["id_offset"], u["mounting"]) for u in units] == [
        ("A1", "virtual:bus-a", 0, "z-up"), ("A2", "virtual:bus-a", 16, "x-up"), ("B1", "virtual:bus-b", 0, "y-down")]
    assert units[1]["frame_ids"][0] == "0x110" and units[1]["mounting_matrix"] == [[0, 0, 1], [1, 0, 0], [0, 1, 0]]
    for serial, *_ in UNITS:               # each unit's result, attached to the log as it was written
        name = f"{several_run.stem}.{serial}.result.json"
        assert json.loads(log.attachments[name][1]) == unit_result(several_run, serial)
    assert log.scan().complete
    a2 = read_log(several_run, unit="A2")
    frames = a2.read_can_frames()
    assert len(frames.ids) and set(frames.ids.tolist()) == {0x110 + k for k in range(7)}   # its own ids, offset
    # /can/raw is the reference unit's: A1's frames only (A2's, on the same bus-a, are on A2's topic), none of B1's
    reference = log.read_can_frames().ids
    assert set(reference.tolist()) == {0x100 + k for k in range(7)}
    b1 = read_log(several_run, unit="B1").read_can_frames().ids
    assert set(b1.tolist()) == {0x100 + k for k in range(7)} and len(reference) == len(b1)


def test_bench_solve_reproduces_every_unit_bit_for_bit(several_run, tmp_path):
    rc, out, err = cli(["solve", str(several_run), "--out", str(tmp_path), "--no-db", "--no-html"])
    assert rc == 0, err
    for serial, *_ in UNITS:
        assert f"unit {serial}: result:" in out
        run, solved = unit_result(several_run, serial), json.loads(
            (tmp_path / f"{several_run.stem}.{serial}.solved.result.json").read_text(encoding="utf-8"))
        assert solved["coefficients"] == run["coefficients"], serial
    assert not list(tmp_path.glob("*.html"))       # --no-html holds for every unit
    rc, out, err = cli(["solve", str(several_run), "--out", str(tmp_path / "one"), "--no-db", "--no-html",
                        "--unit", "B1"])
    assert rc == 0 and [p.name for p in (tmp_path / "one").glob("*.result.json")] == [
        f"{several_run.stem}.B1.solved.result.json"]
    rc, _, err = cli(["solve", str(several_run), "--no-db", "--unit", "C9"])
    assert rc == 2 and "no unit 'C9'" in err and "(its units: A1, A2, B1)" in err


def test_bench_solve_of_several_units_takes_model_and_refuses_against(several_run, tmp_path):
    rc, out, err = cli(["solve", str(several_run), "--out", str(tmp_path), "--no-db", "--no-html", "--unit", "A2",
                        "--model", "gyro_g_sensitivity"])
    assert rc in (0, 4), err
    solved = json.loads((tmp_path / f"{several_run.stem}.A2.solved.result.json").read_text(encoding="utf-8"))
    assert "Gg_Xx" in json.dumps(solved)        # the family asked for is solved for the unit
    assert "Gg_Xx" not in json.dumps(unit_result(several_run, "A2"))
    rc, _, err = cli(["solve", str(several_run), "--out", str(tmp_path / "against"), "--no-db",
                      "--against", str(tmp_path / f"{several_run.stem}.A2.solved.result.json")])
    assert rc == 2 and "several IMUs: --against" in err and len(err.strip().splitlines()) == 1


def test_a_silent_unit_gets_no_result_saying_why_and_the_others_are_finished(tmp_path):
    from bench.config.load import parse_config
    from bench.run.devices import SIMULATOR
    from bench.run.runner import BenchRun, compile_from_config

    config = parse_config(several_config(UNITS[:2], black_box_arcsec=0.0), source="two.toml")
    with BenchRun(config, compile_from_config(config), devices=SIMULATOR, out_dir=tmp_path) as run:
        run.open()
        assert run.world is not None
        run.world.units[0].drop_frames(10 ** 9)           # unit A2 sends nothing at all
        run.run()
        outcome = run.finish()
    assert outcome.result is not None and outcome.result.run.imu.serial == "A1"
    silent = outcome.units["A2"]
    assert silent.result is None and silent.result_path is None
    assert silent.failures and silent.failures[0].startswith("unit A2 has no result: ")
    assert not (tmp_path / f"{run.run_id}.A2.result.json").exists()


def test_the_reference_unit_is_solved_bit_for_bit_as_a_single_imu_of_the_same_plan(several_run, tmp_path):
    """The other units change nothing of the reference unit's run: a single [imu] with its bus, truth and seed
    gives the very same coefficients and uncertainties."""
    single = several_config(UNITS[:1]).replace("[[imu]]", "[imu]").replace("id_offset = 0\n", "").replace(
        'mounting = "z-up"\n', "")
    config = tmp_path / "single.toml"
    config.write_text(single, encoding="utf-8")
    rc, _, err = cli(["run", "--config", str(config), "--out", str(tmp_path / "run"), "--no-db", "--quiet"])
    assert rc == 0, err
    alone = json.loads(only_file(tmp_path / "run", "*.result.json").read_text(encoding="utf-8"))
    assert alone["coefficients"] == unit_result(several_run, "A1")["coefficients"]


def test_unit_is_refused_for_a_log_of_one_imu(short_run, tmp_path):
    rc, _, err = cli(["solve", str(short_run.log), "--out", str(tmp_path), "--no-db", "--unit", "A1"])
    assert rc == 2 and "records one IMU, not several ([[imu]]): drop --unit" in err


def test_each_unit_is_a_record_of_its_own_in_the_records(several_run, tmp_path):
    """`bench run` recorded every unit, `<run-id>.<serial>` of its run, as `bench db import` of its files does;
    `bench solve` adds each unit's re-solve to that unit's record; a certificate is of one unit (--unit)."""
    from bench.records.store import open_records

    run_id, serials = several_run.stem, [serial for serial, *_ in UNITS]
    imported = tmp_path / "imported.sqlite"
    rc, _, err = cli(["db", "--db", str(imported), "import", str(several_run.parent), "--quiet"])
    assert rc == 0, err
    for db in (several_run.parent.parent / "records.sqlite", imported):
        with open_records(str(db), create=False) as records:
            assert records.units_of_run(run_id) == [(f"{run_id}.{serial}", serial) for serial in serials]
            for serial in serials:
                rows = records.list_runs(serial=serial)
                assert [row.run_id for row in rows] == [f"{run_id}.{serial}"], db
                truth = [r for r in records.results_of(f"{run_id}.{serial}") if r.truth]
                assert len(truth) == 1 and truth[0].origin == "run"
                assert Path(truth[0].path).name == f"{run_id}.{serial}.result.json"
            assert not records.run_known(run_id)            # the run is its units' records, none of its own
    rc, out, _ = cli(["db", "--db", str(imported), "list"])
    assert rc == 0 and all(f"{run_id}.{serial}" in out for serial in serials)
    rc, out, _ = cli(["db", "--db", str(imported), "results", run_id, "--unit", "A2"])
    assert rc == 0 and out.startswith(f"results of run {run_id}.A2 ")
    rc, _, err = cli(["db", "--db", str(imported), "results", run_id])
    assert rc == 2 and "calibrated 3 units (A1, A2, B1): name one with --unit SERIAL" in err
    rc, out, err = cli(["solve", str(several_run), "--out", str(tmp_path / "solved"), "--db", str(imported),
                        "--no-html", "--unit", "B1"])
    assert rc == 0, err
    with open_records(str(imported), create=False) as records:
        assert sorted(r.origin for r in records.results_of(f"{run_id}.B1")) == ["re-solve", "run"]
        assert [r.origin for r in records.results_of(f"{run_id}.A2")] == ["run"]
    base = ["cert", "--db", str(imported)]
    for argv, words in (([*base, "review", run_id, "--reviewer", "bob"],
                         f"run '{run_id}' calibrated 3 units (A1, A2, B1): name one with --unit SERIAL"),
                        ([*base, "issue", run_id, "--out", str(tmp_path / "cert")], "name one with --unit SERIAL"),
                        ([*base, "review", run_id, "--unit", "C9", "--reviewer", "bob"], "has no unit 'C9' recorded")):
        rc, _, err = cli(argv)
        assert rc == 2 and err.count("\n") == 1 and words in err, err
    assert cli([*base, "review", run_id, "--unit", "A2", "--reviewer", "bob"])[0] == 0
    assert cli([*base, "sign", f"{run_id}.A2", "--signer", "carol", "--role", "technical manager"])[0] == 0
    rc, out, err = cli([*base, "issue", run_id, "--unit", "A2", "--out", str(tmp_path / "cert")])
    assert rc == 0, err
    rc, out, _ = cli([*base, "trail", run_id, "--unit", "A2"])
    assert rc == 0 and out.splitlines()[-1] == "2 entries" and f"of run {run_id}.A2 " in out


class _SilenceAt(RunListener):
    """Silences a simulated unit (it sends nothing more; `garble`: every frame with a bad CRC) when step `index`
    starts: a unit that fails mid-run."""

    def __init__(self, run, index: int, garble: bool = False) -> None:
        self.run, self.index, self.garble = run, index, garble

    def on_event(self, event) -> None:
        if isinstance(event, StepStarted) and event.step_index == self.index:
            unit = self.run.world.units[0]
            (unit.corrupt_crc if self.garble else unit.drop_frames)(10 ** 9)


def _run_silencing_a2(tmp_path: Path, on_unit_failure: str, garble: bool = False):
    """A run of A1 and A2 with [run] on_unit_failure, A2 silenced (or garbled) when the plan's 30th step starts."""
    from bench.config.load import parse_config
    from bench.run.devices import SIMULATOR
    from bench.run.runner import BenchRun, compile_from_config

    text = several_config(UNITS[:2], black_box_arcsec=0.0) + f'[run]\non_unit_failure = "{on_unit_failure}"\n'
    config = parse_config(text, source="two.toml")
    assert config.on_unit_failure == on_unit_failure
    plan = compile_from_config(config)
    assert len(plan.steps) > 40
    run = BenchRun(config, plan, devices=SIMULATOR, out_dir=tmp_path)
    run.extra_listeners.append(_SilenceAt(run, 30, garble))
    with run:
        run.open()
        state = run.run()
        outcome = run.finish()
    return run, state, outcome


def test_a_unit_silenced_mid_run_is_dropped_and_the_others_finish(tmp_path):
    run, state, outcome = _run_silencing_a2(tmp_path, "continue")
    assert state.value == "done" and outcome.error is None
    assert outcome.result is not None and outcome.result.run.imu.serial == "A1"
    assert outcome.verdict is not None and not outcome.verdict.failed         # the reference unit finished
    silent = outcome.units["A2"]
    assert silent.result is None and not (tmp_path / f"{run.run_id}.A2.result.json").exists()
    assert len(silent.failures) == 1
    assert silent.failures[0].startswith("unit A2 has no result: dropped from the run at ")
    quiet_s = float(re.search(r"\(silent: no sample for ([0-9.]+) s\)$", silent.failures[0]).group(1))
    assert quiet_s > 2.0                                                # longer than the IMU timeout
    log = read_log(run.log_path)
    warnings = [e for e in log.events if e.message.startswith("unit A2 dropped from the run: silent")]
    assert len(warnings) == 1 and warnings[0].step_index is not None and warnings[0].step_index >= 30
    assert log.scan().complete                                      # the log was closed whole
    rc, out, err = cli(["solve", str(run.log_path), "--out", str(tmp_path / "solved"), "--no-db", "--no-html"])
    assert rc == 4 and "unit A1: result:" in out and "unit A2 has no result: dropped from the run at" in err


def test_a_unit_that_fails_stops_the_run_when_configured(tmp_path):
    run, state, outcome = _run_silencing_a2(tmp_path, "stop")
    assert state.value == "failed" and outcome.result is None
    assert str(outcome.error).startswith("unit A2 failed: silent: no sample for ")
    assert str(outcome.error).endswith('([run] on_unit_failure = "stop")')
    log = read_log(run.log_path)
    assert log.scan().complete                                      # closed, not cut off
    messages = [e.message for e in log.events]
    assert messages[-2:] == ["table stopped and servos off", "run ended early; table stopped"]   # the safe stop
    assert sum(m.startswith("UnitFailed: unit A2 failed: silent") for m in messages) == 2       # fault, transition


def test_a_unit_sending_only_garbage_is_dropped_saying_so(tmp_path):
    _, state, outcome = _run_silencing_a2(tmp_path, "continue", garble=True)
    assert state.value == "done" and outcome.result is not None and outcome.units["A1"].result is not None
    why = outcome.units["A2"].failures[0]
    assert outcome.units["A2"].result is None and why.startswith("unit A2 has no result: dropped from the run at ")
    garbled = int(re.search(r"no valid sample for [0-9.]+ s, (\d+) garbled frame\(s\) of its ids", why).group(1))
    assert garbled > 0


# -- two units on one bus (issue 31: a shared bus's other unit is not the reference unit's fault) ----------------

#: an id no configured unit sends (A1 sends 0x100.., A2 0x110..)
STRAY_ID = 0x7AB


class _StrayFrameAt(RunListener):
    """Sends one frame of an id no unit has on the shared bus when step `index` starts."""

    def __init__(self, run, index: int) -> None:
        self.run, self.index = run, index

    def on_event(self, event) -> None:
        import can

        if isinstance(event, StepStarted) and event.step_index == self.index:
            world = self.run.world
            world.sender_bus.send(can.Message(arbitration_id=STRAY_ID, is_extended_id=False, data=bytes(8),
                                              timestamp=world.clock.now()))


def _shared_bus_run(folder: Path, stray: bool = False):
    """A short run of A1 and A2 on one bus (A2's ids offset by 16), with a stray frame injected or not."""
    from bench.config.load import parse_config
    from bench.run.devices import SIMULATOR
    from bench.run.runner import BenchRun, compile_from_config

    text = several_config(UNITS[:2]).replace("dwell_s = 2.0", "dwell_s = 0.5").replace(
        "settle_s = 1.0", "settle_s = 0.2").replace("turn_rate_dps = 20.0", "turn_rate_dps = 60.0")
    config = parse_config(text, source="shared.toml")
    run = BenchRun(config, compile_from_config(config), devices=SIMULATOR, out_dir=folder)
    if stray:
        run.extra_listeners.append(_StrayFrameAt(run, 3))
    with run:
        run.open()
        state = run.run()
        outcome = run.finish()
    assert state.value == "done" and outcome.error is None
    return run.log_path


@pytest.fixture(scope="module")
def shared_bus_run(tmp_path_factory) -> Path:
    return _shared_bus_run(tmp_path_factory.mktemp("shared"), stray=False)


def _link(log: Path, serial: str) -> dict:
    return unit_result(log, serial)["run"]["imu_link"]


def test_units_sharing_a_bus_are_not_each_others_faults(shared_bus_run):
    log = read_log(shared_bus_run)
    link_warnings = [e.message for e in log.events if e.message.startswith("IMU link:")]
    assert not [m for m in link_warnings if " 0 unknown id" not in m], link_warnings[:3]
    for serial in ("A1", "A2"):
        link = _link(shared_bus_run, serial)
        assert link["unknown_id"] == 0 and link["frames"] == link["frames_ok"] > 0, (serial, link)


def test_each_frame_of_a_shared_bus_is_recorded_once(shared_bus_run):
    """/can/raw holds the reference unit's frames only, /imu/A2/can/raw A2's: no frame in both."""
    reference = read_log(shared_bus_run).read_can_frames().ids
    a2 = read_log(shared_bus_run, unit="A2").read_can_frames().ids
    assert set(reference.tolist()) == {0x100 + k for k in range(7)}
    assert set(a2.tolist()) == {0x110 + k for k in range(7)}
    assert _link(shared_bus_run, "A1")["frames"] == len(reference) and _link(shared_bus_run, "A2")["frames"] == len(a2)


def test_bench_solve_of_a_shared_bus_reproduces_each_unit_and_its_link(shared_bus_run, tmp_path):
    rc, _, err = cli(["solve", str(shared_bus_run), "--out", str(tmp_path), "--no-db", "--no-html"])
    assert rc == 0, err
    for serial in ("A1", "A2"):
        run = unit_result(shared_bus_run, serial)
        solved = json.loads((tmp_path / f"{shared_bus_run.stem}.{serial}.solved.result.json").read_text("utf-8"))
        assert solved["coefficients"] == run["coefficients"], serial
        assert solved["run"]["imu_link"] == run["run"]["imu_link"], serial


def test_a_frame_of_no_unit_on_a_shared_bus_is_still_an_unknown_id(tmp_path):
    """The reference unit (the bus's first) counts it, warns of it, and records it: it is evidence."""
    log_path = _shared_bus_run(tmp_path, stray=True)
    log = read_log(log_path)
    warnings = [e for e in log.events if e.message.startswith("IMU link:")]
    assert warnings and all(e.details["imu_stats"]["unknown_id"] == 1 for e in warnings)
    assert _link(log_path, "A1")["unknown_id"] == 1 and _link(log_path, "A2")["unknown_id"] == 0
    assert log.read_can_frames().ids.tolist().count(STRAY_ID) == 1
    assert STRAY_ID not in read_log(log_path, unit="A2").read_can_frames().ids.tolist()


def test_an_older_log_with_the_whole_bus_in_can_raw_decodes_without_faults(tmp_path, monkeypatch):
    """A log written before the receivers took only their own frames: the reference unit's /can/raw is its bus as
    received (A2's frames too) and the units record has no frame_keys. Its decode leaves A2's frames to A2 (by the
    units record), in the run's own result as in `bench solve`."""
    import bench.run.devices
    import bench.run.units

    whole_bus = bench.run.units.unit_shares

    def old_record(unit, reference):
        record = original(unit, reference)
        del record["frame_keys"]
        return record

    original = bench.run.units.unit_record
    monkeypatch.setattr(bench.run.devices, "unit_shares", lambda config: [None, *whole_bus(config)[1:]])
    monkeypatch.setattr(bench.run.units, "unit_record", old_record)
    log_path = _shared_bus_run(tmp_path)
    log = read_log(log_path)
    assert "frame_keys" not in log.metadata["units"]["units_json"]
    assert set(log.read_can_frames().ids.tolist()) == {0x100 + k for k in range(7)} | {0x110 + k for k in range(7)}
    assert _link(log_path, "A1")["unknown_id"] == 0
    rc, _, err = cli(["solve", str(log_path), "--out", str(tmp_path / "solved"), "--no-db", "--no-html"])
    assert rc == 0, err
    for serial in ("A1", "A2"):
        solved = json.loads((tmp_path / "solved" / f"{log_path.stem}.{serial}.solved.result.json").read_text("utf-8"))
        run = unit_result(log_path, serial)
        assert solved["run"]["imu_link"] == run["run"]["imu_link"] and solved["run"]["imu_link"]["unknown_id"] == 0
        assert solved["coefficients"] == run["coefficients"], serial
