"""The [chamber] configuration section: what it builds, and one ConfigError `file:line: key: message` for each
kind of bad value (the same style as the rest of the configuration)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.config.load import ConfigError, parse_config
from bench.config.register_map import load_chamber_register_map
from drivers.chamber import ChamberLimits, open_chamber
from drivers.chamber.modbus_map import ChamberRegisterMap
from drivers.chamber.watlow_f4 import REGISTERS, WatlowF4Map
from tests.unit.config.test_config import BASE

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
    text = MODBUS + "\n[chamber.modbus]\npreset = 'generic'\nunit = 4\n[chamber.modbus.registers]\nramp_rate = -1\n"
    assert parse(text).chamber.register_map == ChamberRegisterMap(unit=4, ramp_rate=-1)
    err = error_of(MODBUS + "\n[chamber.modbus]\npreset = 'generic'\nunit = 4\ntemperature_scale_c = 50.0\n")
    assert (err.line, err.key) == (31, "chamber.modbus.temperature_scale_c") and "must be <= 10 degC" in err.message
    err = error_of(MODBUS + "\n[chamber.modbus]\npreset = 'generic'\n[chamber.modbus.registers]\nsetpont = 5\n")
    assert (err.line, err.key) == (31, "chamber.modbus.registers.setpont") and "unknown key" in err.message


def test_the_modbus_default_is_the_f4p_map_and_presets_are_named():
    assert parse(MODBUS).chamber.register_map is None       # the client's default: watlow-f4
    assert open_chamber("modbus+tcp://127.0.0.1:1502").map == WatlowF4Map()
    for name, expected in (("watlow-f4", WatlowF4Map()), ("generic", ChamberRegisterMap())):
        text = MODBUS.replace('timeout_s = 0.5', f'register_map = "{name}"')
        assert parse(text).chamber.register_map == expected
    # a table without a preset is the F4P's: the unit and register overrides it takes
    text = MODBUS + "\n[chamber.modbus]\nunit = 4\n[chamber.modbus.registers]\nsetpoint = 308\n"
    assert parse(text).chamber.register_map == WatlowF4Map(unit=4, registers={**REGISTERS, "setpoint": 308})


@pytest.mark.parametrize("table, line, key, fragment", [
    # 4000 is in no list of the manual's chapter 9; 40101 is input 1 value's absolute (40001-based) number
    ("[chamber.modbus.registers]\nprocess_value = 4000", 29, "chamber.modbus.registers.process_value",
     "the Watlow F4P has no register 4000"),
    ("[chamber.modbus.registers]\nprocess_value = 40101", 29, "chamber.modbus.registers.process_value",
     "give the relative number 100"),
    ("[chamber.modbus]\npreset = 'watlow-f4'\n[chamber.modbus.registers]\nsetpoint = 100", 31,
     "chamber.modbus.registers.setpoint", "overlaps registers.process_value"),
    ("[chamber.modbus]\ntemperature_scale_c = 0.1", 29, "chamber.modbus.temperature_scale_c", "unknown key"),
    ("[chamber.modbus]\npreset = 'watlow-f5'", 29, "chamber.modbus.preset", "no register map preset 'watlow-f5'"),
])
def test_a_map_naming_a_register_the_f4p_lacks_is_file_line_key(table, line, key, fragment):
    err = error_of(MODBUS + "\n" + table + "\n")
    assert (err.path, err.line, err.key) == ("bench.toml", line, key), str(err)
    assert fragment in err.message, str(err)
    assert str(err).startswith(f"bench.toml:{line}: {key}: ")


def test_register_map_file(tmp_path):
    (tmp_path / "chamber-map.toml").write_text("[modbus]\npreset = 'generic'\nunit = 9\n[modbus.alarm_bits]\n"
                                               "door_open = 9\n", encoding="utf-8")
    text = MODBUS.replace('timeout_s = 0.5', 'register_map = "chamber-map.toml"')
    assert parse(text, base_dir=tmp_path).chamber.register_map == ChamberRegisterMap(
        unit=9, alarm_bits=(0, 1, 9, 3, 4))
    assert load_chamber_register_map(tmp_path / "chamber-map.toml").unit == 9
    (tmp_path / "chamber-map.toml").write_text("[modbus]\npreset = 'generic'\nunit = 9\n[modbus.alarm_bits]\n"
                                               "door_open = 99\n", encoding="utf-8")
    err = error_of(text, base_dir=tmp_path)
    assert (err.path, err.line, err.key) == (str(tmp_path / "chamber-map.toml"), 5, "modbus.alarm_bits.door_open")
    assert "must be 0-15" in err.message
    # a file claiming to be the F4P's map, naming a register its manual does not list
    (tmp_path / "chamber-map.toml").write_text("# our F4P\n[modbus]\npreset = 'watlow-f4'\nunit = 2\n\n"
                                               "[modbus.registers]\nramp_rate = 1103\n", encoding="utf-8")
    err = error_of(text, base_dir=tmp_path)
    assert (err.path, err.line, err.key) == (str(tmp_path / "chamber-map.toml"), 7, "modbus.registers.ramp_rate")
    assert "the Watlow F4P has no register 1103" in err.message
    assert load_chamber_register_map("watlow-f4") == WatlowF4Map()


def test_the_examples_commented_chamber_section_loads_when_uncommented():
    example = (Path(__file__).resolve().parents[3] / "bench.example.toml").read_text(encoding="utf-8")
    start = example.index("# [chamber]\n")
    keys = ("url", "dialect", "timeout_s", "retries", "poll_s", "safe_setpoint_c", "[chamber", "min_", "max_")
    section = [line[2:] for line in example[start:].splitlines() if line.startswith("# ") and line[2:].startswith(keys)]
    chamber = parse(example[:start] + "\n".join(section) + "\n", base_dir=Path(__file__).resolve().parents[3]).chamber
    assert chamber.url == "tcp://192.168.1.40:5030" and chamber.safe_setpoint_c == 23.0
    assert chamber.limits == ChamberLimits(-40.0, 85.0, 5.0)
