"""Units off the table's rotation centre (issue 31: `[[imu]] lever_arm_mm`): the simulator places each unit there,
the extended model's lever-arm fit takes the known place out of the turns, and the log and the result say where the
unit sat. (The bias without it, in sigma, is tests/unit/solve/test_known_lever_arm.py's.)"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.log.reader import read_log
from tests.e2e.test_several_imus import UNITS, several_config
from tests.helpers.run import cli, only_file

#: the reference unit 80 mm along the fixture's -y, the x-up unit 100 mm along its x
LEVER_ARMS = {"A1": "[0, -80, 0]", "A2": "[100, 0, 0]"}


def lever_arm_config() -> str:
    text = several_config(UNITS[:2], black_box_arcsec=0.0) + '[model]\nterms = ["acc_lever_arm"]\n'
    for serial, value in LEVER_ARMS.items():
        text = text.replace(f'serial = "{serial}" }}\n', f'serial = "{serial}" }}\nlever_arm_mm = {value}\n')
    assert text.count("lever_arm_mm") == 2
    return text


@pytest.fixture(scope="module")
def placed_run(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("lever")
    config = folder / "lever.toml"
    config.write_text(lever_arm_config(), encoding="utf-8")
    rc, out, err = cli(["run", "--config", str(config), "--out", str(folder / "run"), "--no-db", "--quiet"])
    assert rc in (0, 4), err
    return only_file(folder / "run", "*.mcap")


def _result(log: Path, serial: str, solved: bool = False) -> dict:
    return json.loads((log.parent / f"{log.stem}.{serial}{'.solved' if solved else ''}.result.json")
                      .read_text(encoding="utf-8"))


def test_each_unit_off_centre_has_its_accelerometer_lever_arms_within_u(placed_run):
    """The simulated units have no lever arm of their accelerometers' own: the fit finds none, within U, once the
    unit's place is taken out (without it, La along the place would be about 100 mm)."""
    for serial in LEVER_ARMS:
        coefficients = _result(placed_run, serial)["coefficients"]
        for name in ("La_x", "La_y", "La_z"):
            entry = coefficients[name]
            assert abs(entry["value"]) <= entry["expanded"], (serial, name, entry["value"], entry["expanded"])


def test_the_log_and_the_result_say_where_each_unit_sat(placed_run):
    units = json.loads(read_log(placed_run).metadata["units"]["units_json"])
    assert {u["serial"]: u["lever_arm_mm"] for u in units} == {"A1": [0.0, -80.0, 0.0], "A2": [100.0, 0.0, 0.0]}
    for serial, value in LEVER_ARMS.items():
        assert _result(placed_run, serial)["run"]["lever_arm_mm"] == json.loads(value)


def test_bench_solve_takes_the_recorded_lever_arm_out_again(placed_run, tmp_path):
    rc, _, err = cli(["solve", str(placed_run), "--out", str(tmp_path), "--no-db", "--quiet", "--no-html"])
    assert rc in (0, 4), err
    for serial in LEVER_ARMS:
        solved = json.loads((tmp_path / f"{placed_run.stem}.{serial}.solved.result.json").read_text())
        assert solved["coefficients"] == _result(placed_run, serial)["coefficients"]
