"""`bench schedules recommend`: the schedule pair, dwell and revolutions with the least predicted error in a budget."""

from __future__ import annotations

import argparse
import math

from bench.cli.common import (
    ExitCode,
    add_noise_arguments,
    add_scheduler_arguments,
    fail,
    noise_from_args,
    task_progress,
)
from bench.errors import InputError
from bench.files import write_output_text
from bench.model.earth import Site
from bench.model.families import DESIGN_UNITS, TITLES
from bench.model.units import format_hms
from bench.parallel import SchedulerError, check_scheduler
from schedules import ScheduleError

PROG = "bench schedules recommend"


def register_recommend(commands: argparse._SubParsersAction) -> None:
    """Add `recommend` to the `schedules` command's subparsers."""
    rc = commands.add_parser(
        "recommend", help="propose the schedules, dwell and revolutions for a time budget and a table",
        description="Predict, for every pair of a position and a rotation schedule and every dwell time and "
                    "number of revolutions on a small grid that fits the budget, the error of each coefficient "
                    "family from the table's pointing error (first-order sensitivity and a short Monte Carlo) "
                    "and the sensor noise, and recommend the plan with the lowest score.")
    rc.add_argument("--budget-s", type=float, required=True, metavar="SECONDS", help="time budget of the whole plan")
    level = rc.add_mutually_exclusive_group(required=True)
    level.add_argument("--pointing-arcsec", type=float, metavar="RMS", help="the table's pointing error, RMS per angle")
    level.add_argument("--check", metavar="FILE", help="a <run-id>.table-check.json written by `bench check-table`")
    add_noise_arguments(rc)
    rc.add_argument("--latitude", type=float, default=30.27, help="site latitude, deg (default 30.27)")
    rc.add_argument("--candidates", nargs="+", default=[], metavar="NAME|FILE",
                    help="more position or rotation schedules to consider (e.g. from `bench schedules search`)")
    rc.add_argument("--runs", type=int, default=64, help="Monte-Carlo draws for the second-order part (default 64)")
    rc.add_argument("--top", type=int, default=9, help="rows of the candidate table (default 9)")
    rc.add_argument("--write-config", metavar="FILE", help="write the recommended plan as a [plan] table here")
    add_scheduler_arguments(rc, default="loop", what="the predictions (a task per schedule, with its Monte Carlo) run",
                            after="; the result is the same on any")
    rc.set_defaults(func=cmd_recommend)


def _cell(e) -> str:
    return f"{e.total:>9.2e}{'B' if e.dominant == 'black box' else 'N'}"


def format_recommendation(rec, top: int = 9) -> list[str]:
    """The printed result: recommendation, per-family errors, candidate table, score, irreducible part, why."""
    # heavy (scipy): imported when the command runs, not for its --help
    from bench.schedule_design.recommend import FAMILIES, REFERENCE_PAIR, fmt_value

    best, n = rec.best, rec.noise
    lines = [f"table: {rec.level.source}"]
    lines += [f"  {note}" for note in rec.level.notes]
    lines.append(f"noise: ARW {n.gyro_arw_deg_rt_h} deg/rt h, VRW {n.acc_vrw_ug_rt_hz} ug/rt Hz, bias instability "
                 f"{n.gyro_bias_instability_dph} deg/h / {n.acc_bias_instability_ug} ug, quantisation "
                 f"{'on' if n.quantise else 'off'}")
    lines.append(f"budget {format_hms(rec.budget_s)} ({rec.budget_s:.0f} s): {rec.considered} plans considered, "
                 f"{len(rec.ranked)} fit")
    lines += ["", f"recommended: {best.pair}, dwell {best.dwell_s:g} s, {best.revolutions} rev: "
                  f"{format_hms(best.duration_s)} ({best.duration_s:.0f} s) of the {format_hms(rec.budget_s)} budget, "
                  f"score {best.score:.3g}", "",
              f"{'family':<12}{'unit':<8}{'total':>10}{'black box':>11}{'(1st':>10}{'2nd)':>10}{'noise':>10}  dominant"]
    for f in FAMILIES:
        e = best.errors[f]
        lines.append(f"{TITLES[f]:<12}{DESIGN_UNITS[f][0]:<8}{e.total:>10.2e}{e.black_box:>11.2e}"
                     f"{e.first_order:>10.2e}{e.second_order:>10.2e}{e.noise:>10.2e}  {e.dominant}")
    head = (f"{'#':>2} {'positions + rotations':<34}{'dwell':>6}{'rev':>4}{'duration':>9}{'score':>9} "
            + "".join(f"{TITLES[f][:11]:>11}" for f in FAMILIES))
    units = " " * 64 + "".join(f"{DESIGN_UNITS[f][0]:>11}" for f in FAMILIES)
    lines += ["", "best setting of each pair (B = black box dominates, N = noise):", head, units]
    for i, c in enumerate(rec.best_per_pair()[:top], 1):
        lines.append(f"{i:>2} {c.pair:<34}{c.dwell_s:>5g}s{c.revolutions:>4}{format_hms(c.duration_s):>9}"
                     f"{c.score:>9.3g} " + "".join(f"{_cell(c.errors[f]):>11}" for f in FAMILIES))
    ref = ", ".join(f"{TITLES[f]} {fmt_value(rec.reference[f], f)}" for f in FAMILIES)
    lines += ["", f"score = RMS over the six families of predicted total / reference; reference = noise alone of "
                  f"{REFERENCE_PAIR[0]} at {rec.timing.dwell_s:g} s dwell and {REFERENCE_PAIR[1]} as shipped "
                  f"(1 = the paper's optimal plan on a perfect table): {ref}"]
    irr = {f: best.errors[f].irreducible for f in ("Ea", "Eg")}
    if any(v > 0 for v in irr.values()):
        lines.append(f"not in the score: the inner frame's zero offset turns the IMU about the inner axis as its "
                     f"mounting would; every plan keeps it in acc axes ({fmt_value(irr['Ea'], 'Ea')}) and gyro "
                     f"axes ({fmt_value(irr['Eg'], 'Eg')}) XY/YX alike")
    lines += ["", "why:"] + [f"  {line}" for line in rec.why()]
    return lines


def cmd_recommend(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy): imported when the command runs, not for its --help
    from bench.schedule_design.recommend import (
        PointingLevel,
        RecommendError,
        load_table_check,
        plan_snippet,
        recommend,
        resolve_candidates,
    )

    noise_values = (args.gyro_arw, args.acc_vrw, args.gyro_bi, args.acc_bi)
    if not all(math.isfinite(v) and v >= 0 for v in noise_values):
        return fail(PROG, "the noise options must be finite and >= 0", ExitCode.USAGE)
    if args.runs < 1 or args.top < 1:
        return fail(PROG, "--runs and --top must be >= 1", ExitCode.USAGE)
    try:
        site = Site(args.latitude)
        check_scheduler(args.scheduler, args.workers)
    except InputError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    try:
        level = (load_table_check(args.check) if args.check is not None
                 else PointingLevel.uniform(args.pointing_arcsec))
        positions, rotations = resolve_candidates(args.candidates)
        rec = recommend(args.budget_s, level, noise_from_args(args), positions=positions, rotations=rotations,
                        site=site, runs=args.runs, scheduler=args.scheduler, workers=args.workers,
                        progress=task_progress("schedule predictions"))
    except ScheduleError as exc:
        return fail(PROG, str(exc), ExitCode.INVALID_SCHEDULE)
    except (RecommendError, SchedulerError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    for line in format_recommendation(rec, args.top):
        print(line)
    if args.write_config:
        try:
            write_output_text(args.write_config, plan_snippet(rec), [args.check] if args.check else [],
                              option="--write-config")
        except InputError as exc:   # a run log
            return fail(PROG, str(exc), ExitCode.USAGE)
        except OSError as exc:
            return fail(PROG, f"cannot write {args.write_config}: {exc.strerror or exc}", ExitCode.USAGE)
        print(f"\nwrote {args.write_config}: the [plan] table for `bench run --config` (replace your config's [plan])")
    return ExitCode.OK
