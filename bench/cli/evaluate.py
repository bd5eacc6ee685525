"""`bench evaluate`: the paper's Monte-Carlo Tables 2 and 4, ours beside the paper's value."""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from bench.cli.common import ExitCode, add_scheduler_arguments, fail, task_progress
from bench.errors import InputError
from bench.files import write_output_text
from bench.model.earth import Site
from bench.model.families import ERROR_TITLES, POSITION_KEYS, ROTATION_KEYS
from bench.parallel import SchedulerError, check_scheduler, describe

PROG = "bench evaluate"


def register(sub: argparse._SubParsersAction) -> None:
    ev = sub.add_parser("evaluate",
                        description="Reproduce the paper's Tables 2 and 4: optimal vs traditional schedules at "
                                    "three black-box levels, ours beside the paper's value.")
    ev.add_argument("--runs", type=int, default=100, help="Monte-Carlo runs per level (default 100)")
    ev.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    ev.add_argument("--json", metavar="FILE", help="also write the table as JSON")
    ev.add_argument("--latitude", type=float, default=30.27, help="site latitude, deg (default Hangzhou 30.27)")
    ev.add_argument("--rate-dps", type=float, default=10.0, help="turn rate of the rotation method, deg/s (default 10)")
    add_scheduler_arguments(ev, default="loop", what="the Monte-Carlo chunks (2000 runs each) run",
                            after="; the table is the same to the last bit on any")
    ev.set_defaults(func=cmd_evaluate)


def _unwritable(path: Path) -> str:
    """Why `path` cannot be written as a file ('' if it looks writable): checked before the work."""
    folder = path.parent
    if path.is_dir():
        return "it is a folder"
    if not folder.is_dir():
        return f"folder {folder} does not exist" if not folder.exists() else f"{folder} is not a folder"
    if not os.access(folder, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        return "permission denied"
    return ""


def cmd_evaluate(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy): imported when the command runs, not for its --help
    from bench.schedule_design.monte_carlo import builtin_schedules, evaluate, paper_value

    if args.runs < 1:
        return fail(PROG, "--runs must be at least 1", ExitCode.USAGE)
    if args.rate_dps <= 0:
        return fail(PROG, "--rate-dps must be positive", ExitCode.USAGE)
    try:
        site = Site(args.latitude)
        check_scheduler(args.scheduler, args.workers)
    except InputError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    if args.json:
        problem = _unwritable(Path(args.json))
        if problem:     # before the work, not after it
            return fail(PROG, f"cannot write {args.json}: {problem}", ExitCode.USAGE)
    positions, rotations = builtin_schedules()
    started = time.perf_counter()
    try:
        table = evaluate(positions, rotations, runs=args.runs, seed=args.seed, site=site, rate_dps=args.rate_dps,
                         scheduler=args.scheduler, workers=args.workers,
                         progress=task_progress("Monte-Carlo chunks"))
    except SchedulerError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    elapsed = time.perf_counter() - started
    print(f"Monte-Carlo evaluation: {args.runs} runs per level, seed {args.seed}, latitude {args.latitude} deg, "
          f"black box only (noise-free IMU); {elapsed:.3f} s on {describe(args.scheduler, args.workers)}")
    print("each cell: ours (paper, ours/paper); error = RSS over axes per run, RMS over runs\n")
    for name, keys, caption in (("positions", POSITION_KEYS, "Positions: optimal-24 vs traditional-12 (paper Table 2)"),
                                ("rotations", ROTATION_KEYS,
                                 "Rotations: optimal-5s6r vs traditional-3s6r (paper Table 4)")):
        print(caption)
        print(f"{'level':>8} {'method':<12}" + "".join(f"{ERROR_TITLES[k]:<29}" for k in keys))
        for row in table[name]:
            cells = []
            for k in keys:
                paper = paper_value(name, row["level_arcsec"], row["method"], k)
                ref = f"({paper:.2e}, {row[k] / paper:5.2f})" if paper else "(-)"
                cells.append(f"{row[k]:.2e} {ref:<20}")
            print(f"{row['level_arcsec']:>7.1f}\" {row['method']:<12}" + "".join(cells))
        print()
    if args.json:
        try:
            write_output_text(args.json, json.dumps(table, indent=2) + "\n", option="--json")
        except InputError as exc:   # a run log
            return fail(PROG, str(exc), ExitCode.USAGE)
        except OSError as exc:
            return fail(PROG, f"cannot write {args.json}: {exc.strerror or exc}", ExitCode.USAGE)
        print(f"wrote {args.json}")
    return ExitCode.OK
