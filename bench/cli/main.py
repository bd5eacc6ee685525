"""The `bench` command line. Subcommands live in small modules; this file wires them."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from bench import __version__

EXIT_OK = 0
EXIT_USAGE = 2


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from bench.model.earth import Site
    from bench.schedule_design.monte_carlo import POSITION_KEYS, ROTATION_KEYS, builtin_schedules, evaluate, paper_value

    if args.runs < 1:
        print("bench evaluate: --runs must be at least 1", file=sys.stderr)
        return EXIT_USAGE
    if args.rate_dps <= 0:
        print("bench evaluate: --rate-dps must be positive", file=sys.stderr)
        return EXIT_USAGE
    try:
        site = Site(args.latitude)
    except ValueError as exc:
        print(f"bench evaluate: {exc}", file=sys.stderr)
        return EXIT_USAGE
    positions, rotations = builtin_schedules()
    started = time.perf_counter()
    table = evaluate(positions, rotations, runs=args.runs, seed=args.seed, site=site,
                     rate_dps=args.rate_dps)
    elapsed = time.perf_counter() - started
    print(f"Monte-Carlo evaluation: {args.runs} runs per level, seed {args.seed}, latitude {args.latitude} deg, "
          f"black box only (noise-free IMU); {elapsed:.3f} s")
    print("each cell: ours (paper, ours/paper); error = RSS over axes per run, RMS over runs\n")
    titles = {"gyro_bias_dph": "gyro bias deg/h", "acc_bias_g": "acc bias g", "acc_scale": "acc scale (rel)",
              "acc_axes": "acc axes", "gyro_scale": "gyro scale (rel)", "gyro_axes": "gyro axes"}
    for name, keys, caption in (("positions", POSITION_KEYS, "Positions: optimal-24 vs traditional-12 (paper Table 2)"),
                                ("rotations", ROTATION_KEYS,
                                 "Rotations: optimal-5s6r vs traditional-3s6r (paper Table 4)")):
        print(caption)
        print(f"{'level':>8} {'method':<12}" + "".join(f"{titles[k]:<29}" for k in keys))
        for row in table[name]:
            cells = []
            for k in keys:
                paper = paper_value(name, row["level_arcsec"], row["method"], k)
                ref = f"({paper:.2e}, {row[k] / paper:5.2f})" if paper else "(-)"
                cells.append(f"{row[k]:.2e} {ref:<20}")
            print(f"{row['level_arcsec']:>7.1f}\" {row['method']:<12}" + "".join(cells))
        print()
    if args.json:
        Path(args.json).write_text(json.dumps(table, indent=2) + "\n", encoding="utf-8")
        print(f"wrote {args.json}")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    from bench.cli import check_table as check_table_cli
    from bench.cli import replay as replay_cli
    from bench.cli import run as run_cli
    from bench.cli import schedules as schedules_cli
    from bench.cli import solve as solve_cli
    from bench.cli import table as table_cli
    from bench.cli import tui as tui_cli

    parser = argparse.ArgumentParser(prog="bench", description="IMU calibration on a three-axis turntable")
    parser.add_argument("--version", action="version", version=f"turntable-bench {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    ev = sub.add_parser("evaluate", help="Monte-Carlo tables of schedule errors under turntable pointing error",
                        description="Reproduce the paper's Tables 2 and 4: optimal vs traditional schedules at "
                                    "three black-box levels, ours beside the paper's value.")
    ev.add_argument("--runs", type=int, default=100, help="Monte-Carlo runs per level (default 100)")
    ev.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    ev.add_argument("--json", metavar="FILE", help="also write the table as JSON")
    ev.add_argument("--latitude", type=float, default=30.27, help="site latitude, deg (default Hangzhou 30.27)")
    ev.add_argument("--rate-dps", type=float, default=10.0, help="turn rate of the rotation method, deg/s")
    ev.set_defaults(func=_cmd_evaluate)

    run_cli.register(sub)
    tui_cli.register(sub)
    replay_cli.register(sub)
    solve_cli.register(sub)
    schedules_cli.register(sub)
    table_cli.register_table(sub)
    table_cli.register_sim(sub)
    check_table_cli.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("bench: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
