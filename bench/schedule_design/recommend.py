"""Plan recommender: the schedule pair and dwell/revolutions that minimise the predicted error in a time budget.

For every pair (one position schedule, one rotation schedule) and every dwell time and
number of revolutions on a small grid, the plan's duration comes from the real plan
compiler (`bench.plan.compiler.compile_plan`, moves included). One compile per pair serves the
whole grid: the dwell enters the estimate linearly, and on a table without travel limits
(the compiler's default) whole turns end where they started modulo 360 deg, so the
visiting order and the moves do not depend on the revolutions, only each turn's time.
Plans that fit the budget are scored by their predicted error per coefficient family (gyro bias D0,
accelerometer bias K0, accelerometer scale Ka and axes Ea, gyro scale Kg and axes Eg):

- black box: the table's pointing error. First order: the root-sum-square over the
  family's coefficients and the nine angles of sensitivity (`bench.schedule_design.sensitivity`) x the
  angle's RMS level. Second order: a short Monte Carlo (fixed seed) of the exact
  noise-free solve with the angles drawn at their levels, minus each draw's first-order
  prediction, RMS over draws. Both are zero-mean in the angles, hence added in
  quadrature (odd moments of a normal vanish).
- irreducible: the inner frame's zero offset (gamma of C_m^i0) turns the IMU about the
  inner axis exactly as its mounting would; no schedule separates it (the paper's
  EXy/EYx remark), so it enters Ea and Eg of every plan alike at first order. It is
  reported on its own and left out of the comparison.
- noise: the 1-sigma of `position_noise_sigma` (dwell) / `rotation_noise_sigma` (turns).
- total = RSS of black box and noise.

Score = RMS over the six families of total / reference, the reference being the
noise-only error of optimal-24 at the default dwell and optimal-5s6r at its own
revolutions (`PlanTiming` defaults): 1.0 is what the paper's optimal plan achieves on a
perfect table. Lower is better.

Pointing level from a table check: each observable combination (sum over angles of
c_j * angle_j) of value v and 1-sigma s gives each angle it involves the level
sqrt((v^2 + s^2) / sum c_j^2), i.e. the angles are taken as independent, equally likely
contributors (the middle/inner split is unobservable at middle 0). Angles no
combination involves (the three gammas) take the RMS of the observed angles' levels.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.errors import InputError
from bench.model.earth import Site
from bench.model.families import (
    DESIGN_UNITS,
    POSITION_FAMILIES,
    ROTATION_FAMILIES,
    TITLES,
    family_of,
)
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu
from bench.parallel import run_tasks
from bench.plan.compiler import PlanError, PlanTiming, compile_plan
from bench.plan.steps import DwellStep, TurnStep
from bench.schedule_design.sensitivity import (
    ANGLE_NAMES,
    position_noise_sigma,
    predict_black_box,
    rotation_noise_sigma,
)
from bench.solve.methods import SolverError
from bench.table_check.estimate import ANGLE_NAMES as CHECK_ANGLES  # same flat order as the black box
from schedules import Schedule, load_builtin, resolve_schedule

FAMILIES = POSITION_FAMILIES + ROTATION_FAMILIES
POSITION_CANDIDATES = ("optimal-24", "traditional-12", "all-64")
ROTATION_CANDIDATES = ("optimal-5s6r", "traditional-3s6r", "all-96")
REFERENCE_PAIR = ("optimal-24", "optimal-5s6r")
DWELL_GRID_S = (10.0, 20.0, 30.0, 60.0, 120.0, 180.0, 300.0)
REVOLUTIONS_GRID = (1, 2, 3, 4, 5)
TABLE_CHECK_FORMAT = "turntable-bench/table-check"


class RecommendError(InputError):
    """Inputs from which no recommendation can be made (bad budget, level, check file, candidates)."""


# --- the table's pointing level ------------------------------------------------------------

@dataclass(frozen=True)
class PointingLevel:
    """RMS level of each of the nine black-box angles, arcsec (3, 3): rows outer/middle/inner, cols alpha/beta/gamma."""

    per_angle_arcsec: np.ndarray
    source: str
    notes: tuple[str, ...] = ()

    @classmethod
    def uniform(cls, rms_arcsec: float) -> "PointingLevel":
        if isinstance(rms_arcsec, bool) or not isinstance(rms_arcsec, (int, float)) \
                or not math.isfinite(rms_arcsec) or rms_arcsec < 0:
            raise RecommendError(f"the pointing RMS must be a finite number of arcsec >= 0, got {rms_arcsec!r}")
        return cls(np.full((3, 3), float(rms_arcsec)), f"{rms_arcsec:g} arcsec RMS on all nine angles")

    @property
    def rms_arcsec(self) -> float:
        return float(np.sqrt(np.mean(self.per_angle_arcsec ** 2)))


def pointing_from_table_check(data: dict, source: str = "<table check>") -> PointingLevel:
    """Per-angle levels from a `<run-id>.table-check.json` document (see the module docstring)."""
    if not isinstance(data, dict) or data.get("format") != TABLE_CHECK_FORMAT:
        found = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise RecommendError(f"{source}: not a table-check result (format {found!r}, expected "
                             f"{TABLE_CHECK_FORMAT!r}; write one with `bench check-table`)")
    combos = data.get("combinations")
    if not isinstance(combos, list) or not combos:
        raise RecommendError(f"{source}: field 'combinations' must be a non-empty list")
    levels = np.full(9, np.nan)
    notes = []
    for i, c in enumerate(combos):
        where = f"{source}: combinations[{i}]"
        try:
            value, sigma = float(c["value_arcsec"]), float(c["sigma_arcsec"])
            coefficients = {str(k): float(v) for k, v in dict(c["coefficients"]).items()}
        except (KeyError, TypeError, ValueError) as exc:
            raise RecommendError(f"{where}: needs value_arcsec, sigma_arcsec and coefficients ({exc})") from exc
        unknown = [k for k in coefficients if k not in CHECK_ANGLES]
        norm2 = sum(v * v for v in coefficients.values())
        if unknown or not norm2 > 0 or not (math.isfinite(value) and math.isfinite(sigma) and sigma >= 0):
            what = f"unknown angle {unknown[0]!r}" if unknown else "no non-zero coefficient or a bad value/sigma"
            raise RecommendError(f"{where}: {what}")
        level = math.sqrt((value ** 2 + sigma ** 2) / norm2)
        for name, coef in coefficients.items():
            if coef != 0.0:
                j = CHECK_ANGLES.index(name)
                levels[j] = level if np.isnan(levels[j]) else max(levels[j], level)
        if len(coefficients) > 1:
            notes.append(f"{c.get('key', i)} = {value:.1f} +- {sigma:.1f} arcsec split evenly over "
                         f"{', '.join(coefficients)}: {level:.1f} arcsec each")
    seen = ~np.isnan(levels)
    rms = float(np.sqrt(np.mean(levels[seen] ** 2)))
    unseen = [ANGLE_NAMES[j] for j in range(9) if not seen[j]]
    levels[~seen] = rms
    if unseen:
        notes.append(f"not observed by the check: {', '.join(unseen)}; taken at the observed RMS {rms:.1f} arcsec")
    return PointingLevel(levels.reshape(3, 3), f"table check {source}", tuple(notes))


def load_table_check(path: str | Path) -> PointingLevel:
    """Read a table-check JSON file; RecommendError naming the file when it cannot be used."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise RecommendError(f"{path}: cannot read the table check: {exc.strerror or exc}") from exc
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RecommendError(f"{path}: not a JSON table-check result ({exc})") from exc
    return pointing_from_table_check(data, str(path))


# --- predictions ------------------------------------------------------------------------------

@dataclass(frozen=True)
class FamilyError:
    """Predicted error of one family (display units of `DESIGN_UNITS`), RSS over its coefficients."""

    first_order: float
    second_order: float
    noise: float
    irreducible: float = 0.0        # inner zero offset, the same for every schedule: not in `total`

    @property
    def black_box(self) -> float:
        return math.hypot(self.first_order, self.second_order)

    @property
    def total(self) -> float:
        return math.hypot(self.black_box, self.noise)

    @property
    def dominant(self) -> str:
        return "black box" if self.black_box > self.noise else "noise"


@dataclass(frozen=True)
class Candidate:
    """One plan: schedules, dwell, revolutions, its compiled duration and predicted errors."""

    positions: Schedule
    rotations: Schedule
    dwell_s: float
    revolutions: int
    duration_s: float
    errors: dict[str, FamilyError]
    score: float

    @property
    def pair(self) -> str:
        return f"{self.positions.name} + {self.rotations.name}"


@dataclass
class Recommendation:
    """The best plan within the budget, every plan that fits (best first) and how they were scored."""

    budget_s: float
    level: PointingLevel
    noise: NoiseModel
    timing: PlanTiming
    reference: dict[str, float]     # family -> noise-only error of the reference plan
    ranked: list[Candidate]
    considered: int

    @property
    def best(self) -> Candidate:
        return self.ranked[0]

    def best_per_pair(self) -> list[Candidate]:
        """Each schedule pair's best fitting plan, best first."""
        seen: dict[str, Candidate] = {}
        for c in self.ranked:
            seen.setdefault(c.pair, c)
        return list(seen.values())

    def why(self) -> list[str]:
        """Plain-words reasons: what limits the best plan and why each other pair lost."""
        return explain(self)


def _family_rss(sigmas: dict[str, float], fam: str) -> float:
    return math.sqrt(sum(v * v for n, v in sigmas.items() if family_of(n) == fam))


def _with_revolutions(schedule: Schedule, revolutions: int) -> Schedule:
    return dataclasses.replace(schedule, rotations=tuple(dataclasses.replace(r, revolutions=revolutions)
                                                         for r in schedule.rotations))


def _turn_s(schedule: Schedule, revolutions: int, timing: PlanTiming) -> float:
    """The compiler's estimate of one turn of `revolutions` (rests and ramps included)."""
    one = dataclasses.replace(schedule, rotations=schedule.rotations[:1])
    plan = compile_plan(None, one, dataclasses.replace(timing, revolutions=revolutions))
    return sum(s.estimated_s for s in plan.steps if isinstance(s, TurnStep))


def reference_noise(noise: NoiseModel, timing: PlanTiming, site: Site, imu: ImuCoefficients) -> dict[str, float]:
    """Noise-only family errors of the reference plan (optimal-24 at the timing's dwell, optimal-5s6r as shipped)."""
    pos = np.array([p.angles_deg for p in load_builtin(REFERENCE_PAIR[0]).positions])
    turns = list(load_builtin(REFERENCE_PAIR[1]).rotations)
    with np.errstate(divide="ignore", invalid="ignore"):   # zero noise: no weights; caught just below
        try:
            sig = {**position_noise_sigma(pos, noise, timing.dwell_s, imu, site),
                   **rotation_noise_sigma(turns, noise, timing.turn_rate_dps, imu, site)}
        except SolverError:
            sig = {}
    ref = {f: _family_rss(sig, f) for f in FAMILIES}
    zero = [f for f, v in ref.items() if not (v > 0 and math.isfinite(v))]
    if zero:
        raise RecommendError(f"the noise model gives no noise for {', '.join(TITLES[f] for f in zero)}: "
                             "the score is relative to the noise of the optimal plan, so give a non-zero noise")
    return ref


def resolve_candidates(extra=()) -> tuple[list[Schedule], list[Schedule]]:
    """The shipped position and rotation candidates plus schedules named in `extra` (builtin names or files)."""
    positions = [load_builtin(n) for n in POSITION_CANDIDATES]
    rotations = [load_builtin(n) for n in ROTATION_CANDIDATES]
    for spec in extra:
        schedule = resolve_schedule(spec)   # ScheduleError names the file
        target = {"positions": positions, "rotations": rotations}.get(schedule.kind)
        if target is None:
            raise RecommendError(f"{spec}: a {schedule.kind!r} schedule cannot calibrate; candidates must be "
                                 "positions or rotations schedules")
        if all(s.name != schedule.name or s.source != schedule.source for s in target):
            target.append(schedule)
    return positions, rotations


def recommend(budget_s: float, level: PointingLevel, noise: NoiseModel, *, positions=None, rotations=None,
              site: Site | None = None, timing: PlanTiming | None = None, dwell_grid_s=DWELL_GRID_S,
              revolutions_grid=REVOLUTIONS_GRID, runs: int = 64, seed: int = 0,
              imu: ImuCoefficients | None = None, scheduler: str = "loop", workers: int | None = None,
              progress: Callable[[int, int], None] | None = None) -> Recommendation:
    """Score every (position, rotation, dwell, revolutions) plan that fits `budget_s` and rank them.

    The black-box predictions (one per schedule, with its Monte Carlo) are tasks of
    `bench.parallel.run_tasks` on `scheduler`; `progress(done, total)` after each.

    `positions` / `rotations` default to the shipped candidates. `timing` supplies the
    move, settle and turn profiles (its dwell and revolutions are the grid's to choose).
    Raises RecommendError (bad inputs, nothing fits) and ScheduleError (a bad candidate).
    """
    if isinstance(budget_s, bool) or not isinstance(budget_s, (int, float)) or not budget_s > 0 \
            or not math.isfinite(budget_s):
        raise RecommendError(f"the time budget must be a positive number of seconds, got {budget_s!r}")
    if not isinstance(runs, int) or runs < 1:
        raise RecommendError(f"the Monte-Carlo runs must be a whole number >= 1, got {runs!r}")
    dwell_grid_s = sorted({float(d) for d in dwell_grid_s})
    revolutions_grid = sorted({int(n) for n in revolutions_grid})
    if not dwell_grid_s or dwell_grid_s[0] <= 0 or not revolutions_grid or revolutions_grid[0] < 1:
        raise RecommendError("the dwell grid needs positive times and the revolutions grid whole numbers >= 1")
    if positions is None or rotations is None:
        default_pos, default_rot = resolve_candidates()
        positions = default_pos if positions is None else positions
        rotations = default_rot if rotations is None else rotations
    if not positions or not rotations:
        raise RecommendError("need at least one position and one rotation schedule as candidates")
    site = site or Site()
    imu = imu or default_sim_imu()
    timing = timing or PlanTiming()
    level_arcsec = np.asarray(level.per_angle_arcsec, dtype=float)
    unit_draws = np.random.default_rng(seed).standard_normal((runs, 3, 3))
    reference = reference_noise(noise, timing, site, imu)

    for sched, kind, what in [(x, "positions", "position") for x in positions] + \
                             [(x, "rotations", "rotation") for x in rotations]:
        if sched.kind != kind:
            raise RecommendError(f"{sched.source}: a {sched.kind!r} schedule given as a {what} candidate")
    plans = _durations(positions, rotations, timing, dwell_grid_s, revolutions_grid)
    shortest = min(plans, key=lambda k: plans[k])
    fitting = [k for k, d in plans.items() if d <= budget_s]
    if not fitting:
        p, r, dwell, revs = shortest
        raise RecommendError(f"no candidate plan fits a budget of {budget_s:g} s: the shortest is "
                             f"{positions[p].name} + {rotations[r].name} at {dwell:g} s dwell, {revs} rev "
                             f"({plans[shortest]:.0f} s)")

    # Predictions only for what some fitting plan uses (the Monte Carlo is the costly part): one task per
    # position schedule and per (rotation schedule, revolutions), a pure function of its arguments, so the same
    # on any scheduler
    pos_keys = sorted({k[0] for k in fitting})
    rot_keys = sorted({(k[1], k[3]) for k in fitting})
    calls: list[tuple] = [(np.array([x.angles_deg for x in positions[p].positions]), None, imu, site, unit_draws,
                           level_arcsec) for p in pos_keys]
    calls += [(None, list(_with_revolutions(rotations[r], revs).rotations), imu, site, unit_draws, level_arcsec,
               timing.turn_rate_dps) for r, revs in rot_keys]
    black_box: list = [None] * len(calls)
    for done, (index, result, error) in enumerate(run_tasks(predict_black_box, calls, scheduler=scheduler,
                                                            workers=workers), 1):
        if isinstance(error, SolverError):
            source = positions[pos_keys[index]].source if index < len(pos_keys) else \
                rotations[rot_keys[index - len(pos_keys)][0]].source
            raise RecommendError(f"{source}: {error}") from error
        if error is not None:
            raise error
        black_box[index] = result
        if progress is not None:
            progress(done, len(calls))
    pos_err, rot_err = {}, {}
    for k, p in enumerate(pos_keys):
        first, second, irreducible = black_box[k]
        angles = calls[k][0]
        for dwell in sorted({k[2] for k in fitting if k[0] == p}):
            sigma = position_noise_sigma(angles, noise, dwell, imu, site)
            pos_err[(p, dwell)] = {f: FamilyError(first[f], second[f], _family_rss(sigma, f), irreducible[f])
                                   for f in POSITION_FAMILIES}
    for k, (r, revs) in enumerate(rot_keys):
        first, second, irreducible = black_box[len(pos_keys) + k]
        try:
            sigma = rotation_noise_sigma(calls[len(pos_keys) + k][1], noise, timing.turn_rate_dps, imu, site)
        except SolverError as exc:
            raise RecommendError(f"{rotations[r].source}: {exc}") from exc
        rot_err[(r, revs)] = {f: FamilyError(first[f], second[f], _family_rss(sigma, f), irreducible[f])
                              for f in ROTATION_FAMILIES}

    ranked = []
    for key in fitting:
        p, r, dwell, revs = key
        errors = {**pos_err[(p, dwell)], **rot_err[(r, revs)]}
        score = math.sqrt(sum((errors[f].total / reference[f]) ** 2 for f in FAMILIES) / len(FAMILIES))
        ranked.append(Candidate(positions[p], rotations[r], dwell, revs, plans[key], errors, score))
    ranked.sort(key=lambda c: (c.score, c.duration_s))
    return Recommendation(float(budget_s), level, noise, timing, reference, ranked, len(plans))


def _durations(positions, rotations, timing: PlanTiming, dwell_grid_s, revolutions_grid) -> dict[tuple, float]:
    """(position index, rotation index, dwell, revolutions) -> the compiled plan's estimated duration, s.

    Positions and rotations are compiled apart, the rotations from where the positions
    end: `compile_plan` orders them the same way (positions first, then rotations).
    """
    n0, d0 = revolutions_grid[0], dwell_grid_s[0]
    turn_s = {n: _turn_s(rotations[0], n, timing) for n in revolutions_grid}
    out = {}
    for p, psched in enumerate(positions):
        try:
            plan = compile_plan(psched, None, dataclasses.replace(timing, dwell_s=d0))
        except PlanError as exc:
            raise RecommendError(f"{psched.source}: {exc}") from exc
        end = [s for s in plan.steps if isinstance(s, DwellStep)][-1].target_deg
        for r, rsched in enumerate(rotations):
            try:
                rot_plan = compile_plan(None, _with_revolutions(rsched, n0),
                                        dataclasses.replace(timing, revolutions=n0), start_deg=end)
            except PlanError as exc:
                raise RecommendError(f"{rsched.source}: {exc}") from exc
            for revs in revolutions_grid:
                rot_s = rot_plan.estimated_total_s + len(rsched.rotations) * (turn_s[revs] - turn_s[n0])
                for dwell in dwell_grid_s:
                    out[(p, r, dwell, revs)] = (plan.estimated_total_s + len(psched.positions) * (dwell - d0)
                                                + rot_s)
    return out


# --- words and config -----------------------------------------------------------------------------

def fmt_value(value: float, fam: str) -> str:
    return f"{value:.3g} {DESIGN_UNITS[fam][0]}"


def _setting(c: Candidate) -> str:
    return f"{c.dwell_s:g} s dwell, {c.revolutions} rev"


def explain(rec: Recommendation) -> list[str]:
    """What limits the best plan, and for each other pair the family that makes it worse."""
    best, ref = rec.best, rec.reference
    lines = []
    worst = max(FAMILIES, key=lambda f: best.errors[f].total / ref[f])
    e = best.errors[worst]
    lines.append(f"{best.pair} at {_setting(best)}: its largest error relative to the reference is "
                 f"{TITLES[worst]} {fmt_value(e.total, worst)} ({e.dominant} dominates: black box "
                 f"{fmt_value(e.black_box, worst)}, noise {fmt_value(e.noise, worst)})")
    longer = [c for c in rec.ranked if c.pair == best.pair and (c.dwell_s > best.dwell_s
                                                                or c.revolutions > best.revolutions)]
    noisy = [f for f in FAMILIES if best.errors[f].dominant == "noise"]
    if noisy and not longer:
        lines.append(f"noise dominates {', '.join(TITLES[f] for f in noisy)}: a longer dwell or more "
                     "revolutions would lower it, but no longer setting of this pair fits the budget")
    for other in rec.best_per_pair()[1:]:
        f = max(FAMILIES, key=lambda k: other.errors[k].total / best.errors[k].total)
        o, b = other.errors[f], best.errors[f]
        if o.dominant == "black box":
            part = "first-order" if o.first_order >= o.second_order else "second-order"
            reason = (f"leaves {part} {TITLES[f]} {fmt_value(o.black_box, f)} at the table's "
                      f"{rec.level.rms_arcsec:.3g} arcsec RMS, larger than the noise "
                      f"{fmt_value(o.noise, f)} after {_setting(other)}")
        else:
            reason = (f"its best setting that fits ({_setting(other)}, {other.duration_s:.0f} s) leaves "
                      f"{TITLES[f]} {fmt_value(o.total, f)}, mostly noise ({fmt_value(o.noise, f)})")
        lines.append(f"{other.pair}: {reason}; recommended: {fmt_value(b.total, f)}; score {other.score:.3g} "
                     f"vs {best.score:.3g}")
    return lines


def _schedule_ref(schedule: Schedule) -> str:
    if schedule.source.startswith("builtin:"):
        return schedule.name
    return str(Path(schedule.source).resolve())


def plan_snippet(rec: Recommendation, candidate: Candidate | None = None) -> str:
    """A [plan] table for a bench configuration (replace the config's own [plan] with it)."""
    c = candidate or rec.best
    t = rec.timing
    return "\n".join([
        f"# bench schedules recommend: budget {rec.budget_s:g} s, table {rec.level.source}; "
        f"estimated {c.duration_s:.0f} s, score {c.score:.3g}",
        "# Replace the [plan] table of your bench configuration with this one.",
        "[plan]",
        f"positions = {json.dumps(_schedule_ref(c.positions))}",
        f"rotations = {json.dumps(_schedule_ref(c.rotations))}",
        f"dwell_s = {c.dwell_s:g}",
        f"revolutions = {c.revolutions}",
        f"settle_s = {t.settle_s:g}",
        f"move_rate_dps = {t.move_rate_dps:g}",
        f"move_accel_dps2 = {t.move_accel_dps2:g}",
        f"turn_rate_dps = {t.turn_rate_dps:g}",
        f"turn_accel_dps2 = {t.turn_accel_dps2:g}",
        f"rest_s = {t.rest_s:g}",
        "",
    ])


__all__ = ["DWELL_GRID_S", "FAMILIES", "POSITION_CANDIDATES", "REFERENCE_PAIR", "REVOLUTIONS_GRID",
           "ROTATION_CANDIDATES", "Candidate", "FamilyError", "PointingLevel", "RecommendError", "Recommendation",
           "explain", "fmt_value", "load_table_check", "plan_snippet", "pointing_from_table_check", "recommend",
           "reference_noise", "resolve_candidates"]
