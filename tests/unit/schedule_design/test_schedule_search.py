"""Exhaustive schedule search: criteria against brute force and against part-1 sensitivities."""

import math
from itertools import combinations

import numpy as np
import pytest

from bench.cli.main import main
from bench.model.earth import Site
from bench.model.imu import ImuCoefficients
from bench.model.units import ARCSEC, DEG_PER_HOUR, G0
from bench.schedule_design.search import (
    POSITION_GROUPS,
    SCALE_BIAS_ENTRIES,
    all_rotations,
    combo_of_angles,
    combo_of_turns,
    group_angles,
    position_combo_sensitivity,
    position_tables,
    search_positions,
    search_rotations,
)
from bench.schedule_design.sensitivity import position_sensitivity, rotation_sensitivity
from schedules import load_builtin, load_schedule

PAPER = combo_of_angles([p.angles_deg for p in load_builtin("optimal-24").positions])


@pytest.fixture(scope="module")
def reduced():
    """The paper's 12 groups plus 6 others: C(18, 12) = 18,564 choices."""
    others = [i for i in range(32) if i not in PAPER][::3][:6]
    groups = [POSITION_GROUPS[i] for i in sorted(PAPER + tuple(others))]
    return groups, search_positions(groups, 12, reference_groups=POSITION_GROUPS)


def test_reduced_search_matches_brute_force(reduced):
    groups, result = reduced
    tables = position_tables(groups)
    combos = np.array(list(combinations(range(len(groups)), 12)))
    sens = position_combo_sensitivity(tables, combos)
    p = sens["params"]
    full = ~np.isnan(p).any(axis=(1, 2, 3))
    ref = position_combo_sensitivity(position_tables(), np.arange(32)[None])["params"][0]
    scale_bias = np.stack([p[:, c, r] for c, r in SCALE_BIAS_ENTRIES], axis=1)
    gyro_zero = np.all(tables.gyro[combos].sum(axis=1) == 0, axis=(1, 2, 3))
    b = full & np.all(np.abs(scale_bias) < 1e-9, axis=(1, 2)) & gyro_zero
    c = b & np.all(np.abs(p - ref) < 1e-9, axis=(1, 2, 3))
    assert result.total == math.comb(18, 12) == len(combos)
    assert (result.counts["a"], result.counts["b"], result.counts["c"]) == (full.sum(), b.sum(), c.sum())
    assert {tuple(x) for x in result.equivalent} == {tuple(x) for x in combos[c]}
    assert 0 < result.counts["d"] <= result.counts["c"]


def test_paper_table_1_is_optimal_in_the_reduced_search(reduced):
    groups, result = reduced
    paper = combo_of_angles([p.angles_deg for p in load_builtin("optimal-24").positions], groups)
    assert paper in {tuple(x) for x in result.optimal}


@pytest.mark.parametrize("seed", range(4))
def test_vectorised_sensitivity_equals_part_1_on_random_schedules(seed):
    combo = np.sort(np.random.default_rng(seed).permutation(32)[:12])
    angles = np.concatenate([group_angles(POSITION_GROUPS[i]) for i in combo])
    site = Site()
    fast = position_combo_sensitivity(position_tables(), combo[None], site)
    dp, gyro = fast["params"][0], fast["gyro_bias"][0]
    if np.isnan(dp).any():
        pytest.skip("rank-deficient draw")
    slow = position_sensitivity(angles, imu=ImuCoefficients.ideal(), site=site)
    for c, s in enumerate("xyz"):
        assert np.allclose(slow.row(f"Ka_{s}") / 1e6 / ARCSEC, dp[c, c], atol=1e-7)
        assert np.allclose(slow.row(f"K0_{s}") / ARCSEC, dp[c, 3] * site.gravity / G0, atol=1e-7)
        assert np.allclose(slow.row(f"D0_{s}") * DEG_PER_HOUR / ARCSEC, gyro[c], atol=1e-15)
        for a, body in enumerate("XYZ"):
            if a != c:
                assert np.allclose(slow.row(f"Ea_{body}{s}"), dp[c, a], atol=1e-7)


@pytest.mark.slow
def test_rotation_search_finds_table_3_and_agrees_with_part_1():
    result = search_rotations()
    assert len(all_rotations()) == 96
    assert result.total == 12 * 12 * 12 * 12 * 24 * 24  # (+X, -X) x (+Y, -Y) x (+Z, -Z) candidate pairs
    paper = combo_of_turns(load_builtin("optimal-5s6r").rotations)
    assert paper in {tuple(sorted(x)) for x in result.optimal}
    trad = combo_of_turns(load_builtin("traditional-3s6r").rotations)
    assert trad not in {tuple(sorted(x)) for x in result.equivalent}
    # Every equivalent set checked on a few: part 1's geometric sensitivity has only inner.gamma left.
    turns = result.items
    for row in result.equivalent[:: max(1, len(result.equivalent) // 3)][:3]:
        sens = rotation_sensitivity([turns[i] for i in row], imu=ImuCoefficients.ideal())
        assert sorted(sens.remaining_geometric.nonzero()[1].tolist()) == [8, 8]


@pytest.mark.slow
def test_cli_search_writes_loadable_files(tmp_path, capsys):
    assert main(["schedules", "search", "--groups", "16", "--choose", "6", "--out", str(tmp_path),
                 "--best", "2"]) == 0
    out = capsys.readouterr().out
    assert "(c) (b) and every first-order sensitivity" in out and "optimal-5s6r (Table 3): among the optimal" in out
    files = sorted(tmp_path.glob("*.toml"))
    assert files
    for path in files:
        schedule = load_schedule(path)
        assert schedule.kind in ("positions", "rotations")
    assert main(["schedules", "validate", *map(str, files)]) == 0


@pytest.mark.slow
def test_cli_search_without_out_says_that_nothing_was_written(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["schedules", "search", "--groups", "8", "--choose", "3", "--best", "2"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[-1] == "no schedule files written: give --out DIR to write the best 2 of each kind as TOML"
    assert list(tmp_path.iterdir()) == []


def test_the_position_search_reports_its_progress_up_to_the_whole():
    """Issue 33: `bench schedules search` was silent for about 30 s; the search now says how far it is."""
    seen = []
    result = search_positions(POSITION_GROUPS[:8], 4, reference_groups=POSITION_GROUPS,
                              progress=lambda searched, total: seen.append((searched, total)))
    assert seen and all(total == result.total for _, total in seen)
    assert [s for s, _ in seen] == sorted(s for s, _ in seen) and seen[-1][0] == result.total
