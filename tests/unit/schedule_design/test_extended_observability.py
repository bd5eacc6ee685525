"""`bench schedules analyze`'s extended part (issue 30 item 3): which higher-order families a plan observes, the
predicted sigma, and which are confounded."""

from __future__ import annotations

from bench.model.imu import NoiseModel
from bench.schedule_design.extended import extended_observability, observability_lines
from schedules import load_builtin
from tests.helpers.run import cli


def _rows(angles, turns):
    return {row.term: row for row in extended_observability(angles, turns, NoiseModel())}


def test_positions_at_multiples_of_90_confound_asymmetry_with_second_order_and_miss_the_cross_terms():
    rows = _rows([p.angles_deg for p in load_builtin("optimal-24").positions], [])
    assert rows["gyro_g_sensitivity"].observed and rows["gyro_g_sensitivity"].confounded_with == []
    assert len(rows["gyro_g_sensitivity"].sigma) == 9 and all(v > 0 for v in rows["gyro_g_sensitivity"].sigma.values())
    assert rows["acc_asymmetry"].confounded_with == ["acc_second_order"]
    assert rows["acc_second_order"].confounded_with == ["acc_asymmetry"]
    assert not rows["acc_cross"].observed and "rank-deficient" in rows["acc_cross"].reason


def test_tilts_of_45_deg_observe_every_accelerometer_family_apart():
    rows = _rows([p.angles_deg for p in load_builtin("extended-44").positions], [])
    for term in ("acc_asymmetry", "acc_second_order", "acc_cross"):
        assert rows[term].observed and rows[term].confounded_with == [], term


def test_turns_at_one_rate_confound_gyro_asymmetry_with_nonlinearity():
    rows = _rows(None, list(load_builtin("optimal-5s6r").rotations))
    assert set(rows) == {"gyro_asymmetry", "gyro_nonlinearity"}
    assert rows["gyro_asymmetry"].confounded_with == ["gyro_nonlinearity"]
    assert any("confounded with gyro_nonlinearity" in line for line in observability_lines(list(rows.values())))


def test_bench_schedules_analyze_prints_it():
    rc, stdout, stderr = cli(["schedules", "analyze", "optimal-24", "--runs", "1"])
    assert rc == 0, stderr
    assert "Extended model" in stdout and "acc_cross            not observed" in stdout


def test_the_shipped_extended_plan_observes_every_family():
    """Issue 30 item 3: extended-44 with extended-5s6r-2rates (turns at their own 10 and 40 deg/s) observes every
    family, none confounded; the same turns at one rate confound the gyro asymmetry with the nonlinearity."""
    from bench.model.extended import MEAN_TERMS as TERMS  # the time offset is seen inside turns, not predicted

    angles = [p.angles_deg for p in load_builtin("extended-44").positions]
    rows = _rows(angles, list(load_builtin("extended-5s6r-2rates").rotations))
    assert set(rows) == set(TERMS)
    for term in TERMS:
        assert rows[term].observed and rows[term].confounded_with == [], (term, rows[term])
    one_rate = _rows(angles, list(load_builtin("optimal-5s6r").rotations))
    assert one_rate["gyro_asymmetry"].confounded_with == ["gyro_nonlinearity"]
    rc, stdout, stderr = cli(["schedules", "analyze", "extended-44", "--with", "extended-5s6r-2rates", "--runs", "1"])
    assert rc == 0, stderr
    extended = stdout[stdout.index("Extended model"):stdout.index("Monte Carlo")]
    assert "together with extended-5s6r-2rates" in extended
    assert [line.split()[0] for line in extended.splitlines() if "observed" in line] == list(TERMS)
    assert "not observed" not in extended and "confounded" not in extended
    assert "time_offset          not predicted here: seen inside turns about a horizontal axis" in extended
    rc, _, stderr = cli(["schedules", "analyze", "extended-44", "--with", "optimal-24", "--runs", "1"])
    assert rc == 2 and "goes with a 'rotations' schedule" in stderr
