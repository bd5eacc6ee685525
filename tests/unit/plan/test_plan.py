"""Plan compiler: step records, travel-time ordering, absolute targets, limits, estimates."""

from __future__ import annotations

import itertools
import math
import random

import numpy as np
import pytest

from bench.model.motion import trapezoid_timing
from bench.model.units import format_hms
from bench.plan.compiler import CompiledPlan, PlanError, PlanTiming, compile_plan
from bench.plan.order import _exact_order, _path_cost, order_units
from bench.plan.steps import DwellStep, MoveStep, SettleStep, TurnStep
from drivers.turntable.base import AxisLimits, TurntableLimits
from schedules import load_builtin, parse_schedule

TIMING = PlanTiming()


def positions_schedule(angles, kind="table-check", name="tiny"):
    body = "".join(f"[[position]]\nangles_deg = {list(a)}\n" for a in angles)
    return parse_schedule(f'format = "turntable-bench/schedule"\nversion = 1\nname = "{name}"\n'
                          f'kind = "{kind}"\ndescription = "test"\n{body}')


def rotations_schedule(rotations, name="tiny-rot"):
    body = "".join(f'[[rotation]]\nstart_deg = {list(s)}\nframe = "{f}"\ndirection = "{d}"\nrevolutions = {n}\n'
                   for s, f, d, n in rotations)
    return parse_schedule(f'format = "turntable-bench/schedule"\nversion = 1\nname = "{name}"\n'
                          f'kind = "rotations"\ndescription = "test"\n{body}')


@pytest.fixture(scope="module")
def optimal():
    return load_builtin("optimal-24"), load_builtin("optimal-5s6r")


@pytest.fixture(scope="module")
def optimal_plan(optimal):
    return compile_plan(*optimal, TIMING)


def walk_positions(plan: CompiledPlan, start=(0.0, 0.0, 0.0)):
    """(move step, where the table was before it) for every move, tracking turns."""
    here, out = tuple(start), []
    for step in plan.steps:
        if isinstance(step, MoveStep):
            out.append((step, here))
            here = step.target_deg
        elif isinstance(step, TurnStep):
            assert step.target_deg == here
            here = step.end_deg
    return out


# --- structure -------------------------------------------------------------------------

def test_optimal_plan_structure(optimal, optimal_plan):
    positions, rotations = optimal
    plan = optimal_plan
    assert len(plan.steps) == 3 * (24 + 6)
    assert [s.index for s in plan.steps] == list(range(len(plan.steps)))
    units = plan.units
    assert len(units) == 30 and len(set(units)) == 30
    assert all(u.startswith("P") for u in units[:24]) and all(u.startswith("R") for u in units[24:])
    assert sorted(units[:24]) == [f"P{i:02d}" for i in range(1, 25)]
    assert sorted(units[24:]) == [f"R{i:02d}" for i in range(1, 7)]
    for unit in units:
        kinds = [s.kind for s in plan.steps_of(unit)]
        assert kinds == (["move", "settle", "dwell"] if unit[0] == "P" else ["move", "settle", "turn"])
    dwells = [s for s in plan.steps if isinstance(s, DwellStep)]
    assert sorted(d.schedule_index for d in dwells) == list(range(24))  # each position exactly once
    for d in dwells:
        assert d.unit == f"P{d.schedule_index + 1:02d}" and d.schedule == "optimal-24"
        assert d.angles_deg == positions.positions[d.schedule_index].angles_deg
        assert d.dwell_s == d.estimated_s == 60.0
    turns = [s for s in plan.steps if isinstance(s, TurnStep)]
    assert sorted(t.schedule_index for t in turns) == list(range(6))
    for t in turns:
        r = rotations.rotations[t.schedule_index]
        assert t.unit == f"R{t.schedule_index + 1:02d}"
        assert (t.start_deg, t.frame, t.direction, t.revolutions) == (r.start_deg, r.frame, r.direction, 1)
        assert (t.rate_dps, t.accel_dps2, t.rest_s) == (10.0, 5.0, 2.0)
    assert all(s.duration_s == 5.0 for s in plan.steps if isinstance(s, SettleStep))
    assert math.isclose(plan.estimated_total_s, sum(s.estimated_s for s in plan.steps))
    with pytest.raises(KeyError, match="P99"):
        plan.steps_of("P99")


def test_optimal_order_beats_listing_order(optimal, optimal_plan):
    plan = optimal_plan
    assert plan.order == "optimal"
    assert plan.lower_bound_s <= plan.estimated_total_s <= plan.listed_total_s
    assert plan.estimated_total_s < plan.listed_total_s  # strictly: the paper's listing is not the best tour
    listed = compile_plan(*optimal, TIMING, order="listed")
    assert listed.units == [f"P{i:02d}" for i in range(1, 25)] + [f"R{i:02d}" for i in range(1, 7)]
    assert listed.estimated_total_s == pytest.approx(plan.listed_total_s)
    assert listed.listed_total_s == listed.estimated_total_s
    assert listed.lower_bound_s == pytest.approx(plan.lower_bound_s)
    # Lower bound: 24 x (5 + 60) + 6 x (5 + 2 + 2 + turn of 360 deg at 10 deg/s, 5 deg/s^2 = 38 s)
    assert plan.lower_bound_s == pytest.approx(24 * 65 + 6 * (5 + 4 + 38))
    # Every move here is >= one 90 deg move (7.0 s): 23 position moves + 5 rotation moves is the optimum.
    assert plan.move_total_s == pytest.approx((23 + 5) * 7.0)


@pytest.mark.parametrize("names", [("optimal-24", "optimal-5s6r"), ("traditional-12", "traditional-3s6r"),
                                   ("all-64", "all-96")])
def test_every_builtin_pair_ordered_no_worse_than_listed(names):
    plan = compile_plan(load_builtin(names[0]), load_builtin(names[1]), TIMING)
    assert plan.lower_bound_s <= plan.estimated_total_s <= plan.listed_total_s + 1e-9
    assert len(plan.units) == len(load_builtin(names[0]).steps) + len(load_builtin(names[1]).steps)


def test_deterministic(optimal, optimal_plan):
    assert compile_plan(*optimal, TIMING).steps == optimal_plan.steps


# --- absolute targets --------------------------------------------------------------------

def test_targets_are_nearest_equivalents_after_turns(optimal_plan):
    moves = walk_positions(optimal_plan)
    steps = optimal_plan.steps
    for move, here in moves:
        observation = next(s for s in steps if s.unit == move.unit and s.kind in ("dwell", "turn"))
        nominal = observation.angles_deg if isinstance(observation, DwellStep) else observation.start_deg
        assert observation.target_deg == move.target_deg
        for k in range(3):
            assert (move.target_deg[k] - nominal[k]) % 360 == pytest.approx(0.0, abs=1e-9)
            assert abs(move.target_deg[k] - here[k]) <= 180.0  # never unwinds a turn
    # The plan does turn CCW on the outer axis, so some target sits a whole turn away from nominal.
    assert any(isinstance(s, TurnStep) and s.end_deg[0] != s.target_deg[0] for s in steps)


def test_start_position_multi_turn_is_not_unwound():
    plan = compile_plan(positions_schedule([(0, 0, 0), (90, 0, 0)], kind="positions"), None, TIMING,
                        start_deg=(720.0, 0.0, -360.0))
    first = plan.steps[0]
    assert first.target_deg == (720.0, 0.0, -360.0) and first.estimated_s == 0.0
    assert plan.steps[3].target_deg == (810.0, 0.0, -360.0)


def test_limited_axis_uses_equivalent_within_limits(optimal):
    limits = TurntableLimits((AxisLimits(), AxisLimits(-90.0, 180.0), AxisLimits()))
    plan = compile_plan(*optimal, TIMING, limits=limits)
    middles = [m.target_deg[1] for m, _ in walk_positions(plan)]
    assert all(-90.0 <= m <= 180.0 for m in middles)
    assert -90.0 in middles and 270.0 not in middles
    for s in plan.steps:
        if isinstance(s, TurnStep):
            assert -90.0 <= s.target_deg[1] <= 180.0 and -90.0 <= s.end_deg[1] <= 180.0
    assert plan.lower_bound_s <= plan.estimated_total_s <= plan.listed_total_s


def test_limited_outer_axis_turns_stay_inside():
    limits = TurntableLimits((AxisLimits(-400.0, 400.0), AxisLimits(), AxisLimits()))
    rot = rotations_schedule([((0, 90, 0), "outer", "ccw", 1), ((0, 270, 180), "outer", "cw", 1),
                              ((0, 90, 90), "outer", "ccw", 1)])
    plan = compile_plan(None, rot, TIMING, limits=limits)
    for s in plan.steps:
        if isinstance(s, TurnStep):
            assert -400 <= s.target_deg[0] <= 400 and -400 <= s.end_deg[0] <= 400
    # Two CCW turns in a row would leave -720: the second must start back at 0 (a full unwind).
    assert [s.target_deg[0] for s in plan.steps if isinstance(s, TurnStep)].count(0.0) >= 2


def test_limits_make_plan_impossible():
    narrow = TurntableLimits((AxisLimits(), AxisLimits(-10.0, 100.0), AxisLimits()))
    with pytest.raises(PlanError, match=r"P05 .*middle angle 180 deg"):
        compile_plan(load_builtin("optimal-24"), None, TIMING, limits=narrow)
    half_turn = TurntableLimits((AxisLimits(), AxisLimits(-180.0, 180.0), AxisLimits()))
    rot = rotations_schedule([((0, 0, 0), "outer", "ccw", 1), ((0, 0, 0), "middle", "cw", 1)])
    with pytest.raises(PlanError, match=r"R02 .*middle a CW turn of 1 rev"):
        compile_plan(None, rot, TIMING, limits=half_turn)
    slow = TurntableLimits((AxisLimits(max_rate_dps=5.0), AxisLimits(), AxisLimits()))
    with pytest.raises(PlanError, match=r"R01 .*outer turn at 10 deg/s"):
        compile_plan(None, rot, TIMING, limits=slow)


# --- estimates ----------------------------------------------------------------------------

def test_hand_computed_durations():
    pos = positions_schedule([(0, 0, 0), (0, 0, 10), (0, 180, 10)])
    rot = rotations_schedule([((0, 90, 0), "outer", "ccw", 1)])
    plan = compile_plan(pos, rot, TIMING, order="listed")
    est = [s.estimated_s for s in plan.steps]
    # P01: no move (no overhead). P02: 10 deg triangle at 10 deg/s^2: 2 x 1 s + 0.5 s.
    # P03: 180 deg trapezoid: 2 x 2 s ramps + 140 deg / 20 deg/s + 0.5 s = 11.5 s.
    # R01: middle 90 deg (6.5 s) and inner 10 deg (2 s) together: 6.5 + 0.5 s; turn 2 + 2 + 38 s.
    assert est == pytest.approx([0.0, 5, 60, 2.5, 5, 60, 11.5, 5, 60, 7.0, 5, 42.0])
    assert plan.estimated_total_s == pytest.approx(263.0)
    assert plan.lower_bound_s == pytest.approx(3 * 65 + 5 + 42)
    assert plan.steps[-1].end_deg == (-360.0, 90.0, 0.0)
    # The optimal order visits (0, 180, 10) before (0, 0, 10)? No: 0 -> 10 -> 180 is already best.
    assert compile_plan(pos, rot, TIMING).estimated_total_s == pytest.approx(263.0)


def test_move_rate_capped_by_limits():
    limits = TurntableLimits((AxisLimits(), AxisLimits(), AxisLimits(max_rate_dps=10.0, max_accel_dps2=5.0)))
    plan = compile_plan(positions_schedule([(0, 0, 0), (90, 0, 0), (90, 0, 90)], kind="positions"), None,
                        PlanTiming(move_overhead_s=0.0), limits=limits, order="listed")
    moves = [s for s in plan.steps if isinstance(s, MoveStep)]
    assert all(m.rate_dps == 10.0 for m in moves)
    # outer at 10 deg/s, 10 deg/s^2: 1 s ramps + 80/10 s; inner at 10 deg/s, 5 deg/s^2: 2 s ramps + 70/10 s.
    assert [m.estimated_s for m in moves] == pytest.approx([0.0, 10.0, 11.0])


def test_revolutions_override():
    timing = PlanTiming(revolutions=2)
    plan = compile_plan(None, load_builtin("optimal-5s6r"), timing)
    turns = [s for s in plan.steps if isinstance(s, TurnStep)]
    ramp, cruise, _ = trapezoid_timing(720.0, 10.0, 5.0)
    for t in turns:
        assert t.revolutions == 2
        assert abs(t.end_deg[t.frame_index] - t.target_deg[t.frame_index]) == 720.0
        assert t.estimated_s == pytest.approx(4.0 + 2 * ramp + cruise) == pytest.approx(78.0)
    assert plan.lower_bound_s == pytest.approx(6 * (5 + 78))


# --- ordering heuristic ---------------------------------------------------------------

def _random_instance(rng: random.Random, n: int):
    everything = [(o, m, i) for o in range(0, 360, 90) for m in range(0, 360, 90) for i in range(0, 360, 90)]
    angles = rng.sample(everything, n)
    start = tuple(float(rng.choice(range(0, 360, 90))) for _ in range(3))
    return angles, start


def test_exact_order_matches_brute_force():
    rng = np.random.default_rng(1)
    for _ in range(5):
        n = 7
        start, cost = rng.uniform(0, 10, n), rng.uniform(0, 10, (n, n))
        best = min(itertools.permutations(range(n)), key=lambda o: _path_cost(start, cost, o))
        assert _path_cost(start, cost, _exact_order(start, cost)) == pytest.approx(_path_cost(start, cost, best))


@pytest.mark.parametrize("seed", range(6))
def test_heuristic_finds_the_optimum_on_small_sets(seed):
    rng = random.Random(seed)
    angles, start = _random_instance(rng, 9)
    from bench.plan.compiler import _build_units, _Motion, _static_costs
    limits = TurntableLimits()
    motion = _Motion(TIMING, limits)
    units, _ = _build_units(positions_schedule(angles, kind="positions"), None, TIMING, limits)
    s, c = _static_costs(units, start, motion)
    exact = _path_cost(s, c, _exact_order(s, c))
    heuristic = _path_cost(s, c, order_units(s, c, exact_max=0)[0])
    assert heuristic <= exact * 1.01 + 1e-9
    # And the compiled plan (exact below 10 units) reaches that optimum.
    plan = compile_plan(positions_schedule(angles, kind="positions"), None, TIMING, start_deg=start)
    assert plan.move_total_s == pytest.approx(exact)


def test_heuristic_on_random_asymmetric_matrices():
    rng = np.random.default_rng(7)
    for _ in range(4):
        n = 9
        start, cost = rng.uniform(0, 10, n), rng.uniform(0, 10, (n, n))
        exact = _path_cost(start, cost, _exact_order(start, cost))
        orders = order_units(start, cost, exact_max=0)
        assert sorted(orders[0]) == list(range(n))
        assert _path_cost(start, cost, orders[0]) <= exact * 1.01 + 1e-9


def test_static_costs_match_the_walk_for_continuous_axes(optimal):
    from bench.plan.compiler import _build_units, _Motion, _static_costs, _walk
    limits = TurntableLimits()
    motion = _Motion(TIMING, limits)
    units, rot_units = _build_units(*optimal, TIMING, limits)
    for group in (units, rot_units):
        s, c = _static_costs(group, (0.0, 0.0, 0.0), motion)
        order = list(range(len(group)))[::-1]
        assert _walk(group, order, (0.0, 0.0, 0.0), motion)[1] == pytest.approx(_path_cost(s, c, order))


# --- dry run and validation --------------------------------------------------------------

def test_format_dry_run(optimal_plan):
    text = optimal_plan.format_dry_run()
    for unit in optimal_plan.units:
        assert f" {unit} " in text
    assert "estimated total:" in text and format_hms(optimal_plan.estimated_total_s) in text
    assert "listing-order total:" in text and format_hms(optimal_plan.listed_total_s) in text
    assert "lower bound:" in text and format_hms(optimal_plan.lower_bound_s) in text
    assert "saving vs listing order:" in text
    assert "dwell 60 s at (0, 90, 270) [optimal-24 #4]" in text
    assert "turn outer CCW 1 rev at 10 deg/s from (0, 90, 0) [optimal-5s6r #1]" in text
    assert len(text.splitlines()) == 2 + len(optimal_plan.steps) + 6
    assert format_hms(3725.4) == "1:02:05"


@pytest.mark.parametrize("field,value", [("dwell_s", 0.0), ("dwell_s", -1.0), ("settle_s", -0.1),
                                         ("move_rate_dps", math.nan), ("turn_accel_dps2", math.inf),
                                         ("move_accel_dps2", 0.0), ("rest_s", True), ("revolutions", 0),
                                         ("revolutions", 1.5), ("revolutions", True)])
def test_timing_validation_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        PlanTiming(**{field: value})
    assert PlanTiming(settle_s=0.0, rest_s=0.0, move_overhead_s=0.0).settle_s == 0.0


def test_bad_inputs_raise_plan_error(optimal):
    positions, rotations = optimal
    with pytest.raises(PlanError, match="not positions"):
        compile_plan(rotations, None, TIMING)
    with pytest.raises(PlanError, match="not rotations"):
        compile_plan(None, positions, TIMING)
    with pytest.raises(PlanError, match="nothing to compile"):
        compile_plan(None, None, TIMING)
    with pytest.raises(PlanError, match="unknown order"):
        compile_plan(positions, None, TIMING, order="fastest")
    with pytest.raises(PlanError, match="start_deg"):
        compile_plan(positions, None, TIMING, start_deg=(0.0, math.nan, 0.0))
    with pytest.raises(PlanError, match="start_deg"):
        compile_plan(positions, None, TIMING, start_deg=(0.0, 0.0))
    with pytest.raises(PlanError, match="start_deg"):
        compile_plan(positions, None, TIMING, start_deg=None)
    with pytest.raises(PlanError, match="PlanTiming"):
        compile_plan(positions, None, {"dwell_s": 1})


@pytest.mark.parametrize("name,moves", [("all-64", 63), ("all-96", 36), ("optimal-24", 23)])
def test_heuristic_reaches_the_move_count_bound_on_big_sets(name, moves):
    # Distinct positive attitudes are >= 90 deg apart (one 7.0 s move); shared start states cost nothing.
    schedule = load_builtin(name)
    plan = compile_plan(schedule if schedule.kind == "positions" else None,
                        schedule if schedule.kind == "rotations" else None, TIMING)
    assert plan.move_total_s == pytest.approx(moves * 7.0)


def test_version_2_plan_compiles_tilts_and_each_turns_own_rate():
    """Issue 30: the shipped extended plan (version 2) compiles its 45-deg tilts as they are and each turn at its
    own rate, whatever [plan] turn_rate_dps says; its estimate takes each turn's rate."""
    from bench.plan.retime import TimingProfile, retime

    positions, rotations = load_builtin("extended-44"), load_builtin("extended-5s6r-2rates")
    timing = PlanTiming(dwell_s=20.0, turn_rate_dps=25.0)
    plan = compile_plan(positions, rotations, timing)
    dwells = {s.unit: s.angles_deg for s in plan.steps if isinstance(s, DwellStep)}
    assert len(dwells) == 44 and dwells["P25"] == (0.0, 45.0, 0.0) and dwells["P29"] == (0.0, 45.0, 270.0)
    turns = {s.unit: s for s in plan.steps if isinstance(s, TurnStep)}
    assert {u: t.rate_dps for u, t in turns.items()} == {f"R{k:02d}": 10.0 if k <= 6 else 40.0 for k in range(1, 13)}
    for unit, turn in turns.items():
        ramp, cruise, _ = trapezoid_timing(360.0, turn.rate_dps, timing.turn_accel_dps2)
        assert turn.estimated_s == pytest.approx(2 * timing.rest_s + 2 * ramp + cruise), unit
    assert turns["R01"].estimated_s > turns["R07"].estimated_s    # 10 deg/s turns last longer
    # the re-timing takes the same rates
    accel = (timing.turn_accel_dps2,) * 3
    estimates = retime(plan.steps, TimingProfile("plan", (timing.move_accel_dps2,) * 3, accel, 0.5, 0.0))
    for step, estimate in zip(plan.steps, estimates):
        if isinstance(step, TurnStep):
            assert estimate == pytest.approx(step.estimated_s)
    # another [plan] turn rate leaves the turns as they are: each keeps its own
    other = compile_plan(positions, rotations, PlanTiming(dwell_s=20.0, turn_rate_dps=40.0))
    assert [s for s in other.steps if isinstance(s, TurnStep)] == [s for s in plan.steps if isinstance(s, TurnStep)]
