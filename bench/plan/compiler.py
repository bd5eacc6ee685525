"""Plan compiler: schedules + timing -> a flat tuple of step records, ordered for least table travel.

`compile_plan` turns a position schedule and a rotation schedule into `bench.plan.steps`
records (move, settle, dwell per position; move, settle, turn per rotation), chooses
the order in which the units are visited so that the total move time is small (the
set of positions is what the solver needs, not the paper's listing order) and
estimates every step's duration. Unit labels follow the *listing* order ("P03" is
the third position as listed) whatever order the plan visits them in.

Controller angles are multi-turn and absolute: each move goes to the equivalent of
the nominal angle (nominal + 360 k) nearest to where the axis is, inside the axis
travel limits if it has any, so that after a CCW turn the next move does not unwind
a whole revolution. Durations use trapezoidal rest-to-rest profiles
(`bench.model.motion.trapezoid_timing`); a move lasts as long as its slowest axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Sequence

import numpy as np

from bench.errors import InputError
from bench.model.kinematics import FRAMES
from bench.model.motion import trapezoid_timing
from bench.model.units import format_hms
from bench.plan.order import order_units
from bench.plan.steps import DwellStep, MoveStep, SetTemperatureStep, SettleStep, SoakStep, Step, TurnStep
from drivers.turntable.base import TurntableLimits
from schedules import RotationStep, Schedule

ORDERS = ("optimal", "listed")
_EPS_DEG = 1e-9


class PlanError(InputError):
    """A plan that cannot be compiled (bad schedule kind, a target outside the travel limits, ...)."""


@dataclass(frozen=True)
class PlanTiming:
    """Timing of a plan: dwell, settle, move and turn profiles, revolutions override.

    `revolutions` (if set) replaces every rotation's own number of turns;
    `move_overhead_s` is the command/poll latency added to every move that moves.
    """

    dwell_s: float = 60.0
    settle_s: float = 5.0
    move_rate_dps: float = 20.0
    move_accel_dps2: float = 10.0
    turn_rate_dps: float = 10.0
    turn_accel_dps2: float = 5.0
    rest_s: float = 2.0
    revolutions: int | None = None
    move_overhead_s: float = 0.5

    def __post_init__(self) -> None:
        # Waiting times may be zero; rates, accelerations and the dwell may not.
        may_be_zero = ("settle_s", "rest_s", "move_overhead_s")
        for f in fields(PlanTiming):   # not a subclass's own fields (PlanConfig)
            value = getattr(self, f.name)
            if f.name == "revolutions":
                if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
                    raise PlanError(f"revolutions must be a whole number >= 1 or None, got {value!r}")
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise PlanError(f"{f.name} must be a finite number, got {value!r}")
            if value < 0 or (value == 0 and f.name not in may_be_zero):
                raise PlanError(f"{f.name} must be {'>= 0' if f.name in may_be_zero else 'positive'}, got {value!r}")


def _fmt_angles(angles: tuple[float, ...]) -> str:
    return "(" + ", ".join(f"{a + 0.0:g}" for a in angles) + ")"


@dataclass(frozen=True)
class CompiledPlan:
    """The compiled plan: steps in execution order plus the duration estimates (s)."""

    steps: tuple[Step, ...]
    timing: PlanTiming
    order: str
    estimated_total_s: float
    lower_bound_s: float          # dwells + settles + turns: no moves at all
    listed_total_s: float         # the same plan visited in listing order

    @property
    def units(self) -> list[str]:
        """Unit labels in execution order."""
        return list(dict.fromkeys(s.unit for s in self.steps))

    def steps_of(self, unit: str) -> tuple[Step, ...]:
        """The steps of one unit, in order (KeyError if the plan has no such unit)."""
        found = tuple(s for s in self.steps if s.unit == unit)
        if not found:
            raise KeyError(f"no unit {unit!r} in this plan")
        return found

    @property
    def move_total_s(self) -> float:
        return sum(s.estimated_s for s in self.steps if isinstance(s, MoveStep))

    @property
    def saving_s(self) -> float:
        """Time saved against the listing order."""
        return self.listed_total_s - self.estimated_total_s

    def format_dry_run(self, estimates: Sequence[float] | None = None, timing: str = "") -> str:
        """The steps as a table (index, unit, kind, what, estimate, cumulative) and the totals. `estimates` (one
        per step, `bench.plan.retime`, whose profile `timing` names) replace the steps' own: the table, the
        estimated total and the lower bound take them; the listing-order comparison stays the plan's."""
        own = [s.estimated_s for s in self.steps]
        each = own if estimates is None else [float(e) for e in estimates]
        if len(each) != len(self.steps):
            raise ValueError(f"{len(each)} estimates for {len(self.steps)} steps")
        rows = []
        elapsed = 0.0
        for step, estimate_s in zip(self.steps, each):
            elapsed += estimate_s
            rows.append((str(step.index), step.unit, step.kind, _describe(step),
                         f"{estimate_s:.1f} s", format_hms(elapsed)))
        head = ("#", "unit", "kind", "description", "estimate", "cumulative")
        widths = [max(len(r[k]) for r in rows + [head]) for k in range(len(head))]
        align = ("r", "l", "l", "l", "r", "r")

        def line(cells):
            return "  ".join(c.rjust(w) if a == "r" else c.ljust(w)
                             for c, w, a in zip(cells, widths, align)).rstrip()

        out = [line(head), line(["-" * w for w in widths])] + [line(r) for r in rows]
        total_s = sum(each)
        moves_s = sum(e for s, e in zip(self.steps, each) if isinstance(s, MoveStep))
        saving = self.saving_s
        pct = 100.0 * saving / self.listed_total_s if self.listed_total_s > 0 else 0.0
        n_units = len(self.units)
        whose = f" by {timing}" if timing else ""
        out += [
            "",
            f"units: {n_units}, steps: {len(self.steps)}, order: {self.order}",
            f"estimated total:     {format_hms(total_s)} ({total_s:.1f} s), of which moves {moves_s:.1f} s{whose}",
        ]
        if estimates is not None:
            soaks = ", soaks as the air's change plus the stable time" if any(
                isinstance(s, SoakStep) for s in self.steps) else ""
            out.append(f"plan's own estimate: {format_hms(self.estimated_total_s)} ({self.estimated_total_s:.1f} s; "
                       f"[plan]'s move profile{soaks}; the log records it)")
        out += [
            f"listing-order total: {format_hms(self.listed_total_s)} ({self.listed_total_s:.1f} s)"
            + (" by [plan]'s profile" if estimates is not None else ""),
            f"lower bound:         {format_hms(total_s - moves_s)} ({total_s - moves_s:.1f} s; "
            "dwells, settles and turns, no moves)",
            f"saving vs listing order: {saving:.1f} s ({pct:.1f} %)",
        ]
        return "\n".join(out)


def _describe(step: Step) -> str:
    if isinstance(step, MoveStep):
        return f"move to {_fmt_angles(step.target_deg)} deg at {step.rate_dps:g} deg/s"
    if isinstance(step, SettleStep):
        return f"settle {step.duration_s:g} s"
    if isinstance(step, SetTemperatureStep):
        ramp = "controller's ramp" if step.ramp_c_per_min is None else f"ramp {step.ramp_c_per_min:g} degC/min"
        return f"chamber to {step.setpoint_c:g} degC ({ramp})"
    if isinstance(step, SoakStep):
        return (f"soak: IMU rate < {step.rate_c_per_min:g} degC/min for {step.stable_s / 60.0:g} min "
                f"(at most {step.max_soak_s / 60.0:g} min)")
    if isinstance(step, DwellStep):
        return (f"dwell {step.dwell_s:g} s at {_fmt_angles(step.angles_deg)} "
                f"[{step.schedule} #{step.schedule_index + 1}]")
    rev = "rev" if step.revolutions == 1 else "revs"
    return (f"turn {step.frame} {step.direction.upper()} {step.revolutions} {rev} at {step.rate_dps:g} deg/s "
            f"from {_fmt_angles(step.start_deg)} "
            f"[{step.schedule} #{step.schedule_index + 1}]")


# --- units and absolute targets ------------------------------------------------------

@dataclass(frozen=True)
class _Unit:
    label: str
    schedule: str
    schedule_index: int
    nominal_deg: tuple[float, float, float]
    # Per axis, the allowed range of k in nominal + 360 k (inclusive, +-inf when unbounded).
    k_range: tuple[tuple[float, float], ...]
    rotation: RotationStep | None = None
    revolutions: int = 0

    @property
    def turn_delta_deg(self) -> float:
        """Signed change of the turning axis's controller angle (CCW decreases it)."""
        if self.rotation is None:
            return 0.0
        return (-360.0 if self.rotation.direction == "ccw" else 360.0) * self.revolutions

    def target(self, axis: int, current_deg: float) -> float:
        """The equivalent of the nominal angle nearest to `current_deg` inside the allowed range."""
        nominal = self.nominal_deg[axis]
        lo, hi = self.k_range[axis]
        k = min(max(round((current_deg - nominal) / 360.0), lo), hi)
        return nominal + 360.0 * k

    def exit_deg(self, target_deg: tuple[float, ...]) -> tuple[float, float, float]:
        if self.rotation is None:
            outer, middle, inner = target_deg
            return outer, middle, inner
        end = list(target_deg)
        end[self.rotation.frame_index] += self.turn_delta_deg
        outer, middle, inner = end
        return outer, middle, inner


def _k_range(nominal: float, lo_deg: float | None, hi_deg: float | None, span: float = 0.0) -> tuple[float, float]:
    """Range of k with nominal + 360 k and nominal + 360 k + span both within [lo, hi]."""
    lo_k = -math.inf if lo_deg is None else math.ceil((lo_deg - nominal - min(span, 0.0)) / 360.0 - 1e-12)
    hi_k = math.inf if hi_deg is None else math.floor((hi_deg - nominal - max(span, 0.0)) / 360.0 + 1e-12)
    return lo_k, hi_k


def unit_label(prefix: str, index: int, count: int) -> str:
    """A unit's label: "P03" is the third of a schedule's positions, "R012" the 12th of its >= 100 rotations."""
    return f"{prefix}{index + 1:0{max(2, len(str(count)))}d}"


def own_turn_rates(rotations: Schedule | None) -> tuple[tuple[str, float], ...]:
    """(unit label, deg/s) of the turns of `rotations` that name their own rate (the others take the plan's)."""
    if rotations is None:
        return ()
    steps = rotations.rotations
    return tuple((unit_label("R", i, len(steps)), r.rate_dps) for i, r in enumerate(steps) if r.rate_dps is not None)


def _build_units(positions: Schedule | None, rotations: Schedule | None, timing: PlanTiming,
                 limits: TurntableLimits) -> tuple[list[_Unit], list[_Unit]]:
    pos_units, rot_units = [], []
    if positions is not None:
        if positions.kind not in ("positions", "table-check", "static", "verification"):
            raise PlanError(f"schedule {positions.name!r} is a {positions.kind!r} schedule, not positions")
        for i, p in enumerate(positions.positions):
            label = unit_label("P", i, len(positions.positions))
            ranges = []
            for axis, lim in enumerate(limits.axes):
                ranges.append(_k_range(p.angles_deg[axis], lim.min_deg, lim.max_deg))
                if ranges[-1][0] > ranges[-1][1]:
                    raise PlanError(f"{label} ({positions.name} #{i + 1}, move): {FRAMES[axis]} angle "
                                    f"{p.angles_deg[axis]:g} deg has no equivalent within the limits "
                                    f"[{lim.min_deg}, {lim.max_deg}] deg")
            pos_units.append(_Unit(label, positions.name, i, p.angles_deg, tuple(ranges)))
    if rotations is not None:
        if rotations.kind not in ("rotations", "verification"):
            raise PlanError(f"schedule {rotations.name!r} is a {rotations.kind!r} schedule, not rotations")
        for i, r in enumerate(rotations.rotations):
            label = unit_label("R", i, len(rotations.rotations))
            revs = timing.revolutions if timing.revolutions is not None else r.revolutions
            lim_turn = limits.axes[r.frame_index]
            rate_dps = r.rate_dps if r.rate_dps is not None else timing.turn_rate_dps   # the turn's own, if any
            if rate_dps > lim_turn.max_rate_dps or timing.turn_accel_dps2 > lim_turn.max_accel_dps2:
                raise PlanError(f"{label} ({rotations.name} #{i + 1}, turn): {r.frame} turn at "
                                f"{rate_dps:g} deg/s, {timing.turn_accel_dps2:g} deg/s^2 exceeds the "
                                f"axis limits {lim_turn.max_rate_dps:g} deg/s, {lim_turn.max_accel_dps2:g} deg/s^2")
            unit = _Unit(label, rotations.name, i, r.start_deg, (), r, revs)
            ranges = []
            for axis, lim in enumerate(limits.axes):
                span = unit.turn_delta_deg if axis == r.frame_index else 0.0
                ranges.append(_k_range(r.start_deg[axis], lim.min_deg, lim.max_deg, span))
                if ranges[-1][0] > ranges[-1][1]:
                    what = (f"a {r.direction.upper()} turn of {revs} rev from {r.start_deg[axis]:g} deg"
                            if axis == r.frame_index else f"angle {r.start_deg[axis]:g} deg")
                    raise PlanError(f"{label} ({rotations.name} #{i + 1}, turn): {FRAMES[axis]} {what} does not fit "
                                    f"within the limits [{lim.min_deg}, {lim.max_deg}] deg")
            rot_units.append(_Unit(label, rotations.name, i, r.start_deg, tuple(ranges), r, revs))
    return pos_units, rot_units


class _Motion:
    """Move and turn durations for a timing and a set of limits."""

    def __init__(self, timing: PlanTiming, limits: TurntableLimits):
        self.timing = timing
        # One rate for all axes (a move is one command); accelerations are per axis.
        self.move_rate_dps = min([timing.move_rate_dps] + [a.max_rate_dps for a in limits.axes])
        self.move_accel = [min(timing.move_accel_dps2, a.max_accel_dps2) for a in limits.axes]

    def axis_time(self, axis: int, distance_deg: float) -> float:
        if abs(distance_deg) <= _EPS_DEG:
            return 0.0
        ramp, cruise, _ = trapezoid_timing(distance_deg, self.move_rate_dps, self.move_accel[axis])
        return 2.0 * ramp + cruise

    def move_time(self, from_deg, to_deg) -> float:
        t = max(self.axis_time(k, to_deg[k] - from_deg[k]) for k in range(3))
        moved = any(abs(to_deg[k] - from_deg[k]) > _EPS_DEG for k in range(3))
        return t + self.timing.move_overhead_s if moved else 0.0

    def turn_time(self, revolutions: int, rate_dps: float | None = None) -> float:
        ramp, cruise, _ = trapezoid_timing(360.0 * revolutions, rate_dps or self.timing.turn_rate_dps,
                                           self.timing.turn_accel_dps2)
        return 2.0 * self.timing.rest_s + 2.0 * ramp + cruise


def _walk(units: list[_Unit], order, start_deg, motion: _Motion):
    """Visit `units` in `order` from `start_deg`: ([(unit, target, move_s)], total move s, end attitude)."""
    here = tuple(start_deg)
    legs, total = [], 0.0
    for i in order:
        unit = units[i]
        target = tuple(unit.target(k, here[k]) for k in range(3))
        move_s = motion.move_time(here, target)
        legs.append((unit, target, move_s))
        total += move_s
        here = unit.exit_deg(target)
    return legs, total, here


def _static_costs(units: list[_Unit], start_deg, motion: _Motion) -> tuple[np.ndarray, np.ndarray]:
    """Move times from the start to each unit and from each unit's exit to each unit's entry.

    Exact for continuous axes (the nearest equivalent depends only on the angle mod 360);
    for limited axes the best pair of allowed equivalents (a lower bound of what the walk does).
    """
    n = len(units)
    start = np.array([motion.move_time(start_deg, [u.target(k, start_deg[k]) for k in range(3)]) for u in units])
    axis_s = np.zeros((3, n, n))
    moved = np.zeros((n, n), dtype=bool)
    for k in range(3):
        nominal = np.array([u.nominal_deg[k] for u in units])
        lo = np.array([u.k_range[k][0] for u in units])
        hi = np.array([u.k_range[k][1] for u in units])
        # Candidate absolute exits of each unit: its allowed equivalents (a few around 0 when unbounded).
        centre = np.clip(0.0, lo, hi)
        ks = np.clip(centre[:, None] + np.arange(-3, 4)[None, :], lo[:, None], hi[:, None])
        if np.all(np.isinf(lo)) and np.all(np.isinf(hi)):
            ks = np.zeros((n, 1))
        delta = np.array([u.turn_delta_deg if u.rotation is not None and u.rotation.frame_index == k else 0.0
                          for u in units])
        exits = nominal[:, None] + 360.0 * ks + delta[:, None]                  # (n, candidates)
        x = exits[:, None, :]                                                   # (i, 1, w)
        a = nominal[None, :, None]                                              # (1, j, 1)
        kk = np.clip(np.round((x - a) / 360.0), lo[None, :, None], hi[None, :, None])
        dist = np.abs(a + 360.0 * kk - x)                                       # (i, j, w)
        axis_s[k] = _trapezoid_s(dist, motion.move_rate_dps, motion.move_accel[k]).min(axis=2)
        moved |= dist.min(axis=2) > _EPS_DEG
    cost = axis_s.max(axis=0) + np.where(moved, motion.timing.move_overhead_s, 0.0)
    np.fill_diagonal(cost, 0.0)
    return start, cost


def _trapezoid_s(distance_deg: np.ndarray, rate: float, accel: float) -> np.ndarray:
    """Vectorised 2*ramp + cruise of `trapezoid_timing` (0 for no distance)."""
    d = np.where(distance_deg > _EPS_DEG, distance_deg, 0.0)
    full = d * accel >= rate * rate
    return np.where(full, rate / accel + d / rate, 2.0 * np.sqrt(d / accel))


def _choose_order(units: list[_Unit], start_deg, motion: _Motion, order: str) -> list[int]:
    listed = list(range(len(units)))
    if order == "listed" or len(units) <= 1:
        return listed
    start, cost = _static_costs(units, start_deg, motion)
    # The walk is the truth (greedy equivalents on limited axes): the best walk wins, listing order included.
    candidates = order_units(start, cost) + [listed]
    return min(candidates, key=lambda o: _walk(units, o, start_deg, motion)[1])


# --- compile ------------------------------------------------------------------------

def _emit(units, order, start_deg, motion, steps: list) -> tuple[float, float, float]:
    legs, _, end = _walk(units, order, start_deg, motion)
    t = motion.timing
    for unit, target, move_s in legs:
        steps.append(MoveStep(index=len(steps), unit=unit.label, target_deg=target, rate_dps=motion.move_rate_dps,
                              estimated_s=move_s))
        steps.append(SettleStep(index=len(steps), unit=unit.label, duration_s=t.settle_s, estimated_s=t.settle_s))
        if unit.rotation is None:
            steps.append(DwellStep(index=len(steps), unit=unit.label, schedule=unit.schedule,
                                   schedule_index=unit.schedule_index, angles_deg=unit.nominal_deg,
                                   target_deg=target, dwell_s=t.dwell_s, estimated_s=t.dwell_s))
        else:
            r = unit.rotation
            steps.append(TurnStep(index=len(steps), unit=unit.label, schedule=unit.schedule,
                                  schedule_index=unit.schedule_index, start_deg=unit.nominal_deg, target_deg=target,
                                  frame=r.frame, direction=r.direction, revolutions=unit.revolutions,
                                  rate_dps=r.rate_dps or t.turn_rate_dps, accel_dps2=t.turn_accel_dps2,
                                  rest_s=t.rest_s, estimated_s=motion.turn_time(unit.revolutions, r.rate_dps)))
    return end


def _plan_steps(pos_units, rot_units, start_deg, motion, order: str) -> list[Step]:
    steps: list[Step] = []
    pos_order = _choose_order(pos_units, start_deg, motion, order)
    here = _emit(pos_units, pos_order, start_deg, motion, steps)
    rot_order = _choose_order(rot_units, here, motion, order)
    _emit(rot_units, rot_order, here, motion, steps)
    return steps


def compile_plan(positions: Schedule | None, rotations: Schedule | None, timing: PlanTiming, *,
                 start_deg=(0.0, 0.0, 0.0), limits: TurntableLimits | None = None,
                 order: str = "optimal") -> CompiledPlan:
    """Compile schedules into steps: positions first (move, settle, dwell), then rotations (move, settle, turn).

    `start_deg` is where the table is (absolute controller angles); `order` "optimal"
    visits the units in the order of least move time, "listed" keeps the schedules' order.
    Raises `PlanError` when a target or a turn does not fit within `limits`.
    """
    if order not in ORDERS:
        raise PlanError(f"unknown order {order!r} (expected one of {', '.join(ORDERS)})")
    if not isinstance(timing, PlanTiming):
        raise PlanError(f"timing must be a PlanTiming, got {type(timing).__name__}")
    try:
        start = tuple(float(a) for a in start_deg)
    except (TypeError, ValueError) as exc:
        raise PlanError(f"start_deg must be three angles in deg, got {start_deg!r}") from exc
    if len(start) != 3 or not all(math.isfinite(a) for a in start):
        raise PlanError(f"start_deg must be three finite angles in deg, got {start_deg!r}")
    if positions is None and rotations is None:
        raise PlanError("nothing to compile: no position schedule and no rotation schedule")
    limits = limits if limits is not None else TurntableLimits()
    motion = _Motion(timing, limits)
    pos_units, rot_units = _build_units(positions, rotations, timing, limits)

    steps = _plan_steps(pos_units, rot_units, start, motion, order)
    total = sum(s.estimated_s for s in steps)
    lower = sum(s.estimated_s for s in steps if not isinstance(s, MoveStep))
    listed = total if order == "listed" else sum(
        s.estimated_s for s in _plan_steps(pos_units, rot_units, start, motion, "listed"))
    return CompiledPlan(tuple(steps), timing, order, total, lower, listed)


__all__ = ["ORDERS", "CompiledPlan", "PlanError", "PlanTiming", "compile_plan",
           "order_units"]
