"""Plan recommender: `bench.schedule_design.recommend` and `bench schedules recommend`."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from bench.config.load import SIM_CONFIG_TOML, parse_config
from bench.model.earth import Site
from bench.model.imu import NoiseModel, default_sim_imu
from bench.model.units import ARCSEC
from bench.plan.compiler import PlanTiming, compile_plan
from bench.run.runner import compile_from_config
from bench.schedule_design.monte_carlo import position_errors
from bench.schedule_design.recommend import (
    FAMILIES,
    PointingLevel,
    RecommendError,
    load_table_check,
    plan_snippet,
    pointing_from_table_check,
    recommend,
)
from bench.schedule_design.sensitivity import position_sensitivity
from bench.table_check.estimate import Conversion, estimate, horizontal_force
from bench.table_check.from_log import TableCheckAnalysis
from schedules import ScheduleError, builtin_path, load_builtin
from tests.helpers.run import cli

NOISE = NoiseModel()
OPT = (load_builtin("optimal-24"), load_builtin("optimal-5s6r"))
TRAD = (load_builtin("traditional-12"), load_builtin("traditional-3s6r"))
CHECK_324 = np.array([p.angles_deg for p in load_builtin("table-check-324").positions])


def _small(budget_s: float, level: PointingLevel, **kw):
    """The paper's optimal and traditional schedules only: fast."""
    return recommend(budget_s, level, NOISE, positions=[OPT[0], TRAD[0]], rotations=[OPT[1], TRAD[1]], **kw)


def _with_plan(snippet: str) -> str:
    """The built-in simulator configuration with its [plan] table replaced by `snippet`."""
    head, rest = SIM_CONFIG_TOML.split("[plan]\n", 1)
    tail = rest[rest.index("[output]"):]
    return head + snippet + "\n" + tail


# --- the physics of the prediction -------------------------------------------------------------

def test_large_table_error_makes_the_optimal_pair_win_over_traditional():
    rec = _small(20000.0, PointingLevel.uniform(200.0))
    assert (rec.best.positions.name, rec.best.rotations.name) == ("optimal-24", "optimal-5s6r")
    by_pair = {c.pair: c for c in rec.best_per_pair()}
    trad = by_pair["traditional-12 + traditional-3s6r"]
    assert trad.score > 100 * rec.best.score
    # The traditional schedules leave first-order bias and axis terms far above the noise.
    for fam in ("D0", "K0", "Ea", "Eg"):
        assert trad.errors[fam].first_order > trad.errors[fam].noise
        assert trad.errors[fam].dominant == "black box"
    # The optimal ones cancel the first order (the inner zero offset is kept apart as irreducible),
    # but for the Earth-rate coupling of the gyro scale factor (shrinks with faster turns).
    for fam in FAMILIES:
        limit = 0.1 if fam == "Kg" else 1e-3
        assert rec.best.errors[fam].first_order < limit * trad.errors[fam].first_order + 1e-6, fam
    assert rec.best.errors["Ea"].irreducible == pytest.approx(trad.errors["Ea"].irreducible)
    assert rec.best.errors["Ea"].irreducible == pytest.approx(200.0 * np.sqrt(2.0), rel=1e-3)
    why = "\n".join(rec.why())
    assert re.search(r"traditional-12 \+ \S+: leaves first-order", why)


def test_first_order_part_is_sensitivity_times_level_and_second_order_grows_as_its_square():
    recs = {lvl: _small(50000.0, PointingLevel.uniform(lvl), runs=200) for lvl in (100.0, 200.0)}
    pick = {lvl: next(c for c in r.ranked if c.pair == "traditional-12 + optimal-5s6r") for lvl, r in recs.items()}
    angles = np.array([p.angles_deg for p in TRAD[0].positions])
    sens = position_sensitivity(angles)
    rows = [i for i, n in enumerate(sens.names) if n.startswith("D0")]
    expected = np.sqrt(np.sum((sens.matrix[rows] * 200.0) ** 2))
    assert pick[200.0].errors["D0"].first_order == pytest.approx(expected, rel=1e-9)
    assert pick[200.0].errors["D0"].first_order == pytest.approx(2 * pick[100.0].errors["D0"].first_order)
    for fam in ("Ka", "Kg"):   # same draws: the second order is quadratic in the level
        assert pick[200.0].errors[fam].second_order == pytest.approx(4 * pick[100.0].errors[fam].second_order,
                                                                     rel=0.02)
    # Together they agree with the exact Monte Carlo of `bench evaluate` (RSS over axes, RMS over runs).
    draws = np.random.default_rng(0).standard_normal((200, 3, 3)) * 200.0 * ARCSEC
    mc = position_errors(angles, draws, default_sim_imu(), Site())
    mc_rms = float(np.sqrt(np.mean(mc["gyro_bias_dph"] ** 2)))
    assert pick[200.0].errors["D0"].black_box == pytest.approx(mc_rms, rel=0.25)


def test_a_perfect_table_is_driven_by_noise_longer_dwell_is_better_within_the_budget():
    budget = 6000.0
    rec = _small(budget, PointingLevel.uniform(0.0))
    assert all(e.black_box == 0.0 for c in rec.ranked for e in c.errors.values())
    best = rec.best
    same = [c for c in rec.ranked if c.pair == best.pair and c.revolutions == best.revolutions]
    assert best.dwell_s == max(c.dwell_s for c in same)
    by_dwell = sorted(same, key=lambda c: c.dwell_s)
    assert all(a.score > b.score for a, b in zip(by_dwell, by_dwell[1:]))
    assert best.duration_s <= budget
    assert best.duration_s > 0.6 * budget     # it uses the budget


def test_a_tiny_budget_takes_only_what_fits_and_too_tiny_is_an_error():
    full = _small(1e6, PointingLevel.uniform(20.0))
    shortest = min(full.ranked, key=lambda c: c.duration_s)
    budget = shortest.duration_s + 50.0
    rec = _small(budget, PointingLevel.uniform(20.0))
    assert rec.ranked and all(c.duration_s <= budget for c in rec.ranked)
    assert len(rec.ranked) < len(full.ranked) / 10
    with pytest.raises(RecommendError, match=r"no candidate plan fits a budget of .* the shortest is "
                                             r"traditional-12 \+ \S+ at 10 s dwell, 1 rev"):
        _small(shortest.duration_s - 1.0, PointingLevel.uniform(20.0))


def test_durations_are_the_plan_compilers():
    rec = _small(1e6, PointingLevel.uniform(20.0))
    for c in rec.ranked[::13]:
        plan = compile_plan(c.positions, c.rotations, PlanTiming(dwell_s=c.dwell_s, revolutions=c.revolutions))
        assert c.duration_s == pytest.approx(plan.estimated_total_s, abs=1e-6)


def test_bad_api_inputs_are_typed_errors():
    for budget in (0, -5.0, float("nan"), True, "100"):
        with pytest.raises(RecommendError, match="time budget"):
            _small(budget, PointingLevel.uniform(1.0))
    for level in (-1.0, float("inf"), None):
        with pytest.raises(RecommendError, match="pointing RMS"):
            PointingLevel.uniform(level)
    with pytest.raises(RecommendError, match="no noise for"):
        recommend(1e5, PointingLevel.uniform(1.0), NoiseModel.off(), positions=[OPT[0]], rotations=[OPT[1]])
    with pytest.raises(RecommendError, match="table-check.*position candidate"):
        recommend(1e5, PointingLevel.uniform(1.0), NOISE, positions=[load_builtin("table-check-324")],
                  rotations=[OPT[1]])


# --- table checks -------------------------------------------------------------------------------

def _check_json(tmp_path, box_arcsec) -> tuple[str, dict]:
    """A real table-check result: the estimate from exact horizontal force on the 324 positions."""
    box = np.asarray(box_arcsec, dtype=float).reshape(3, 3) * ARCSEC
    sigma = np.full((len(CHECK_324), 2), 1e-6)
    noise = np.random.default_rng(3).standard_normal(sigma.shape) * 1e-6
    est = estimate(CHECK_324, horizontal_force(CHECK_324, box) + noise, sigma)
    analysis = TableCheckAnalysis("check-1", str(tmp_path / "check-1.mcap"), "simulator", est,
                                  Conversion(np.full(3, 1.0), "test", True, 0.0), [f"P{i}" for i in range(324)],
                                  10.0, {}, {}, black_box_rad=box)
    doc = analysis.to_json()
    path = tmp_path / "check-1.table-check.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    return str(path), doc


def test_a_table_check_sets_per_angle_levels(tmp_path):
    # alpha_o 40", beta_o -15", alpha_m + alpha_i = 60 + 20, beta_m + beta_i = 0; gammas unseen.
    path, doc = _check_json(tmp_path, [[40, -15, 7], [60, 0, 30], [20, 0, -9]])
    level = load_table_check(path)
    values = {c["key"]: (c["value_arcsec"], c["sigma_arcsec"]) for c in doc["combinations"]}
    lv = level.per_angle_arcsec
    assert lv[0, 0] == pytest.approx(np.hypot(*values["level_alpha"]))
    assert lv[0, 0] == pytest.approx(40.0, abs=0.5)
    assert lv[0, 1] == pytest.approx(15.0, abs=0.5)
    assert lv[1, 0] == lv[2, 0] == pytest.approx(80.0 / np.sqrt(2.0), abs=0.5)   # split evenly
    assert lv[1, 1] == lv[2, 1] < 1.0
    observed = lv[:, :2]
    assert lv[:, 2] == pytest.approx(np.full(3, np.sqrt(np.mean(observed ** 2))))
    assert any("not observed" in n and "gamma" in n for n in level.notes)
    assert level.source.endswith("check-1.table-check.json")

    rc, out, err = cli(["schedules", "recommend", "--budget-s", "3000", "--check", path, "--runs", "16"])
    assert rc == 0, err
    assert "table: table check" in out and "split evenly" in out and "recommended:" in out


def test_bad_table_check_documents_are_one_line_errors(tmp_path):
    _, doc = _check_json(tmp_path, np.zeros(9))
    bad = [({"format": "something/else"}, "not a table-check result"),
           ({**doc, "combinations": []}, "'combinations' must be a non-empty list"),
           ({**doc, "combinations": [{"value_arcsec": 1.0}]}, r"combinations\[0\]: needs value_arcsec"),
           ({**doc, "combinations": [{**doc["combinations"][0], "coefficients": {"delta_x": 1.0}}]},
            "unknown angle 'delta_x'")]
    for data, message in bad:
        with pytest.raises(RecommendError, match=message):
            pointing_from_table_check(data, "x.json")
    broken = tmp_path / "broken.json"
    broken.write_text("{not json", encoding="utf-8")
    for path, message in ((broken, "not a JSON table-check result"), (tmp_path / "missing.json", "cannot read")):
        rc, out, err = cli(["schedules", "recommend", "--budget-s", "8000", "--check", str(path)])
        assert rc == 2 and out == ""
        assert err.count("\n") == 1 and message in err and str(path) in err


# --- the command ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    """One run over the shipped candidates plus a candidate file (a renamed copy of optimal-24)."""
    tmp = tmp_path_factory.mktemp("recommend")
    own = tmp / "mine-24.toml"
    own.write_text(builtin_path("optimal-24").read_text(encoding="utf-8")
                   .replace('name = "optimal-24"', 'name = "mine-24"'), encoding="utf-8")
    config = tmp / "plan.toml"
    rc, out, err = cli(["schedules", "recommend", "--budget-s", "9000", "--pointing-arcsec", "200",
                        "--candidates", str(own), "--runs", "16", "--top", "20", "--write-config", str(config)])
    return rc, out, err, config, own


def test_the_command_prints_recommendation_table_score_and_why(default_run):
    rc, out, err, _, _ = default_run
    assert rc == 0, err
    m = re.search(r"recommended: (\S+) \+ (\S+), dwell (\d+) s, (\d) rev: \S+ \((\d+) s\) of the 2:30:00 budget, "
                  r"score ([\d.]+)", out)
    assert m, out
    assert m.group(1) != "traditional-12" and m.group(2) != "traditional-3s6r"
    assert int(m.group(5)) <= 9000
    for title in ("gyro bias", "acc bias", "acc scale", "acc axes", "gyro scale", "gyro axes"):
        assert title in out
    assert "315 plans considered" not in out and "420 plans considered" in out   # 4 x 3 pairs x 7 x 5
    assert "mine-24 + " in out
    assert re.search(r"traditional-12 \+ \S+: leaves first-order \S+ \S+ [\d.e+-]+ \S+ at the table's 200 arcsec",
                     out)
    assert "score = RMS over the six families" in out and "not in the score: the inner frame's zero offset" in out


def test_the_written_config_loads_and_compiles_to_the_predicted_duration(default_run):
    rc, out, err, config, own = default_run
    assert rc == 0, err
    snippet = config.read_text(encoding="utf-8")
    parsed = parse_config(_with_plan(snippet), source=str(config))
    m = re.search(r"recommended: (\S+) \+ (\S+), dwell (\d+) s, (\d) rev: \S+ \((\d+) s\)", out)
    assert parsed.plan.positions.name == m.group(1) and parsed.plan.rotations.name == m.group(2)
    assert parsed.plan.dwell_s == float(m.group(3)) and parsed.plan.revolutions == int(m.group(4))
    assert compile_from_config(parsed).estimated_total_s == pytest.approx(float(m.group(5)), abs=1.0)


def test_a_snippet_names_candidate_files_by_absolute_path(tmp_path):
    own = tmp_path / "mine-5s6r.toml"
    own.write_text(builtin_path("optimal-5s6r").read_text(encoding="utf-8")
                   .replace('name = "optimal-5s6r"', 'name = "mine-5s6r"'), encoding="utf-8")
    from schedules import load_schedule

    rec = recommend(20000.0, PointingLevel.uniform(100.0), NOISE, positions=[OPT[0]],
                    rotations=[load_schedule(own), TRAD[1]], runs=8)
    assert rec.best.rotations.name == "mine-5s6r"
    snippet = plan_snippet(rec)
    assert f'rotations = "{own.resolve()}"' in snippet
    parsed = parse_config(_with_plan(snippet), source="<elsewhere>", base_dir="/")
    assert parsed.plan.rotations.name == "mine-5s6r"
    assert compile_from_config(parsed).estimated_total_s == pytest.approx(rec.best.duration_s, abs=1e-6)


@pytest.mark.parametrize("argv, code, message", [
    (["--budget-s", "100", "--pointing-arcsec", "20"], 2, "no candidate plan fits a budget of 100 s"),
    (["--budget-s", "0", "--pointing-arcsec", "20"], 2, "time budget must be a positive number"),
    (["--budget-s", "5000", "--pointing-arcsec", "-3"], 2, "pointing RMS must be"),
    (["--budget-s", "5000", "--pointing-arcsec", "20", "--gyro-arw", "-1"], 2, "noise options must be"),
    (["--budget-s", "5000", "--pointing-arcsec", "20", "--runs", "0"], 2, "--runs and --top must be >= 1"),
    (["--budget-s", "5000", "--pointing-arcsec", "20", "--latitude", "100"], 2, "latitude"),
    (["--budget-s", "5000", "--pointing-arcsec", "20", "--candidates", "no-such.toml"], 1, "no-such.toml"),
    (["--budget-s", "5000", "--pointing-arcsec", "20", "--candidates", "table-check-324"], 2,
     "'table-check' schedule cannot calibrate"),
])
def test_bad_command_inputs_are_one_line_errors(argv, code, message):
    rc, out, err = cli(["schedules", "recommend", *argv])
    assert rc == code and out == ""
    assert err.count("\n") == 1 and message in err, err


def test_pointing_and_check_are_exclusive_and_one_is_required(capsys):
    for argv in (["--budget-s", "5000"], ["--budget-s", "5000", "--pointing-arcsec", "1", "--check", "x.json"]):
        with pytest.raises(SystemExit) as exc:
            cli(["schedules", "recommend", *argv])
        assert exc.value.code == 2


def test_an_unwritable_config_path_is_a_one_line_error(tmp_path):
    rc, out, err = cli(["schedules", "recommend", "--budget-s", "3000", "--pointing-arcsec", "20", "--runs", "4",
                        "--write-config", str(tmp_path / "no" / "such" / "dir" / "plan.toml")])
    assert rc == 2 and "recommended:" in out
    assert err.count("\n") == 1 and "cannot write" in err


def test_schedule_errors_propagate_from_candidate_files(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 3\n", encoding="utf-8")
    from bench.schedule_design.recommend import resolve_candidates

    with pytest.raises(ScheduleError):
        resolve_candidates([str(bad)])
