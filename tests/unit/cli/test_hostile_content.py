"""Hostile content in files the bench reads (issue 34 items 5 and 6): one line, never a traceback.

Labels (`T²-P01`, `T` + 5,000 digits), an out-of-range start date, thermal steps with 10**400, 1e999 or
NaN, JSON files named by a configuration ([table] check, [acceptance] reference, [imu] noise) holding
such numbers or nested deep; chamber states whose alarm texts are 1 MB each are cut before they are
parsed in bulk.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest

from bench.config.load import ConfigError, parse_config
from bench.files import InputFileError, parse_json
from bench.log.events import Event
from bench.log.json_topics import chamber_state_row, event_row, parse_json_rows, utc_text_ok
from bench.log.reader import read_log
from bench.plan.steps import thermal_block
from bench.thermal.from_log import _setpoints
from tests.helpers import mcap_surgery as ms
from tests.helpers.run import cli

BIG = "1" + "0" * 400


@pytest.fixture(scope="module")
def short_log(short_run) -> Path:
    return short_run.log


def _relabel(new: str):
    def edit(topic: str, data: bytes) -> bytes:
        if topic != "/events":
            return data
        event = json.loads(data)
        if event.get("step_unit") != "P01":
            return data
        return json.dumps({**event, "step_unit": new}).encode()
    return edit


@pytest.mark.slow
@pytest.mark.parametrize("label", ["T²-P01", "T" + "1" * 5000], ids=["superscript", "5000-digits"])
def test_a_hostile_step_label_is_no_traceback_in_solve(short_log, tmp_path, label):
    log = ms.rewrite(short_log, tmp_path / "label.mcap", _relabel(label))
    rc, _, err = cli(["solve", str(log), "--out", str(tmp_path / "out"), "--quiet", "--no-db"])
    assert rc in (0, 4) and "Traceback" not in err, err
    assert thermal_block(label) is None and thermal_block("T12-P03") == 12 and thermal_block("T٣-P01") is None


@pytest.mark.slow
def test_a_start_date_that_is_no_utc_date_is_damage_not_a_traceback(short_log, tmp_path):
    when = "0001-01-01T00:00:00+05:00"
    log = ms.rewrite(short_log, tmp_path / "date.mcap",
                     metadata=lambda name, data: {**data, "started_utc": when} if name == "run" else data)
    read = read_log(log)
    assert "started_utc" not in read.metadata["run"]
    assert any("run.started_utc" in line and "not a date" in line for line in read.scan().damage), read.scan().damage
    rc, _, err = cli(["solve", str(log), "--out", str(tmp_path / "out"), "--quiet"])   # the records database on
    assert rc in (0, 4) and "Traceback" not in err, err
    assert not utc_text_ok(when) and utc_text_ok("2026-11-24T02:49:01Z") and not utc_text_ok("x" * 100)


def _set_temperature(index, setpoint) -> dict:
    return {"kind": "step_started", "time_s": 1.0, "state": "running", "step_index": 0, "step_unit": "T1",
            "data": {"step": {"kind": "set_temperature", "index": 0, "unit": "T1", "temperature_index": index,
                              "setpoint_c": setpoint}}}


@pytest.mark.parametrize("index, setpoint", [(1, 10 ** 400), (math.inf, 20.0), (1, math.nan), (1, math.inf),
                                             (10 ** 30, 20.0)],
                         ids=["setpoint-10^400", "index-inf", "setpoint-nan", "setpoint-inf", "index-10^30"])
def test_thermal_steps_with_numbers_out_of_range_are_left_out(short_log, index, setpoint):
    row = _set_temperature(index, setpoint)
    assert event_row(row) is None       # the log's boundary: such an event is malformed
    log = dataclasses.replace(read_log(short_log), events=[Event.from_dict(row)])
    assert _setpoints([log]) == {}      # and the reader of setpoints takes none of them
    assert _setpoints([dataclasses.replace(log, events=[Event.from_dict(_set_temperature(2, -20))])]) == {2: -20.0}


def test_nan_and_infinity_in_a_log_message_make_it_malformed():
    rows, bad = parse_json_rows([b'{"a": 1}', b'{"a": NaN}', b'{"a": -Infinity}'])
    assert bad == 2 and rows[0] == {"a": 1}
    state = {"time_s": 1.0, "temperature_c": 1e999, "setpoint_c": 20.0, "alarms": 0, "alarm_text": "",
             "running": True}
    assert chamber_state_row(state) is None and chamber_state_row({**state, "temperature_c": None}) is not None
    assert chamber_state_row({**state, "setpoint_c": 10 ** 400}) is None


# -- JSON files a configuration names -------------------------------------------------------------------------

BASE = ('format = "turntable-bench/config"\nversion = 1\n[site]\nlatitude_deg = 30.27\n[table]\nurl = "sim"\n'
        'dialect = "scpi"\n{table}\n[imu]\ninterface = "virtual"\nchannel = "t"\nrate_hz = 200.0\n{imu}\n'
        '[plan]\npositions = "optimal-24"\n{acceptance}')
CHECK = {"format": "turntable-bench/table-check", "correlation": [[1.0, 0.0], [0.0, 1.0]],
         "combinations": [{"coefficients": {"alpha_o": 1.0}, "value_arcsec": 12.0, "sigma_arcsec": 0.5},
                          {"coefficients": {"beta_o": 1.0}, "value_arcsec": -3.0, "sigma_arcsec": 0.5}]}


def _with(doc: dict, path: tuple, raw: str) -> str:
    copy = json.loads(json.dumps(doc))
    target = copy
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = "@@"
    return json.dumps(copy).replace('"@@"', raw)


@pytest.mark.parametrize("path, raw", [
    (("correlation", 1, 0), BIG), (("correlation", 0, 1), "-1e300"), (("correlation", 0, 1), "1e999"),
    (("combinations", 0, "sigma_arcsec"), "[" * 5000 + "]" * 5000), (("combinations", 0, "value_arcsec"), "1" * 5000),
    (("combinations", 1, "coefficients", "beta_o"), "1e300"), (("combinations", 0, "value_arcsec"), "NaN"),
], ids=["10^400", "-1e300", "1e999", "deep", "5000-digits", "coefficient-1e300", "nan"])
def test_a_table_check_file_with_hostile_numbers_is_a_config_error(tmp_path, path, raw):
    check = tmp_path / "t.table-check.json"
    check.write_text(_with(CHECK, path, raw), encoding="utf-8")
    with pytest.raises(ConfigError, match="table.check") as info:
        parse_config(BASE.format(table=f'check = "{check}"', imu="", acceptance=""))
    assert len(str(info.value)) < 400 and "\n" not in str(info.value)


@pytest.mark.parametrize("field, raw", [("k", BIG), ("value", BIG), ("sigma", "1e999"), ("value", "NaN")])
def test_a_reference_result_with_hostile_numbers_is_a_config_error(short_log, tmp_path, field, raw):
    result = json.loads(next(short_log.parent.glob("*.result.json")).read_text(encoding="utf-8"))
    name = next(iter(result["coefficients"]))
    reference = tmp_path / "old.result.json"
    reference.write_text(_with(result, ("coefficients", name, field), raw), encoding="utf-8")
    with pytest.raises(ConfigError, match="acceptance.reference"):
        parse_config(BASE.format(table="", imu="", acceptance=f'[acceptance]\nreference = "{reference}"\n'))


@pytest.mark.parametrize("raw", [BIG, "1e999", "NaN", "[" * 5000 + "]" * 5000])
def test_a_noise_file_with_hostile_numbers_is_a_config_error(tmp_path, raw):
    noise = tmp_path / "n.noise.json"
    noise.write_text('{"format": "turntable-bench/noise", "rate_hz": ' + raw + "}", encoding="utf-8")
    with pytest.raises(ConfigError, match="imu.noise"):
        parse_config(BASE.format(table="", imu=f'noise = "{noise}"', acceptance=""), base_dir=tmp_path)


def test_parse_json_is_the_one_boundary_for_numbers():
    for raw, why in ((BIG, "an integer of 401 digits"), ("1e999", "beyond the range"), ("NaN", "NaN is not"),
                     ("[" * 5000 + "]" * 5000, "nested too deeply"), ("{", "invalid JSON")):
        with pytest.raises(InputFileError, match=why):
            parse_json(raw, "f.json")
    assert parse_json('{"a": [1, 2.5, -3e-300, 123456789012345678901234567890]}', "f") == {
        "a": [1, 2.5, -3e-300, 123456789012345678901234567890]}


@pytest.mark.slow
@pytest.mark.parametrize("time_s", [math.nan, 1e300, -1e300], ids=["nan", "1e300", "-1e300"])
@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_export_can_leaves_out_frames_whose_time_is_no_time(short_log, tmp_path, time_s, suffix):
    seen: list[int] = []

    def forge(topic: str, data: bytes) -> bytes:
        if topic != "/can/raw" or seen:
            return data
        seen.append(1)
        return ms.can_frames(5, 8, 0x100, time_s)

    log = ms.rewrite(short_log, tmp_path / "frames.mcap", forge)
    out = tmp_path / f"frames{suffix}"
    rc, stdout, err = cli(["export-can", str(log), "--out", str(out)])
    assert rc == 0 and "Traceback" not in err, err
    assert err.count("\n") == 1 and "5 frames whose recorded time is no time" in err, err
    assert out.stat().st_size > 0 and sorted(p.name for p in tmp_path.iterdir()) == sorted(["frames.mcap", out.name])


# -- item 6: long text fields are cut before they are held or parsed in bulk ----------------------------------

def _chamber_log(path: Path, states: int, text_bytes: int) -> Path:
    from mcap.writer import CompressionType, Writer

    with open(path, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD, chunk_size=4 << 20)
        writer.start(profile="", library="tests")
        channel = writer.register_channel("/chamber/state", "json", 0)
        for k in range(states):
            state = {"time_s": float(k), "temperature_c": 25.0, "setpoint_c": 25.0, "ramp_c_per_min": None,
                     "running": True, "alarms": 1, "alarm_text": "x" * text_bytes}
            writer.add_message(channel, k * 1_000_000_000, json.dumps(state).encode(), k * 1_000_000_000)
        writer.finish()
    return path


@pytest.mark.slow
def test_chamber_states_with_1_mb_alarm_texts_are_cut_as_they_are_read(tmp_path):
    """200 states of 1 MB each (a file of ~1 MB: the text compresses) were held, joined and parsed whole:
    three copies of 200 MB at once. Cut as they are gathered, the read holds about one message at a time."""
    import tracemalloc

    log_path = _chamber_log(tmp_path / "alarms.mcap", 200, 1 << 20)
    tracemalloc.start()
    try:
        log = read_log(log_path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(log.chamber_states) == 200
    assert {len(s.alarm_text) for s in log.chamber_states} == {500}
    assert peak < 64 << 20, f"{peak / 2 ** 20:.0f} MiB traced at the peak"


def test_a_design_matrix_with_nan_is_a_solver_error_not_a_linalg_error():
    """Found by fuzz/hostile_files.py: a thermal log whose table states hold null in every message gave
    `LinAlgError: SVD did not converge` in bench solve."""
    import numpy as np

    from bench.solve.methods import SolverError, _require_rank

    design = np.ones((6, 4))
    design[2, 1] = np.nan
    with pytest.raises(SolverError, match="not all finite"):
        _require_rank(design, "rotation schedule")
