"""Monte-Carlo tables against the paper's Tables 2 and 4."""

import json
import math

import numpy as np
import pytest

from bench.cli.main import main
from bench.model.earth import Site
from bench.model.families import POSITION_KEYS, ROTATION_KEYS
from bench.model.imu import default_sim_imu
from bench.model.units import ARCSEC
from bench.schedule_design.monte_carlo import (
    builtin_schedules,
    draw_black_boxes,
    evaluate,
    paper_value,
    position_errors,
)
from schedules import load_builtin


@pytest.fixture(scope="module")
def table():
    positions, rotations = builtin_schedules()
    return evaluate(positions, rotations, runs=100, seed=0)


def _cells(table, name, keys):
    for row in table[name]:
        for key in keys:
            yield row["level_arcsec"], row["method"], key, row[key]


def test_every_cell_within_factor_5_of_the_paper(table):
    checked = 0
    for name, keys in (("positions", POSITION_KEYS), ("rotations", ROTATION_KEYS)):
        for level, method, key, ours in _cells(table, name, keys):
            paper = paper_value(name, level, method, key)
            assert paper / 5 < ours < paper * 5, (name, level, method, key, ours, paper)
            checked += 1
    assert checked == 3 * 2 * 4 + 3 * 2 * 2


def test_optimal_beats_traditional():
    # 1000 runs: at 273" the gyro scale-factor cells are within 10 % of each other, so
    # 100 runs would leave the verdict to the dice.
    positions, rotations = builtin_schedules()
    table = evaluate(positions, rotations, runs=1000, seed=7)
    by_cell = {(n, lv, m, k): v for n, keys in (("positions", POSITION_KEYS), ("rotations", ROTATION_KEYS))
               for lv, m, k, v in _cells(table, n, keys)}
    for (name, level, method, key), ours in by_cell.items():
        if method != "optimal":
            continue
        trad = by_cell[(name, level, "traditional", key)]
        if name == "positions" and key == "acc_scale" and level > 30:
            # Second-order floor shared by every schedule solved with the nominal specific
            # force (the projection of g onto a tilted axis is g cos(tilt)); here the
            # traditional set and the optimal one are equal to within 40 %, and the optimal
            # one equals the all-64 solution (see test_optimal_positions_equal_all_64).
            assert ours < 1.4 * trad, (level, ours, trad)
            continue
        assert ours < trad, (name, level, key, ours, trad)


def test_optimal_positions_equal_all_64():
    imu, site = default_sim_imu(), Site()
    unit = draw_black_boxes(50, 1)
    opt = np.array([p.angles_deg for p in load_builtin("optimal-24").positions])
    full = np.array([p.angles_deg for p in load_builtin("all-64").positions])
    for level in (26.7, 275.5):
        a = position_errors(opt, unit * level * ARCSEC, imu, site)
        b = position_errors(full, unit * level * ARCSEC, imu, site)
        for key in POSITION_KEYS:
            assert np.allclose(a[key], b[key], rtol=1e-5, atol=1e-13), key


def _slope(table, name, key):
    rows = [r for r in table[name] if r["method"] == "optimal"]
    lo, hi = rows[0], rows[-1]
    return math.log(hi[key] / lo[key]) / math.log(hi["level_arcsec"] / lo["level_arcsec"])


@pytest.mark.parametrize("name, key, order", [
    ("positions", "gyro_bias_dph", 2), ("positions", "acc_bias_g", 2), ("positions", "acc_scale", 2),
    ("positions", "acc_axes", 1), ("rotations", "gyro_scale", 2), ("rotations", "gyro_axes", 1)])
def test_optimal_error_order_in_the_angle(table, name, key, order):
    assert _slope(table, name, key) == pytest.approx(order, abs=0.25)


def test_traditional_biases_are_first_order(table):
    rows = [r for r in table["positions"] if r["method"] == "traditional"]
    slope = math.log(rows[-1]["acc_bias_g"] / rows[0]["acc_bias_g"]) / math.log(275.5 / 26.7)
    assert slope == pytest.approx(1.0, abs=0.2)


def test_cli_writes_json_in_the_documented_shape(tmp_path, capsys):
    out = tmp_path / "mc.json"
    assert main(["evaluate", "--runs", "20", "--seed", "3", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "Table 2" in printed and "Table 4" in printed and "optimal" in printed
    data = json.loads(out.read_text())
    assert [r["level_arcsec"] for r in data["positions"]] == [26.7, 26.7, 85.0, 85.0, 275.5, 275.5]
    assert {r["method"] for r in data["rotations"]} == {"optimal", "traditional"}
    assert set(data["positions"][0]) == {"level_arcsec", "method", *POSITION_KEYS}
    assert set(data["rotations"][0]) == {"level_arcsec", "method", *ROTATION_KEYS}


def test_cli_rejects_bad_runs(capsys):
    assert main(["evaluate", "--runs", "0"]) == 2
    assert "--runs" in capsys.readouterr().err
    assert main(["evaluate", "--latitude", "100"]) == 2
    assert "latitude" in capsys.readouterr().err
