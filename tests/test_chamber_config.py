"""The [chamber] configuration section: what it builds, and one ConfigError `file:line: key: message` for each
kind of bad value (the same style as the rest of the configuration)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.config.load import ConfigError, parse_config
from bench.config.register_map import load_chamber_register_map
from drivers.chamber import ChamberLimits
from drivers.chamber.modbus_map import ChamberRegisterMap
from tests.test_config import BASE

# Line numbers below are asserted exactly: the [chamber] section starts on line 23.
ASCII = BASE + """
[chamber]
url = "sim"
dialect = "ascii"
safe_setpoint_c = 23.0

[chamber.limits]
min_setpoint_c = -40.0
max_setpoint_c = 85.0
max_ramp_c_per_min = 3.0
"""
MODBUS = BASE + """
[chamber]
url = "modbus+tcp://127.0.0.1:5021"
dialect = "modbus"
timeout_s = 0.5
"""


def parse(text: str, **kw):
    return parse_config(text, source="bench.toml", **kw)


def error_of(text: str, **kw) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        parse(text, **kw)
    return info.value


def test_no_section_is_no_chamber_and_a_section_builds_one():
    assert parse(BASE).chamber is None
    chamber = parse(ASCII).chamber
    assert chamber is not None and chamber.is_sim and chamber.dialect == "ascii"
    assert chamber.limits == ChamberLimits(-40.0, 85.0, 3.0) and chamber.safe_setpoint_c == 23.0
    assert chamber.register_map is None and chamber.driver_options()["limits"] == chamber.limits
    modbus = parse(MODBUS).chamber
    assert (modbus.url, modbus.timeout_s, modbus.safe_setpoint_c) == ("modbus+tcp://127.0.0.1:5021", 0.5, None)
    assert modbus.limits == ChamberLimits()


@pytest.mark.parametrize("url, dialect, link", [
    ("modbus+tcp://127.0.0.1:5021", "modbus", "tcp"), ("modbus+rtu:///dev/ttyUSB0?baud=19200", "modbus", "pty"),
    ("tcp://127.0.0.1:5030", "ascii", "tcp"), ("/dev/ttyUSB1", "ascii", "pty"), ("sim", "ascii", "tcp")])
def test_the_url_chooses_the_dialect_and_the_simulators_link(url, dialect, link):
    """Without a dialect the url's is taken (modbus+... is Modbus, anything else the ASCII lines), and the
    simulator serves the chamber over the kind of link the url names (a pty for RTU and serial devices)."""
    chamber = parse(BASE + f'\n[chamber]\nurl = "{url}"\n').chamber
    assert (chamber.dialect, chamber.sim_link) == (dialect, link)


@pytest.mark.parametrize("old, new, line, key, fragment", [
    ('dialect = "ascii"', 'dialect = "espec"', 25, "chamber.dialect", "unknown chamber dialect 'espec'"),
    ('url = "sim"', 'url = "modbus+tcp://h:502"', 24, "chamber.url", "is a Modbus url but chamber.dialect"),
    ('safe_setpoint_c = 23.0', 'safe_setpoint_c = 90.0', 26, "chamber.safe_setpoint_c", "must be <= 85 degC"),
    ('max_setpoint_c = 85.0', 'max_setpoint_c = -50.0', 30, "chamber.limits.max_setpoint_c", "must be above"),
    ('max_ramp_c_per_min = 3.0', 'max_ramp_c_per_min = 0', 31, "chamber.limits.max_ramp_c_per_min", "must be > 0"),
    ('safe_setpoint_c = 23.0', 'safe_setpoint = 23.0', 26, "chamber.safe_setpoint", "unknown key"),
    ('url = "sim"\n', '', 23, "chamber.url", "missing required key"),
    ('dialect = "ascii"', 'dialect = "ascii"\nregister_map = "map.toml"', 26, "chamber.register_map",
     "modbus dialect only (chamber.dialect is 'ascii')"),
])
def test_bad_values_name_file_line_and_key(old, new, line, key, fragment):
    err = error_of(ASCII.replace(old, new, 1))
    assert (err.path, err.line, err.key) == ("bench.toml", line, key), str(err)
    assert fragment in err.message, str(err)


def test_inline_register_map_and_its_errors():
    text = MODBUS + "\n[chamber.modbus]\nunit = 4\n[chamber.modbus.registers]\nramp_rate = -1\n"
    assert parse(text).chamber.register_map == ChamberRegisterMap(unit=4, ramp_rate=-1)
    err = error_of(MODBUS + "\n[chamber.modbus]\nunit = 4\ntemperature_scale_c = 50.0\n")
    assert (err.line, err.key) == (30, "chamber.modbus.temperature_scale_c") and "must be <= 10 degC" in err.message
    err = error_of(MODBUS + "\n[chamber.modbus.registers]\nsetpont = 5\n")
    assert (err.line, err.key) == (29, "chamber.modbus.registers.setpont") and "unknown key" in err.message


def test_register_map_file(tmp_path):
    (tmp_path / "chamber-map.toml").write_text("[modbus]\nunit = 9\n[modbus.alarm_bits]\ndoor_open = 9\n",
                                               encoding="utf-8")
    text = MODBUS.replace('timeout_s = 0.5', 'register_map = "chamber-map.toml"')
    assert parse(text, base_dir=tmp_path).chamber.register_map == ChamberRegisterMap(
        unit=9, alarm_bits=(0, 1, 9, 3, 4))
    assert load_chamber_register_map(tmp_path / "chamber-map.toml").unit == 9
    (tmp_path / "chamber-map.toml").write_text("[modbus]\nunit = 9\n[modbus.alarm_bits]\ndoor_open = 99\n",
                                               encoding="utf-8")
    err = error_of(text, base_dir=tmp_path)
    assert (err.path, err.line, err.key) == (str(tmp_path / "chamber-map.toml"), 4, "modbus.alarm_bits.door_open")
    assert "must be 0-15" in err.message


def test_the_examples_commented_chamber_section_loads_when_uncommented():
    example = (Path(__file__).resolve().parents[1] / "bench.example.toml").read_text(encoding="utf-8")
    start = example.index("# [chamber]\n")
    keys = ("url", "dialect", "timeout_s", "retries", "poll_s", "safe_setpoint_c", "[chamber", "min_", "max_")
    section = [line[2:] for line in example[start:].splitlines() if line.startswith("# ") and line[2:].startswith(keys)]
    chamber = parse(example[:start] + "\n".join(section) + "\n", base_dir=Path(__file__).resolve().parents[1]).chamber
    assert chamber.url == "tcp://192.168.1.40:5030" and chamber.safe_setpoint_c == 23.0
    assert chamber.limits == ChamberLimits(-40.0, 85.0, 5.0)
