"""[[imu]] entries: several units in one configuration (issue 31), each error with its file, line and key."""

from __future__ import annotations

import numpy as np
import pytest

from bench.config.load import ConfigError, default_sim_config, parse_config
from bench.config.units import FACES, bus_load, frame_bits

HEAD = """\
format = "turntable-bench/config"
version = 1
[site]
latitude_deg = 30.0
[table]
url = "sim"
dialect = "scpi"
[plan]
positions = "optimal-24"
rotations = "optimal-5s6r"
"""


def unit(serial: str = "A1", channel: str = "bus-a", extra: str = "", rate_hz: float = 200.0) -> str:
    return (f'[[imu]]\ninterface = "virtual"\nchannel = "{channel}"\nrate_hz = {rate_hz}\n{extra}'
            f'[imu.identity]\nmodel = "sim"\nserial = "{serial}"\n')


def parse(*units: str):
    return parse_config(HEAD + "".join(units), source="multi.toml")


def error(*units: str) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        parse(*units)
    return info.value


def test_two_units_on_one_bus_with_an_id_offset_and_two_faces():
    config = parse(unit("A1", extra='mounting = "z-up"\n'), unit("A2", extra='id_offset = 16\nmounting = "x-up"\n'))
    assert config.several and config.imu is config.units[0]
    first, second = config.units
    assert [k - 16 for k in second.layout.keys] == list(first.layout.keys)
    assert second.mounting == FACES["x-up"] and second.mounting_name == "x-up" and second.id_offset == 16
    assert first.mounting == FACES["z-up"]


def test_a_single_imu_is_as_before():
    config = default_sim_config()
    assert config.units == () and not config.several and config.imu.mounting is None and config.imu.id_offset == 0


def test_every_face_is_a_proper_rotation_whose_named_axis_is_up():
    for name, rows in FACES.items():
        matrix = np.array(rows, float)
        assert np.allclose(matrix @ matrix.T, np.eye(3)) and np.isclose(np.linalg.det(matrix), 1.0)
        up = matrix @ np.array([0.0, 0.0, 1.0])       # the fixture's z in the unit's axes
        axis, sign = name.split("-")
        expected = np.zeros(3)
        expected["xyz".index(axis)] = 1.0 if sign == "up" else -1.0
        assert np.allclose(up, expected), name


def test_a_mounting_matrix_is_taken_when_orthonormal():
    config = parse(unit(extra="mounting = [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]\n"))
    assert config.imu.mounting_name == "matrix" and config.imu.mounting == ((0, 1, 0), (-1, 0, 0), (0, 0, 1))


@pytest.mark.parametrize("value, line, words", [
    ("[[1, 0, 0], [0, 1, 0], [0, 0.5, 1]]", 15, "not orthonormal"),
    ("[[1, 0, 0], [0, 1, 0], [0, 0, -1]]", 15, "reflection"),
    ('"w-up"', 15, "unknown face"),
    ("[[1, 0, 0], [0, 1, 0]]", 15, "3 rows"),
])
def test_a_bad_mounting_names_file_line_and_key(value, line, words):
    exc = error(unit(extra=f"mounting = {value}\n"))
    assert exc.path == "multi.toml" and exc.line == line and exc.key == "imu[0].mounting" and words in exc.message


def test_a_bad_row_of_a_mounting_matrix_is_named():
    exc = error(unit(), unit("A2", channel="b", extra="mounting = [[1, 0, 0], [0, 1, 0], [0, 0, 2]]\n"))
    assert exc.key == "imu[1].mounting[2]" and "within -1..1" in exc.message


def test_every_unit_needs_a_distinct_safe_serial():
    assert "needs its serial" in error(unit(""), unit("A2")).message
    exc = error(unit("A1"), unit("A1", channel="b"))
    assert exc.key == "imu[1].identity.serial" and "already the serial of [[imu]] entry 1" in exc.message
    assert "letters, digits" in error(unit("../x")).message


def test_units_on_one_bus_must_send_at_distinct_ids():
    exc = error(unit("A1"), unit("A2"))
    assert exc.key == "imu[1].id_offset" and "frame id 0x100 is also sent by [[imu]] entry 1 on bus virtual:bus-a" \
        in exc.message
    parse(unit("A1"), unit("A2", channel="bus-b"))       # on two buses the same ids are fine


def test_an_id_offset_that_leaves_the_id_range_is_refused():
    exc = error(unit(extra="id_offset = 2000\n"))
    assert exc.key == "imu[0].id_offset" and "outside 0..0x7ff" in exc.message


def test_a_bus_that_cannot_carry_its_units_is_refused_with_the_load():
    bitrate = 'bitrate = 500000\n'
    one = frame_bits(8, False)
    assert one == 8 * 8 + 47 + (34 + 64 - 1) // 4          # 135 bits: a full classic frame, worst-case stuffing
    parse(unit("A1", extra=bitrate), unit("A2", extra=bitrate + "id_offset = 16\n"))   # 2 x 200 Hz x 7 frames: fits
    exc = error(unit("A1", extra=bitrate, rate_hz=300.0), unit("A2", extra=bitrate + "id_offset = 16\n",
                                                                 rate_hz=300.0))
    config_one = parse(unit("A1", extra=bitrate, rate_hz=300.0))
    load = 2 * bus_load([config_one.imu], 500000)
    assert load > 1.0 and f"need about {100 * load:.0f} % of its 500000 bit/s" in exc.message
    assert exc.key == "imu[1]"


def test_mounting_and_id_offset_belong_to_imu_entries():
    text = HEAD + '[imu]\ninterface = "virtual"\nchannel = "x"\nrate_hz = 200.0\nmounting = "x-up"\n'
    with pytest.raises(ConfigError, match=r"imu.mounting: belongs to an \[\[imu\]\] entry"):
        parse_config(text)


def test_several_units_with_a_verification_plan_are_not_supported_yet():
    text = HEAD.replace('rotations = "optimal-5s6r"\n', 'rotations = "optimal-5s6r"\nverification = '
                        '"verify-default"\n') + unit()
    with pytest.raises(ConfigError, match="not supported yet"):
        parse_config(text)


def test_on_unit_failure_is_continue_stop_or_named():
    assert parse(unit(), unit("A2", channel="b")).on_unit_failure == "continue"
    config = parse_config(HEAD + unit() + unit("A2", channel="b") + '[run]\non_unit_failure = "stop"\n', "multi.toml")
    assert config.on_unit_failure == "stop"
    with pytest.raises(ConfigError) as info:
        parse_config(HEAD + unit() + '[run]\non_unit_failure = "pause"\n', "multi.toml")
    assert "multi.toml" in str(info.value) and "run.on_unit_failure" in str(info.value)
    assert 'expected one of continue, stop' in str(info.value)


def test_a_lever_arm_is_taken_in_mm_and_turned_into_the_unit_axes():
    from bench.config.units import lever_arm_in_body_m
    config = parse(unit("A1"), unit("A2", extra='id_offset = 16\nmounting = "x-up"\nlever_arm_mm = [100, 0, -2.5]\n'))
    first, second = config.units
    assert first.lever_arm_mm is None and lever_arm_in_body_m(first) is None
    assert second.lever_arm_mm == (100.0, 0.0, -2.5)
    # x-up: the unit's y lies along the fixture's x, its x along the fixture's z
    assert np.allclose(lever_arm_in_body_m(second), [-0.0025, 0.1, 0.0])


@pytest.mark.parametrize("value, words", [
    ("[100, 0]", "3 finite numbers"),
    ("[100, nan, 0]", "3 finite numbers"),
    ("[inf, 0, 0]", "3 finite numbers"),
    ('["100", 0, 0]', "3 finite numbers"),
    ("[true, 0, 0]", "3 finite numbers"),
    ("[0, 2500, 0]", "more than 2000 mm"),
    ("[0.1, 0.0, -2001]", "more than 2000 mm"),
])
def test_a_bad_lever_arm_names_file_line_and_key(value, words):
    exc = error(unit(extra=f"lever_arm_mm = {value}\n"))
    assert exc.path == "multi.toml" and exc.line == 15 and exc.key == "imu[0].lever_arm_mm" and words in exc.message


def test_a_lever_arm_belongs_to_imu_entries():
    text = HEAD + '[imu]\ninterface = "virtual"\nchannel = "x"\nrate_hz = 200.0\nlever_arm_mm = [100, 0, 0]\n'
    with pytest.raises(ConfigError, match=r"imu.lever_arm_mm: belongs to an \[\[imu\]\] entry"):
        parse_config(text)
