"""`bench schedules analyze | search`: first-order sensitivity, noise, duration, Monte Carlo, search."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from bench.cli.common import ExitCode, add_noise_arguments, fail, noise_from_args
from bench.cli.progress import CountProgress
from bench.config.units import FACES
from bench.errors import InputError
from bench.files import OutputFileError, make_output_folder
from bench.model.earth import Site
from bench.model.units import format_hms
from bench.plan.compiler import PlanError, PlanTiming, compile_plan
from schedules import ScheduleError, load_builtin, load_schedule, resolve_schedule


def register_tools(commands: argparse._SubParsersAction) -> None:
    """Add `analyze` and `search` to the `schedules` command's subparsers."""
    an = commands.add_parser("analyze", help="first-order black-box sensitivity, noise sigma, duration, Monte Carlo",
                             description="Analyse a position or rotation schedule: which black-box angles cancel "
                                         "at first order, the noise-driven 1-sigma per coefficient, the plan "
                                         "duration and a Monte-Carlo table beside the paper's optimal schedule.")
    an.add_argument("schedule", metavar="NAME|FILE",
                    help="a built-in schedule name (see bench schedules list) or a schedule TOML file")
    an.add_argument("--dwell-s", type=float, default=60.0, help="dwell per position, s (default 60)")
    an.add_argument("--turn-rate-dps", type=float, default=10.0,
                    help="turn rate of the turns that name none, deg/s (default 10)")
    an.add_argument("--with", dest="with_schedule", metavar="NAME|FILE",
                    help="the plan's other schedule (rotations with positions, or positions with rotations): the "
                         "extended model's part then says which families the two observe together")
    add_noise_arguments(an)
    an.add_argument("--runs", type=int, default=30, help="Monte-Carlo runs per level (default 30)")
    an.add_argument("--latitude", type=float, default=30.27, help="site latitude, deg (default 30.27)")
    an.add_argument("--config", metavar="FILE",
                    help="also analyse the plan as each unit of this configuration's [[imu]] entries sees it "
                         "through its mounting")
    an.add_argument("--mounting", metavar="FACE", action="append", choices=tuple(FACES), default=[],
                    help="also analyse the plan for a unit mounted on this face (repeatable): "
                         + ", ".join(FACES))
    an.set_defaults(func=cmd_analyze)

    se = commands.add_parser("search", help="exhaustive search of 24-position and 6-rotation schedules",
                             description="Enumerate every 24-position schedule of 12 of the 32 inner-symmetric "
                                         "groups and every 6-rotation set with one +u/-u turn pair per body "
                                         "axis; count those first-order equivalent to all-64 / all-96.")
    se.add_argument("--out", metavar="DIR", help="write the best schedules as TOML files here")
    se.add_argument("--best", type=int, default=3, help="how many of each kind to write (default 3)")
    se.add_argument("--groups", type=int, default=32, help=argparse.SUPPRESS)   # tests: first N groups only
    se.add_argument("--choose", type=int, default=12, help=argparse.SUPPRESS)   # tests: groups per schedule
    se.add_argument("--latitude", type=float, default=30.27, help="site latitude, deg (default 30.27)")
    se.set_defaults(func=cmd_search)


def _fmt(value: float, status: str) -> str:
    return f"{'0':>10}" if status == "0" else f"{value:>9.1e}{'*' if status == 'E' else ' '}"


def sensitivity_lines(sens) -> list[str]:
    """The table: one row per coefficient, one column per black-box angle (display unit per arcsec)."""
    # heavy (scipy): imported when the command runs, not for its --help
    from bench.schedule_design.sensitivity import ANGLE_NAMES

    short = [n.replace("outer", "o").replace("middle", "m").replace("inner", "i").replace("alpha", "a")
             .replace("beta", "b").replace("gamma", "g") for n in ANGLE_NAMES]
    lines = [f"{'coef':<7}{'unit/arcsec':<12}" + "".join(f"{s:>10}" for s in short)]
    status = sens.status()
    for i, name in enumerate(sens.names):
        lines.append(f"{name:<7}{sens.units[i]:<12}" + "".join(_fmt(v, st) for v, st in zip(sens.matrix[i], status[i])))
    lines.append("0 = cancels at first order; * = Earth-rate coupling only (vanishes with the Earth rate, "
                 "shrinks with faster turns)")
    for fam, angles in sens.families_remaining().items():
        geo = [ANGLE_NAMES[j] for j in range(9)
               if sens.remaining_geometric[[k for k, n in enumerate(sens.names) if n.startswith(fam)], j].any()]
        lines.append(f"  {fam}: remains {', '.join(geo) if geo else 'nothing'}"
                     + (f" (+ Earth coupling: {', '.join(a for a in angles if a not in geo)})"
                        if set(angles) - set(geo) else ""))
    return lines


def mountings_to_analyse(args: argparse.Namespace) -> list[tuple[str, np.ndarray | None]]:
    """(label, mounting `C_i^b` or None for the fixture's own axes) per unit of `--config`, then per `--mounting`.
    Raises InputError (ConfigError) for a configuration that does not load."""
    units: list[tuple[str, tuple[tuple[float, ...], ...] | None]] = []
    if args.config:
        from bench.config.load import load_config  # python-can, the drivers: only when a config is given

        config = load_config(args.config)
        if config.units:
            units += [(f"{u.identity.serial} ({u.mounting_name})", u.mounting) for u in config.units]
        else:                                   # one [imu]: the fixture's axes
            units.append((f"{config.imu.identity.serial or 'the IMU'} (z-up)", None))
    units += [(f"--mounting {face}", FACES[face]) for face in args.mounting]
    out: list[tuple[str, np.ndarray | None]] = []
    for label, rows in units:
        matrix = None if rows is None else np.array(rows, dtype=float)
        # the fixture's own axes: no rotation at all, so the figures are the single unit's exactly
        out.append((label, None if matrix is not None and np.array_equal(matrix, np.eye(3)) else matrix))
    return out


def _family_line(sigma: dict[str, float], units: dict[str, str], family: str) -> str:
    names = [n for n in sigma if n.split("_", 1)[0] == family]
    return f"    {family} ({units[names[0]]}): " + ", ".join(f"{n} {sigma[n]:.3g}" for n in names)


def unit_lines(label: str, figures: tuple) -> list[str]:
    """The observability of the plan for one unit: black-box angles left, noise 1-sigma, extended families."""
    # heavy (scipy): imported when the command runs, not for its --help
    from bench.schedule_design.extended import observability_lines

    sens, sigma, extended = figures
    units = dict(zip(sens.names, sens.units))
    lines = [f"unit {label}:", "  black box (first order): " + "; ".join(
        f"{fam} remains {', '.join(angles) if angles else 'nothing'}"
        for fam, angles in sens.families_remaining().items())]
    families = list(dict.fromkeys(n.split("_", 1)[0] for n in sigma))
    lines.append("  noise-driven 1-sigma:")
    lines += [_family_line(sigma, units, fam) for fam in families]
    # the coefficient worst observed against the best of its own family: the axis this mounting leaves weak
    spread = {fam: [n for n in sigma if n.split("_", 1)[0] == fam] for fam in families}
    ratio = {n: sigma[n] / min(sigma[m] for m in names) for names in spread.values() for n in names}
    worst = max(ratio, key=lambda n: ratio[n])
    lines.append(f"    least observed: {worst}, {ratio[worst]:.3g}x the best of its family" if ratio[worst] > 1.01
                 else "    least observed: none (every family's coefficients within 1 % of each other)")
    lines.append("  extended model:")
    lines += ["  " + line for line in observability_lines(extended)]
    return lines


def observability_of(angles, turns, noise, args: argparse.Namespace, site: Site, mounting, extended_plan) -> tuple:
    """(black-box sensitivity, noise 1-sigma per coefficient, extended families) of the plan for an IMU mounted
    with `mounting` (None: the fixture's axes); the extended families of `extended_plan` (positions' angles, turns:
    the schedule with its `--with` one). Raises SolverError."""
    # heavy (scipy): imported when the command runs, not for its --help
    from bench.schedule_design.extended import extended_observability
    from bench.schedule_design.sensitivity import (
        position_noise_sigma,
        position_sensitivity,
        rotation_noise_sigma,
        rotation_sensitivity,
    )

    if turns is not None:
        sens = rotation_sensitivity(turns, site=site, rate_dps=args.turn_rate_dps, mounting=mounting)
        sigma = rotation_noise_sigma(turns, noise, args.turn_rate_dps, site=site, mounting=mounting)
    else:
        sens = position_sensitivity(angles, site=site, mounting=mounting)
        sigma = position_noise_sigma(angles, noise, args.dwell_s, site=site, mounting=mounting)
    ext_angles, ext_turns = extended_plan
    extended = extended_observability(ext_angles, ext_turns, noise, args.dwell_s, args.turn_rate_dps, site=site,
                                      mounting=mounting)
    return sens, sigma, extended


def cmd_analyze(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy): imported when the command runs, not for its --help
    from bench.schedule_design.extended import observability_lines
    from bench.schedule_design.monte_carlo import evaluate
    from bench.solve.methods import SolverError

    if args.runs < 1 or args.dwell_s <= 0 or args.turn_rate_dps <= 0:
        return fail("bench schedules analyze", "--runs, --dwell-s and --turn-rate-dps must be positive", ExitCode.USAGE)
    try:
        schedule = resolve_schedule(args.schedule)
        other = None if args.with_schedule is None else resolve_schedule(args.with_schedule)
        site = Site(args.latitude)
    except ScheduleError as exc:
        print(exc, file=sys.stderr)
        return ExitCode.INVALID_SCHEDULE
    except InputError as exc:
        return fail("bench schedules analyze", str(exc), ExitCode.USAGE)
    try:
        mountings = mountings_to_analyse(args)
    except InputError as exc:
        return fail("bench schedules analyze", str(exc), ExitCode.USAGE)
    noise = noise_from_args(args)
    rotations = schedule.kind == "rotations"
    turns = list(schedule.rotations) if rotations else None
    angles = None if rotations else np.array([p.angles_deg for p in schedule.positions])
    wanted = "positions" if rotations else "rotations"
    if other is not None and other.kind != wanted:
        return fail("bench schedules analyze", f"--with {args.with_schedule}: a {other.kind!r} schedule; "
                    f"{schedule.name} ({schedule.kind}) goes with a {wanted!r} schedule", ExitCode.USAGE)
    # the extended families: this schedule with the --with one, if any (the lever arms need both kinds)
    ext_angles, ext_turns = (None, list(turns or [])) if rotations else (angles, [])
    if other is not None:
        if other.kind == "rotations":
            ext_turns = list(other.rotations)
        else:
            ext_angles = np.array([p.angles_deg for p in other.positions])
    try:
        sens, sigma, extended = observability_of(angles, turns, noise, args, site, None, (ext_angles, ext_turns))
        per_unit = [(label, observability_of(angles, turns, noise, args, site, mounting, (ext_angles, ext_turns)))
                    for label, mounting in mountings]
    except SolverError as exc:
        print(f"{schedule.source}: {exc}", file=sys.stderr)
        return ExitCode.INVALID_SCHEDULE
    print(f"schedule: {schedule.name} ({schedule.kind}, {len(schedule.steps)} steps) from {schedule.source}")
    print(f"\nFirst-order sensitivity to the nine black-box angles (simulated IMU, latitude {args.latitude} deg):")
    for line in sensitivity_lines(sens):
        print(line)
    setting = 'turn rate %g deg/s' % args.turn_rate_dps if rotations else 'dwell %g s' % args.dwell_s
    own_rates = sorted({t.rate_dps for t in schedule.rotations if t.rate_dps is not None})
    if own_rates:
        setting = "each turn at its own rate (" + ", ".join(f"{r:g}" for r in own_rates) + " deg/s)" + (
            f", the others at {args.turn_rate_dps:g} deg/s"
            if any(t.rate_dps is None for t in schedule.rotations) else "")
    print(f"\nNoise-driven 1-sigma ({setting}"
          f"; ARW {noise.gyro_arw_deg_rt_h} deg/rt h, VRW {noise.acc_vrw_ug_rt_hz} ug/rt Hz, bias instability "
          f"{noise.gyro_bias_instability_dph} deg/h / {noise.acc_bias_instability_ug} ug, "
          f"quantisation {'on' if noise.quantise else 'off'}):")
    for name, value in sigma.items():
        print(f"  {name:<7}{value:.3g} {sens.units[sens.names.index(name)]}")
    timing = PlanTiming(dwell_s=args.dwell_s, turn_rate_dps=args.turn_rate_dps)
    try:
        plan = compile_plan(None if rotations else schedule, schedule if rotations else None, timing)
        print(f"\nPlan duration estimate: {format_hms(plan.estimated_total_s)} "
              f"({plan.estimated_total_s:.0f} s; moves {plan.move_total_s:.0f} s)")
    except PlanError as exc:
        print(f"\nPlan duration: not compiled ({exc})")
    together = f"on its own ({setting}"
    if other is not None:
        together = f"together with {other.name} (dwell {args.dwell_s:g} s, turn rate {args.turn_rate_dps:g} deg/s"
    if other is not None and any(t.rate_dps is not None for t in ext_turns):
        together += " or the turn's own"
    print(f"\nExtended model (docs/explanation/extended-model.md): the higher-order families this schedule shows "
          f"{together}; predicted sample-noise 1-sigma, the simulated IMU):")
    for line in observability_lines(extended):
        print(line)
    if ext_turns:       # not predicted from the windows' means: it is seen inside the turns (bench.model.turn_timing)
        print(f"  {'time_offset':<20} not predicted here: seen inside turns about a horizontal axis, made CCW and CW "
              "from one start (docs/explanation/extended-model.md#time-offset)")
    if per_unit:
        print("\nPer unit: the same plan as each unit sees it through its mounting (its coefficients in its own "
              f"axes; {setting}):")
        for label, figures in per_unit:
            for line in unit_lines(label, figures):
                print(line)
    reference = "optimal-5s6r" if rotations else "optimal-24"
    keys: tuple[str, ...]
    if turns is not None:
        table = evaluate({}, {schedule.name: turns, reference: list(load_builtin(reference).rotations)},
                         runs=args.runs, site=site, rate_dps=args.turn_rate_dps)["rotations"]
        keys = ("gyro_scale", "gyro_axes")
    else:
        assert angles is not None
        ref_angles = np.array([p.angles_deg for p in load_builtin(reference).positions])
        table = evaluate({schedule.name: angles, reference: ref_angles}, {}, runs=args.runs, site=site)["positions"]
        keys = ("gyro_bias_dph", "acc_bias_g", "acc_scale", "acc_axes")
    print(f"\nMonte Carlo ({args.runs} runs per level, black box only; RSS over axes, RMS over runs):")
    print(f"{'level':>8} {'schedule':<22}" + "".join(f"{k:>15}" for k in keys))
    for row in table:
        print(f"{row['level_arcsec']:>7.1f}\" {row['method']:<22}" + "".join(f"{row[k]:>15.3e}" for k in keys))
    return ExitCode.OK


def cmd_search(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy): imported when the command runs, not for its --help
    from bench.schedule_design.search import (
        CRITERIA_TEXT,
        POSITION_GROUPS,
        combo_of_angles,
        combo_of_turns,
        search_positions,
        search_rotations,
        write_best,
    )

    if not 1 <= args.groups <= 32 or not 1 <= args.choose <= args.groups or args.best < 0:
        return fail("bench schedules search", "need 1 <= --choose <= --groups <= 32 and --best >= 0", ExitCode.USAGE)
    try:
        site = Site(args.latitude)
    except InputError as exc:
        return fail("bench schedules search", str(exc), ExitCode.USAGE)
    if args.out and args.best:
        try:    # the output folder is checked (and made) before the search, not after it
            make_output_folder(args.out)
        except OutputFileError as exc:
            return fail("bench schedules search", f"cannot write: {exc}", ExitCode.USAGE)
    started = time.perf_counter()
    groups = POSITION_GROUPS[:args.groups]
    # the position search takes tens of seconds: a bar on a terminal (stderr), in percent of the subsets
    bar = CountProgress(100, stream=sys.stderr)
    try:
        pos = search_positions(groups, args.choose, reference_groups=POSITION_GROUPS,
                               progress=lambda searched, total: bar.advance_to(100 * searched // max(total, 1)))
        rot = search_rotations(site=site)
    finally:
        bar.close()
    paper_pos = combo_of_angles([p.angles_deg for p in load_builtin("optimal-24").positions], groups)
    paper_rot = combo_of_turns(load_builtin("optimal-5s6r").rotations, rot.items)
    for result, label, paper, paper_name in ((pos, f"{2 * args.choose}-position schedules from "
                                              f"{args.choose} of {len(groups)} inner-symmetric groups",
                                              paper_pos, "optimal-24 (Table 1)"),
                                             (rot, "6-rotation sets, one +u/-u pair per body axis "
                                              f"(from the {len(rot.items)} rotations)", paper_rot,
                                              "optimal-5s6r (Table 3)")):
        print(f"{label}: {result.total:,} choices, searched exhaustively in {result.elapsed_s:.1f} s")
        for text, key in zip(CRITERIA_TEXT[result.kind], "abcd"):
            print(f"  {result.counts[key]:>13,}  {text}")
        if result.kind == "rotations":
            print(f"  {result.counts['earth_free']:>13,}  of (c) with no first-order Earth-rate coupling either")
        found = paper is not None and any(tuple(sorted(c)) == tuple(sorted(paper)) for c in result.optimal)
        print(f"  {paper_name}: {'among the optimal' if found else 'NOT among the optimal'}")
        if args.out and args.best:
            try:
                written = write_best(result, args.out, args.best)
            except OSError as exc:
                return fail("bench schedules search", f"cannot write to --out {args.out}: {exc.strerror or exc}",
                            ExitCode.USAGE)
            for path in written:
                load_schedule(path)  # every written file must load; raises ScheduleError otherwise
                print(f"  wrote {path}")
        print()
    print(f"total {time.perf_counter() - started:.1f} s; criteria are first order at a zero black box with an "
          "ideal IMU (a real IMU's first-order errors are a linear map of these)")
    if not args.out and args.best:
        print(f"no schedule files written: give --out DIR to write the best {args.best} of each kind as TOML")
    return ExitCode.OK
