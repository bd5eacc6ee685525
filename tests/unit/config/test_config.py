"""Bench configuration: the example and the built-in sim config load; every kind of bad
file gives one ConfigError line naming the file, line and key; the TOML line locator."""

from __future__ import annotations

import json
import math
import os
import pickle
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.config.load import SIM_CONFIG_TOML, BenchConfig, ConfigError, default_sim_config, load_config, parse_config
from bench.model.imu import NoiseModel, default_sim_imu
from bench.model.units import ARCSEC, format_hms
from bench.run.runner import compile_from_config
from drivers.imu import DEFAULT_FD_DBC, DEFAULT_FD_SPEC, default_fd_layout, default_layout, default_packed_layout
from drivers.turntable import AxisLimits
from drivers.turntable.modbus_map import RegisterMap
from schedules import builtin_path
from schedules.tomllines import leaf_paths, locate_lines

REPO_ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = REPO_ROOT / "bench.example.toml"

# Line numbers below are asserted exactly: keep this text's layout.
BASE = """\
format = "turntable-bench/config"
version = 1

[site]
latitude_deg = 30.27

[table]
url = "tcp://127.0.0.1:5000"
dialect = "scpi"

[table.limits.outer]
max_rate_dps = 50.0

[imu]
interface = "virtual"
channel = "test"
rate_hz = 200.0

[plan]
positions = "optimal-24"
rotations = "optimal-5s6r"
"""


def parse(text: str, **kw) -> BenchConfig:
    return parse_config(text, source="bench.toml", **kw)


def error_of(text: str, **kw) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        parse(text, **kw)
    return info.value


def edit(old: str, new: str, text: str = BASE) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


# --- good files ---------------------------------------------------------------------

def test_example_loads_and_applies_every_section():
    config = load_config(EXAMPLE)
    assert config.path == EXAMPLE and config.source_text == EXAMPLE.read_text(encoding="utf-8")
    assert (config.site.latitude_deg, config.site.height_m, config.site.local_g_mps2) == (30.27, 12.0, None)
    assert config.site.site.latitude_deg == 30.27 and config.site.site.height_m == 12.0
    table = config.table
    assert (table.url, table.is_sim, table.dialect, table.timeout_s, table.retries) == ("sim", True, "scpi", 0.5, 2)
    assert table.limits.axes == (AxisLimits(None, None, 100.0, 50.0),) * 3 and table.register_map is None
    imu = config.imu
    assert imu.layout.messages == default_layout().messages and imu.rate_hz == 200.0 and imu.fd is False
    assert imu.bus_kwargs() == {"interface": "virtual", "channel": "turntable-bench-example", "fd": False,
                                "receive_own_messages": False}
    assert (imu.identity.model, imu.identity.serial, imu.identity.gyro_bias_stability_dph,
            imu.identity.acc_bias_stability_ug) == ("example FOG IMU", "EX-0001", 0.003, 5.0)
    plan = config.plan
    assert (plan.positions.name, len(plan.positions.positions)) == ("optimal-24", 24)
    assert (plan.rotations.name, len(plan.rotations.rotations)) == ("optimal-5s6r", 6)
    assert (plan.dwell_s, plan.settle_s, plan.turn_rate_dps, plan.rest_s, plan.order) == (60, 5, 10, 2, "optimal")
    assert config.output.folder == Path("runs")
    truth = config.sim.imu.to_canonical()
    assert truth["D0_x"] == pytest.approx(0.05) and truth["K0_z"] == pytest.approx(2e-4)
    assert truth["Eg_Yx"] == pytest.approx(6e-4, rel=1e-12)
    assert truth["Kg_y"] == pytest.approx(default_sim_imu().to_canonical()["Kg_y"])
    np.testing.assert_allclose(np.linalg.norm(config.sim.imu.gyro_axes, axis=1), 1.0, rtol=1e-15)
    assert config.sim.noise == NoiseModel()
    assert config.sim.black_box_arcsec == 20.0


EXAMPLE_KEYS = """format version latitude_deg height_m local_g_mps2 url dialect timeout_s retries
settle_tolerance_deg poll_s register_map unit encoding angle_scale_deg rate_scale_dps word_order watchdog_s
max_rate_dps max_accel_dps2 min_deg max_deg interface channel bitrate fd layout dbc slcan_client rate_hz gyro_x
gyro_y gyro_z acc_x acc_y acc_z temperature status counter crc model serial gyro_bias_stability_dph
acc_bias_stability_ug
positions rotations dwell_s settle_s move_rate_dps move_accel_dps2 turn_rate_dps turn_accel_dps2 rest_s
revolutions order folder seed black_box_arcsec noise enabled gyro_arw_deg_rt_h gyro_bias_instability_dph
acc_vrw_ug_rt_hz acc_bias_instability_ug correlation_time_s quantise chunk_run_interval_s reference_c
time_constant_s ambient_c initial_c Kg_x""".split()
EXAMPLE_TABLES = """site table table.modbus table.limits.outer table.limits.middle table.limits.inner imu
imu.signals imu.bus_options imu.identity plan output sim sim.noise sim.imu sim.imu.thermal""".split()


def test_example_shows_every_key_and_table_with_a_comment():
    text = EXAMPLE.read_text(encoding="utf-8")
    for key in EXAMPLE_KEYS:
        assert re.search(rf"^#? *{key} = .*#", text, re.M), key
    for name in EXAMPLE_TABLES:
        assert re.search(rf"^#? *\[{re.escape(name)}\]", text, re.M), name


def test_builtin_sim_config():
    config = default_sim_config()
    assert config.source_text == SIM_CONFIG_TOML and config.path is None
    assert config.site.latitude_deg == 30.27
    assert (config.table.url, config.table.dialect) == ("sim", "scpi")
    assert (config.imu.interface, config.imu.channel, config.imu.rate_hz) == ("virtual", "turntable-bench-sim", 200)
    assert config.plan.positions.name == "optimal-24" and config.plan.rotations.name == "optimal-5s6r"
    assert {step.revolutions for step in config.plan.rotations.rotations} == {1}
    assert (config.plan.dwell_s, config.plan.settle_s, config.plan.turn_rate_dps) == (60, 5, 10)
    assert config.sim.seed == 0 and config.sim.noise == NoiseModel()
    expected = np.random.default_rng(0).standard_normal((3, 3)) * 20 * ARCSEC
    np.testing.assert_array_equal(config.sim.black_box_rad, expected)


def test_defaults_of_a_minimal_file():
    config = parse(BASE)
    assert config.site.height_m == 0 and config.site.site.gravity == pytest.approx(9.7932, abs=1e-3)
    assert config.table.limits.axes[0] == AxisLimits(None, None, 50.0, 50.0)
    assert config.table.limits.axes[1:] == (AxisLimits(),) * 2
    assert (config.table.timeout_s, config.table.retries, config.table.settle_tolerance_deg,
            config.table.poll_s) == (0.5, 2, 0.001, 0.05)
    assert config.imu.dbc.name == "sim_imu.dbc" and config.imu.bitrate is None and config.imu.bus_options == {}
    plan = config.plan
    assert (plan.dwell_s, plan.settle_s, plan.move_rate_dps, plan.move_accel_dps2, plan.turn_rate_dps,
            plan.turn_accel_dps2, plan.rest_s, plan.revolutions, plan.order) == (60, 5, 20, 10, 10, 5, 2, None,
                                                                                 "optimal")
    assert config.output.folder == Path("runs") and config.output.chunk_run_interval_s is None
    assert config.sim.seed == 0 and config.sim.black_box_arcsec == 20.0 and config.sim.imu_overrides == {}
    assert config.sim.imu.to_canonical() == pytest.approx(default_sim_imu().to_canonical(), rel=1e-12)


def test_fd_bus_defaults_to_the_fd_layout_and_a_classic_bus_refuses_fd_frames():
    config = parse(edit("rate_hz = 200.0", "rate_hz = 200.0\nfd = true\nbitrate = 500000"))
    assert config.imu.layout.messages == default_fd_layout().messages and config.imu.spec == DEFAULT_FD_SPEC
    assert config.imu.bus_kwargs() == {"interface": "virtual", "channel": "test", "fd": True, "bitrate": 500000}
    signals = "\n".join(f'{column} = "{ref}"' for column, ref in DEFAULT_FD_SPEC.channels.items())
    err = error_of(edit("rate_hz = 200.0", f'rate_hz = 200.0\ndbc = "{DEFAULT_FD_DBC}"\n[imu.signals]\n{signals}'))
    assert (err.line, err.key) == (18, "imu.dbc")
    assert "message IMU_SAMPLE_FD of sim_imu_fd.dbc is a CAN FD frame (64 bytes); set imu.fd = true" in err.message


def test_a_shipped_layout_by_name_and_the_slcan_reader():
    config = parse(edit("rate_hz = 200.0", 'rate_hz = 200.0\nlayout = "packed"'))
    assert config.imu.layout.messages == default_packed_layout().messages and config.imu.layout_name == "packed"
    assert config.imu.dbc.name == "sim_imu_packed.dbc" and len(config.imu.layout.messages) == 3
    assert parse(BASE).imu.layout_name == "classic"
    slcan = parse(edit('interface = "virtual"\nchannel = "test"', 'interface = "slcan"\nchannel = "/dev/ttyACM0"'))
    assert slcan.imu.bus_kwargs() == {"interface": "slcan", "channel": "/dev/ttyACM0", "fd": False,
                                      "slcan_client": "bench"}
    slcan = parse(edit('interface = "virtual"\nchannel = "test"',
                       'interface = "slcan"\nchannel = "/dev/ttyACM0"\nslcan_client = "python-can"'))
    assert slcan.imu.bus_kwargs()["slcan_client"] == "python-can"
    assert "slcan_client" not in parse(BASE).imu.bus_kwargs()     # not a python-can option: only for slcan
    err = error_of(edit("rate_hz = 200.0", 'rate_hz = 200.0\nlayout = "packed"\ndbc = "x.dbc"'))
    assert (err.line, err.key) == (18, "imu.layout") and "give one" in err.message
    err = error_of(edit("rate_hz = 200.0", 'rate_hz = 200.0\nlayout = "compact"'))
    assert (err.line, err.key) == (18, "imu.layout") and "expected one of classic, packed, fd" in err.message
    err = error_of(edit("rate_hz = 200.0", 'rate_hz = 200.0\nlayout = "fd"'))
    assert (err.line, err.key) == (18, "imu.layout") and "set imu.fd = true" in err.message
    err = error_of(edit("rate_hz = 200.0", 'rate_hz = 200.0\nslcan_client = "fast"'))
    assert (err.line, err.key) == (18, "imu.slcan_client") and "expected one of bench, python-can" in err.message


# --- errors ---------------------------------------------------------------------------

ERRORS = [
    # (edit old, edit new, line, key, message fragment)
    ("latitude_deg = 30.27\n", "", 4, "site.latitude_deg", "missing required key"),
    ('latitude_deg = 30.27', 'latitude_deg = "thirty"', 5, "site.latitude_deg",
     "must be a finite number, got the string 'thirty'"),
    ("rate_hz = 200.0", "rate_hz = true", 17, "imu.rate_hz", "got true (a boolean)"),
    ("latitude_deg = 30.27", "latitude_deg = 91", 5, "site.latitude_deg", "must be <= 90 deg, got 91"),
    ("rate_hz = 200.0", "rate_hz = 0", 17, "imu.rate_hz", "must be > 0 Hz"),
    ('rotations = "optimal-5s6r"', 'rotations = "optimal-5s6r"\ndwel_s = 3', 22, "plan.dwel_s",
     "unknown key (did you mean 'dwell_s'?)"),
    ('rotations = "optimal-5s6r"', 'rotations = "optimal-5s6r"\nfrobnicate = 3', 22, "plan.frobnicate",
     "unknown key (known: positions, rotations, dwell_s"),
    ("[site]", "[sitee]", 4, "sitee", "unknown key (did you mean 'site'?)"),
    ('dialect = "scpi"', 'dialect = "scpy"', 9, "table.dialect", "unknown dialect 'scpy' (did you mean 'scpi'?)"),
    ('dialect = "scpi"', 'dialect = "acme"', 9, "table.dialect",
     "unknown dialect 'acme' (known dialects: scpi, mn, modbus, acutrol)"),
    ('positions = "optimal-24"', 'positions = "optimal-25"', 20, "plan.positions",
     "no builtin schedule 'optimal-25' and no such file"),
    ('positions = "optimal-24"', 'positions = "optimal-5s6r"', 20, "plan.positions",
     "schedule 'optimal-5s6r' is a 'rotations' schedule; plan.positions needs a 'positions' schedule"),
    ('rotations = "optimal-5s6r"', 'rotations = "traditional-12"', 21, "plan.rotations", "is a 'positions'"),
    ('positions = "optimal-24"\nrotations = "optimal-5s6r"\n', 'positions = ""\n', 19, "plan",
     "the plan needs a positions schedule, a rotations schedule or both"),
    ('rotations = "optimal-5s6r"', 'rotations = "optimal-5s6r"\nturn_rate_dps = 60', 22, "plan.turn_rate_dps",
     "60 deg/s exceeds the outer axis limit 50 deg/s (table.limits.outer.max_rate_dps)"),
    ('rotations = "optimal-5s6r"', 'rotations = "optimal-5s6r"\nmove_accel_dps2 = 70', 22, "plan.move_accel_dps2",
     "70 deg/s^2 exceeds the outer axis limit 50 deg/s^2"),
    ('rotations = "optimal-5s6r"', 'rotations = "optimal-5s6r"\nrevolutions = 0', 22, "plan.revolutions",
     "must be >= 1"),
    ('rotations = "optimal-5s6r"', 'rotations = "optimal-5s6r"\norder = "fast"', 22, "plan.order",
     "got 'fast', expected one of optimal, listed"),
    ('rotations = "optimal-5s6r"', 'rotations = "optimal-5s6r"\nrevolutions = 1.5', 22, "plan.revolutions",
     "must be a whole number, got 1.5"),
    ('format = "turntable-bench/config"', 'format = "turntable-bench/schedule"', 1, "format",
     "expected 'turntable-bench/config', got 'turntable-bench/schedule'"),
    ('format = "turntable-bench/config"\n', "", None, "format", "missing required key"),
    ("version = 1", "version = 2", 2, "version", "unsupported version: must be 1, got 2"),
    ("version = 1", 'version = "1"', 2, "version", "unsupported version: must be 1, got the string '1'"),
    ("[imu]\ninterface", "[imux]\ninterface", 14, "imux", "unknown key (did you mean 'imu'?)"),
    ('interface = "virtual"', 'interface = "socketcann"', 15, "imu.interface",
     "unknown python-can interface 'socketcann' (did you mean 'socketcan'?)"),
    ('channel = "test"', "channel = []", 16, "imu.channel", "must be a non-empty string or a whole number"),
    ('url = "tcp://127.0.0.1:5000"', 'url = "modbus+tcp://127.0.0.1:502"', 8, "table.url",
     "is a Modbus url but table.dialect is 'scpi'"),
    ('dialect = "scpi"', 'dialect = "modbus"', 8, "table.url", "the modbus dialect needs a modbus+tcp://"),
    ('dialect = "scpi"', 'dialect = "scpi"\nretries = -1', 10, "table.retries", "must be >= 0"),
    ('dialect = "scpi"', 'dialect = "scpi"\nregister_map = "map.toml"', 10, "table.register_map",
     "a register map is for the modbus dialect only"),
    ("max_rate_dps = 50.0", "max_rate_dps = 50.0\nmin_deg = 10\nmax_deg = -10", 14, "table.limits.outer.max_deg",
     "must be above min_deg (10 deg), got -10"),
    ("[table.limits.outer]", "[table.limits.outter]", 11, "table.limits.outter", "did you mean 'outer'?"),
    ("latitude_deg = 30.27", "latitude_deg = 30.27\nlocal_g_mps2 = 98.1", 6, "site.local_g_mps2",
     "must be <= 9.9 m/s^2"),
    ("rate_hz = 200.0", "rate_hz = 200.0\n[imu.bus_options]\nchannel = 'x'", 19, "imu.bus_options.channel",
     "set imu.channel instead"),
    ("rate_hz = 200.0", 'rate_hz = 200.0\n[imu.signals]\ngyro_x = "IMU_GYRO_X.GyroX"', 18, "imu.signals",
     "the IMU signal mapping lacks gyro_y"),
    ("rate_hz = 200.0", "rate_hz = 200.0\nsignals = 3", 18, "imu.signals", "must be a table"),
    ("[plan]", "[output]\nfolder = 3\n[plan]", 20, "output.folder", "must be a string, got 3"),
    ("[plan]", "[output]\nchunk_run_interval_s = 0\n[plan]", 20, "output.chunk_run_interval_s", "must be > 0 s"),
    ("rate_hz = 200.0", "rate_hz = = 200.0", 17, None, "invalid TOML: Invalid value (column 11)"),
    ('channel = "test"', 'channel = "test', 16, None, "invalid TOML"),
]


@pytest.mark.parametrize("old, new, line, key, fragment", ERRORS, ids=[f"{e[3]}-{i}" for i, e in enumerate(ERRORS)])
def test_bad_configuration_gives_one_located_line(old, new, line, key, fragment):
    err = error_of(edit(old, new))
    assert (err.path, err.line, err.key) == ("bench.toml", line, key), str(err)
    assert fragment in err.message, str(err)
    assert "\n" not in str(err)
    head = "bench.toml" if line is None else f"bench.toml:{line}"
    assert str(err) == ": ".join([head] + ([key] if key else []) + [err.message])


def test_missing_section_has_no_line():
    err = error_of(edit('[imu]\ninterface = "virtual"\nchannel = "test"\nrate_hz = 200.0\n', ""))
    assert (err.line, err.key, err.message) == (None, "imu", "missing required table [imu]")
    assert str(err) == "bench.toml: imu: missing required table [imu]"


def test_config_error_is_a_picklable_value_error():
    err = ConfigError("a.toml", 3, "plan.dwell_s", "must be\n> 0")
    assert isinstance(err, ValueError) and str(err) == "a.toml:3: plan.dwell_s: must be > 0"
    again = pickle.loads(pickle.dumps(err))
    assert (again.path, again.line, again.key, again.message, str(again)) == (
        "a.toml", 3, "plan.dwell_s", "must be > 0", str(err))


# --- files and paths --------------------------------------------------------------------

def test_unreadable_files(tmp_path):
    missing = tmp_path / "nope.toml"
    with pytest.raises(ConfigError) as info:
        load_config(missing)
    assert (info.value.path, info.value.line, info.value.key) == (str(missing), None, None)
    assert str(info.value) == f"{missing}: cannot read the configuration file: No such file or directory"
    with pytest.raises(ConfigError, match="cannot read the configuration file: Is a directory"):
        load_config(tmp_path)
    latin1 = tmp_path / "latin1.toml"
    latin1.write_bytes(BASE.encode() + b"# caf\xe9\n")
    with pytest.raises(ConfigError) as info:
        load_config(latin1)
    assert info.value.path == str(latin1) and "not UTF-8 text" in info.value.message


def test_load_config_names_the_file_in_errors(tmp_path):
    path = tmp_path / "bench.toml"
    path.write_text(edit("latitude_deg = 30.27", "latitude_deg = -95"), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == f"{path}:5: site.latitude_deg: must be >= -90 deg, got -95"


SCHEDULE = """\
format = "turntable-bench/schedule"
version = 1
name = "mine"
kind = "positions"
description = "two positions"

[[position]]
angles_deg = [0, 0, 0]

[[position]]
angles_deg = [0, 0, 180]
"""


def test_relative_paths_start_at_the_config_folder(tmp_path, monkeypatch):
    folder = tmp_path / "bench"
    (folder / "plans").mkdir(parents=True)
    (folder / "plans" / "mine.toml").write_text(SCHEDULE, encoding="utf-8")
    (folder / "imu.dbc").write_text(Path(default_layout().source).read_text(encoding="utf-8"), encoding="utf-8")
    text = edit('positions = "optimal-24"', 'positions = "plans/mine.toml"')
    text = edit("rate_hz = 200.0", 'rate_hz = 200.0\ndbc = "imu.dbc"', text)
    text += '\n[output]\nfolder = "results"\n'
    (folder / "bench.toml").write_text(text, encoding="utf-8")
    monkeypatch.chdir(tmp_path)  # not the config's folder
    config = load_config("bench/bench.toml")
    assert config.plan.positions.name == "mine" and len(config.plan.positions.positions) == 2
    assert Path(config.plan.positions.source).resolve() == (folder / "plans" / "mine.toml").resolve()
    assert config.imu.dbc.resolve() == (folder / "imu.dbc").resolve()
    assert config.imu.layout.messages == default_layout().messages
    assert config.output.folder == Path("results")  # relative to the cwd at run time, left as written
    # The same text parsed elsewhere does not find them.
    err = error_of(text, base_dir=tmp_path)
    assert (err.line, err.key) == (18, "imu.dbc") and "cannot read the DBC file" in err.message
    err = error_of(edit('dbc = "imu.dbc"\n', "", text), base_dir=tmp_path)
    assert (err.line, err.key) == (20, "plan.positions") and "no such file" in err.message


def test_a_bad_schedule_file_is_reported_where_its_error_is(tmp_path):
    (tmp_path / "mine.toml").write_text(edit("angles_deg = [0, 0, 180]", "angles_deg = [0, 0, 45]", SCHEDULE),
                                        encoding="utf-8")
    err = error_of(edit('positions = "optimal-24"', 'positions = "mine.toml"'), base_dir=tmp_path)
    assert (err.path, err.line, err.key) == (str(tmp_path / "mine.toml"), 11, "position[2].angles_deg")
    assert "not a multiple of 90 deg" in err.message


@pytest.mark.parametrize("dbc_text, fragment", [
    ("this is not a DBC file", "is not a readable DBC file"),
    ('VERSION ""\n\nBU_: IMU\n', "has no message 'IMU_GYRO_X'"),
])
def test_bad_dbc_is_reported_at_the_dbc_key(tmp_path, dbc_text, fragment):
    (tmp_path / "bad.dbc").write_text(dbc_text, encoding="utf-8")
    err = error_of(edit("rate_hz = 200.0", 'rate_hz = 200.0\ndbc = "bad.dbc"'), base_dir=tmp_path)
    assert (err.path, err.line, err.key) == ("bench.toml", 18, "imu.dbc") and fragment in err.message, str(err)


def test_missing_dbc_file_is_reported_at_the_dbc_key(tmp_path):
    err = error_of(edit("rate_hz = 200.0", 'rate_hz = 200.0\ndbc = "gone.dbc"'), base_dir=tmp_path)
    assert (err.line, err.key) == (18, "imu.dbc") and "cannot read the DBC file" in err.message


def test_signal_mapping_errors_point_at_the_signals_table():
    signals = 'gyro_x = "IMU_GYRO_X.GyroX"\ngyro_y = "IMU_GYRO_Y.Nope"\ngyro_z = "IMU_GYRO_Z.GyroZ"\n' \
              'acc_x = "IMU_ACC_X.AccX"\nacc_y = "IMU_ACC_Y.AccY"\nacc_z = "IMU_ACC_Z.AccZ"'
    err = error_of(edit("rate_hz = 200.0", f"rate_hz = 200.0\n\n[imu.signals]\n{signals}"))
    assert (err.line, err.key) == (19, "imu.signals") and "has no gyro_y signal 'Nope'" in err.message


# --- register maps --------------------------------------------------------------------------

MODBUS_BASE = edit('url = "tcp://127.0.0.1:5000"\ndialect = "scpi"',
                   'url = "modbus+tcp://127.0.0.1:5020"\ndialect = "modbus"')


def test_inline_register_map():
    text = edit('dialect = "modbus"', 'dialect = "modbus"\n[table.modbus]\nunit = 3\nencoding = "float32"\n'
                '[table.modbus.registers]\nstatus = [100, 101, 102]', MODBUS_BASE)
    config = parse(text)
    assert config.table.register_map == RegisterMap(unit=3, encoding="float32", status=(100, 101, 102))
    assert parse(MODBUS_BASE).table.register_map is None


@pytest.mark.parametrize("lines, line, key, fragment", [
    ("[table.modbus]\nunit = 300", 11, "table.modbus.unit", "must be 0-255, got 300"),
    ("[table.modbus]\nunits = 3", 11, "table.modbus.units", "unknown key (known: angle_scale_deg"),
    ("[table.modbus.registers]\nstatus = [0, 1]", 11, "table.modbus.registers.status",
     "must be three addresses (outer, middle, inner), got [0, 1]"),
    ("[table.modbus.fault_codes]\n0 = 'x'", 11, "table.modbus.fault_codes.0", "must be 1-65535"),
    ("[table.modbus.registers]\nstatus = [8, 9, 10]", 10, "table.modbus", "status"),  # overlap: no one key
])
def test_inline_register_map_errors(lines, line, key, fragment):
    err = error_of(edit('dialect = "modbus"', f'dialect = "modbus"\n{lines}', MODBUS_BASE))
    assert (err.path, err.line, err.key) == ("bench.toml", line, key), str(err)
    assert fragment in err.message and not err.message.startswith("bench.toml"), str(err)


def test_register_map_file(tmp_path):
    (tmp_path / "map.toml").write_text("# my table\n[modbus]\nunit = 7\nword_order = 'little'\n", encoding="utf-8")
    text = edit('dialect = "modbus"', 'dialect = "modbus"\nregister_map = "map.toml"', MODBUS_BASE)
    config = parse(text, base_dir=tmp_path)
    assert config.table.register_map == RegisterMap(unit=7, word_order="little")
    assert config.table.register_map.source == str(tmp_path / "map.toml")
    (tmp_path / "map.toml").write_text("# my table\n[modbus]\nunit = 7\nword_order = 'middle'\n", encoding="utf-8")
    err = error_of(text, base_dir=tmp_path)
    assert (err.path, err.line, err.key) == (str(tmp_path / "map.toml"), 4, "modbus.word_order"), str(err)
    assert err.message == "must be one of ('big', 'little'), got 'middle'"
    (tmp_path / "map.toml").write_text("[modbus]\nunit = 7\n[other]\n", encoding="utf-8")
    err = error_of(text, base_dir=tmp_path)
    assert (err.line, err.key) == (3, "other")
    (tmp_path / "map.toml").write_text("[modbus]\nunit = \n", encoding="utf-8")
    err = error_of(text, base_dir=tmp_path)
    assert (err.path, err.line) == (str(tmp_path / "map.toml"), 2) and "invalid TOML" in err.message
    err = error_of(edit('"map.toml"', '"gone.toml"', text), base_dir=tmp_path)
    assert (err.path, err.line, err.key) == ("bench.toml", 10, "table.register_map")
    both = edit('register_map = "map.toml"', 'register_map = "map.toml"\n[table.modbus]\nunit = 2', text)
    assert error_of(both, base_dir=tmp_path).message.startswith("give either register_map")


# --- plan and [sim] ---------------------------------------------------------------------------

def test_revolutions_override_every_rotation():
    config = parse(edit('rotations = "optimal-5s6r"', 'rotations = "optimal-5s6r"\nrevolutions = 3\norder = "listed"'))
    assert {step.revolutions for step in config.plan.rotations.rotations} == {3}
    assert config.plan.revolutions == 3 and config.plan.order == "listed"
    assert parse(edit('positions = "optimal-24"\n', "")).plan.positions is None


def test_sim_overrides():
    text = BASE + """
[sim]
seed = 7
black_box_arcsec = [[10, -5, 3], [4, 12, -8], [-6, 2, 15.5]]

[sim.noise]
gyro_arw_deg_rt_h = 0.01
quantise = false

[sim.imu]
Kg_x = 36000.0
D0_z = -0.5
Eg_Zx = 1e-3
Ea_Xy = 2e-4
Ea_Yy = 0.9
Ea_Zy = 0.4358898943540674
"""
    sim = parse(text).sim
    assert sim.seed == 7 and sim.black_box_arcsec == ((10, -5, 3), (4, 12, -8), (-6, 2, 15.5))
    np.testing.assert_array_equal(sim.black_box_rad, np.array(sim.black_box_arcsec) * ARCSEC)
    assert sim.noise == NoiseModel(gyro_arw_deg_rt_h=0.01, quantise=False)
    truth = sim.imu.to_canonical()
    assert truth["Kg_x"] == pytest.approx(36000.0) and truth["D0_z"] == pytest.approx(-0.5)
    assert truth["Eg_Zx"] == 1e-3 and truth["Eg_Yx"] == default_sim_imu().to_canonical()["Eg_Yx"]
    assert truth["Eg_Xx"] == pytest.approx(np.sqrt(1 - 1e-6 - truth["Eg_Yx"] ** 2), rel=1e-15)
    assert (truth["Ea_Xy"], truth["Ea_Yy"]) == pytest.approx((2e-4, 0.9), rel=1e-6)
    np.testing.assert_allclose(np.linalg.norm(sim.imu.acc_axes, axis=1), 1.0, rtol=1e-15)
    assert sim.imu_overrides["D0_z"] == -0.5 and len(sim.imu_overrides) == 6


def test_black_box_rms_draw_depends_on_the_seed():
    def draw(seed, rms):
        return parse(BASE + f"[sim]\nseed = {seed}\nblack_box_arcsec = {rms}\n").sim.black_box_rad
    np.testing.assert_array_equal(draw(3, 50), np.random.default_rng(3).standard_normal((3, 3)) * 50 * ARCSEC)
    assert not np.array_equal(draw(3, 50), draw(4, 50))
    assert not draw(0, 0).any()


def test_noise_switches():
    assert parse(BASE + "[sim]\nnoise = false\n").sim.noise == NoiseModel.off()
    assert parse(BASE + "[sim]\nnoise = true\n").sim.noise == NoiseModel()
    off_quantised = parse(BASE + "[sim.noise]\nenabled = false\nquantise = true\n").sim.noise
    assert off_quantised == NoiseModel(0, 0, 0, 0, 300.0, True)


SIM_ERRORS = [
    ("[sim]\nseed = -1", 24, "sim.seed", "must be >= 0"),
    ("[sim]\nblack_box_arcsec = -3", 24, "sim.black_box_arcsec", "must be >= 0 arcsec"),
    ("[sim]\nblack_box_arcsec = [[1, 2, 3], [4, 5, 6]]", 24, "sim.black_box_arcsec", "must be 3 rows"),
    ("[sim]\nblack_box_arcsec = [\n  [1, 2, 3],\n  [4, 5],\n  [7, 8, 9],\n]", 26, "sim.black_box_arcsec[1]",
     "must be 3 finite angles [alpha, beta, gamma] in arcsec, got [4, 5]"),
    ("[sim]\nnoise = 'yes'", 24, "sim.noise", "must be a table ([sim.noise]), got the string 'yes'"),
    ("[sim.noise]\ngyro_arw = 0.1", 24, "sim.noise.gyro_arw", "did you mean 'gyro_arw_deg_rt_h'?"),
    ("[sim.noise]\nenabled = false\nacc_vrw_ug_rt_hz = 3", 25, "sim.noise.acc_vrw_ug_rt_hz",
     "noise levels need sim.noise.enabled = true"),
    ("[sim.noise]\ncorrelation_time_s = 0", 24, "sim.noise.correlation_time_s", "must be > 0"),
    ("[sim.imu]\nD0_X = 0.1", 24, "sim.imu.D0_X", "unknown key (did you mean 'D0_x'?)"),
    ("[sim.imu]\nKg_y = -36000", 24, "sim.imu.Kg_y", "must be > 0"),
    ("[sim.imu]\nEa_Xz = 0.8\nEa_Yz = 0.8", 24, "sim.imu.Ea_Xz", "leave no unit row"),
    ("[sim.imu]\nEg_Xx = 1.0\nEg_Yx = 0.1", 24, "sim.imu.Eg_Xx", "must have unit length"),
    ("[sim]\nseeds = 1", 24, "sim.seeds", "did you mean 'seed'?"),
]


@pytest.mark.parametrize("lines, line, key, fragment", SIM_ERRORS, ids=[e[2] for e in SIM_ERRORS])
def test_sim_errors(lines, line, key, fragment):
    err = error_of(BASE + "\n" + lines + "\n")
    assert (err.line, err.key) == (line, key), str(err)
    assert fragment in err.message, str(err)


# --- the line locator (schedules.tomllines) -------------------------------------------------

def test_every_value_of_the_shipped_files_has_its_line():
    texts = [EXAMPLE.read_text(encoding="utf-8"), SIM_CONFIG_TOML]
    texts += [builtin_path(name).read_text(encoding="utf-8") for name in ("all-96", "optimal-24")]
    for text in texts:
        lines, raw = locate_lines(text), text.splitlines()
        for path in leaf_paths(tomllib.loads(text)):
            line = lines.exact(*path)
            assert line is not None, path
            key = next(p for p in reversed(path) if isinstance(p, str))
            assert key in raw[line - 1] or isinstance(path[-1], int), (path, raw[line - 1])


TRICKY = '''\
a = 1 # c
"b.c".'d' = "x#y" # comment [x]
s = """ml
[not]
x = 1"""
arr = [
  [1, 2], # c
  [3, 4],
]
inl = { p = 1, q.r = { s = 's' }, t = [ {u = 1}, {u = 2} ] }
[t1]
k = 2020-01-01 10:00:00
[[f]]
n = 1
[[f.v]]
w = 1
[[f.v]]
w = 2
[[f]]
n = 2
[t1.sub]
z = """a"""""
zz = \'\'\'b\'\'\'\'\'
e = {}
"esc\\u0041" = 1
'''


def test_tricky_toml_lines():
    lines = locate_lines(TRICKY)
    expected = {("a",): 1, ("b.c", "d"): 2, ("s",): 3, ("arr", 0, 0): 7, ("arr", 1, 1): 8,
                ("inl", "q", "r", "s"): 10, ("inl", "t", 1, "u"): 10, ("t1",): 11, ("t1", "k"): 12,
                ("f", 0, "n"): 14, ("f", 0, "v", 0, "w"): 16, ("f", 0, "v", 1, "w"): 18, ("f", 1): 19,
                ("f", 1, "n"): 20, ("t1", "sub"): 21, ("t1", "sub", "z"): 22, ("t1", "sub", "zz"): 23,
                ("t1", "sub", "e"): 24, ("t1", "sub", "escA"): 25}
    assert {path: lines.exact(*path) for path in expected} == expected
    assert set(leaf_paths(tomllib.loads(TRICKY))) <= set(lines.lines)
    assert lines.line("t1", "sub", "missing") == 21 and lines.line("nowhere") is None


# A tiny TOML writer that knows where it puts each value, to check the locator against.
_TEXT = st.text(st.sampled_from("ab #[]{}=,.'\"\\\n\té"), max_size=8)
_KEY = st.one_of(st.from_regex(r"[a-z][a-z0-9_-]{0,5}", fullmatch=True), _TEXT.filter(lambda k: "\n" not in k))
_SCALAR = st.one_of(st.integers(-10**6, 10**6), st.floats(allow_nan=False, allow_infinity=False), st.booleans(),
                    _TEXT)


def _key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key, ensure_ascii=False)


def _scalar(value, style: int) -> str:
    if isinstance(value, str):
        if style == 1 and "'" not in value and "\n" not in value:
            return f"'{value}'"
        if style == 2:
            body = value.replace("\\", "\\\\").replace('"', '\\"')
            return f'"""{body}"""'
        return json.dumps(value, ensure_ascii=False)
    return json.dumps(value)  # ints, floats and true/false read the same in TOML


@st.composite
def documents(draw):
    """(text, {path: line}) for a random document with tables, arrays, inline tables."""
    out, expected = [], {}

    def emit(line: str, paths=()) -> None:
        start = sum(chunk.count("\n") + 1 for chunk in out) + 1  # paths are written first on the line
        out.append(line)
        for path in paths:
            expected[path] = start

    def body(prefix: tuple, n: int) -> None:
        for key in draw(st.lists(_KEY, min_size=n, max_size=4, unique=True)):
            path, kind = prefix + (key,), draw(st.integers(0, 3))
            if kind == 0:
                emit(f"{_key(key)} = {_scalar(draw(_SCALAR), draw(st.integers(0, 2)))}  # {draw(_TEXT)!r}", [path])
            elif kind == 1:  # a multi-line array, one element per line
                values = draw(st.lists(_SCALAR, min_size=1, max_size=3))
                emit(f"{_key(key)} = [  # opens", [path])
                for i, value in enumerate(values):
                    emit(f"  {_scalar(value, draw(st.integers(0, 2)))},", [path + (i,)])
                emit("]")
            elif kind == 2:  # an inline table
                inner = draw(st.lists(_KEY, min_size=1, max_size=3, unique=True))
                items = ", ".join(f"{_key(k)} = {_scalar(draw(_SCALAR), 0)}" for k in inner)
                emit(f"{_key(key)} = {{ {items} }}", [path + (k,) for k in inner])
            else:  # a dotted key
                sub = draw(_KEY)
                emit(f"{_key(key)}.{_key(sub)} = {_scalar(draw(_SCALAR), 0)}", [path + (sub,)])

    body((), 0)
    for name in draw(st.lists(_KEY, max_size=3, unique=True)):
        emit(f"\n[{_key('top-' + name)}]  # a table")
        body(("top-" + name,), 1)
    return "\n".join(out) + "\n", expected


@pytest.mark.slow
@settings(max_examples=250, deadline=None)
@given(documents())
def test_locator_finds_what_a_writer_wrote(doc):
    text, expected = doc
    try:
        parsed = tomllib.loads(text)
    except tomllib.TOMLDecodeError:  # e.g. a dotted key clashing with an earlier key
        return
    lines = locate_lines(text)
    assert {path: lines.exact(*path) for path in expected} == expected
    assert set(leaf_paths(parsed)) <= set(lines.lines)


# --- input limits (issue 13 item 8) ----------------------------------------------------------

def test_format_hms_of_durations_that_are_not_finite():
    assert (format_hms(3725.4), format_hms(-5.0), format_hms(0.4)) == ("1:02:05", "0:00:00", "0:00:00")
    assert (format_hms(math.inf), format_hms(math.nan), format_hms(-math.inf)) == ("?:??:??", "?:??:??", "0:00:00")
    assert format_hms(1e30).endswith(":24:16")


DIGITS_400 = "1" + "0" * 399
PLAN_LINE = 'rotations = "optimal-5s6r"'

LIMIT_ERRORS = [
    # (text, line, key, message fragment): every numeric key has a range
    (edit(PLAN_LINE, f"{PLAN_LINE}\ndwell_s = 1e308"), 22, "plan.dwell_s", "must be <= 86400 s, got 1e+308"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\ndwell_s = 86401"), 22, "plan.dwell_s", "must be <= 86400 s"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\ndwell_s = 0"), 22, "plan.dwell_s", "must be > 0 s"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\nsettle_s = 3601"), 22, "plan.settle_s", "must be <= 3600 s"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\nrest_s = -1"), 22, "plan.rest_s", "must be >= 0 s"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\nturn_rate_dps = 1e-300"), 22, "plan.turn_rate_dps",
     "must be >= 0.001 deg/s, got 1e-300"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\nmove_rate_dps = 1001"), 22, "plan.move_rate_dps", "must be <= 1000 deg/s"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\nturn_accel_dps2 = 0"), 22, "plan.turn_accel_dps2", "must be >= 0.001 deg/s^2"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\nmove_accel_dps2 = 1e5"), 22, "plan.move_accel_dps2", "must be <= 10000 deg/s^2"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\nrevolutions = 1000000000000"), 22, "plan.revolutions",
     "must be <= 100, got 1000000000000"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\nrevolutions = {DIGITS_400}"), 22, "plan.revolutions",
     "must be <= 100, got 1.000e+399 (a 400-digit integer)"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\nrevolutions = 'many'"), 22, "plan.revolutions",
     "must be a whole number, got the string 'many' (allowed: 1 <= revolutions <= 100)"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\ndwell_s = true"), 22, "plan.dwell_s",
     "must be a finite number, got true (a boolean) (allowed: 0 < dwell_s <= 86400 s)"),
    (edit(PLAN_LINE, f"{PLAN_LINE}\ndwell_s = nan"), 22, "plan.dwell_s", "must be a finite number, got nan"),
    (edit("latitude_deg = 30.27", f"latitude_deg = -{DIGITS_400}"), 5, "site.latitude_deg",
     "must be >= -90 deg, got -1.000e+399 (a 400-digit integer)"),
    (edit("latitude_deg = 30.27", "latitude_deg = " + "9" * 5000), 5, None, "an integer with more than 4300 digits"),
    (edit("latitude_deg = 30.27", "latitude_deg = " + "[" * 5000 + "]" * 5000), 5, None,
     "arrays and inline tables nested more than 32 levels deep"),
    (edit("latitude_deg = 30.27", "latitude_deg = " + "{a=" * 3000 + "1" + "}" * 3000), 5, None,
     "nested more than 32 levels deep"),
    (edit('dialect = "scpi"', 'dialect = "scpi"\ntimeout_s = 61'), 10, "table.timeout_s", "must be <= 60 s"),
    (edit('dialect = "scpi"', 'dialect = "scpi"\ntimeout_s = 1e-300'), 10, "table.timeout_s", "must be >= 0.001 s"),
    (edit('dialect = "scpi"', 'dialect = "scpi"\nretries = 1e12'), 10, "table.retries", "must be a whole number"),
    (edit('dialect = "scpi"', 'dialect = "scpi"\nretries = 11'), 10, "table.retries", "must be <= 10, got 11"),
    (edit('dialect = "scpi"', 'dialect = "scpi"\nsettle_tolerance_deg = 5'), 10, "table.settle_tolerance_deg",
     "must be <= 1 deg"),
    (edit('dialect = "scpi"', 'dialect = "scpi"\npoll_s = 0'), 10, "table.poll_s", "must be >= 0.001 s"),
    (edit("max_rate_dps = 50.0", "max_rate_dps = 1e9"), 12, "table.limits.outer.max_rate_dps",
     "must be <= 1000 deg/s"),
    (edit("max_rate_dps = 50.0", "max_rate_dps = 50.0\nmax_accel_dps2 = 1e-300"), 13,
     "table.limits.outer.max_accel_dps2", "must be >= 0.001 deg/s^2"),
    (edit("max_rate_dps = 50.0", "max_rate_dps = 50.0\nmin_deg = -1e308"), 13, "table.limits.outer.min_deg",
     "must be >= -3600 deg"),
    (edit("rate_hz = 200.0", "rate_hz = 0.5"), 17, "imu.rate_hz", "must be >= 1 Hz, got 0.5"),
    (edit("rate_hz = 200.0", "rate_hz = 1e6"), 17, "imu.rate_hz", "must be <= 100000 Hz"),
    (edit("rate_hz = 200.0", "rate_hz = 200.0\nbitrate = 100000000"), 18, "imu.bitrate", "must be <= 10000000"),
    (edit('channel = "test"', "channel = -1"), 16, "imu.channel", "must be >= 0, got -1"),
    (edit('channel = "test"', f"channel = {DIGITS_400}"), 16, "imu.channel", "must be <= 65535"),
    (edit("rate_hz = 200.0", "rate_hz = 200.0\n[imu.identity]\ngyro_bias_stability_dph = 1e300"), 19,
     "imu.identity.gyro_bias_stability_dph", "must be <= 3600 deg/h"),
    (edit("rate_hz = 200.0", "rate_hz = 200.0\n[imu.identity]\nacc_bias_stability_ug = 1e6"), 19,
     "imu.identity.acc_bias_stability_ug", "must be <= 100000 ug"),
    (BASE + "[output]\nchunk_run_interval_s = 1e-300\n", 23, "output.chunk_run_interval_s", "must be >= 0.01 s"),
    (BASE + "[output]\nchunk_run_interval_s = 1e300\n", 23, "output.chunk_run_interval_s", "must be <= 3600 s"),
    (BASE + "[sim]\nseed = 4294967296\n", 23, "sim.seed", "must be <= 4294967295, got 4294967296"),
    (BASE + "[sim]\nblack_box_arcsec = 3601\n", 23, "sim.black_box_arcsec", "must be <= 3600 arcsec"),
    (BASE + f"[sim]\nblack_box_arcsec = [[0, 0, 0], [0, {DIGITS_400}, 0], [0, 0, 0]]\n", 23,
     "sim.black_box_arcsec[1]", "got [0, 1000"),
    (BASE + "[sim]\nblack_box_arcsec = [[0, 0, 0], [0, 0, 0], [0, 0, 1e308]]\n", 23, "sim.black_box_arcsec[2]",
     "(allowed: -3600 <= angle <= 3600 arcsec)"),
    (BASE + "[sim.noise]\ngyro_arw_deg_rt_h = 11\n", 23, "sim.noise.gyro_arw_deg_rt_h", "must be <= 10 deg/sqrt(h)"),
    (BASE + "[sim.noise]\nacc_vrw_ug_rt_hz = 1e300\n", 23, "sim.noise.acc_vrw_ug_rt_hz",
     "must be <= 10000 ug/sqrt(Hz)"),
    (BASE + "[sim.noise]\ncorrelation_time_s = 1e7\n", 23, "sim.noise.correlation_time_s", "must be <= 1e+06 s"),
    (BASE + "[sim.imu]\nKg_x = 1e7\n", 23, "sim.imu.Kg_x", "must be <= 1e+06 counts/s per deg/s"),
    (BASE + f"[sim.imu]\nD0_x = {DIGITS_400}\n", 23, "sim.imu.D0_x", "must be <= 36000 deg/h"),
    (BASE + "[sim.imu]\nK0_y = -2\n", 23, "sim.imu.K0_y", "must be >= -1 g"),
    (BASE + "[sim.imu]\nEg_Yx = 1e300\n", 23, "sim.imu.Eg_Yx", "must be <= 1, got 1e+300"),
    (edit('dialect = "scpi"', 'dialect = "modbus"\n[table.modbus]\nangle_scale_deg = 0',
          edit('url = "tcp://127.0.0.1:5000"', 'url = "modbus+tcp://127.0.0.1:5020"')), 11,
     "table.modbus.angle_scale_deg", "must be >= 1e-09 deg, got 0"),
    (edit('dialect = "scpi"', f'dialect = "modbus"\n[table.modbus]\nwatchdog_s = {DIGITS_400}',
          edit('url = "tcp://127.0.0.1:5000"', 'url = "modbus+tcp://127.0.0.1:5020"')), 11,
     "table.modbus.watchdog_s", "must be <= 3600 s"),
    # missing keys point at the table they belong in
    (edit('url = "tcp://127.0.0.1:5000"\n', ""), 7, "table.url", "missing required key"),
    (edit('channel = "test"\n', ""), 14, "imu.channel", "missing required key"),
    # [table] only implied by [table.limits.outer]: its line
    (edit('[table]\nurl = "tcp://127.0.0.1:5000"\ndialect = "scpi"\n', ""), 8, "table.url", "missing required key"),
]
LIMIT_IDS = ["dwell-1e308", "dwell-86401", "dwell-0", "settle", "rest", "turn-rate-1e-300", "move-rate",
             "turn-accel", "move-accel", "revolutions-1e12", "revolutions-400-digits", "revolutions-string",
             "dwell-bool", "dwell-nan", "latitude-400-digits", "5000-digits", "deep-array", "deep-inline-table",
             "timeout-61", "timeout-tiny", "retries-float", "retries-11", "tolerance", "poll", "limit-rate",
             "limit-accel", "min-deg", "rate-hz-0.5", "rate-hz-1e6", "bitrate", "channel-negative", "channel-huge",
             "gyro-stability", "acc-stability", "chunk-tiny", "chunk-huge", "seed", "black-box-rms",
             "black-box-400-digits", "black-box-1e308", "arw", "vrw", "correlation", "Kg", "D0", "K0", "Eg",
             "modbus-scale", "modbus-watchdog", "missing-url", "missing-channel", "missing-url-implied-table"]


@pytest.mark.parametrize("text, line, key, fragment", LIMIT_ERRORS, ids=LIMIT_IDS)
def test_out_of_range_values_give_one_located_line(text, line, key, fragment):
    err = error_of(text)
    assert (err.path, err.line, err.key) == ("bench.toml", line, key), str(err)
    assert fragment in err.message and "\n" not in str(err) and len(str(err)) < 400, str(err)


def test_every_range_holds_at_its_edges():
    text = edit(PLAN_LINE, f"{PLAN_LINE}\ndwell_s = 86400\nsettle_s = 3600\nrest_s = 0\nmove_rate_dps = 1000\n"
                "move_accel_dps2 = 10000\nturn_rate_dps = 0.001\nturn_accel_dps2 = 0.001\nrevolutions = 100")
    text = edit("[table.limits.outer]\nmax_rate_dps = 50.0",
                "timeout_s = 60\nretries = 10\nsettle_tolerance_deg = 1e-6\npoll_s = 10\n" + "".join(
                    f"[table.limits.{frame}]\nmax_rate_dps = 1000\nmax_accel_dps2 = 10000\n"
                    for frame in ("outer", "inner", "middle")) + "min_deg = -3600\nmax_deg = 3600\n", text)
    text = edit("rate_hz = 200.0", "rate_hz = 100000\nbitrate = 10000000\n[imu.identity]\n"
                "gyro_bias_stability_dph = 3600\nacc_bias_stability_ug = 100000", text)
    text += ("[output]\nchunk_run_interval_s = 0.01\n[sim]\nseed = 4294967295\n"
             "black_box_arcsec = [[3600, -3600, 0], [0, 0, 0], [0, 0, 0]]\n[sim.noise]\ngyro_arw_deg_rt_h = 10\n"
             "gyro_bias_instability_dph = 3600\nacc_vrw_ug_rt_hz = 10000\nacc_bias_instability_ug = 100000\n"
             "correlation_time_s = 1e6\n[sim.imu]\nKg_x = 1e6\nKa_z = 1e6\nD0_y = -36000\nK0_x = 1\n")
    config = parse(text)
    assert (config.plan.dwell_s, config.plan.revolutions, config.plan.turn_rate_dps) == (86400, 100, 0.001)
    assert (config.imu.rate_hz, config.sim.seed, config.output.chunk_run_interval_s) == (100000, 2 ** 32 - 1, 0.01)
    assert config.table.limits.axes[1] == AxisLimits(-3600, 3600, 1000, 10000)
    assert "\n" in compile_from_config(config).format_dry_run()


def test_dry_run_of_the_longest_plan_the_ranges_allow_prints_finite_estimates():
    text = edit(PLAN_LINE, 'rotations = "all-96"\ndwell_s = 86400\nturn_rate_dps = 0.001\nrevolutions = 100',
                edit('positions = "optimal-24"', 'positions = "all-64"'))
    out = compile_from_config(parse(text)).format_dry_run()
    assert "?:??:??" not in out and "inf" not in out and "nan" not in out


def test_only_small_regular_files_are_read(tmp_path):
    for special, fragment in (("/dev/zero", "not a regular file (a character device)"),
                              (str(tmp_path), "Is a directory")):
        with pytest.raises(ConfigError) as info:
            load_config(special)
        assert str(info.value) == f"{special}: cannot read the configuration file: {fragment}"
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    with pytest.raises(ConfigError, match=r"not a regular file \(a FIFO\)"):
        load_config(fifo)  # does not wait for a writer
    big = tmp_path / "bench.toml"
    big.write_text(BASE + "#" * (1024 * 1024 - len(BASE)), encoding="utf-8")  # exactly 1 MiB: read
    assert load_config(big).plan.positions.name == "optimal-24"
    big.write_text(BASE + "#" * (1024 * 1024 - len(BASE) + 1), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(big)
    assert str(info.value) == f"{big}: cannot read the configuration file: larger than the 1 MiB limit for input files"
    latin1 = tmp_path / "latin1.toml"
    latin1.write_bytes(BASE.encode() + b"# caf\xe9\n")
    with pytest.raises(ConfigError) as info:
        load_config(latin1)
    assert info.value.line == 22  # where the bad byte is


MODBUS_URL = ('url = "tcp://127.0.0.1:5000"', 'url = "modbus+tcp://127.0.0.1:5020"')
REFERENCES = {  # key: (line, dotted key, the BASE edit that sets it to {value})
    "dbc": (18, "imu.dbc", ("rate_hz = 200.0", "rate_hz = 200.0\ndbc = {value}"), BASE),
    "register_map": (10, "table.register_map", ('dialect = "scpi"', 'dialect = "modbus"\nregister_map = {value}'),
                     edit(*MODBUS_URL)),
    "positions": (20, "plan.positions", ('positions = "optimal-24"', "positions = {value}"), BASE),
}


@pytest.mark.parametrize("name", sorted(REFERENCES))
@pytest.mark.parametrize("value, fragment", [
    ('"/dev/zero"', "not a regular file"), ('"folder"', "not a regular file"),
    ('"big"', "larger than the 1 MiB limit"), ('"a\\u0000b"', "must not contain a NUL character"),
    ('"~nosuchuser-fuzz/x"', "cannot expand '~nosuchuser-fuzz/x'"), ('"' + "p" * 5000 + '"', "File name too long"),
], ids=["dev-zero", "directory", "big", "nul", "unknown-user", "long-name"])
def test_a_referenced_file_must_be_a_small_regular_file(tmp_path, name, value, fragment):
    (tmp_path / "folder").mkdir()
    (tmp_path / "big").write_bytes(b"#" * (1024 * 1024 + 1))
    line, key, (old, new), base = REFERENCES[name]
    err = error_of(edit(old, new.format(value=value), base), base_dir=tmp_path)
    if value == '"big"' and name != "dbc":  # refused by the reader of that file, which it names
        assert (err.path, err.line) == (str(tmp_path / "big"), None) and fragment in err.message, str(err)
    else:
        assert (err.path, err.line, err.key) == ("bench.toml", line, key) and fragment in err.message, str(err)
    assert len(str(err)) < 400, str(err)


def test_output_folder_with_an_unknown_user_is_a_config_error():
    err = error_of(BASE + '[output]\nfolder = "~nosuchuser-fuzz/runs"\n')
    assert (err.line, err.key) == (23, "output.folder") and "cannot expand" in err.message
